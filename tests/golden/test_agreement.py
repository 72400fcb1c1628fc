"""The two golden engines agree exactly, and both match expectations computed here.

``vectorized.detect`` and ``streaming.detect`` are called directly on C-contiguous ``uint16``
frames; every comparison is ``DetectionResult`` equality (records in emission order and all
header counts), the full header, and the returned ``FrameStats``.  ``label_capacity`` stays
None (``max_open_blobs(width)``, which cannot overflow), so the vectorized engine never hands
a frame to the streaming model and both code paths really run.

Besides agreement, frames are checked against expectations derived independently in this
file: a plain breadth-first-search labeller with Python integers (:func:`reference`),
``scipy.ndimage.label`` counts, per-shape facts of ``lodestar.golden.shapes`` and the
contract's formulas for global and local levels.
"""

import itertools
import zlib

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from scipy import ndimage

from lodestar import contract as C
from lodestar.golden import (
    DetectionResult,
    Detector,
    DetectorConfig,
    shapes,
    streaming,
    vectorized,
)
from lodestar.golden.frame import FrameStats

CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)
H, W = shapes.DEFAULT_SHAPE
DENSITIES = (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, shapes.PERCOLATION_THRESHOLD, 0.7, 0.8)


def _seed(*parts):
    return zlib.crc32(repr(parts).encode())


def _repro(frame, cfg, prev_stats):
    if frame.size <= 64:
        return f"\nframe={frame.tolist()}\ncfg={cfg!r}\nprev_stats={prev_stats!r}"
    return f"\nframe shape {frame.shape}\ncfg={cfg!r}\nprev_stats={prev_stats!r}"


def both(frame, cfg, prev_stats=None):
    """Run both engines on ``frame``; assert exact agreement; return ``(result, stats)``."""
    assert frame.dtype == np.uint16 and frame.flags.c_contiguous
    assert frame.shape == (cfg.height, cfg.width)
    assert cfg.label_capacity is None  # keeps the vectorized engine on its own path
    rv, sv = vectorized.detect(frame, cfg, prev_stats)
    rs, ss = streaming.detect(frame, cfg, prev_stats)
    assert rv == rs, "engines disagree" + _repro(frame, cfg, prev_stats) + \
        f"\nvectorized={rv}\nstreaming={rs}"
    assert rv.header() == rs.header()
    assert sv == ss
    return rv, sv


# --------------------------------------------------------------------------------------
# Independent reference: BFS labelling with Python integers, straight from the contract
# --------------------------------------------------------------------------------------


def numpy_stats(frame):
    """``FrameStats`` of a frame with exact Python integers."""
    p = frame.astype(np.uint64)
    return FrameStats(int(frame.size), int(p.sum()), int((p * p).sum()))


