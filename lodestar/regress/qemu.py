"""The flight computer on its own instruction set: MicroPython 1.27's qemu port built as an
STM32F401-class Cortex-M4F (``build-qemu.sh``: Thumb-2, hard single-precision FPU,
MicroPython's libm, the F401's 96 KiB RAM map, a fixed GC heap, object representation C)
with the MCU image and the regression set frozen into flash, run on QEMU's
``netduinoplus2`` (``run-qemu.py``).  The MCU reference of ``lodestar regress``: the set's
float32 expectations are this build's outcomes.

:func:`flight_build` stages and builds (cached under the cache folder by content hash, as
:mod:`lodestar.regress.unixport`'s builds; :func:`expectation_build` is the same with more
heap, for the expectations); :func:`flight_loop` replays runs in one QEMU run
(:mod:`lodestar.regress.qemuloop`: per-stage ticks through ``Settings.clock``, live peaks,
the stack's high-water mark, F-RAM reads); :func:`float32_outcomes` gives the expectations;
:func:`reference_build` and :func:`calibrate` turn ticks into F401 time with the published
``bm_float`` and ``bm_nqueens`` figures (:mod:`lodestar.regress.mcutime`);
:func:`memory_map` reads statics, heap, stack and flash from the ELF.  How each figure is
measured: ``docs/mcu_board.md``, "Measured on the Cortex-M4F build"."""

import fcntl
import hashlib
import json
import math
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

from lodestar.cache import default_cache_dir
from lodestar.regress import mcutime, unixport
from lodestar.regress.micropython import MicroPythonError

FLIGHT_HEAP = 72 * 1024
"""The flight build's GC heap (bytes), set by the flight loop: the executive with its link
needs 70,656 bytes over the set's estcube2 Pyramid runs (smallest heap in 512-byte steps;
the figure moves by a step or two with any change of the allocation pattern), so 72 KiB
keeps 3 KiB of margin.  The F401's 96 KiB less this heap and the 16 KiB stack leaves
:data:`STM32_STATICS` for the statics (0.8 KiB on this port)."""
SET_HEAP = 64 * 1024
"""The heap the regression set must replay in, every case and method, in the plain flight
loop (the flight packet buffer, no executive): issue 29's "the regression set on the ARM
build within 64 KB".  It needs 62,976 bytes (``docs/mcu_board.md``, "The flight heap")."""
RAM_BYTES = 96 * 1024
"""The F401's RAM (the build's link map)."""
FLASH_BYTES = 512 * 1024
"""The F401's flash."""
STACK_BUDGET = 16 * 1024
"""The stack the flight image reserves (bytes), against which the measured depth is held."""
STM32_STATICS = 8 * 1024
"""RAM (bytes) the flight heap and stack leave for the STM32 port's statics: twice their
estimate (2-4 KiB with the internal-flash filesystem off; its 16 KiB sector cache would not
fit).  An estimate until the flight build's map is read (``docs/mcu_board.md``)."""
REFERENCE_HEAP = 80 * 1024
"""The representation-A build's heap: the ``M=80`` of the published F401 run."""
EXPECTATION_HEAP = 80 * 1024
"""The heap of the build that gives a set's float32 expectations (:func:`float32_outcomes`):
the flight build's configuration with 8 KiB more heap (it still links in 96 KiB), so that
no case comes near running out and the outcomes are the arithmetic's.  At the flight heap
some frames have no margin: replayed after the whole set, estcube2_tracking_1dps with
Pyramid runs out of heap in tracking and solves lost in space instead (the same stars)."""
BUILD_NAME = f"micropython-1.27-qemu-cortex-m4f-repr-c-heap-{EXPECTATION_HEAP}"
"""The build of the expectations as a set's manifest names it (``float32.build``)."""
FROZEN_DATABASES = ("estcube2",)
"""Databases of the set frozen into flash as ``regset.db_<name>`` (``Database(buffer)``);
the others do not fit the emulated 1 MiB beside them and are read from host files through
the F-RAM model (:mod:`lodestar.regress.fram`)."""
QEMU_MODULES = ("qemuloop", "semihost", "fram", "linkmodel")
"""The modules of :mod:`lodestar.regress` that the Cortex-M4F image adds to the MCU image."""
TOOLS = ("arm-none-eabi-gcc", "qemu-system-arm", "make", "patch", "tar")
DEBIAN = "gcc-arm-none-eabi libnewlib-arm-none-eabi qemu-system-arm"


