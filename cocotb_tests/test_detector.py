"""The detection gateware, Verilated, bit-exact against the golden model (cocotb).

Each test builds one geometry once (``lodestar.cosim.runner.Build``, cached) and plays scenarios
at the documented minimum blanking (``MIN_HBLANK`` per row, ``min_vblank`` per frame),
back to back; ``detector_tb.py`` compares every frame with the golden model.
"""

import json
from pathlib import Path

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.cosim.runner import Build, Stimulus, frame_gap, scenario
from lodestar.golden import DetectorConfig, shapes
from lodestar.hdl.labeller import MIN_HBLANK

# the Verilated detector builds are shared (cached, one build per parameter set): one
# worker runs every test that plays them, so none waits on the other's build (pyproject:
# loadgroup)
pytestmark = pytest.mark.xdist_group("cosim")

HERE = Path(__file__).parent
GOLDEN_SET = HERE.parent / "tests" / "data" / "golden_small"


def play(build, frames, cfgs, tmp, stim=None, faults=None, reader=None):
    """Write the scenario, play it (``stim`` or the plain stimulus) and let the cocotb test
    check it; ``faults`` maps frame index -> ``truncated`` / ``reset``."""
    tmp.mkdir(parents=True, exist_ok=True)
    path = tmp / "scenario.json"
    np.savez_compressed(path.with_suffix(".npz"), frames=np.stack(frames))
    path.write_text(json.dumps({"frames": [
        {"index": i, "config": _fields(cfg),
         **({"fault": faults[i]} if faults and i in faults else {})}
        for i, cfg in enumerate(cfgs)]}))
    stim = stim or scenario(frames, cfgs, MIN_HBLANK)
    build.simulate(stim, tmp, reader=reader, test_module="detector_tb", test_dir=HERE,
                   extra_env={"COSIM_SCENARIO": str(path)})


def _fields(cfg):
    import dataclasses
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}


def random_frame(rng, h, w, bits, density, low, high):
    fs = C.full_scale(bits)
    lit = rng.random((h, w)) < density
    return np.where(lit, rng.integers(high, fs + 1, (h, w)),
                    rng.integers(0, low + 1, (h, w))).astype(np.uint16)


