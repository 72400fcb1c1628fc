"""The labeller's algorithm (``golden/wavefront.py``) against the golden streaming model,
and the memory-access spacing the gateware relies on."""

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.golden import DetectorConfig
from lodestar.golden.streaming import StreamingModel
from lodestar.golden.wavefront import WavefrontLabeller


def frame_of(mask, rng):
    return np.where(mask, rng.integers(51, 4096, size=mask.shape),
                    rng.integers(0, 51, size=mask.shape)).astype(np.uint16)


def check(frame, cap, rcap=C.DEFAULT_RECORD_CAPACITY):
    h, w = frame.shape
    cfg = DetectorConfig(width=w, height=h, threshold=50, background=40, label_capacity=cap,
                         record_capacity=rcap)
    res, _ = StreamingModel(cfg).run(frame, None)
    weights = np.where(frame > 40, frame.astype(int) - 40, 0)
    model = WavefrontLabeller(w, h, 12, cap, rcap).run(frame > 50, frame, weights)
    assert model.records == list(res.blobs)
    assert (model.n_blobs, model.n_filtered, model.dropped_records, model.dropped_labels) == \
        (res.n_blobs, res.n_filtered, res.dropped_records, res.dropped_labels)
    return model


@pytest.mark.parametrize("shape", [(3, 3), (3, 4), (4, 3)])
def test_every_small_mask_at_every_capacity(shape):
    h, w = shape
    rng = np.random.default_rng(h * 10 + w)
    for bits in range(1 << (h * w)):
        mask = np.array([(bits >> i) & 1 for i in range(h * w)], dtype=bool).reshape(h, w)
        frame = frame_of(mask, rng)
        for cap in range(1, C.max_open_blobs(w) + 1):
            check(frame, cap)


def spacing_problems(events):
    """Same-kind memory accesses closer than two clocks, or first/last patches sharing
    a clock (they share a write port)."""
    problems = []
    by_clock = {}
    for t, kind in events:
        by_clock.setdefault(t, []).append(kind)
    last = {}
    for t in sorted(by_clock):
        kinds = by_clock[t]
        if len(set(kinds)) != len(kinds):
            problems.append((t, "twice", kinds))
        if "first_patch" in kinds and "last_patch" in kinds:
            problems.append((t, "patches", kinds))
        for kind in kinds:
            if kind in last and t - last[kind] < 2 and kind != "push" and kind != "pop":
                problems.append((t, kind))
            last[kind] = t
    return problems


@pytest.mark.parametrize("density", [0.2, 0.45, 0.6, 0.8])
def test_random_frames_capacities_and_spacing(density):
    rng = np.random.default_rng(int(density * 100))
    for _ in range(400):
        h, w = int(rng.integers(1, 12)), int(rng.integers(2, 12))
        frame = frame_of(rng.random((h, w)) < density, rng)
        model = check(frame, int(rng.integers(1, C.max_open_blobs(w) + 1)),
                      int(rng.integers(1, 12)))
        assert spacing_problems(model.events) == []


def test_spacing_check_can_fail():
    assert spacing_problems([(0, "node_write"), (1, "node_write")]) == [(1, "node_write")]
    assert spacing_problems([(4, "first_patch"), (4, "last_patch")])
