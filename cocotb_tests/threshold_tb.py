"""cocotb testbench of the threshold unit (Verilator): random frames in fixed, global and
local mode, every output beat compared with the golden model's levels.

Parameters come from the environment: ``TB_WIDTH``, ``TB_HEIGHT``, ``TB_BITS``, ``TB_FRAMES``,
``TB_SEED``, ``TB_GAP`` (idle clocks before each frame, after its registers are written: the
test passes ``global_cycles``), ``TB_LOG2_WINDOW_MAX`` (largest local window the width
admits, 0 for none) and ``TB_DRAIN`` (most clocks from a frame's last pixel to its last
beat).  After a frame's last pixel the bench clocks on until the frame's last beat, so the
blanking before a frame is that drain plus ``TB_GAP``.  Inputs are driven and outputs
sampled on the falling edge.
"""

import os

import cocotb
import numpy as np
from cocotb.clock import Clock
from cocotb.triggers import FallingEdge

from lodestar import contract as C
from lodestar.cosim.runner import unpack
from lodestar.golden import DetectorConfig
from lodestar.golden.frame import frame_levels
from lodestar.golden.vectorized import frame_stats, local_levels
from lodestar.hdl.layouts import lit_layout


def _random_config(rng, w, h, pb, lg_max):
    """A configuration with random mode and registers (local windows up to ``2**lg_max``)."""
    fs = C.full_scale(pb)
    mode = int(rng.integers(0, 3 if lg_max else 2))
    return DetectorConfig(width=w, height=h, pixel_bits=pb, threshold_mode=C.MODE_NAMES[mode],
                          threshold=int(rng.integers(0, fs + 1)),
                          background=int(rng.integers(0, fs + 1)),
                          ksigma=int(rng.integers(0, 256)) / 16,
                          local_log2_window=int(rng.integers(C.LOCAL_LOG2_WINDOW_MIN,
                                                             (lg_max or 1) + 1)),
                          local_offset=int(rng.integers(0, fs // 4 + 1)))


@cocotb.test()
async def random_frames(dut):
    w, h, pb = (int(os.environ[k]) for k in ("TB_WIDTH", "TB_HEIGHT", "TB_BITS"))
    n_frames, gap = int(os.environ["TB_FRAMES"]), int(os.environ["TB_GAP"])
    rng = np.random.default_rng(int(os.environ["TB_SEED"]))
    out_fields = [(name, field.width) for name, field in lit_layout(w, h, pb)]
    fs = C.full_scale(pb)
    lg_max, drain = int(os.environ["TB_LOG2_WINDOW_MAX"]), int(os.environ["TB_DRAIN"])

    cocotb.start_soon(Clock(dut.clk, 10, unit="ns").start())
    dut.rst.value = 1
    dut.pixels__valid.value = 0
    for _ in range(2):
        await FallingEdge(dut.clk)
    dut.rst.value = 0

    prev_stats = None
    mismatches = 0
    modes = []
    for k in range(n_frames):
        cfg = _random_config(rng, w, h, pb, lg_max)
        modes.append(cfg.threshold_mode)
        regs = cfg.registers()
        for name in ("mode", "threshold", "background", "ksigma", "local_log2_window",
                     "local_offset"):
            getattr(dut, name).value = regs[name]
        for _ in range(gap):              # the MCU writes registers between frames
            await FallingEdge(dut.clk)
        density = rng.uniform(0, 1)
        frame = np.where(rng.random((h, w)) < density, rng.integers(0, fs + 1, (h, w)),
                         rng.integers(0, fs // 8 + 1, (h, w))).astype(np.uint16)
        t, b, _ = frame_levels(cfg, prev_stats)
        if cfg.threshold_mode == "local":
            t_px, b_px = local_levels(frame, cfg)
        else:
            t_px, b_px = np.full((h, w), t), np.full((h, w), b)
        got = []
        for i in range(h * w + drain):
            if i < h * w:
                y, x = divmod(i, w)
                dut.pixels__valid.value = 1
                dut.pixels__payload.value = (int(frame[y, x]) | (int(i == 0) << pb)
                                             | (int(x == w - 1) << (pb + 1)))
            else:
                dut.pixels__valid.value = 0
            await FallingEdge(dut.clk)
            if int(dut.out__valid.value):
                got.append(unpack(int(dut.out__payload.value), out_fields))
            if i >= h * w and got and got[-1]["eof"]:
                break
        status = (int(dut.frame_threshold.value), int(dut.frame_background.value),
                  int(dut.frame_local_fallback.value), int(dut.frame_tail_dropped.value))
        assert status == (t, b, 0, 0), f"frame {k} ({cfg.threshold_mode}): status {status}"
        for i, o in enumerate(got):
            y, x = divmod(i, w)
            p = int(frame[y, x])
            tp, bp = int(t_px[y, x]), int(b_px[y, x])
            want = {"data": p, "x": x, "y": y, "lit": int(p > tp), "weight": max(p - bp, 0),
                    "eof": int(i == h * w - 1)}
            mismatches += o != want
        assert len(got) == h * w and mismatches == 0, \
            f"frame {k} ({cfg.threshold_mode}): {len(got)} beats, {mismatches} mismatches"
        prev_stats = frame_stats(frame)
    dut._log.info("%d frames (%s), %d pixels, 0 mismatches", n_frames,
                  ", ".join(f"{modes.count(n)} {n}" for n in C.MODE_NAMES), n_frames * h * w)
