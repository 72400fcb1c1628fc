"""MicroPython 1.27's unix port as the flight MCU runs it: built 32-bit with single-precision
floats stored in the object word (``MICROPY_OBJ_REPR_C``) and the MCU image frozen (bytecode
in "flash"), then the regression set replayed as a flight loop with a fixed heap.

:func:`build` builds the interpreter with MicroPython's ``build.sh`` and the repository's
``manifest.py``; :func:`flight_loop` replays cases one after another in one process, with
only the current camera's database open, as the flight software would; :func:`min_heap`
bisects the smallest heap with which a loop still gives the recorded results;
:func:`float32_build` and :func:`float32_outcomes` give the set's float32 expectations
(recorded and replayed by ``lodestar regress``); :func:`reference_build` is the same
MicroPython in the STM32 port's default object representation, which ran the published F401
benchmarks (:mod:`lodestar.regress.mcutime`).  How each figure is measured:
``docs/regression.md``, "A real MicroPython".
"""

import fcntl
import hashlib
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import tempfile
from pathlib import Path

from lodestar import contract as C
from lodestar.cache import default_cache_dir
from lodestar.regress import reprprobe
from lodestar.regress.micropython import MicroPythonError, mcu_image, write_runs

BUILD_ENV = "LODESTAR_MICROPYTHON_BUILD"
"""Environment variable naming MicroPython's ``build.sh`` (else ``../shared/micropython``
beside the checkout)."""

HEAP_STEP = 2048
"""Resolution of :func:`min_heap`, bytes."""

FLIGHT_BUFFER = C.packet_bytes(C.FLIGHT_RECORD_CAPACITY)
"""The flight SPI loop's packet buffer (bytes): the largest packet the flight gateware sends
(``docs/mcu_board.md``), whatever packets a loop replays (:func:`flight_loop`'s
``buffer_bytes``)."""

EXPECTATION_HEAP = 4 << 20
"""Heap (bytes) of the replays that give the float32 expectations: no case comes near it, so
they are the arithmetic's results; the flight heap budget is tested on its own."""

PORT_COPT = "-Os"
"""The unix port's own ``COPT`` (its ``Makefile``'s default), which a build's ``COPT``
replaces and so repeats."""

SSE_COPT = f"{PORT_COPT} -msse2 -mfpmath=sse"
"""The unix port's ``COPT`` on x86 hosts: its own plus SSE floating point, so every
single-precision operation is rounded to float32 as on the Cortex-M4F's FPU.  The i686
default (x87) keeps intermediates in 80-bit registers: 6 of the set's 84 replays then differ
from the x86-64 build, one attitude by 0.67 arcsec; with SSE the 32-bit and the 64-bit
build gave bit-identical results (object representation ``A``, ``docs/regression.md``)."""

OBJ_REPRS = {"A": "", "C": "-DMICROPY_OBJ_REPR=MICROPY_OBJ_REPR_C"}
"""MicroPython's object representations a build can have (``py/mpconfig.h``), as additions
to its ``COPT``.  ``A``: MicroPython's default and the STM32 port's; every float result is
a 16-byte heap object.  ``C``: a float is stored in the 32-bit object word itself (30 bits:
float32 with the two lowest significand bits dropped, a 22-bit significand), so float
arithmetic allocates nothing; it needs 32-bit words and single-precision floats."""

FLIGHT_REPR = "C"
"""The flight build's object representation (:data:`OBJ_REPRS`), as the flight board's
``mpconfigboard.h`` sets it: on the regression set 31-43 % fewer instructions per frame at
the median and 4-10 KiB smaller flight-loop heaps than ``A`` (``docs/mcu_board.md``)."""

NO_32BIT = ("the C compiler cannot build 32-bit programs (cc -m32; Debian: install "
            "gcc-multilib), which the flight build's MICROPY_OBJ_REPR_C needs")
"""Why the flight build cannot be made without a 32-bit target, and the fix."""

M32_PROBE = "int main(void){return 0;}"
"""The C program ``build.sh`` links with ``cc -m32`` to choose a 32-bit build."""


class Unavailable(MicroPythonError):
    """The float32 build cannot be made on this machine (the message says why)."""


