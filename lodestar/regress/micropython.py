"""MicroPython 1.27 (WebAssembly port under Node.js): the one runner of scripts with the MCU
image (:func:`run`), and the regression set replayed on it with the time and heap of every
solve (:func:`replay`).

The tool folder is ``tools/micropython`` of the checkout (``npm ci --prefix
tools/micropython``) or ``$LODESTAR_MICROPYTHON_TOOL``; its ``run.mjs`` runs a script with
:func:`mcu_image` under ``/lib/lodestar`` and, for a replay, :mod:`lodestar.regress.mcu`, the
databases and the packet files under ``/regress``, read by offset and from files as on the
MCU.  :func:`replay` reports per solve ``live_before``, ``alloc`` (an upper bound of the peak
heap) and ``ms`` (WebAssembly wall time, not an MCU's), and the ``resident`` heap per run:
``docs/regression.md`` says how each is measured.
"""

import json
import math
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import lodestar
from lodestar import contract, firmware
from lodestar.regress import mcu

PACKAGE = "@micropython/micropython-webassembly-pyscript"
TOOL_ENV = "LODESTAR_MICROPYTHON_TOOL"
INSTALL_HINT = "npm ci --prefix tools/micropython"
TARGET_DIR = "/regress"
"""Folder of the copied databases and packets in MicroPython's filesystem."""


class MicroPythonError(RuntimeError):
    """MicroPython is unavailable, or the replay script failed (the message says which)."""


def tool_dir():
    """The folder of ``run.mjs`` and its ``node_modules``: ``$LODESTAR_MICROPYTHON_TOOL``, or
    ``tools/micropython`` under the current directory (the checkout's root)."""
    return Path(os.environ.get(TOOL_ENV) or Path.cwd() / "tools" / "micropython")


def unavailable_reason():
    """Why MicroPython cannot run here (a message with the fix), or None when it can."""
    if shutil.which("node") is None:
        return "node is not installed (MicroPython runs in Node.js, v18 or later)"
    if not (tool_dir() / "node_modules" / PACKAGE / "package.json").is_file():
        return (f"{PACKAGE} is not installed in {tool_dir()}: run `{INSTALL_HINT}` from the "
                f"repository root (or set {TOOL_ENV})")
    return None


def _package_files(package, target):
    root = Path(package.__file__).parent
    return [(path, target + "/" + path.relative_to(root).as_posix())
            for path in sorted(root.rglob("*.py"))]


def mcu_image():
    """``[(host path, target path)]`` of the modules the MCU holds: the ``lodestar`` root
    (``__init__.py``), :mod:`lodestar.contract` and :mod:`lodestar.firmware`, under
    ``/lib/lodestar``."""
    return ([(Path(lodestar.__file__), "/lib/lodestar/__init__.py")]
            + _package_files(contract, "/lib/lodestar/contract")
            + _package_files(firmware, "/lib/lodestar/firmware"))


def run(script_text, copies=(), heapsize=None, timeout=120):
    """Run ``script_text`` under MicroPython with :func:`mcu_image` and ``copies`` (more
    ``(host path, target path)`` pairs) in its filesystem; returns the finished
    ``subprocess.CompletedProcess`` (text output; exit status 0 when the script finished, 1
    when it raised, the traceback on stderr).  ``heapsize``: bytes of initial heap (the port
    grows it on demand).  Raises :class:`MicroPythonError` when MicroPython is unavailable
    or the script runs longer than ``timeout`` seconds."""
    reason = unavailable_reason()
    if reason is not None:
        raise MicroPythonError("MicroPython unavailable: " + reason)
    with tempfile.TemporaryDirectory() as tmp:
        script = Path(tmp) / "script.py"
        script.write_text(script_text, encoding="utf-8")
        command = ["node", str(tool_dir() / "run.mjs")]
        if heapsize is not None:
            command += ["--heapsize", str(int(heapsize))]
        for host, target in mcu_image() + list(copies):
            command += ["--copy", f"{os.path.abspath(host)}={target}"]
        command.append(str(script))
        try:
            return subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise MicroPythonError(f"the MicroPython script ran more than {timeout} s") \
                from None


