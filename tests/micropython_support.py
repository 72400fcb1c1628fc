"""Run Python scripts under MicroPython (the WebAssembly port, in Node) with the firmware.

    from micropython_support import run_micropython
    code, out = run_micropython("from lodestar.firmware import packet\\nprint('ok')")

``tools/micropython/run.mjs`` loads ``@micropython/micropython-webassembly-pyscript`` (the
exact version is pinned in ``tools/micropython/package.json`` and ``package-lock.json``;
install it with ``npm ci --prefix tools/micropython``), copies ``lodestar/__init__.py``,
``lodestar/contract.py`` and every ``firmware/*.py`` to ``/lib/lodestar/...`` in its
in-memory filesystem and runs the script.

When ``node`` or the installed package is missing the calling test is *skipped* with a
message saying how to install it -- unless the environment variable
``LODESTAR_REQUIRE_MICROPYTHON`` is set to a non-empty value other than ``0`` (CI), in which
case it *fails*, so a broken CI set-up cannot pass silently.
"""

import os

import pytest

from lodestar.regress import micropython
from tests import REPO

os.environ.setdefault(micropython.TOOL_ENV,
                      str(REPO / "tools" / "micropython"))
unavailable_reason = micropython.unavailable_reason


def require_micropython():
    """Skip the calling test (or fail it, under ``LODESTAR_REQUIRE_MICROPYTHON``) when
    MicroPython is unavailable."""
    reason = unavailable_reason()
    if reason is None:
        return
    if os.environ.get("LODESTAR_REQUIRE_MICROPYTHON", "") not in ("", "0"):
        pytest.fail("MicroPython required (LODESTAR_REQUIRE_MICROPYTHON is set) but " + reason)
    pytest.skip("MicroPython unavailable: " + reason)


def run_micropython(script_text, heapsize=None, timeout=120):
    """Run ``script_text`` under MicroPython with the MCU image on ``sys.path``: returns
    ``(returncode, output)``, 0 when the script finished, 1 when it raised (the traceback is
    in ``output``, stdout then stderr)."""
    require_micropython()
    proc = micropython.run(script_text, heapsize=heapsize, timeout=timeout)
    return proc.returncode, proc.stdout + proc.stderr