class Unavailable(unixport.Unavailable):
    """The Cortex-M4F build cannot be made or run here (the message says why)."""


def script_dir(repo=None):
    """The folder of ``build-qemu.sh`` and ``run-qemu.py``: beside ``build.sh``
    (``$LODESTAR_MICROPYTHON_BUILD``, else ``../shared/micropython`` beside checkout
    ``repo``); None when absent."""
    build = unixport.build_script(Path.cwd() if repo is None else Path(repo))
    folder = Path(os.environ.get(unixport.BUILD_ENV) or "").parent if build is None else \
        build.parent
    ok = all((folder / name).is_file() for name in ("build-qemu.sh", "run-qemu.py"))
    return folder if ok else None


def unavailable_reason(repo=None):
    """Why the Cortex-M4F build cannot be made and run from checkout ``repo`` here (a message
    with the fix), or None when it can."""
    repo = Path.cwd() if repo is None else Path(repo)
    if not (repo / "manifest.py").is_file():
        return f"no manifest.py (the MCU image's freeze manifest) in {repo}"
    if script_dir(repo) is None:
        return (f"no build-qemu.sh and run-qemu.py beside MicroPython's build.sh (set "
                f"{unixport.BUILD_ENV} or put ../shared/micropython beside the checkout)")
    for tool in TOOLS:
        if shutil.which(tool) is None:
            return f"{tool} is not installed (Debian: {DEBIAN})"
    return None


def check_available(repo=None):
    """Checkout ``repo`` (default the current directory) as a path; raises
    :class:`Unavailable` with :func:`unavailable_reason`."""
    repo = Path.cwd() if repo is None else Path(repo)
    reason = unavailable_reason(repo)
    if reason is not None:
        raise Unavailable(f"the Cortex-M4F build is unavailable: {reason}")
    return repo