def reference_levels(frame, cfg, prev_frame):
    """Per-pixel T and B (lists of rows), header (T, B) and frame flags."""
    h, w = frame.shape
    fs = C.full_scale(cfg.pixel_bits)
    rows = frame.tolist()
    if cfg.threshold_mode == "local":
        win = 1 << cfg.local_log2_window
        ts, bs = [], []
        for row in rows:
            trow, brow = [], []
            for x in range(w):
                s = min(max(x - win // 2, 0), w - 1 - win)
                mean = (sum(row[s:s + win + 1]) - row[x]) // win
                trow.append(min(mean + cfg.local_offset, fs))
                brow.append(mean)
            ts.append(trow)
            bs.append(brow)
        return ts, bs, (cfg.local_offset, 0), 0
    flags = 0
    t, b = cfg.threshold, cfg.background
    if cfg.threshold_mode == "global":
        if prev_frame is None:
            flags = C.FRAME_GLOBAL_FALLBACK
        else:
            st_ = numpy_stats(prev_frame)
            t, b = C.global_levels(st_.n, st_.s1, st_.s2, cfg.ksigma_reg, cfg.pixel_bits)
    return [[t] * w for _ in range(h)], [[b] * w for _ in range(h)], (t, b), flags


def reference_blobs(frame, ts, bs, pixel_bits):
    """Every 4-connected blob's exact record, in raster order of its last pixel."""
    h, w = frame.shape
    rows = frame.tolist()
    fs = C.full_scale(pixel_bits)
    lim = C.moment_max(pixel_bits)
    lit = [[rows[y][x] > ts[y][x] for x in range(w)] for y in range(h)]
    seen = [[False] * w for _ in range(h)]
    blobs = []
    for y0 in range(h):
        for x0 in range(w):
            if not lit[y0][x0] or seen[y0][x0]:
                continue
            seen[y0][x0] = True
            stack, pixels = [(x0, y0)], []
            while stack:
                x, y = stack.pop()
                pixels.append((x, y))
                for nx, ny in ((x - 1, y), (x + 1, y), (x, y - 1), (x, y + 1)):
                    if 0 <= nx < w and 0 <= ny < h and lit[ny][nx] and not seen[ny][nx]:
                        seen[ny][nx] = True
                        stack.append((nx, ny))
            true = dict.fromkeys(C.MOMENTS, 0)
            nsat = peak = 0
            for x, y in pixels:
                p = rows[y][x]
                wt = max(p - bs[y][x], 0)
                true["s0"] += wt
                true["sx"] += wt * x
                true["sy"] += wt * y
                true["sxx"] += wt * x * x
                true["syy"] += wt * y * y
                true["sxy"] += wt * x * y
                nsat += p == fs
                peak = max(peak, p)
            sat = any(true[m] > lim[m] for m in C.MOMENTS)
            moments = {m: min(true[m], lim[m]) for m in C.MOMENTS}
            xs = [x for x, _ in pixels]
            ys = [y for _, y in pixels]
            last = max(y * w + x for x, y in pixels)
            rec = C.BlobRecord(n=len(pixels), nsat=nsat, xmin=min(xs), xmax=max(xs),
                               ymin=min(ys), ymax=max(ys), peak=peak,
                               flags=C.BLOB_MOMENTS_SATURATED if sat else 0, **moments)
            blobs.append((last, rec))
    blobs.sort(key=lambda item: item[0])
    return [rec for _, rec in blobs]


def reference(frame, cfg, prev_frame=None):
    """The ``DetectionResult`` the contract prescribes (label capacity never overflows)."""
    ts, bs, (t, b), flags = reference_levels(frame, cfg, prev_frame)
    records = reference_blobs(frame, ts, bs, cfg.pixel_bits)
    emitted, n_filtered, dropped = [], 0, 0
    for rec in records:
        if not (cfg.min_pixels <= rec.n <= cfg.max_pixels_reg and rec.s0 >= cfg.min_sum):
            n_filtered += 1
        elif len(emitted) < cfg.record_capacity:
            emitted.append(rec)
        else:
            dropped += 1
    if dropped:
        flags |= C.FRAME_RECORD_OVERFLOW
    return DetectionResult(blobs=emitted, mode=cfg.mode, threshold=t, background=b,
                           n_blobs=len(records), n_filtered=n_filtered, dropped_records=dropped,
                           dropped_labels=0, flags=flags)


def check(frame, cfg, prev_frame=None):
    """Both engines agree with each other and with :func:`reference`; returns the result."""
    prev_stats = None if prev_frame is None else numpy_stats(prev_frame)
    res, stats = both(frame, cfg, prev_stats)
    assert stats == numpy_stats(frame)
    ref = reference(frame, cfg, prev_frame)
    assert res == ref, "engines disagree with the reference" + _repro(frame, cfg, prev_stats) \
        + f"\nengines={res}\nreference={ref}"
    return res


def lit_frame(mask, rng, t, pixel_bits, sat_fraction=0.1):
    """Random pixel values: lit pixels in ``t+1 .. full scale`` (some exactly at full scale),
    the others in ``0 .. t``.  Requires ``t < full_scale``."""
    fs = C.full_scale(pixel_bits)
    assert 0 <= t < fs
    lit = rng.integers(t + 1, fs + 1, size=mask.shape)
    lit = np.where(rng.random(mask.shape) < sat_fraction, fs, lit)
    dark = rng.integers(0, t + 1, size=mask.shape)
    return shapes.to_frame(mask, lit, dark)


# --------------------------------------------------------------------------------------
# Shape generators
# --------------------------------------------------------------------------------------


def test_shape_registry_is_deterministic_and_well_formed():
    for kind in ("spiral", "merge_chain", "comb_down", "comb_up", "nested_u", "staircase_",
                 "diagonal_staircase", "checkerboard", "vertical_stripes", "random_",
                 "edges_and_corners", "full", "empty", "serpentine_", "w_shape", "sawtooth"):
        assert any(name.startswith(kind) for name in shapes.ADVERSARIAL), kind
    for name, make in shapes.ADVERSARIAL.items():
        a, b = make(), make()
        assert a.dtype == np.bool_ and a.shape == (H, W), name
        assert a.flags.c_contiguous, name
        assert np.array_equal(a, b), name


def test_to_frame():
    mask = shapes.checkerboard(3, 4)
    f = shapes.to_frame(mask, 7, 2)
    assert f.dtype == np.uint16 and f.flags.c_contiguous and f.shape == (3, 4)
    assert np.array_equal(f, np.where(mask, 7, 2))
    vals = np.arange(12).reshape(3, 4) + 100
    g = shapes.to_frame(mask, vals, dtype=np.uint8)
    assert g.dtype == np.uint8 and np.array_equal(g, np.where(mask, vals, 0))
    with pytest.raises(ValueError):
        shapes.to_frame(mask, 256, dtype=np.uint8)
    with pytest.raises(ValueError):
        shapes.to_frame(mask, 1, -1)


def _bbox(mask):
    ys, xs = np.nonzero(mask)
    return int(xs.min()), int(xs.max()), int(ys.min()), int(ys.max())


def fact_single_blob(mask, res):
    assert res.n_blobs == 1 and len(res.blobs) == 1
    rec = res.blobs[0]
    assert rec.n == int(mask.sum())
    assert (rec.xmin, rec.xmax, rec.ymin, rec.ymax) == _bbox(mask)


def fact_spiral(mask, res):
    """One blob, and the mask is a simple path: every pixel has at most two lit
    4-neighbours and exactly two (the ends) have one."""
    fact_single_blob(mask, res)
    p = np.pad(mask, 1).astype(int)
    degree = (p[:-2, 1:-1] + p[2:, 1:-1] + p[1:-1, :-2] + p[1:-1, 2:])[mask]
    assert degree.max() == 2 and (degree == 1).sum() == 2
    assert res.blobs[0].n > H * W // 2  # it really winds through the frame


def fact_last_row_merge(mask, res):
    """One blob whose last pixel is on the last row (it completes at the end of the frame)."""
    fact_single_blob(mask, res)
    assert res.blobs[0].ymax == H - 1 and mask[-1].any()


def fact_isolated_pixels(mask, res):
    lit = list(zip(*np.nonzero(mask)))
    assert res.n_blobs == len(lit) == len(res.blobs)
    assert all(r.n == 1 for r in res.blobs)
    assert [(r.ymin, r.xmin) for r in res.blobs] == lit  # raster order


def fact_full(mask, res):
    assert mask.all()
    fact_single_blob(mask, res)
    assert res.blobs[0].n == H * W
    assert (res.blobs[0].xmin, res.blobs[0].xmax, res.blobs[0].ymin, res.blobs[0].ymax) == \
        (0, W - 1, 0, H - 1)


def fact_empty(mask, res):
    assert not mask.any()
    assert res.n_blobs == 0 and res.blobs == [] and res.flags == 0


def fact_stripes(mask, res):
    cols = np.flatnonzero(mask.all(axis=0))
    assert np.array_equal(mask.any(axis=0), mask.all(axis=0))  # whole columns only
    assert len(cols) == W // 2
    assert res.n_blobs == len(cols) == len(res.blobs)
    # all complete at the end of the frame: order of their last pixels (H-1, x)
    assert [(r.xmin, r.xmax, r.ymin, r.ymax, r.n) for r in res.blobs] == \
        [(c, c, 0, H - 1, H) for c in cols]


def fact_nested_u(mask, res):
    count = 0
    while 2 * count + 1 <= W - 1 - 2 * count and H - 1 - 2 * count >= 0:
        count += 1
    assert res.n_blobs == count
    # the innermost U completes first (its bottom-right corner is its last pixel)
    want = []
    for k in reversed(range(count)):
        left, right, bottom = 2 * k, W - 1 - 2 * k, H - 1 - 2 * k
        n = 2 * (bottom + 1) + (right - left + 1) - 2
        want.append((left, right, 0, bottom, n))
    assert [(r.xmin, r.xmax, r.ymin, r.ymax, r.n) for r in res.blobs] == want


def fact_cells(cell):
    """Diagonal-only staircase: one blob per (cell x cell) step cell."""
    def fact(mask, res):
        ys, xs = np.nonzero(mask)
        cells = {}
        for y, x in zip(ys, xs):
            key = (y // cell, x // cell)
            cells[key] = cells.get(key, 0) + 1
        assert res.n_blobs == len(cells) == len(res.blobs)
        got = {}
        for r in res.blobs:
            key = (r.ymin // cell, r.xmin // cell)
            assert key == (r.ymax // cell, r.xmax // cell)  # inside one cell
            got[key] = r.n
        assert got == cells
    return fact


def fact_stairs(step, direction):
    """4-connected staircase: one blob per stair, every row of a stair one run."""
    period = 2 * step + 2

    def fact(mask, res):
        ys, xs = np.nonzero(mask)
        xx = xs if direction == "right" else W - 1 - xs
        assert np.all((xx - ys * step) % period <= step)
        stairs = set(((xx - ys * step) // period).tolist())
        assert res.n_blobs == len(stairs)
        for r in res.blobs:
            assert r.n <= (r.ymax - r.ymin + 1) * (step + 1)
    return fact


def fact_edges(mask, res):
    assert res.n_blobs == 12
    for r in res.blobs:
        assert r.xmin == 0 or r.ymin == 0 or r.xmax == W - 1 or r.ymax == H - 1
    corners = {(r.xmin, r.ymin) for r in res.blobs if r.n == 1}
    assert {(0, 0), (W - 1, 0), (0, H - 1), (W - 1, H - 1)} <= corners


def fact_random(mask, res):
    assert res.n_blobs == ndimage.label(mask, CROSS)[1]
    assert sum(r.n for r in res.blobs) == int(mask.sum())


SHAPE_FACTS = {
    "spiral": fact_spiral,
    "merge_chain": fact_single_blob,
    "comb_down": fact_last_row_merge,
    "comb_down_pitch3": fact_last_row_merge,
    "comb_up": fact_single_blob,
    "nested_u": fact_nested_u,
    "staircase_right": fact_stairs(1, "right"),
    "staircase_left": fact_stairs(2, "left"),
    "diagonal_staircase": fact_cells(1),
    "diagonal_staircase_cells": fact_cells(3),
    "diagonal_staircase_anti": fact_cells(2),
    "checkerboard": fact_isolated_pixels,
    "checkerboard_odd": fact_isolated_pixels,
    "vertical_stripes": fact_stripes,
    "vertical_stripes_odd": fact_stripes,
    "edges_and_corners": fact_edges,
    "full": fact_full,
    "empty": fact_empty,
    "serpentine_rows": fact_single_blob,
    "serpentine_columns": fact_last_row_merge,
    "w_shape": fact_last_row_merge,
    "w_shape_wide": fact_last_row_merge,
    "sawtooth": fact_last_row_merge,
}


def _fact_for(name):
    if name.startswith("random_"):
        return fact_random
    return SHAPE_FACTS[name]


def test_every_shape_has_facts():
    missing = [name for name in shapes.ADVERSARIAL
               if not name.startswith("random_") and name not in SHAPE_FACTS]
    assert not missing, f"add facts for new shapes: {missing}"
    densities = {float(name[len("random_"):]) for name in shapes.ADVERSARIAL
                 if name.startswith("random_")}
    assert shapes.PERCOLATION_THRESHOLD in densities
    assert min(densities) <= 0.3 and max(densities) >= 0.8


@pytest.mark.parametrize("pixel_bits", [10, 12])
@pytest.mark.parametrize("name", sorted(shapes.ADVERSARIAL))
def test_adversarial_shape(name, pixel_bits):
    mask = shapes.ADVERSARIAL[name]()
    rng = np.random.default_rng(_seed(name, pixel_bits))
    fs = C.full_scale(pixel_bits)
    t = int(rng.integers(fs // 16, fs // 2))
    b = int(rng.integers(0, t + 1))
    frame = lit_frame(mask, rng, t, pixel_bits)
    cfg = DetectorConfig(width=W, height=H, pixel_bits=pixel_bits, threshold=t, background=b)
    res = check(frame, cfg)
    assert np.array_equal(frame > t, mask)
    _fact_for(name)(mask, res)
    if name == "full":  # s0 of the one blob is the sum of all weights
        assert res.blobs[0].s0 == int(np.maximum(frame.astype(np.int64) - b, 0).sum())


ORIENTATIONS = {
    "fliplr": np.fliplr,
    "flipud": np.flipud,
    "rot180": lambda m: m[::-1, ::-1],
    "transpose": np.transpose,
}


@pytest.mark.parametrize("orient", sorted(ORIENTATIONS))
def test_adversarial_shapes_reoriented_random_registers(orient):
    """Every shape mirrored/transposed, in every mode with random registers and capacities."""
    rng = np.random.default_rng(_seed("orient", orient))
    for name in sorted(shapes.ADVERSARIAL):
        mask = np.ascontiguousarray(ORIENTATIONS[orient](shapes.ADVERSARIAL[name]()))
        h, w = mask.shape
        pixel_bits = int(rng.choice([10, 12]))
        fs = C.full_scale(pixel_bits)
        t = int(rng.integers(1, fs // 2))
        frame = lit_frame(mask, rng, t, pixel_bits)
        mode = C.MODE_NAMES[int(rng.integers(3))]
        cfg = random_config(rng, w, h, pixel_bits, mode, t)
        prev = lit_frame(shapes.random_mask(h, w, 0.3, int(rng.integers(1 << 30))), rng, t,
                         pixel_bits) if mode == "global" and rng.random() < 0.8 else None
        res = check(frame, cfg, prev)
        if mode == "fixed" and cfg.threshold == t:
            assert res.n_blobs == ndimage.label(mask, CROSS)[1]


# --------------------------------------------------------------------------------------
# Every binary image up to 4 x 4
# --------------------------------------------------------------------------------------


def all_masks(h, w):
    """All ``2**(h*w)`` masks of shape (h, w), as a (N, h, w) bool array."""
    ids = np.arange(1 << (h * w), dtype=np.uint32)
    bits = (ids[:, None] >> np.arange(h * w, dtype=np.uint32)) & 1
    return bits.astype(bool).reshape(-1, h, w)


@pytest.mark.parametrize("h,w", list(itertools.product(range(1, 5), range(1, 5))))
def test_exhaustive_small_masks(h, w):
    masks = all_masks(h, w)
    n = len(masks)
    t, b = 100, 40
    cfg = DetectorConfig(width=w, height=h, pixel_bits=12, threshold=t, background=b,
                         min_pixels=1)
    # deterministic varied values: lit 101..197, dark 0..100 (some below B)
    idx = np.arange(h * w).reshape(1, h, w)
    ids = np.arange(n).reshape(-1, 1, 1)
    lit = t + 1 + (ids * 7 + idx * 13) % 97
    dark = (ids * 3 + idx * 5) % (t + 1)
    frames = np.ascontiguousarray(np.where(masks, lit, dark).astype(np.uint16))
    pixels = masks.reshape(n, -1).sum(axis=1)
    for i in range(n):
        frame = frames[i]
        res, _ = both(frame, cfg)
        count = ndimage.label(masks[i], CROSS)[1]
        assert res.n_blobs == count == len(res.blobs), _repro(frame, cfg, None)
        assert sum(r.n for r in res.blobs) == pixels[i]
        assert res.flags == 0


# --------------------------------------------------------------------------------------
# Random masks, registers and modes
# --------------------------------------------------------------------------------------


def random_config(rng, w, h, pixel_bits, mode, t=None):
    fs = C.full_scale(pixel_bits)
    t = int(rng.integers(0, fs)) if t is None else t
    min_pixels = int(rng.choice([0, 1, 1, 2, 3, 5]))
    max_pixels = None if rng.random() < 0.5 else min_pixels + int(rng.integers(0, 30))
    lg = int(rng.integers(1, 4))
    while w <= (1 << lg):
        lg -= 1
    if mode == "local" and lg < 1:
        mode = "fixed"
    return DetectorConfig(
        width=w, height=h, pixel_bits=pixel_bits, threshold_mode=mode, threshold=t,
        background=int(rng.integers(0, t + 1)),
        ksigma=int(rng.integers(0, 1 << C.KSIGMA_BITS) if rng.random() < 0.2
                   else rng.integers(0, 3 << C.KSIGMA_FRAC_BITS)) / (1 << C.KSIGMA_FRAC_BITS),
        local_log2_window=max(lg, 1), local_offset=int(rng.integers(0, fs // 4)),
        min_pixels=min_pixels, min_sum=int(rng.choice([0, 0, 1, 50, 500, 5000])),
        max_pixels=max_pixels, record_capacity=int(rng.choice([0, 1, 2, 3, 5, 8, 512])))


def mode_frame(rng, mask, mode, pixel_bits, t):
    """A frame whose bright pixels follow ``mask``; in local mode a noisy background plus
    bright pixels, so the local thresholds separate them."""
    fs = C.full_scale(pixel_bits)
    if mode != "local":
        return lit_frame(mask, rng, t, pixel_bits)
    level = int(rng.integers(0, fs // 2))
    noise = rng.integers(0, fs // 32 + 1, size=mask.shape)
    bright = rng.integers(fs // 8, fs // 2, size=mask.shape)
    return shapes.to_frame(np.ones_like(mask),
                           np.minimum(level + noise + np.where(mask, bright, 0), fs))


@pytest.mark.parametrize("mode", ["fixed", "global", "local"])
@pytest.mark.parametrize("pixel_bits", [10, 12])
@pytest.mark.parametrize("density", DENSITIES)
def test_random_masks(density, pixel_bits, mode):
    h, w = 16, 24
    rng = np.random.default_rng(_seed(density, pixel_bits, mode))
    overflowed = 0
    for trial in range(16):
        mask = shapes.random_mask(h, w, density, int(rng.integers(1 << 30)))
        cfg = random_config(rng, w, h, pixel_bits, mode)
        if trial == 0:  # no filters, one record: every second blob overflows
            cfg = cfg.replace(min_pixels=0, min_sum=0, max_pixels=None, record_capacity=1)
        t = min(cfg.threshold, C.full_scale(pixel_bits) - 1)
        frame = mode_frame(rng, mask, mode, pixel_bits, t)
        prev = None
        if mode == "global" and trial % 3:
            prev = mode_frame(rng, shapes.random_mask(h, w, density, trial), "fixed",
                              pixel_bits, t)
        res = check(frame, cfg, prev)
        if trial == 0:
            assert bool(res.flags & C.FRAME_RECORD_OVERFLOW) == (res.n_blobs >= 2)
            assert res.dropped_records == max(res.n_blobs - 1, 0)
        if mode == "fixed":
            assert res.n_blobs == ndimage.label(frame > cfg.threshold, CROSS)[1]
            if trial == 0:
                assert np.array_equal(frame > cfg.threshold, mask)
        overflowed += bool(res.flags & C.FRAME_RECORD_OVERFLOW)
        assert res.n_blobs == res.n_filtered + res.dropped_records + len(res.blobs)
    if mode == "fixed" and density <= 0.5:
        assert overflowed  # the capacity path was exercised


# --------------------------------------------------------------------------------------
# Hypothesis: arbitrary small frames and registers
# --------------------------------------------------------------------------------------


@st.composite
def frames_and_configs(draw):
    pixel_bits = draw(st.sampled_from([8, 10, 12, 16]))
    fs = C.full_scale(pixel_bits)
    h = draw(st.integers(1, 6))
    w = draw(st.integers(1, 9))
    # a small palette makes equal values, full scale and values at the threshold common
    palette = draw(st.lists(st.integers(0, fs), min_size=1, max_size=4))
    palette = palette + [0, fs]
    elements = st.one_of(st.sampled_from(palette), st.integers(0, fs))
    frame = draw(arrays(np.uint16, (h, w), elements=elements, fill=st.nothing()))
    modes = ["fixed", "global"] + (["local"] if w > 2 else [])
    mode = draw(st.sampled_from(modes))
    # thresholds at (or just below) a pixel value of the frame make non-trivial masks
    values = sorted(set(frame.ravel().tolist()))
    t = draw(st.one_of(st.sampled_from(values), st.sampled_from(values),
                       st.integers(0, fs)))
    t = min(max(t - draw(st.integers(0, 1)), 0), fs)
    lg_max = min(3, (w - 1).bit_length() - 1) if w > 2 else 1  # 2**lg_max < w
    min_pixels = draw(st.integers(0, 4))
    cfg = DetectorConfig(
        width=w, height=h, pixel_bits=pixel_bits, threshold_mode=mode, threshold=t,
        background=draw(st.integers(0, fs)),
        ksigma=draw(st.one_of(st.integers(0, 24), st.integers(0, (1 << C.KSIGMA_BITS) - 1)))
        / (1 << C.KSIGMA_FRAC_BITS),
        local_log2_window=draw(st.integers(1, max(lg_max, 1))),
        local_offset=draw(st.one_of(st.integers(0, 3), st.integers(0, fs))),
        min_pixels=min_pixels,
        min_sum=draw(st.sampled_from([0, 0, 1, fs, 4 * fs])),
        max_pixels=draw(st.one_of(st.none(), st.integers(min_pixels, min_pixels + 8))),
        record_capacity=draw(st.integers(0, 6)))
    prev = None
    if mode == "global" and draw(st.booleans()):
        prev = draw(arrays(np.uint16, (h, w), elements=elements, fill=st.nothing()))
    return np.ascontiguousarray(frame), cfg, prev


@settings(deadline=None, max_examples=400,
          suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(frames_and_configs())
def test_hypothesis_frames(case):
    frame, cfg, prev = case
    res = check(frame, cfg, prev)
    event(f"mode {cfg.threshold_mode}")
    event(f"blobs {min(res.n_blobs, 3)}{'+' if res.n_blobs >= 3 else ''}")
    if res.flags & C.FRAME_RECORD_OVERFLOW:
        event("record overflow")
    if any(r.nsat for r in res.blobs):
        event("saturated pixels")


@settings(deadline=None, max_examples=300)
@given(st.integers(1, 6), st.integers(1, 9), st.data())
def test_hypothesis_masks(h, w, data):
    """Arbitrary masks, random values above/below the threshold, random filters/capacity."""
    mask = data.draw(arrays(np.bool_, (h, w), elements=st.booleans(), fill=st.nothing()))
    pixel_bits = data.draw(st.sampled_from([10, 12]))
    fs = C.full_scale(pixel_bits)
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    t = data.draw(st.integers(0, fs - 1))
    frame = lit_frame(mask, rng, t, pixel_bits, sat_fraction=0.2)
    min_pixels = data.draw(st.integers(0, 3))
    cfg = DetectorConfig(
        width=w, height=h, pixel_bits=pixel_bits, threshold=t,
        background=data.draw(st.integers(0, fs)), min_pixels=min_pixels,
        min_sum=data.draw(st.sampled_from([0, 1, fs])),
        max_pixels=data.draw(st.one_of(st.none(), st.integers(min_pixels, 6))),
        record_capacity=data.draw(st.integers(0, 4)))
    res = check(frame, cfg)
    assert res.n_blobs == ndimage.label(mask, CROSS)[1]
    event(f"blobs {min(res.n_blobs, 3)}{'+' if res.n_blobs >= 3 else ''}")


# --------------------------------------------------------------------------------------
# Saturation: full-scale pixels and saturated moments
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("pixel_bits", [10, 12])
def test_full_scale_pixels_nsat(pixel_bits):
    fs = C.full_scale(pixel_bits)
    rng = np.random.default_rng(_seed("nsat", pixel_bits))
    h, w = 16, 24
    for density in (0.2, 0.5, 0.9):
        mask = shapes.random_mask(h, w, density, int(rng.integers(1 << 30)))
        frame = lit_frame(mask, rng, fs // 4, pixel_bits, sat_fraction=0.5)
        cfg = DetectorConfig(width=w, height=h, pixel_bits=pixel_bits, threshold=fs // 4,
                             background=fs // 8, min_pixels=0)
        res = check(frame, cfg)
        n_fs = int((frame == fs).sum())
        assert n_fs > 0
        assert sum(r.nsat for r in res.blobs) == n_fs
        for r in res.blobs:
            assert (r.peak == fs) == (r.nsat > 0)
    # a full-scale frame: one blob, every pixel saturated
    frame = np.full((h, w), fs, dtype=np.uint16)
    for mode in ("fixed", "local"):
        cfg = DetectorConfig(width=w, height=h, pixel_bits=pixel_bits, threshold_mode=mode,
                             threshold=fs - 1, local_offset=0, local_log2_window=2)
        res = check(frame, cfg)
        if mode == "fixed":
            assert [(r.n, r.nsat, r.peak) for r in res.blobs] == [(h * w, h * w, fs)]
        else:  # T = min(mean + 0, fs) = fs: nothing is above full scale
            assert res.n_blobs == 0


@pytest.mark.parametrize("pixel_bits", [10, 12])
def test_global_threshold_clamps_at_full_scale(pixel_bits):
    fs = C.full_scale(pixel_bits)
    h, w = 8, 12
    prev = shapes.to_frame(shapes.checkerboard(h, w), fs)  # sigma = fs / 2
    frame = np.full((h, w), fs, dtype=np.uint16)
    cfg = DetectorConfig(width=w, height=h, pixel_bits=pixel_bits, threshold_mode="global",
                         ksigma=15.9375)
    res = check(frame, cfg, prev)
    assert res.threshold == fs and res.background == fs // 2 and res.n_blobs == 0


def _blob_expectation(pixels, weights):
    """Exact (unsaturated) moments of ``pixels`` [(x, y)] with ``weights``."""
    pw = list(zip(pixels, weights))
    return {
        "s0": sum(wt for _, wt in pw),
        "sx": sum(wt * x for (x, _), wt in pw),
        "sy": sum(wt * y for (_, y), wt in pw),
        "sxx": sum(wt * x * x for (x, _), wt in pw),
        "syy": sum(wt * y * y for (_, y), wt in pw),
        "sxy": sum(wt * x * y for (x, y), wt in pw),
    }


def saturation_blob(h, w, layout):
    """Pixels [(x, y)] of a bright blob at the far corner of an ``h x w`` frame.

    ``block``: 70 x 70 (4900 pixels), ``exact``: 64 x 64 (``EXACT_BLOB_PIXELS``), ``exact+1``:
    64 x 64 plus one pixel above its top-right corner; ``split``: 70 x 70 with a dark column
    in the middle down to the last row, so the two halves (each exact on its own) saturate
    only when the last row merges them; ``tooth_right`` / ``tooth_left``: a 70 x 70 block
    (saturated on its own) and a one-pixel-wide tooth two columns to its right / left,
    joined by the last row (the merge keeps, respectively absorbs, the saturated part).
    """
    if layout == "exact":
        return [(x, y) for y in range(h - 64, h) for x in range(w - 64, w)]
    if layout == "exact+1":
        return saturation_blob(h, w, "exact") + [(w - 1, h - 65)]
    if layout == "block":
        return [(x, y) for y in range(h - 70, h) for x in range(w - 70, w)]
    if layout == "split":
        gap = w - 35
        return [(x, y) for y in range(h - 70, h) for x in range(w - 70, w)
                if x != gap or y == h - 1]
    if layout == "tooth_right":
        block = [(x, y) for y in range(h - 70, h) for x in range(w - 73, w - 3)]
        return block + [(x, h - 1) for x in range(w - 3, w - 1)] + \
            [(w - 1, y) for y in range(h - 70, h)]
    if layout == "tooth_left":
        block = [(x, y) for y in range(h - 70, h) for x in range(w - 70, w)]
        return block + [(x, h - 1) for x in range(w - 73, w - 70)] + \
            [(w - 73, y) for y in range(h - 70, h - 1)]
    raise ValueError(layout)


SATURATION_CASES = [
    # (height, width, pixel_bits, layout, zero-weight last row, the moments that saturate)
    (4096, 4096, 16, "block", False, set(C.MOMENTS)),
    (80, 4096, 10, "block", False, {"s0", "sx", "sxx"}),
    (80, 4096, 12, "block", False, {"s0", "sx", "sxx"}),
    (80, 4096, 16, "block", False, {"s0", "sx", "sxx"}),
    (4096, 80, 16, "block", False, {"s0", "sy", "syy"}),
    (4096, 80, 12, "split", False, {"s0", "sy", "syy"}),
    (80, 4096, 16, "split", False, {"s0", "sx", "sxx"}),
    (80, 4096, 16, "tooth_right", False, {"s0", "sx", "sxx"}),
    (80, 4096, 12, "tooth_left", False, {"s0", "sx", "sxx"}),
    # the joining last row lit but of weight 0 (T < p <= B): the flag comes from the merge
    (80, 4096, 16, "split", True, {"s0", "sx", "sxx"}),
    (4096, 80, 16, "split", True, {"s0", "sy", "syy"}),
    (80, 4096, 12, "tooth_right", True, {"s0", "sx", "sxx"}),
    (80, 4096, 16, "tooth_left", True, {"s0", "sx", "sxx"}),
    # exactly EXACT_BLOB_PIXELS at the far corner: nothing saturates; one pixel more: s0 does
    (4096, 4096, 16, "exact", False, set()),
    (4096, 4096, 16, "exact+1", False, {"s0"}),
]


@pytest.mark.parametrize("h,w,pixel_bits,layout,join_zero,saturated", SATURATION_CASES)
def test_moment_saturation(h, w, pixel_bits, layout, join_zero, saturated):
    fs = C.full_scale(pixel_bits)
    pixels = saturation_blob(h, w, layout)
    # T = 0, B = 1: full-scale pixels weigh fs - 1, pixels of value 1 are lit but weigh 0
    t, b = 0, 1
    values = [1 if join_zero and y == h - 1 else fs for _, y in pixels]
    frame = np.zeros((h, w), dtype=np.uint16)
    xs, ys = zip(*pixels)
    frame[list(ys), list(xs)] = values
    frame[0, 0] = fs  # a one-pixel blob elsewhere, exact
    assert C.EXACT_BLOB_PIXELS == 4096
    cfg = DetectorConfig(width=w, height=h, pixel_bits=pixel_bits, threshold=t, background=b,
                         min_pixels=0)
    res, stats = both(frame, cfg)
    assert stats == numpy_stats(frame)
    assert res.n_blobs == 2 and len(res.blobs) == 2
    small, big = res.blobs  # the big blob's last pixel is the frame's last pixel
    assert (small.n, small.s0, small.sx, small.sy, small.flags) == (1, fs - b, 0, 0, 0)
    true = _blob_expectation(pixels, [max(v - b, 0) for v in values])
    lim = C.moment_max(pixel_bits)
    assert {m for m in C.MOMENTS if true[m] > lim[m]} == saturated  # the case is what it says
    assert big.flags == (C.BLOB_MOMENTS_SATURATED if saturated else 0)
    for m in C.MOMENTS:
        assert getattr(big, m) == (lim[m] if m in saturated else true[m]), m
    n_fs = sum(v == fs for v in values)
    assert (big.n, big.nsat, big.peak) == (len(pixels), n_fs, fs)
    assert (big.xmin, big.xmax, big.ymin, big.ymax) == (min(xs), max(xs), min(ys), max(ys))
    if pixel_bits == 16 and h * w <= 80 * 4096 and "s0" in saturated:
        # min_sum compares the saturated s0: the register maximum (= s0's maximum for
        # 16-bit pixels) still passes the saturated blob and rejects the small one
        assert lim["s0"] == (1 << C.REGISTER_BY_NAME["min_sum"].bits) - 1
        res2, _ = both(frame, cfg.replace(min_sum=lim["s0"]))
        assert res2.blobs == [big] and res2.n_filtered == 1


# --------------------------------------------------------------------------------------
# Multi-frame sequences: global mode and register changes between frames
# --------------------------------------------------------------------------------------


def sequence_frames(pixel_bits, h=24, w=32, n=5, seed=0):
    """Frames with changing background, noise and content; one of them constant."""
    fs = C.full_scale(pixel_bits)
    rng = np.random.default_rng(seed)
    names = sorted(shapes.ADVERSARIAL)
    frames = []
    for i in range(n):
        if i == 3:
            frames.append(np.full((h, w), fs // 5, dtype=np.uint16))  # sigma = 0
            continue
        level = int(rng.integers(fs // 16, fs // 3))
        noise = rng.integers(0, fs // 20, size=(h, w))
        mask = shapes.ADVERSARIAL[names[int(rng.integers(len(names)))]]()
        stars = np.where(mask, rng.integers(fs // 8, fs // 2, size=(h, w)), 0)
        spots = rng.random((h, w)) < 0.03
        frame = np.minimum(level + noise + stars + np.where(spots, fs, 0), fs)
        frames.append(shapes.to_frame(np.ones((h, w), bool), frame))
    return frames


@pytest.mark.parametrize("pixel_bits", [10, 12])
@pytest.mark.parametrize("ksigma", [0.0, 1.5, 3.0, 5.9375])
def test_global_sequence(pixel_bits, ksigma):
    frames = sequence_frames(pixel_bits, seed=_seed("seq", pixel_bits, ksigma))
    h, w = frames[0].shape
    cfg = DetectorConfig(width=w, height=h, pixel_bits=pixel_bits, threshold_mode="global",
                         threshold=C.full_scale(pixel_bits) // 2, background=7, ksigma=ksigma,
                         min_pixels=2, record_capacity=20)
    dets = {name: Detector(cfg, engine=name) for name in ("vectorized", "streaming")}
    for i, frame in enumerate(frames):
        rv = dets["vectorized"].process(frame)
        rs = dets["streaming"].process(frame)
        assert rv == rs and rv.header() == rs.header(), f"frame {i}"
        assert rv.frame_counter == i
        if i == 0:
            assert rv.flags & C.FRAME_GLOBAL_FALLBACK
            assert (rv.threshold, rv.background) == (cfg.threshold, cfg.background)
            t = cfg.threshold
            ref = reference(frame, cfg)
        else:
            prev = frames[i - 1].astype(np.uint64)
            n, s1, s2 = prev.size, int(prev.sum()), int((prev * prev).sum())
            t, b = C.global_levels(n, s1, s2, int(ksigma * 16), pixel_bits)
            assert not rv.flags & C.FRAME_GLOBAL_FALLBACK
            assert (rv.threshold, rv.background) == (t, b)
            if i - 1 == 3:  # constant previous frame: sigma = 0, T = B = its value
                assert t == b == C.full_scale(pixel_bits) // 5
            ref = reference(frame, cfg, frames[i - 1])
        ref.frame_counter = i
        assert rv == ref
        assert rv.n_blobs == ndimage.label(frame > t, CROSS)[1]


def test_configure_between_frames():
    pixel_bits = 12
    frames = sequence_frames(pixel_bits, n=8, seed=_seed("configure"))
    h, w = frames[0].shape
    base = DetectorConfig(width=w, height=h, pixel_bits=pixel_bits, threshold=900,
                          background=100, ksigma=2.5, local_log2_window=3, local_offset=150,
                          min_pixels=1, record_capacity=50)
    schedule = [
        base,                                                     # fixed
        base.replace(threshold_mode="global"),                    # stats of a fixed frame
        base.replace(threshold_mode="local"),
        base.replace(threshold_mode="global", ksigma=1.0, min_pixels=3),
        base.replace(threshold_mode="local", local_log2_window=1, local_offset=40),
        base.replace(threshold_mode="fixed", threshold=600, record_capacity=2),
        base.replace(threshold_mode="global", max_pixels=40),
        base.replace(threshold_mode="local", local_log2_window=2, min_sum=3000),
    ]
    dets = {name: Detector(base, engine=name) for name in ("vectorized", "streaming")}
    for i, (cfg, frame) in enumerate(zip(schedule, frames)):
        for det in dets.values():
            det.configure(cfg)
        rv = dets["vectorized"].process(frame)
        rs = dets["streaming"].process(frame)
        assert rv == rs and rv.header() == rs.header(), f"frame {i} ({cfg.threshold_mode})"
        ref = reference(frame, cfg, frames[i - 1] if i else None)
        ref.frame_counter = i
        assert rv == ref, f"frame {i}"
        assert rv.mode == cfg.mode
        assert not rv.flags & C.FRAME_GLOBAL_FALLBACK  # statistics gathered in every mode
        if cfg.threshold_mode == "local":
            assert (rv.threshold, rv.background) == (cfg.local_offset, 0)
        elif cfg.threshold_mode == "fixed":
            assert (rv.threshold, rv.background) == (cfg.threshold, cfg.background)
    # after a reset, global mode falls back again, in both engines
    for det in dets.values():
        det.reset()
        det.configure(base.replace(threshold_mode="global"))
    rv = dets["vectorized"].process(frames[0])
    rs = dets["streaming"].process(frames[0])
    assert rv == rs and rv.flags & C.FRAME_GLOBAL_FALLBACK and rv.frame_counter == 0
