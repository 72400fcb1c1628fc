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
import shutil
import subprocess
import tempfile
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TOOL_DIR = REPO / "tools" / "micropython"
RUNNER = TOOL_DIR / "run.mjs"
PACKAGE = "@micropython/micropython-webassembly-pyscript"
PACKAGE_DIR = TOOL_DIR / "node_modules" / PACKAGE
INSTALL_HINT = "npm ci --prefix tools/micropython"


def unavailable_reason():
    """Why MicroPython cannot run here (a message), or None when it can."""
    if shutil.which("node") is None:
        return "node is not installed (MicroPython runs in Node.js, v18 or later)"
    if not (PACKAGE_DIR / "package.json").is_file():
        return "{} is not installed in {}: run `{}` from the repository root".format(
            PACKAGE, TOOL_DIR.relative_to(REPO) / "node_modules", INSTALL_HINT)
    return None


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
    """Run ``script_text`` under MicroPython with the firmware on ``sys.path``.

    Returns ``(returncode, output)``: 0 when the script finished, 1 when it raised (the
    traceback is in ``output``, which merges stdout and stderr).  ``heapsize``: bytes of
    MicroPython heap (``run.mjs`` default 1 MiB; the pyscript build can grow it).
    """
    require_micropython()
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "script.py"
        script.write_text(script_text, encoding="utf-8")
        command = ["node", str(RUNNER)]
        if heapsize is not None:
            command += ["--heapsize", str(int(heapsize))]
        command.append(str(script))
        proc = subprocess.run(command, cwd=str(REPO), stdout=subprocess.PIPE,
                              stderr=subprocess.STDOUT, timeout=timeout)
    return proc.returncode, proc.stdout.decode("utf-8", "replace")
