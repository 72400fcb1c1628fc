"""cocotb testbench of the threshold unit (Verilator): random frames in fixed and global
mode, every output pixel compared with the golden model's levels.

Parameters come from the environment: ``TB_WIDTH``, ``TB_HEIGHT``, ``TB_BITS``, ``TB_FRAMES``,
``TB_SEED``, ``TB_GAP`` (idle clocks before each frame, after its registers are written).  Inputs are driven and outputs sampled
on the falling edge.
"""

import os

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.triggers import FallingEdge

from lodestar import contract as C
from lodestar.golden import DetectorConfig
from lodestar.golden.frame import frame_levels
from lodestar.golden.vectorized import frame_stats


def _unpack(value, widths):
    out = {}
    for name, bits in widths:
        out[name] = value & ((1 << bits) - 1)
        value >>= bits
    return out


@cocotb.test()
async def random_frames(dut):
    w, h, pb = (int(os.environ[k]) for k in ("TB_WIDTH", "TB_HEIGHT", "TB_BITS"))
    n_frames, gap = int(os.environ["TB_FRAMES"]), int(os.environ["TB_GAP"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]))
    out_fields = [("data", pb), ("x", C.bits_for(w - 1)), ("y", C.bits_for(h - 1)),
                  ("lit", 1), ("weight", pb), ("eof", 1)]
    fs = C.full_scale(pb)

    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    dut.rst.value = 1
    dut.pixels__valid.value = 0
    for _ in range(2):
        await FallingEdge(dut.clk)
    dut.rst.value = 0

    prev_stats = None
    mismatches = 0
    for k in range(n_frames):
        mode = int(rng.integers(0, 2))                     # fixed or global
        cfg = DetectorConfig(width=w, height=h, pixel_bits=pb,
                             threshold_mode=C.MODE_NAMES[mode],
                             threshold=int(rng.integers(0, fs + 1)),
                             background=int(rng.integers(0, fs + 1)),
                             ksigma=int(rng.integers(0, 256)) / 16)
        regs = cfg.registers()
        for name in ("mode", "threshold", "background", "ksigma"):
            getattr(dut, name).value = regs[name]
        for _ in range(gap):              # the MCU writes registers between frames
            await FallingEdge(dut.clk)
        density = rng.uniform(0, 1)
        frame = np.where(rng.random((h, w)) < density, rng.integers(0, fs + 1, (h, w)),
                         rng.integers(0, fs // 8 + 1, (h, w))).astype(np.uint16)
        t, b, _ = frame_levels(cfg, prev_stats)
        got = []
        for i in range(h * w + 1):
            if i < h * w:
                y, x = divmod(i, w)
                dut.pixels__valid.value = 1
                dut.pixels__payload.value = (int(frame[y, x]) | (int(i == 0) << pb)
                                             | (int(x == w - 1) << (pb + 1)))
            else:
                dut.pixels__valid.value = 0
            await FallingEdge(dut.clk)
            if int(dut.out__valid.value):
                got.append(_unpack(int(dut.out__payload.value), out_fields))
        assert (int(dut.frame_threshold.value), int(dut.frame_background.value)) == (t, b), \
            f"frame {k}: levels"
        for i, o in enumerate(got):
            y, x = divmod(i, w)
            p = int(frame[y, x])
            want = {"data": p, "x": x, "y": y, "lit": int(p > t), "weight": max(p - b, 0),
                    "eof": int(i == h * w - 1)}
            mismatches += o != want
        assert len(got) == h * w and mismatches == 0, f"frame {k}: {mismatches} mismatches"
        prev_stats = frame_stats(frame)
    dut._log.info("%d frames, %d pixels, 0 mismatches", n_frames, n_frames * h * w)
