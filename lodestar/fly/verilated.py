"""The Verilated board top level as the twin's gateware engine: ``GatewareTop`` (the board's
sensor front end, frame watchdog, detector, packetizer and SPI slave) built once per
configuration with Verilator into a shared library (``lodestar/cosim/top_native.cpp``) and
driven pin by pin through ctypes.

    top = VerilatedTop(BOARDS["estcube2"].gateware_top())   # built and cached once
    top.frame(pixels)                                  # PIXCLK, LINE_VALID, FRAME_VALID, D
    top.cs(0); miso = top.xfer(b"S" + bytes(9)); top.cs(1)

Every byte the MCU side reads is the gateware's; the registers it writes change what the
detector does.  Clocks: ``sync`` at the board's 100 MHz and PIXCLK (:data:`PIX_PS`).
Time is compressed where the gateware idles: a row's horizontal blanking is :data:`HBLANK`
PIXCLKs (not the sensor's 900) and the vertical blanking the detector's ``min_vblank`` plus
a margin; transactions run between frames (``docs/fly.md``).  The board's microsecond
counter is set to each frame's instant on the twin's clock before the frame
(:data:`PUBLIC`), so the header timestamps are the board's, not the compressed time's.
Build cache:
``<cache>/fly/``, keyed by the parameters, the gateware sources and the harness; a lock
serialises processes wanting the same build.
"""

import ctypes
import fcntl
import hashlib
import os
import shutil
import subprocess
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar import hdl
from lodestar.cache import default_cache_dir
from lodestar.cosim import runner
from lodestar.hdl.boards import GatewareTop
from lodestar.hdl.detector import min_vblank
from lodestar.hdl.export import to_verilog
from lodestar.hdl.frontend import STALL_TIMEOUT
from lodestar.hdl.labeller import MIN_HBLANK

HARNESS = Path(runner.__file__).with_name("top_native.cpp")
SYNC_PS = 10000
"""The board's ``sync`` clock period (100 MHz)."""
PIX_PS = SYNC_PS
PIX_OFFSET_PS = 0
"""PIXCLK period and phase: the sync clock's, in phase (the MT9P031 runs at 96 MHz on the
board; at 100 MHz in phase the two clocks share every eval, which halves the simulation
time; the clock-domain crossing itself is verified by the cocotb board tests)."""
SCK_HZ = 10.5e6
"""The MCU's SPI clock (84 MHz / 8, ``docs/mcu_board.md``)."""
HBLANK = 16
"""PIXCLKs of horizontal blanking played per row (compressed; module docstring)."""
CS_SETUP_PS = 6 * SYNC_PS
CS_HOLD_PS = 3 * SYNC_PS
CS_GAP_PS = 4 * SYNC_PS
"""Chip-select timing above the slave's minimums (setup 4, hold 2, high 3 clocks)."""

PUBLIC = """`verilator_config
public_flat_rw -module "top" -var "timestamp"
public_flat_rw -module "top" -var "pre"
"""
"""Verilator configuration: the board's microsecond counter and its prescaler, which the
harness sets before each frame (``twin_set_time``: compressed time, module docstring)."""
_ARGS = ["-Wno-fatal", "-Wno-lint", "-O3", "--x-assign", "fast", "--x-initial", "fast",
         "--cc", "--exe", "--build", "--top-module", "top", "--prefix", "Vtop",
         "-CFLAGS", "-fPIC", "-LDFLAGS", "-shared", "-o", "libtop.so"]


def _digest(params):
    h = hashlib.sha256(repr(params).encode() + repr(_ARGS).encode() + PUBLIC.encode())
    files = [p for package in (hdl, C)
             for p in sorted(Path(package.__file__).resolve().parent.rglob("*.py"))]
    for f in files + [HARNESS]:
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()[:16]


