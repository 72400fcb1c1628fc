"""cocotb check of the Verilated detector against the golden model.

The harness (``lodestar/cosim/harness.sv``) plays the stimulus that ``test_detector.py``
wrote and records every record and trailer.  This test clocks it, then replays the same
scenario through the golden model (``lodestar.golden.Detector``, carrying global-mode state
and the frame counter) and compares frame by frame: the records in order (hence also as a
multiset) and every trailer field.  Scenario (``COSIM_SCENARIO``, JSON) per frame: the
index of its pixels in ``frames.npz``, its ``DetectorConfig`` fields, and an optional
``fault``: ``truncated`` (the frame stops early: its trailer must say
``FRAME_TRUNCATED``) or ``reset`` (the detector is reset inside the frame: no trailer).
"""

import json
import os
from pathlib import Path

import cocotb
import numpy as np
from cocotb.triggers import RisingEdge

from lodestar import contract as C
from lodestar.cosim.runner import group_frames, read_output
from lodestar.golden import Detector, DetectorConfig


def expected_results(scenario, frames):
    """Golden results per emitted trailer, ``None`` for a truncated frame's trailer."""
    cfg0 = DetectorConfig(**scenario["frames"][0]["config"])
    golden = Detector(cfg0)
    out = []
    for spec in scenario["frames"]:
        golden.configure(DetectorConfig(**spec["config"]))
        fault = spec.get("fault")
        if fault == "reset":
            golden.reset()
        elif fault == "truncated":
            golden.frame_counter += 1
            golden.prev_stats = None
            out.append(None)
        else:
            out.append(golden.process(frames[spec["index"]]))
    return out


@cocotb.test()
async def check(dut):
    scenario = json.loads(Path(os.environ["COSIM_SCENARIO"]).read_text())
    frames = np.load(Path(os.environ["COSIM_SCENARIO"]).with_suffix(".npz"))["frames"]
    dut.start.value = 1
    await RisingEdge(dut.done)

    cfg = DetectorConfig(**scenario["frames"][0]["config"])
    records, trailers = read_output(os.environ["COSIM_OUTPUT"], cfg.width, cfg.height,
                                    cfg.pixel_bits)
    got = group_frames(records, trailers, cfg.width, cfg.height, cfg.pixel_bits)
    want = expected_results(scenario, frames)
    assert len(got) == len(want), f"{len(got)} trailers for {len(want)} frames"
    mismatches = []
    n_records = 0
    for k, (g, w) in enumerate(zip(got, want)):
        if w is None:
            if not g.flags & C.FRAME_TRUNCATED:
                mismatches.append(f"frame {k}: truncated frame without FRAME_TRUNCATED")
            continue
        n_records += len(g.blobs)
        if sorted(g.blobs, key=lambda b: b.as_tuple()) != \
                sorted(w.blobs, key=lambda b: b.as_tuple()):
            mismatches.append(f"frame {k}: records differ as a multiset")
        elif g.blobs != w.blobs:
            mismatches.append(f"frame {k}: records in a different order")
        gh, wh = g.header(), w.header()
        for name in gh:
            if gh[name] != wh[name]:
                mismatches.append(f"frame {k}: {name} {gh[name]} != golden {wh[name]}")
    for line in mismatches[:20]:
        dut._log.error(line)
    assert not mismatches, f"{len(mismatches)} mismatches in {len(got)} frames"
    dut._log.info("%d frames, %d records, %d truncated, 0 mismatches", len(got), n_records,
                  sum(w is None for w in want))