def _write(path, text):
    """Write ``text`` to ``path`` unless it holds it already (an unchanged file keeps its
    time, so the incremental build does not re-freeze it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.is_file() or path.read_text(encoding="utf-8") != text:
        path.write_text(text, encoding="utf-8")


def stage_set(folder, manifest, set_dir, db_files, frozen=FROZEN_DATABASES):
    """Write the set as the frozen package ``regset`` into ``folder``: ``CASES`` (per case
    the JSON of ``[name, camera, packet offset, packet length, inputs]``), ``CAMERA_NAMES``,
    ``CAMERAS`` (each camera's settings as JSON), ``PACKETS`` (every packet, one bytes
    constant) and ``db_<name>.DATA`` for each database in ``frozen``: bytes constants, which
    a frozen module keeps in flash.  Returns ``folder``."""
    folder = Path(folder)
    packets, cases = bytearray(), []
    for case in manifest["cases"]:
        data = (Path(set_dir) / case["packet"]).read_bytes()
        cases.append(json.dumps([case["name"], case["camera"], len(packets), len(data),
                                 case["inputs"]]).encode())
        packets += data
    names = tuple(manifest["cameras"])
    cameras = tuple(json.dumps(manifest["cameras"][n]).encode() for n in names)
    _write(folder / "regset" / "__init__.py",
           '"""The regression set frozen into flash (lodestar.regress.qemu.stage_set)."""\n'
           f"CASES = {tuple(cases)!r}\nCAMERA_NAMES = {names!r}\nCAMERAS = {cameras!r}\n"
           f"PACKETS = {bytes(packets)!r}\n")
    for name in frozen:
        _write(folder / "regset" / f"db_{name}.py",
               f"DATA = {Path(db_files[name]).read_bytes()!r}\n")
    for old in (folder / "regset").glob("db_*.py"):
        if old.stem[3:] not in frozen:
            old.unlink()
    return folder


def _stage_image(folder, checkout):
    """The MCU image of ``checkout`` (None: this installation's) and :data:`QEMU_MODULES`."""
    image = unixport.stage_mcu_image(Path(folder), checkout, native=True)
    here = Path(__file__).parent
    for name in QEMU_MODULES:
        _write(image / "lodestar" / "regress" / f"{name}.py",
               (here / f"{name}.py").read_text(encoding="utf-8"))
    return image


def build(repo, out_dir, obj_repr="C", heap=FLIGHT_HEAP, data=None, checkout=None,
          timeout=1800):
    """Build (incrementally) the Cortex-M4F image with ``build-qemu.sh`` into ``out_dir``:
    object representation ``obj_repr``, a ``heap``-byte GC heap, the MCU image of
    ``checkout`` (None: this installation's; ``False``: nothing frozen) and the folder
    ``data`` (:func:`stage_set`) frozen.  Returns the path of a copy of ``firmware.elf``
    named by the build's content hash; builds into one folder take turns (a lock), and an
    unchanged build is not repeated.  Raises :class:`MicroPythonError` when it fails."""
    scripts = script_dir(repo)
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    with open(out_dir / ".build.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        env = dict(os.environ)
        env.pop("FROZEN_MANIFEST", None)
        h = hashlib.sha256(f"{obj_repr}\0{heap}\0".encode())
        files = sorted(scripts.iterdir())
        if checkout is not False:
            image = _stage_image(out_dir / "mcu-image", checkout)
            lines = [f"include({str((Path(repo) / 'manifest.py').resolve())!r})"]
            if data is not None:
                lines.append(f"package('regset', base_path={str(Path(data).resolve())!r})")
            manifest = out_dir / "manifest.py"
            _write(manifest, "\n".join(lines) + "\n")
            env.update(FROZEN_MANIFEST=str(manifest.resolve()),
                       LODESTAR_MCU_IMAGE=str(image.resolve()))
            files += [Path(repo) / "manifest.py", manifest] + sorted(image.rglob("*.py"))
            files += sorted(Path(data).rglob("*.py")) if data is not None else []
        for path in files:
            if path.is_file():
                h.update(path.name.encode() + b"\0" + path.read_bytes())
        key = h.hexdigest()[:16]
        elf = out_dir / f"firmware-{obj_repr}-{heap}-{key}.elf"
        if elf.is_file():
            return elf
        proc = subprocess.run(["bash", str(scripts / "build-qemu.sh"), str(out_dir / "mp"),
                               obj_repr, str(heap)], env=env, capture_output=True, text=True,
                              timeout=timeout)
        lines = proc.stdout.strip().splitlines()
        if proc.returncode != 0 or not lines or not Path(lines[-1]).is_file():
            raise MicroPythonError(f"the Cortex-M4F build failed (exit status "
                                   f"{proc.returncode}):\n"
                                   f"{(proc.stdout + proc.stderr).strip()[-2000:]}")
        for old in out_dir.glob(f"firmware-{obj_repr}-{heap}-*.elf"):
            old.unlink()
        tmp = elf.with_name(elf.name + ".tmp")
        shutil.copyfile(lines[-1], tmp)
        os.replace(tmp, elf)
        return elf


def _cache(cache_dir):
    return (Path(cache_dir) if cache_dir is not None else default_cache_dir()) / "qemu"


def flight_build(manifest, set_dir, db_files, cache_dir=None, repo=None, heap=FLIGHT_HEAP,
                 checkout=None, name=None):
    """The flight image (representation C, ``heap`` bytes of GC heap, the MCU image of
    ``checkout`` (None: this installation's) and the set of ``manifest`` in ``set_dir``
    with its databases ``db_files`` frozen, :func:`stage_set`) built under
    ``cache_dir/qemu/name`` (default :func:`lodestar.cache.default_cache_dir`, ``name``
    ``flight-HEAP``).  Raises :class:`Unavailable` when it cannot be built here."""
    repo = check_available(repo)
    folder = _cache(cache_dir) / (name or f"flight-{heap}")
    data = stage_set(folder / "data", manifest, set_dir, db_files)
    return build(repo, folder, "C", heap, data, checkout)


def expectation_build(manifest, set_dir, db_files, cache_dir=None, repo=None):
    """:func:`flight_build` with :data:`EXPECTATION_HEAP`: the build of the expectations."""
    return flight_build(manifest, set_dir, db_files, cache_dir, repo, EXPECTATION_HEAP)


def reference_build(cache_dir=None, repo=None):
    """The same MicroPython in representation A with :data:`REFERENCE_HEAP` and nothing
    frozen: the configuration of the published F401 figures (:func:`calibrate`)."""
    repo = check_available(repo)
    return build(repo, _cache(cache_dir) / "reference", "A", REFERENCE_HEAP, checkout=False)


SYSTICK_CSR = 0xE000E010
"""The Cortex-M SysTick's control register (the qemu port's millisecond interrupt)."""
SYSTICK_CVR = 0xE000E018
"""SysTick's current value: a write clears it, and the next period starts there."""
SYSTICK_ON = 7
"""``SYSTICK_CSR``: enabled, interrupting, on the processor clock (the port's ``ticks_init``)."""


def clock_restart(elf):
    """The lines :func:`run` puts before a script under ``-icount``: SysTick stopped, the
    port's millisecond count (``_ticks_ms``) zeroed and SysTick restarted from a cleared
    count.  While ``run-qemu.py`` feeds the script over the UART the guest busy-waits for
    each byte, for as many instructions as the host takes to deliver it, so without this the
    millisecond interrupt falls on other instructions in every run: ``ticks_us`` differences
    move by one, its exception frames leave other stale words on the stack, which the
    conservative collector takes for pointers, and a heap with little margin runs out in one
    run and not in the next (``docs/mcu_board.md``, "Heap and stack").  From these lines on,
    the same image and script execute the same instructions with the same interrupts."""
    def word(address):          # an address as a small int (two's complement), not a long
        return address - (1 << 32) if address >= 1 << 30 else address

    ticks = symbols(elf)["_ticks_ms"]
    return ("import machine\n"
            f"machine.mem32[{word(SYSTICK_CSR)}] = 0\n"
            f"machine.mem32[{word(ticks)}] = 0\n"
            f"machine.mem32[{word(SYSTICK_CVR)}] = 0\n"
            f"machine.mem32[{word(SYSTICK_CSR)}] = {SYSTICK_ON}\n"
            "del machine\n")


def run(elf, script, files=(), icount=True, timeout=1800, repo=None):
    """Run the MicroPython ``script`` (text) on ``elf`` under QEMU (``run-qemu.py``;
    ``icount``: guest time counts instructions, and the guest's clock restarts before the
    script, :func:`clock_restart`, so that a run repeats exactly) in a folder holding
    ``files`` (host paths, linked under their names, readable by
    :mod:`lodestar.regress.semihost`); returns the ``subprocess.CompletedProcess`` (exit
    status 1 with a traceback on stderr).  ``repo``: the checkout whose ``../shared`` holds
    ``run-qemu.py`` (:func:`script_dir`)."""
    runner = script_dir(repo)
    if icount:
        script = clock_restart(elf) + script
    with tempfile.TemporaryDirectory() as tmp:
        for path in files:
            os.symlink(Path(path).resolve(), Path(tmp) / Path(path).name)
        (Path(tmp) / "script.py").write_text(script, encoding="utf-8")
        cmd = ["python3", str(runner / "run-qemu.py"), str(Path(elf).resolve()), "script.py",
               "--timeout", str(timeout)] + (["--icount"] if icount else [])
        try:
            return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout + 60,
                                  cwd=tmp)
        except subprocess.TimeoutExpired:
            raise MicroPythonError(f"QEMU ran more than {timeout} s") from None


def symbols(elf):
    """``{name: address}`` of the ELF's symbols."""
    out = subprocess.run(["arm-none-eabi-nm", str(elf)], capture_output=True, text=True,
                         check=True).stdout
    return {w[2]: int(w[0], 16) for w in (line.split() for line in out.splitlines())
            if len(w) == 3}


def memory_map(elf, heap):
    """The image's budgets from its ELF: ``flash`` (text and initialised data, bytes),
    ``statics`` (data and bss without the ``heap``-byte GC heap), ``heap``, ``stack`` (the
    RAM left above them, where the stack grows down from the top), ``ram``."""
    sym = symbols(elf)
    data = sym["_edata"] - sym["_sdata"]
    bss = sym["_ebss"] - sym["_sbss"]
    return {"flash": sym["_etext"] + data, "statics": data + bss - heap, "heap": heap,
            "stack": sym["_estack"] - sym["_ebss"], "ram": RAM_BYTES,
            "stack_low": sym["_ebss"], "stack_top": sym["_estack"]}


def _runs_hex(manifest, runs):
    """The ``runs`` of :mod:`lodestar.regress.qemuloop`: case and method indices in hex."""
    index = {case["name"]: i for i, case in enumerate(manifest["cases"])}
    methods = list(manifest["methods"])
    return "".join(f"{index[case['name']]:02x}{methods.index(method):02x}"
                   for case, method in runs)


def flight_loop(elf, manifest, db_files, runs, heap=FLIGHT_HEAP, peak=False, timing=False,
                ballast=0, buffer_bytes=unixport.FLIGHT_BUFFER, frozen=FROZEN_DATABASES,
                executive=False, timeout=1800):
    """Replay ``runs`` (``[(case, method)]`` of ``manifest``, frozen into ``elf`` by
    :func:`flight_build` with a ``heap``-byte heap) in one QEMU run of
    :mod:`lodestar.regress.qemuloop` (under ``-icount``): a new tracker per run, one
    database open (frozen, else through the F-RAM model over the host file of
    ``db_files``), one ``buffer_bytes`` packet buffer.  ``peak``, ``timing``: as
    :func:`lodestar.regress.unixport.flight_loop` (ticks: the build's ``ticks_us`` under
    ``-icount``, :func:`calibrate` turns them into F401 time); ``ballast``: bytes of heap
    held away from the firmware (a smaller heap in the same build); ``executive``: each
    packet goes through the flight executive and its link (:mod:`lodestar.regress.linkmodel`
    serves it), whose buffer replaces the loop's, ``times`` then adds ``step``, and a
    packet the link refuses has the outcome None and its ``link`` code.  Returns
    :func:`lodestar.regress.unixport.flight_loop`'s dict plus ``io`` (per run the F-RAM
    ``[reads, bytes]``), ``heap`` (free and allocated before the first run) and ``stack``
    (``used``: the high-water mark, bytes)."""
    layout = memory_map(elf, heap)
    fram = {name: Path(path) for name, path in db_files.items() if name not in frozen}
    config = {"runs": _runs_hex(manifest, runs), "methods": list(manifest["methods"]),
              "databases": {name: ["frozen"] if name in frozen else
                            ["fram", fram[name].name] for name in db_files},
              "buffer_bytes": buffer_bytes, "peak": peak, "timing": timing,
              "ballast": ballast, "stack": [layout["stack_low"], layout["stack_top"]],
              "executive": executive}
    script = ("from lodestar.regress import qemuloop\n"
              f"qemuloop.main({json.dumps(config, separators=(',', ':'))!r})\n")
    proc = run(elf, script, fram.values(), timeout=timeout)
    out = unixport.loop_output(proc)
    out["io"], out["heap"], out["stack"], out["link"] = {}, None, None, {}
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            result = json.loads(line[len("RESULT "):])
            key = (result["case"], result["method"])
            if result.get("io") is not None:
                out["io"][key] = result["io"]
            if "link" in result:
                out["link"][key] = result["link"]
        elif line.startswith("HEAP "):
            out["heap"] = json.loads(line[len("HEAP "):])
        elif line.startswith("STACK "):
            out["stack"] = json.loads(line[len("STACK "):])
    return out


def float32_outcomes(elf, manifest, db_files, heap=EXPECTATION_HEAP):
    """``{(case name, method): outcome}`` of every case with each method on ``elf`` (built
    with a ``heap``-byte heap, :func:`expectation_build`) in one QEMU run; raises
    :class:`MicroPythonError` when the run does not finish."""
    runs = [(case, method) for method in manifest["methods"] for case in manifest["cases"]]
    loop = flight_loop(elf, manifest, db_files, runs, heap=heap)
    if not loop["finished"]:
        raise MicroPythonError(f"the Cortex-M4F replay did not finish:\n{loop['error']}")
    return {key: out for key, (out, _peak) in loop["results"].items()}


def calibrate(reference):
    """Each calibration benchmark of :mod:`lodestar.regress.mcutime` once on the
    representation-A ``reference`` (:func:`reference_build`) under ``-icount``: ``{"ticks":
    {name: ticks}, "ratio": {name: F401 us per tick}, "scale": their geometric mean}``, so
    F401 us = ticks x ``scale`` on any build of the same sources (an estimate: QEMU models
    no flash wait states, and the flight build is representation C)."""
    ticks = {}
    for name, (call, expect) in mcutime.CALLS.items():
        script = (mcutime.benchmark_source(name) + "\nimport time\nt0 = time.ticks_us()\n"
                  f"r = {call}\nprint('TICKS', time.ticks_diff(time.ticks_us(), t0), r)\n")
        proc = run(reference, script)
        line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("TICKS ")), "")
        words = line.split(" ", 2)
        if proc.returncode != 0 or len(words) != 3 or not words[2].startswith(expect):
            raise mcutime.CalibrationError(f"{name} on {reference}: "
                                           f"{(proc.stdout + proc.stderr)[-300:]}")
        ticks[name] = int(words[1])
    ratio = {name: mcutime.F401_US[name] / ticks[name] for name in ticks}
    scale = math.exp(sum(math.log(r) for r in ratio.values()) / len(ratio))
    return {"ticks": ticks, "ratio": ratio, "scale": scale}