def build(top, root=None, log=None):
    """The folder of the shared library of ``top`` (a ``GatewareTop``), Verilated and
    compiled unless a build of the same parameters and sources exists."""
    params = (top.sensor, top.width, top.height, top.detector.label_capacity,
              top.detector.record_capacity, top.detector.record_depth)
    root = Path(root) if root else Path(default_cache_dir()) / "fly"
    folder = root / ("top-{}x{}-{}".format(top.width, top.height, _digest(params)))
    folder.mkdir(parents=True, exist_ok=True)
    runner.verilator_env()
    with open(folder / "lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (folder / "built").exists():
            if log:
                log(f"fly: building the gateware top with Verilator in {folder} (once)")
            (folder / "top.v").write_text(to_verilog(top, "top"))
            (folder / "top.vlt").write_text(PUBLIC)
            shutil.copy(HARNESS, folder / HARNESS.name)
            jobs = str(len(os.sched_getaffinity(0)))
            cmd = ["verilator", *_ARGS, "-j", jobs, "-Mdir", str(folder), HARNESS.name,
                   "top.vlt", "top.v"]
            with open(folder / "build.log", "w") as out:
                done = subprocess.run(cmd, cwd=folder, stdout=out, stderr=subprocess.STDOUT)
            if done.returncode:
                raise RuntimeError(f"Verilator build failed; see {folder / 'build.log'}")
            (folder / "built").write_text("ok\n")
    return folder


def _bind(lib):
    p, u32 = ctypes.c_void_p, ctypes.c_uint32
    sigs = {"twin_new": ([u32, u32, u32], p), "twin_free": ([p], None),
            "twin_irq": ([p], ctypes.c_int), "twin_pll_losses": ([p, u32], None),
            "twin_set_time": ([p, u32], None),
            "twin_frame": ([p, p, u32, u32, u32, u32], None),
            "twin_cs": ([p, ctypes.c_int, u32, u32, u32], None),
            "twin_xfer": ([p, p, p, u32, u32], None)}
    for name, (args, res) in sigs.items():
        fn = getattr(lib, name)
        fn.argtypes, fn.restype = args, res
    return lib


class VerilatedTop:
    """One Verilated ``GatewareTop`` instance (its state starts at power-up).  ``width``,
    ``height``, ``pixel_bits``, ``build_id``: the top's; ``vblank``: PIXCLKs played after a
    frame (the detector's worst mode's ``min_vblank`` plus 64)."""

    def __init__(self, top, root=None, log=None, sck_hz=SCK_HZ):
        folder = build(top, root, log)
        self._lib = _bind(ctypes.CDLL(str(folder / "libtop.so"), mode=ctypes.RTLD_LOCAL))
        self._h = self._lib.twin_new(SYNC_PS, PIX_PS, PIX_OFFSET_PS)
        self.width, self.height, self.pixel_bits = top.width, top.height, top.pixel_bits
        self.build_id = top.build
        self.vblank = max(min_vblank(top.width, top.height, top.pixel_bits, mode)
                          for mode in range(len(C.MODE_NAMES))) + 64
        self.half_ps = int(round(0.5e12 / sck_hz))
        self.losses = 0

    @classmethod
    def small(cls, width, height, record_capacity, root=None, log=None):
        """An MT9P031 top of another frame (tests: a small window)."""
        return cls(GatewareTop("mt9p031", width, height, record_capacity=record_capacity,
                               record_depth=2 * record_capacity), root, log)

    def close(self):
        if self._h:
            self._lib.twin_free(self._h)
            self._h = None

    def __del__(self):
        self.close()

    # ---- the engine interface (lodestar.fly.bus) -----------------------------------------

    def irq(self):
        return bool(self._lib.twin_irq(self._h))

    def frame(self, pixels, rows=None, start_us=0):
        """Play ``pixels`` (``height x width``), only its first ``rows`` rows if given; a
        frame cut short is followed by the idle clocks in which the frame watchdog completes
        it as on the board (its stall timeout, then the missing rows in dark pixels, one per
        clock with ``MIN_HBLANK`` after each row: at 2592 x 1944 and 100 MHz, 10.5 + 25 ms,
        long before the sensor's next frame), so it ends ``FRAME_TIMEOUT`` and raises the
        IRQ before the next frame starts (too few clocks and the next frame's first pixel
        ends it ``FRAME_TRUNCATED`` a period late: compressed time must not join the two).
        ``start_us``: the frame's first pixel on the twin's clock, where the board's
        microsecond counter is set before the frame (compressed time), so the gateware
        stamps it with that instant."""
        data = np.ascontiguousarray(pixels, dtype=np.uint16)
        h, w = data.shape
        rows = h if rows is None else max(0, min(rows, h))
        vblank = self.vblank
        if rows < h:
            vblank += STALL_TIMEOUT + (h - rows) * (w + MIN_HBLANK)
        self._lib.twin_set_time(self._h, int(start_us) & ((1 << C.TIMESTAMP_BITS) - 1))
        self._lib.twin_frame(self._h, data.ctypes.data, w, rows, HBLANK, vblank)

    def accepts(self):
        """Every frame is played (the gateware decides what it keeps)."""
        return True

    def pll_loss(self):
        """The board's PLL lost lock once (its Gray-coded count on ``pll_losses`` moves)."""
        self.losses = (self.losses + 1) & 3
        self._lib.twin_pll_losses(self._h, self.losses ^ (self.losses >> 1))

    def cs(self, level):
        self._lib.twin_cs(self._h, 1 if level else 0, CS_SETUP_PS, CS_HOLD_PS, CS_GAP_PS)

    def xfer(self, mosi):
        out = bytes(mosi)
        got = ctypes.create_string_buffer(len(out))
        self._lib.twin_xfer(self._h, out, got, len(out), self.half_ps)
        return bytearray(got.raw)
