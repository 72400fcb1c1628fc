"""MicroPython 1.27 (WebAssembly port under Node.js): the MCU image (:func:`mcu_image`, the
one definition, which the unix port freezes too), the one runner of scripts with it
(:func:`run`), and the regression set replayed on it with the time and heap of every solve
(:func:`replay`).

The tool folder is ``tools/micropython`` of the checkout (``npm ci --prefix
tools/micropython``) or ``$LODESTAR_MICROPYTHON_TOOL``; its ``run.mjs`` runs a script with
:func:`mcu_image` under ``/lib`` and, for a replay, the loop's config and run file, the
databases and the packet files under ``/regress``, read by offset and from files as on the
MCU.  :func:`replay` reports per solve ``live_before``, ``alloc`` (an upper bound of the peak
heap) and ``ms`` (WebAssembly wall time, not an MCU's), and the ``resident`` heap per run:
``docs/regression.md`` says how each is measured.
"""

import importlib
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import lodestar
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


IMAGE_PACKAGES = ("lodestar.contract", "lodestar.firmware")
"""The packages the MCU image holds whole, besides the ``lodestar`` root's ``__init__.py``."""

CHECKOUT_FOLDERS = {"lodestar.contract": "lodestar/contract", "lodestar.firmware": "firmware"}
"""Where a checkout's source tree holds each of :data:`IMAGE_PACKAGES` (``pyproject.toml``'s
``package-dir``), for an image taken from another checkout."""

IMAGE_REGRESS = ("__init__", "mcu", "loop")
"""The MCU side of the regression (:mod:`lodestar.regress`), also in the image: the replay of
one packet (:mod:`.mcu`) and the loop of both runners (:mod:`.loop`)."""


def mcu_image(checkout=None):
    """``[(host path, image path)]`` of the modules the MCU holds, image paths relative to its
    library folder (``lodestar/firmware/pipeline.py``): the ``lodestar`` root,
    :mod:`lodestar.contract`, :mod:`lodestar.firmware` and :data:`IMAGE_REGRESS`.
    ``checkout``: the root, contract and firmware of another checkout's source tree instead
    of the installed ones (a benchmark's baseline; :data:`CHECKOUT_FOLDERS`), replayed by this
    installation's regression modules."""
    if checkout is None:
        pairs = [(Path(lodestar.__file__), "lodestar/__init__.py")]
        folders = [(Path(importlib.import_module(name).__file__).parent, name)
                   for name in IMAGE_PACKAGES]
    else:
        checkout = Path(checkout)
        pairs = [(checkout / "lodestar" / "__init__.py", "lodestar/__init__.py")]
        folders = [(checkout / CHECKOUT_FOLDERS[name], name) for name in IMAGE_PACKAGES]
    for folder, name in folders:
        target = name.replace(".", "/")
        pairs += [(path, target + "/" + path.relative_to(folder).as_posix())
                  for path in sorted(folder.rglob("*.py"))]
    regress = Path(mcu.__file__).parent
    return pairs + [(regress / (name + ".py"), "lodestar/regress/" + name + ".py")
                    for name in IMAGE_REGRESS]


def run(script_text, copies=(), heapsize=None, timeout=120):
    """Run ``script_text`` under MicroPython with :func:`mcu_image` (under ``/lib``) and
    ``copies`` (more ``(host path, target path)`` pairs) in its filesystem; returns the finished
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
        image = [(host, "/lib/" + target) for host, target in mcu_image()]
        for host, target in image + list(copies):
            command += ["--copy", f"{os.path.abspath(host)}={target}"]
        command.append(str(script))
        try:
            return subprocess.run(command, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            raise MicroPythonError(f"the MicroPython script ran more than {timeout} s") \
                from None


STUB = ("from js import performance\n"
        "from lodestar.regress import loop\n"
        f"STEPS = loop.replay({TARGET_DIR + '/replay.json'!r}, performance.now)\n")
"""The script of a replay: :func:`lodestar.regress.loop.replay`, stepped by ``run.mjs``, with
Node's millisecond clock."""


def write_runs(path, manifest, runs, database_path, packet_path):
    """Write ``runs`` (``[(case, method)]``, ``case`` a case of ``manifest``) to ``path`` as
    the JSON-lines run file of :mod:`lodestar.regress.loop`, the files as the interpreter
    opens them: ``database_path(name)``, ``packet_path(case)``."""
    with open(path, "w", encoding="utf-8") as f:
        for case, method in runs:
            camera = manifest["cameras"][case["camera"]]
            f.write(json.dumps([case["name"], method, case["camera"], camera["database"],
                                database_path(camera["database"]), camera,
                                packet_path(case), case["inputs"]]) + "\n")


def replay(manifest, set_dir, database_files, methods, repeats=1, timeout=900):
    """Run the set on MicroPython: ``{"results": [...], "resident": {...}, "live_end": n}``.

    ``database_files``: ``{database name: host path}`` (the images the set's recipes
    build).  Every case with each of ``methods``, ``repeats`` times, by
    :func:`lodestar.regress.loop.replay` with everything resident.  Each result: ``case``,
    ``method``, ``repeat``, ``live_before``, ``alloc`` (bytes), ``ms`` and ``out``
    (:func:`lodestar.regress.mcu.outcome`).  Raises :class:`MicroPythonError` when MicroPython
    is unavailable or the script fails."""
    set_dir = Path(set_dir)
    databases = {name: f"{TARGET_DIR}/{name}.lsdb" for name in manifest["databases"]}
    with tempfile.TemporaryDirectory() as tmp:
        write_runs(Path(tmp) / "runs.jsonl", manifest,
                   [(case, method) for case in manifest["cases"] for method in methods],
                   databases.get, lambda case: f"{TARGET_DIR}/{case['packet']}")
        (Path(tmp) / "replay.json").write_text(json.dumps({
            "runs": f"{TARGET_DIR}/runs.jsonl", "repeats": repeats,
            "resident": {"databases": databases, "cameras": manifest["cameras"],
                         "methods": list(methods)}}), encoding="utf-8")
        copies = [(Path(tmp) / name, f"{TARGET_DIR}/{name}")
                  for name in ("replay.json", "runs.jsonl")]
        copies += [(Path(path), databases[name]) for name, path in database_files.items()]
        copies += [(set_dir / case["packet"], f"{TARGET_DIR}/{case['packet']}")
                   for case in manifest["cases"]]
        proc = run(STUB, copies, timeout=timeout)
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