def unavailable_reason(repo=None):
    """Why the unix port cannot be built from checkout ``repo`` here (a message with the
    fix), or None when it can.  ``repo`` (its ``manifest.py``, ``../shared`` beside it):
    default the current directory, the checkout's root (as
    :func:`lodestar.regress.micropython.tool_dir`)."""
    repo = Path.cwd() if repo is None else Path(repo)
    if not (repo / "manifest.py").is_file():
        return (f"no manifest.py (the MCU image's freeze manifest) in {repo}: run from the "
                "checkout's root")
    if build_script(repo) is None:
        return (f"no MicroPython build script (set {BUILD_ENV} or put ../shared/micropython "
                "beside the checkout)")
    for tool in ("make", "cc", "patch", "tar"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed (needed to build MicroPython)"
    if not links_32bit():
        return NO_32BIT
    return None


def links_32bit():
    """Whether the C compiler (``$CC``, default ``cc``) links :data:`M32_PROBE` with
    ``-m32``: ``build.sh``'s test for a 32-bit build (else it builds 64-bit)."""
    with tempfile.TemporaryDirectory() as tmp:
        try:
            proc = subprocess.run(_cc() + ["-m32", "-x", "c", "-", "-o", str(Path(tmp) / "a")],
                                  input=M32_PROBE, capture_output=True, text=True, timeout=120)
        except OSError:
            return False
    return proc.returncode == 0


def _cc():
    """The C compiler command, as ``build.sh`` runs it (``$CC`` split into words)."""
    return shlex.split(os.environ.get("CC") or "cc")


def float32_build(cache_dir=None, repo=None):
    """The flight MCU's interpreter (:func:`build`: ``float32``, :data:`FLIGHT_REPR`, the MCU
    image frozen by the ``manifest.py`` of checkout ``repo``, default the current directory)
    under ``cache_dir/micropython`` (default :func:`lodestar.cache.default_cache_dir`).
    Raises :class:`Unavailable` when it cannot be built here, :class:`MicroPythonError` when
    the build fails."""
    repo = _available(repo)
    return build(build_script(repo), repo / "manifest.py", _cache(cache_dir), "float32")


def reference_build(cache_dir=None, repo=None):
    """The flight build's MicroPython in the STM32 port's default object representation
    (``A``), float32 and nothing frozen: the configuration that ran the published F401
    benchmarks, which calibrate :mod:`lodestar.regress.mcutime` (they are not the firmware:
    a plain interpreter runs them as a frozen one does).  Built beside :func:`float32_build`
    once (36 s here) and reused while MicroPython's build folder and the flags stay the same;
    raises as :func:`float32_build`."""
    repo = _available(repo)
    return build(build_script(repo), None, _cache(cache_dir), "float32", obj_repr="A")


def _available(repo):
    """Checkout ``repo`` (default the current directory) as a path; raises
    :class:`Unavailable` with :func:`unavailable_reason`."""
    repo = Path.cwd() if repo is None else Path(repo)
    reason = unavailable_reason(repo)
    if reason is not None:
        raise Unavailable(f"the float32 MicroPython build is unavailable: {reason}")
    return repo


def _cache(cache_dir):
    """The builds' folder: ``micropython`` in ``cache_dir`` (default
    :func:`lodestar.cache.default_cache_dir`)."""
    return (Path(cache_dir) if cache_dir is not None else default_cache_dir()) / "micropython"


def build_script(repo):
    """MicroPython's ``build.sh``: ``$LODESTAR_MICROPYTHON_BUILD``, else
    ``../shared/micropython/build.sh`` beside the checkout ``repo``; None when absent."""
    path = Path(os.environ.get(BUILD_ENV) or Path(repo).parent / "shared" / "micropython" /
                "build.sh")
    return path if path.is_file() else None


_NATIVE_IMPORT = re.compile(rb"^from (\.+|lodestar\.firmware\.)emit import native$")


def native_source(data):
    """The module source ``data`` (bytes) for a build whose compiler emits machine code
    (:mod:`lodestar.firmware.emit`): each line ``@native`` becomes ``@micropython.native``
    (same indentation) and ``from .emit import native`` (or ``lodestar.firmware.emit``)
    becomes ``import micropython``; every other line, and the line numbers, stay."""
    lines = data.split(b"\n")
    for i, line in enumerate(lines):
        if line.strip() == b"@native":
            lines[i] = line[:len(line) - len(line.lstrip())] + b"@micropython.native"
        elif _NATIVE_IMPORT.match(line):
            lines[i] = b"import micropython"
    return b"\n".join(lines)


def stage_mcu_image(folder, checkout=None, native=False):
    """Copy :func:`lodestar.regress.micropython.mcu_image` of ``checkout`` (None: this
    installation's) into ``folder`` as the tree ``lodestar/...`` that a freeze manifest
    packages (only changed files are rewritten and files no longer in the image removed, so
    an incremental build re-freezes only what changed); returns ``folder``.  ``native``: for
    a build with a native emitter (the Cortex-M4F build), each module through
    :func:`native_source`."""
    folder = Path(folder)
    wanted = {folder / target: Path(host) for host, target in mcu_image(checkout)}
    if folder.exists():
        for old in sorted(folder.rglob("*"), reverse=True):     # files before their folders
            if old.is_file() and old not in wanted:
                old.unlink()
            elif old.is_dir() and not any(old.iterdir()):
                old.rmdir()
    for dest, host in wanted.items():
        data = host.read_bytes()
        if native:
            data = native_source(data)
        if not dest.is_file() or dest.read_bytes() != data:   # unchanged files keep their
            dest.parent.mkdir(parents=True, exist_ok=True)     # time: no re-freeze
            dest.write_bytes(data)
    return folder


def build(script, manifest, out_dir, variant="float32", checkout=None, obj_repr=FLIGHT_REPR,
          timeout=1200):
    """Build (incrementally) the unix-port interpreter ``variant`` (``float32`` or
    ``double``) in object representation ``obj_repr`` (:data:`OBJ_REPRS`; ``C`` needs
    ``float32`` and a compiler that can target ``-m32``) with the MCU image frozen by
    ``manifest`` (the repository's ``manifest.py``; None: nothing frozen) using MicroPython's
    build ``script``; returns the path of a copy named by its content (the build's own name,
    which says 32- or 64-bit, the representation and a hash), which no later build
    overwrites while it runs.  Each representation builds in its own folder,
    ``out_dir/repr-a`` or ``out_dir/repr-c``: ``build.sh`` names a binary and its build
    folder by variant and word size only, so two representations in one folder would
    rebuild each other.  Builds into one folder take turns (a lock file).  ``checkout``:
    freeze another checkout's image (:func:`stage_mcu_image`).  Raises :class:`Unavailable`
    for ``C`` without a 32-bit compiler, :class:`MicroPythonError` when the build fails."""
    if obj_repr == "C" and variant != "float32":
        raise ValueError(f"MICROPY_OBJ_REPR_C needs single-precision floats, not {variant}")
    if obj_repr == "C" and not links_32bit():
        raise Unavailable(NO_32BIT)
    out_dir = Path(out_dir) / f"repr-{obj_repr.lower()}"
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        image = None if manifest is None else stage_mcu_image(out_dir / "mcu-image", checkout)
        key = _build_key(script, manifest, image, variant, obj_repr)
        known = out_dir / f".{variant}{'' if manifest is None else '-frozen'}-built"
        if known.is_file():
            last_key, _, last = known.read_text().partition(" ")
            if last_key == key and Path(last).is_file():
                return Path(last)        # build.sh rewrites its config header: a full rebuild
        env = dict(os.environ, COPT=_copt(obj_repr))
        env.pop("FROZEN_MANIFEST", None)
        if manifest is None:             # build.sh reuses a plain binary: build this one
            for bits in (32, 64):
                (out_dir / f"micropython-{variant}-{bits}").unlink(missing_ok=True)
        else:
            env.update(FROZEN_MANIFEST=str(Path(manifest).resolve()),
                       LODESTAR_MCU_IMAGE=str(image.resolve()))
        proc = subprocess.run(["bash", str(script), str(out_dir), variant], env=env,
                              capture_output=True, text=True, timeout=timeout)
        lines = proc.stdout.strip().splitlines()
        if proc.returncode != 0 or not lines or not Path(lines[-1]).is_file():
            raise MicroPythonError(f"the MicroPython build failed (exit status "
                                   f"{proc.returncode}):\n"
                                   f"{(proc.stdout + proc.stderr).strip()[-2000:]}")
        built = Path(lines[-1])
        data = built.read_bytes()
        name = f"{built.name}-repr-{obj_repr.lower()}"
        copy = built.with_name(f"{name}-{hashlib.sha256(data).hexdigest()[:12]}")
        if not copy.is_file():
            tmp = copy.with_name(copy.name + ".tmp")
            tmp.write_bytes(data)
            tmp.chmod(0o755)
            os.replace(tmp, copy)
        for old in built.parent.glob(name + "-*"):
            if old != copy:
                old.unlink(missing_ok=True)     # a running copy keeps its inode
        known.write_text(f"{key} {copy}")
        return copy


def _build_key(script, manifest, image, variant, obj_repr):
    """Hash of everything a build depends on: MicroPython's build folder (script, sources,
    patch), the manifest and the staged image (when frozen), the variant, the object
    representation, the C compiler and its flags."""
    h = hashlib.sha256(f"{variant}\0{obj_repr}\0{os.environ.get('CC', 'cc')}\0"
                       f"{_copt(obj_repr)}\0".encode())
    for path in sorted(Path(script).parent.iterdir()) + ([] if manifest is None else
                                                         [Path(manifest)]):
        if path.is_file():
            h.update(path.name.encode() + b"\0" + path.read_bytes())
    for path in sorted(Path(image).rglob("*.py")) if image is not None else []:
        h.update(path.relative_to(image).as_posix().encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def _copt(obj_repr):
    """The build's ``COPT``: :data:`SSE_COPT` on x86 hosts, else :data:`PORT_COPT`, and the
    object representation's flag (:data:`OBJ_REPRS`)."""
    x86 = platform.machine().lower() in ("x86_64", "amd64", "i386", "i686")
    return " ".join(f for f in (SSE_COPT if x86 else PORT_COPT, OBJ_REPRS[obj_repr]) if f)


def object_representation(binary, timeout=60):
    """The object representation of MicroPython ``binary`` (:data:`OBJ_REPRS`), observed:
    ``C`` when 100 more float products allocate nothing more and ``1 + 2**-22`` is 1 (a
    22-bit significand), ``A`` when they allocate and the sum keeps float32's 24 bits.
    Raises :class:`MicroPythonError` for anything else (:mod:`lodestar.regress.reprprobe`,
    run as a script)."""
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.run([str(binary), str(Path(reprprobe.__file__).resolve())],
                              capture_output=True, text=True, timeout=timeout, cwd=tmp)
    words = proc.stdout.split()
    if proc.returncode == 0 and len(words) == 2 and words[0].isdigit():
        boxed, rounded = int(words[0]) > 0, words[1] == "True"
        if boxed != rounded:
            return "A" if boxed else "C"
    raise MicroPythonError(f"no object representation from {binary}: "
                           f"{(proc.stdout + proc.stderr).strip()[-300:]}")


def flight_loop(binary, manifest, set_dir, database_files, runs, heapsize, peak=False,
                threshold=None, timing=False, timeout=900, buffer_bytes=None):
    """Replay ``runs`` (``[(case, method)]``, ``case`` a manifest case) in order in one
    ``binary`` process (:mod:`lodestar.regress.loop`, frozen) with a ``heapsize``-byte heap,
    a new tracker per run, only the current camera's database open and one packet buffer
    (sized for the longest packet, read into and passed as a ``memoryview``, as the flight
    SPI loop does).  ``peak``: also measure
    each solve's live peak above the heap before it (``loop.sample_peaks``: a collection
    every 512 bytes, the firmware's own collections off; ``gc.live_peak()`` of
    MicroPython's ``build.sh``).  ``threshold``: a ``gc.threshold`` (bytes) the loop sets before its
    first run (None: the firmware's).
    ``timing``: also time each solve (``time.ticks_us``, the pipeline's stage ``timings``).
    ``buffer_bytes``: the packet buffer's size (:data:`FLIGHT_BUFFER` for the flight
    loop's); None: the longest packet of ``runs``.

    Returns ``{"finished": bool, "results": {(case name, method): (outcome, peak bytes or
    None)}, "times": {(case name, method): {"process": us, stage: us}}, "resident":
    {database: bytes live with it open}, "error": output tail}``; a run that ran out of heap
    outside the firmware leaves ``finished`` false."""
    set_dir = Path(set_dir)
    longest = max([(set_dir / case["packet"]).stat().st_size for case, _ in runs] + [1])
    if buffer_bytes is not None:
        if buffer_bytes < longest:
            raise MicroPythonError(f"a {buffer_bytes}-byte packet buffer cannot hold the "
                                   f"longest packet of the runs ({longest} bytes)")
        longest = buffer_bytes
    with tempfile.TemporaryDirectory() as tmp:
        write_runs(Path(tmp) / "runs.jsonl", manifest, runs,
                   lambda name: str(Path(database_files[name]).resolve()),
                   lambda case: str((set_dir / case["packet"]).resolve()))
        config = Path(tmp) / "loop.json"
        config.write_text(json.dumps({"runs": str(Path(tmp) / "runs.jsonl"), "peak": peak,
                                      "threshold": threshold, "timing": timing,
                                      "buffer_bytes": longest}), encoding="utf-8")
        try:
            proc = subprocess.run([str(binary), "-X", f"heapsize={int(heapsize)}", "-m",
                                   "lodestar.regress.loop", str(config)],
                                  capture_output=True, text=True, timeout=timeout, cwd=tmp)
        except subprocess.TimeoutExpired:
            raise MicroPythonError(f"the flight loop ran more than {timeout} s") from None
    return loop_output(proc)


def loop_output(proc):
    """The :func:`flight_loop` dict of a finished flight-loop process."""
    out = {"finished": False, "results": {}, "times": {}, "resident": {},
           "error": (proc.stdout + proc.stderr).strip()[-2000:]}
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            result = json.loads(line[len("RESULT "):])
            key = (result["case"], result["method"])
            out["results"][key] = (result["out"], result["peak"])
            if result["times"] is not None:
                out["times"][key] = result["times"]
        elif line.startswith("OPENED "):
            name, live = json.loads(line[len("OPENED "):])
            out["resident"].setdefault(name, live)      # at its first opening
    out["finished"] = proc.returncode == 0 and "DONE" in proc.stdout.splitlines()
    return out


def disagreements(loop, runs):
    """The ``(case name, method)`` of ``runs`` whose status or identified stars differ from
    the recorded ones in a :func:`flight_loop` result (all of them if it did not finish)."""
    bad = []
    for case, method in runs:
        got = loop["results"].get((case["name"], method))
        want = case["expected"][method]
        if not loop["finished"] or got is None or \
                (got[0]["status"], got[0]["matches"]) != (want["status"], want["matches"]):
            bad.append((case["name"], method))
    return bad


def float32_outcomes(binary, manifest, set_dir, database_files):
    """``{(case name, method): outcome}`` of every case of the set with each of its methods,
    replayed on the float32 ``binary`` in one :func:`flight_loop` at
    :data:`EXPECTATION_HEAP` (the outcomes do not depend on the order or the heap: measured
    bit-identical).  Raises :class:`MicroPythonError` when the loop does not finish."""
    runs = [(case, method) for method in manifest["methods"] for case in manifest["cases"]]
    loop = flight_loop(binary, manifest, set_dir, database_files, runs, EXPECTATION_HEAP)
    if not loop["finished"]:
        raise MicroPythonError(f"the float32 replay did not finish:\n{loop['error']}")
    return {key: out for key, (out, _peak) in loop["results"].items()}


def min_heap(binary, manifest, set_dir, database_files, runs, threshold=None,
             low=16 * 1024, high=256 * 1024, buffer_bytes=None):
    """The smallest heap (a multiple of :data:`HEAP_STEP` in ``(low, high]``) with which
    :func:`flight_loop` of ``runs`` (``threshold`` and ``buffer_bytes`` as there) finishes
    with the recorded results, found by bisection;
    None when ``high`` does not suffice.  Assumes that more heap never hurts."""
    def fits(heap):
        loop = flight_loop(binary, manifest, set_dir, database_files, runs, heap,
                           threshold=threshold, buffer_bytes=buffer_bytes)
        return not disagreements(loop, runs)

    low, high = low // HEAP_STEP, high // HEAP_STEP
    if not fits(high * HEAP_STEP):
        return None
    while high - low > 1:
        mid = (low + high) // 2
        if fits(mid * HEAP_STEP):
            high = mid
        else:
            low = mid
    return high * HEAP_STEP
