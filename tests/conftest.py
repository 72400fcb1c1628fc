"""Shared fixtures: MicroPython (the firmware as the MCU runs it) and the work record of
the identification searches.

``micropython(script, heapsize=None, timeout=120)`` runs a script under MicroPython 1.27
with the MCU image (:func:`lodestar.regress.micropython.run`) and returns ``(exit status,
output)``; ``require_micropython`` makes a test need it.  When ``node`` or the npm package
is missing, such a test is skipped with the install command, or fails when
``LODESTAR_REQUIRE_MICROPYTHON`` is set (CI), so a broken set-up cannot pass silently.
Fixtures of one package live in its folder's ``conftest.py`` (firmware: star-id set-up per
method and cameras; hdl: ``tests/hdl/streams.py`` for Amaranth stream testbenches)."""

import os

import pytest

from lodestar.firmware.starid import search
from lodestar.regress import micropython as _micropython
from tests import REPO


@pytest.fixture(autouse=True, scope="session")
def _micropython_tool():
    """The checkout's ``tools/micropython`` for the runner (unless the environment names
    another)."""
    os.environ.setdefault(_micropython.TOOL_ENV, str(REPO / "tools" / "micropython"))


def _require():
    reason = _micropython.unavailable_reason()
    if reason is None:
        return
    if os.environ.get("LODESTAR_REQUIRE_MICROPYTHON", "") not in ("", "0"):
        pytest.fail("MicroPython required (LODESTAR_REQUIRE_MICROPYTHON is set) but " + reason)
    pytest.skip("MicroPython unavailable: " + reason)


@pytest.fixture
def require_micropython():
    """Skip (or under ``LODESTAR_REQUIRE_MICROPYTHON`` fail) when MicroPython is missing."""
    _require()


@pytest.fixture
def micropython(require_micropython):
    """Run a script under MicroPython: ``(exit status, stdout + stderr)``."""
    def run(script_text, heapsize=None, timeout=120):
        _require()
        proc = _micropython.run(script_text, heapsize=heapsize, timeout=timeout)
        return proc.returncode, proc.stdout + proc.stderr
    return run


@pytest.fixture
def work_spent(monkeypatch):
    """``[(work, max_work), ...]``: the work each identification search spent, in call order
    (for calls that reach the search through the pipeline or the ground solve)."""
    spent = []
    run = search.Search.run

    def recording(self, patterns, budget):
        try:
            return run(self, patterns, budget)
        finally:
            spent.append((self.work, self.max_work))

    monkeypatch.setattr(search.Search, "run", recording)
    return spent