def random_config(rng, w, h, bits, cap=None, rcap=C.DEFAULT_RECORD_CAPACITY):
    fs = C.full_scale(bits)
    mode = str(rng.choice(C.MODE_NAMES))
    lg_max = min(C.LOCAL_LOG2_WINDOW_MAX, (w - 1).bit_length() - 1)
    return DetectorConfig(
        width=w, height=h, pixel_bits=bits, threshold_mode=mode,
        threshold=int(rng.integers(fs // 8, fs // 2)), background=int(rng.integers(0, fs // 8)),
        ksigma=int(rng.integers(0, 64)) / 16,
        local_log2_window=int(rng.integers(C.LOCAL_LOG2_WINDOW_MIN, lg_max + 1)),
        local_offset=int(rng.integers(0, fs // 4)),
        min_pixels=int(rng.integers(1, 4)), min_sum=int(rng.integers(0, 4 * fs)),
        max_pixels=int(rng.integers(4, 64)) if rng.random() < 0.3 else None,
        label_capacity=cap, record_capacity=rcap)


def random_frames(rng, n, w, h, bits, cap=None, rcap=C.DEFAULT_RECORD_CAPACITY):
    frames, cfgs = [], []
    fs = C.full_scale(bits)
    for _ in range(n):
        cfg = random_config(rng, w, h, bits, cap, rcap)
        frames.append(random_frame(rng, h, w, bits, rng.uniform(0.05, 0.8),
                                   cfg.threshold // 2, min(fs, cfg.threshold + 1)))
        cfgs.append(cfg)
    return frames, cfgs


def test_shapes_random_frames_and_faults_32x24(tmp_path):
    """Adversarial shapes (three orientations, random registers), 600 random frames in all
    three modes (global mode carries state across frames), and faults."""
    rng = np.random.default_rng(32)
    build = Build(32, 24, 12).ensure()
    frames, cfgs = [], []
    for name in sorted(shapes.ADVERSARIAL):
        mask = shapes.ADVERSARIAL[name]()
        for orient in (mask, mask[::-1], mask[:, ::-1], mask[::-1, ::-1]):
            frames.append(shapes.to_frame(np.ascontiguousarray(orient),
                                          rng.integers(101, 4096, mask.shape),
                                          rng.integers(0, 101, mask.shape)))
            cfgs.append(DetectorConfig(width=32, height=24, threshold=100,
                                       background=int(rng.integers(0, 100)),
                                       min_pixels=int(rng.integers(1, 3))))
    more, more_cfgs = random_frames(rng, 600, 32, 24, 12)
    play(build, frames + more, cfgs + more_cfgs, tmp_path / "shapes_random")

    # faults: an early end, a missing line, a reset inside a frame; the next frames exact
    frames, cfgs = random_frames(rng, 8, 32, 24, 12)
    gap = frame_gap(cfgs)
    stim = Stimulus().reset()
    for i, (frame, cfg) in enumerate(zip(frames, cfgs)):
        stim.registers(cfg.registers()).idle(gap)
        if i == 1:
            stim.frame(frame, MIN_HBLANK, 0, pixels=32 * 10 + 7)
        elif i == 3:
            stim.frame(np.delete(frame, 5, axis=0), MIN_HBLANK, 0)
        elif i == 5:
            stim.frame(frame, MIN_HBLANK, 0, pixels=32 * 12 + 3).reset(3)
        else:
            stim.frame(frame, MIN_HBLANK, 0)
    stim.idle(gap + 8)
    play(build, frames, cfgs, tmp_path / "faults", stim=stim,
         faults={1: "truncated", 3: "truncated", 5: "reset"})


def test_capacity_overflow_and_slow_reader_10bit(tmp_path):
    """Label capacity 3 and record capacity 4 with dense random frames (both overflow),
    10-bit pixels, then a record reader that takes one record every 5 clocks."""
    rng = np.random.default_rng(10)
    build = Build(31, 9, 10, label_capacity=3, record_capacity=4).ensure()
    frames, cfgs = random_frames(rng, 500, 31, 9, 10, cap=3, rcap=4)
    play(build, frames, cfgs, tmp_path / "random")
    frames, cfgs = random_frames(rng, 40, 31, 9, 10, cap=3, rcap=4)
    for k, cfg in enumerate(cfgs):         # fixed mode: the golden model needs no state
        cfgs[k] = cfg.replace(threshold_mode="fixed")
    play(build, frames, cfgs, tmp_path / "slow", reader=lambda clock: clock % 5 == 0)


def _golden_set(pattern):
    from lodestar.sim.goldenset import load_frame_doc

    docs = [load_frame_doc(p) for p in sorted(GOLDEN_SET.glob(pattern))]
    return [d[0] for d in docs], [d[2] for d in docs]


@pytest.mark.slow
@pytest.mark.parametrize("pattern", ["estcube2_*.json", "lohmann_*.json"])
def test_committed_golden_image_set(tmp_path, pattern):
    """The committed 640 x 480 and 752 x 480 golden frames on the cocotb build (opt in:
    --runslow; by default the native build plays them bit-exact,
    ``tests/cosim/test_runner.py``, and writes what the cocotb build writes)."""
    frames, cfgs = _golden_set(pattern)
    c = cfgs[0]
    build = Build(c.width, c.height, c.pixel_bits, c.label_capacity, c.record_capacity)
    play(build.ensure(), frames, cfgs, tmp_path)


@pytest.mark.slow
def test_full_size_estcube2_frames(tmp_path):
    """Two full 2592 x 1944 x 12 frames of the default camera (opt in: --runslow)."""
    from lodestar.sim.presets import load_preset
    from lodestar.sim.scene import detector_config, simulate

    cam = load_preset("estcube2")
    cfg = detector_config(cam)
    frames = []
    for seed, q in ((1, [0.2, -0.4, 0.1, 0.88]), (2, [0.7, 0.1, -0.3, 0.6])):
        q = np.array(q) / np.linalg.norm(q)
        frames.append(simulate(cam, q, seed=seed).frame)
    build = Build(cfg.width, cfg.height, cfg.pixel_bits, cfg.label_capacity,
                  cfg.record_capacity)
    play(build.ensure(), frames, [cfg, cfg], tmp_path)
