"""The streaming model's capacity behaviour against an independent set-based reference.

The reference follows the contract's words with Python sets (no label buffer, merge table or
reference counts): blobs of the raster prefix, open until the scan of the row below passes
their last pixel, tracked iff fewer than ``capacity`` tracked blobs were open when they
started and every blob they merged with was tracked.
"""

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.golden import DetectorConfig
from lodestar.golden.streaming import StreamingModel


def reference(mask, capacity):
    """``(emitted pixel sets in completion order, dropped_labels)`` for a binary mask."""
    h, w = mask.shape
    owner, blobs = {}, {}
    emitted, dropped, next_id = [], 0, 0
    for y in range(h + 1):
        for x in range(w):
            if y < h and mask[y, x]:
                ids = {owner[q] for q in ((x - 1, y), (x, y - 1)) if q in owner}
                if not ids:
                    tracked = sum(b["tracked"] for b in blobs.values()) < capacity
                    blob = {"pixels": set(), "tracked": tracked}
                    blobs[next_id] = blob
                    ids, next_id = {next_id}, next_id + 1
                keep = min(ids)
                blob = blobs[keep]
                for other in ids - {keep}:
                    gone = blobs.pop(other)
                    blob["tracked"] = blob["tracked"] and gone["tracked"]
                    blob["pixels"] |= gone["pixels"]
                    for q in gone["pixels"]:
                        owner[q] = keep
                blob["pixels"].add((x, y))
                blob["last"] = (y, x)
                owner[(x, y)] = keep
            above = owner.get((x, y - 1))
            if above in blobs and blobs[above]["last"] == (y - 1, x):
                blob = blobs.pop(above)
                if blob["tracked"]:
                    emitted.append(blob["pixels"])
                else:
                    dropped += 1
    return emitted, dropped


def check(mask, capacity):
    h, w = mask.shape
    frame = np.where(mask, 100 + np.arange(h * w).reshape(h, w) % 50, 0).astype(np.uint16)
    model = StreamingModel(DetectorConfig(width=w, height=h, threshold=50, background=40,
                                          label_capacity=capacity))
    res, _ = model.run(frame, None)
    emitted, dropped = reference(mask, capacity)
    assert res.dropped_labels == dropped
    assert bool(res.flags & C.FRAME_LABEL_OVERFLOW) == (dropped > 0)
    assert res.n_blobs == len(res.blobs) == len(emitted)
    for blob, pixels in zip(res.blobs, emitted):
        xs = [x for x, _ in pixels]
        ys = [y for _, y in pixels]
        s0 = sum(int(frame[y, x]) - 40 for x, y in pixels)
        assert (blob.n, blob.s0, blob.xmin, blob.xmax, blob.ymin, blob.ymax) == \
            (len(pixels), s0, min(xs), max(xs), min(ys), max(ys))
    assert model.peak_open <= capacity
    return dropped


@pytest.mark.parametrize("shape", [(3, 3), (3, 4), (4, 3)])
def test_every_small_mask_at_every_capacity(shape):
    h, w = shape
    overflowed = 0
    for bits in range(1 << (h * w)):
        mask = np.array([(bits >> i) & 1 for i in range(h * w)], dtype=bool).reshape(h, w)
        for capacity in range(1, C.max_open_blobs(w) + 1):
            overflowed += check(mask, capacity) > 0
    assert overflowed > 0


@pytest.mark.parametrize("density", [0.1, 0.3, 0.5, 0.5927, 0.7])
def test_random_masks_at_low_capacity(density):
    rng = np.random.default_rng(int(density * 1e4))
    for _ in range(200):
        h, w = rng.integers(2, 14, 2)
        mask = rng.random((h, w)) < density
        check(mask, int(rng.integers(1, C.max_open_blobs(w) + 1)))


def test_labels_are_reused_within_a_frame():
    """A frame of many small blobs in sequence needs only a handful of labels."""
    frame = np.zeros((60, 8), dtype=np.uint16)
    frame[::2, ::2] = 500          # 30 rows x 4 single-pixel blobs = 120 blobs
    model = StreamingModel(DetectorConfig(width=8, height=60, threshold=10))
    res, _ = model.run(frame, None)
    assert len(res.blobs) == 120
    assert model.peak_labels <= 4 < 120