def literal(value):
    """MicroPython source text for a JSON-like ``value`` (None, bool, int, finite float, str,
    list, tuple, dict)."""
    if isinstance(value, float):
        if not math.isfinite(value):
            raise ValueError(f"no literal for the non-finite float {value!r}")
        return repr(value)
    if value is None or isinstance(value, (bool, int, str)):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(literal(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(literal(k) + ": " + literal(v) for k, v in value.items()) + "}"
    raise TypeError(f"no literal for {value!r}")


_PRELUDE = r'''
import gc
import json
from js import performance
RESIDENT = {"start": gc.mem_alloc()}
from lodestar.regress import mcu as R
from lodestar.firmware import tracking
from lodestar.firmware import starid
for _m in METHODS:
    starid.method(_m)
gc.collect()
#@split
RESIDENT["code"] = gc.mem_alloc()
DBS = {}
for _name in DB_PATHS:
    DBS[_name] = R.open_database(DB_PATHS[_name])
gc.collect()
#@split
RESIDENT["databases"] = gc.mem_alloc()
TRACKERS = {}
for _cam in CAMERAS:
    for _m in METHODS:
        TRACKERS[_cam + "/" + _m] = R.make_tracker(DBS[CAMERAS[_cam]["database"]],
                                                   CAMERAS[_cam], _m)
gc.collect()
#@split
RESIDENT["trackers"] = gc.mem_alloc()
print("RESIDENT " + json.dumps(RESIDENT))
gc.collect()
'''

_SOLVE = r'''
#@split
LIVE = gc.mem_alloc()
_f = open({path}, "rb")
PKT = _f.read()
_f.close()
_f = None
gc.disable()
T0 = performance.now()
BASE = gc.mem_alloc()
OUT = R.replay(TRACKERS[{tracker}], PKT, {inputs})
ALLOC = gc.mem_alloc() - BASE
MS = performance.now() - T0
gc.enable()
print("RESULT " + json.dumps({{"case": {case}, "method": {method}, "repeat": {repeat},
                              "live_before": LIVE, "ms": MS, "alloc": ALLOC, "out": OUT}}))
PKT = OUT = None
gc.collect()
'''

_END = r'''
#@split
print("LIVE_END " + str(gc.mem_alloc()))
print("DONE")
'''


def build_script(manifest, methods, repeats=1):
    """The MicroPython script replaying every case of ``manifest`` (a loaded set, see
    :mod:`lodestar.regress`) with each of ``methods``, ``repeats`` times."""
    db_paths = {name: f"{TARGET_DIR}/{name}.lsdb" for name in manifest["databases"]}
    parts = ["DB_PATHS = " + literal(db_paths),
             "CAMERAS = " + literal(manifest["cameras"]),
             "METHODS = " + literal(list(methods)),
             _PRELUDE]
    for case in manifest["cases"]:
        for method in methods:
            for repeat in range(repeats):
                parts.append(_SOLVE.format(
                    path=literal(f"{TARGET_DIR}/{case['packet']}"),
                    tracker=literal(case["camera"] + "/" + method),
                    inputs=literal(case["inputs"]), case=literal(case["name"]),
                    method=literal(method), repeat=repeat))
    parts.append(_END)
    return "\n".join(parts)


def replay(manifest, set_dir, database_files, methods, repeats=1, timeout=900):
    """Run the set on MicroPython: ``{"results": [...], "resident": {...}, "live_end": n}``.

    ``database_files``: ``{database name: host path}`` (the images the set's recipes
    build).  Each result: ``case``, ``method``, ``repeat``, ``live_before``, ``alloc`` (bytes),
    ``ms`` and ``out`` (:func:`lodestar.regress.mcu.outcome`).  Raises
    :class:`MicroPythonError` when MicroPython is unavailable or the script fails."""
    set_dir = Path(set_dir)
    copies = [(Path(mcu.__file__).with_name("__init__.py"), "/lib/lodestar/regress/__init__.py"),
              (Path(mcu.__file__), "/lib/lodestar/regress/mcu.py")]
    copies += [(Path(path), f"{TARGET_DIR}/{name}.lsdb")
               for name, path in database_files.items()]
    copies += [(set_dir / case["packet"], f"{TARGET_DIR}/{case['packet']}")
               for case in manifest["cases"]]
    proc = run(build_script(manifest, methods, repeats), copies, timeout=timeout)
    return parse_output(proc.returncode, proc.stdout, proc.stderr)


def parse_output(returncode, stdout, stderr):
    """The :func:`replay` dict from the runner's exit status and output; raises
    :class:`MicroPythonError` when the script did not finish."""
    lines = stdout.splitlines()
    if returncode != 0 or "DONE" not in lines:
        tail = "\n".join((stdout + stderr).strip().splitlines()[-20:])
        raise MicroPythonError(f"the MicroPython replay failed (exit status {returncode}):\n"
                               f"{tail}")
    out = {"results": [], "resident": None, "live_end": None}
    for line in lines:
        if line.startswith("RESULT "):
            out["results"].append(json.loads(line[len("RESULT "):]))
        elif line.startswith("RESIDENT "):
            out["resident"] = json.loads(line[len("RESIDENT "):])
        elif line.startswith("LIVE_END "):
            out["live_end"] = int(line[len("LIVE_END "):])
    return out