def fram_read_ticks(elf, reads=2000, chunk=200):
    """Ticks one read of a star database costs the guest more through
    ``Database.fram`` than from a buffer (``_FramSource`` against ``_BufferSource``, a
    12-byte ``unpack``) with a bus whose four calls do nothing (Python methods here, where
    the board's ``machine.SPI`` and ``Pin`` are C: an upper bound): a frame's F-RAM time is
    its buffer time plus its reads times this plus their wire time
    (:func:`lodestar.regress.fram.wire_us`).  The two readers alternate in runs of
    ``chunk`` reads, each after a collection with the threshold off, so no collection
    falls in a run (with the import's threshold, or a full heap, one did in either and
    the difference came out anywhere from -25 to +39 ticks)."""
    script = f"""import gc
import time
from lodestar.firmware import database
class Bus:
    def write(self, b):
        pass
    def readinto(self, b, w=0):
        pass
    def value(self, v=None):
        pass
bus = Bus()
fr = database._FramSource(bus, bus, 0, 4096)
mem = database._BufferSource(bytearray(4096))
def a(n):
    for _ in range(n):
        fr.unpack("<fff", 0, 12)
def b(n):
    for _ in range(n):
        mem.unpack("<fff", 0, 12)
gc.threshold(-1)
spent = 0
for _ in range({reads // chunk}):
    gc.collect()
    t0 = time.ticks_us()
    a({chunk})
    t1 = time.ticks_us()
    gc.collect()
    t2 = time.ticks_us()
    b({chunk})
    spent += time.ticks_diff(t1, t0) - time.ticks_diff(time.ticks_us(), t2)
print('TICKS', spent)
"""
    proc = run(elf, script)
    line = next((ln for ln in proc.stdout.splitlines() if ln.startswith("TICKS ")), None)
    if proc.returncode != 0 or line is None:
        raise MicroPythonError(f"the F-RAM read timing failed: {proc.stdout + proc.stderr}")
    return int(line.split()[1]) / (reads // chunk * chunk)
