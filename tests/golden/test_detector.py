"""Hand-checked cases for every formula of the contract, through both golden engines."""

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.golden import ENGINES, Detector, DetectorConfig, detect_frame

ENGINE_NAMES = sorted(ENGINES)


def rec(n, nsat, s0, sx, sy, sxx, syy, sxy, xmin, xmax, ymin, ymax, peak, flags=0):
    """A record from a hand-checked row (the fields in record order)."""
    return C.BlobRecord(n=n, nsat=nsat, s0=s0, sx=sx, sy=sy, sxx=sxx, syy=syy, sxy=sxy,
                        xmin=xmin, xmax=xmax, ymin=ymin, ymax=ymax, peak=peak, flags=flags)


# x = column, y = row
HAND_FRAME = np.array([
    [10, 0, 0, 0, 0],    # (0,0) = 10 is not lit: lit means p > T strictly
    [0, 20, 12, 0, 0],
    [0, 0, 30, 0, 0],
    [0, 0, 0, 50, 11],   # (3,3) touches (2,2) only diagonally: a separate blob
], dtype=np.uint16)


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_fixed_mode_moments_by_hand(engine):
    cfg = DetectorConfig(width=5, height=4, threshold=10, background=5)
    res = detect_frame(HAND_FRAME, cfg, engine=engine)
    # A = (1,1) w15, (2,1) w7, (2,2) w25;  B = (3,3) w45, (4,3) w6
    a = rec(3, 0, 47, 79, 72, 143, 122, 129, 1, 2, 1, 2, 30)
    b = rec(2, 0, 51, 159, 153, 501, 459, 477, 3, 4, 3, 3, 50)
    assert res.blobs == [a, b]          # raster order of each blob's last pixel
    assert (res.threshold, res.background, res.mode) == (10, 5, C.MODE_FIXED)
    assert (res.n_blobs, res.n_filtered, res.dropped, res.flags) == (2, 0, 0, 0)


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_lit_pixel_below_background_has_zero_weight(engine):
    frame = np.array([[0, 5, 12, 0]], dtype=np.uint16)
    cfg = DetectorConfig(width=4, height=1, threshold=3, background=10)
    res = detect_frame(frame, cfg, engine=engine)
    # (1,0) w=0, (2,0) w=2
    assert res.blobs == [rec(2, 0, 2, 4, 0, 8, 0, 0, 1, 2, 0, 0, 12)]


@pytest.mark.parametrize("engine", ENGINE_NAMES)
@pytest.mark.parametrize("bits", [10, 12])
def test_saturated_pixels_are_counted(engine, bits):
    fs = C.full_scale(bits)
    frame = np.array([[0, fs, fs, 200], [0, 0, fs, 0]], dtype=np.uint16)
    cfg = DetectorConfig(width=4, height=2, pixel_bits=bits, threshold=100, background=0)
    (blob,) = detect_frame(frame, cfg, engine=engine).blobs
    assert (blob.n, blob.nsat, blob.peak, blob.s0) == (4, 3, fs, 3 * fs + 200)


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_global_mode_uses_previous_frame_statistics(engine):
    cfg = DetectorConfig(width=2, height=2, threshold_mode="global", threshold=25,
                         background=2, ksigma=3.0)
    det = Detector(cfg, engine=engine)
    first = det.process(np.array([[10, 10], [10, 30]], dtype=np.uint16))
    # first frame after reset: fixed registers, flagged
    assert (first.threshold, first.background) == (25, 2)
    assert first.flags == C.FRAME_GLOBAL_FALLBACK
    assert first.blobs == [rec(1, 0, 28, 28, 28, 28, 28, 28, 1, 1, 1, 1, 30)]
    # mean 15, sigma sqrt(75) = 8.660, 3 sigma = 25.98 -> T = 15 + 25 = 40
    second = det.process(np.array([[41, 40], [16, 0]], dtype=np.uint16))
    assert (second.threshold, second.background, second.flags) == (40, 15, 0)
    assert second.blobs == [rec(1, 0, 26, 0, 0, 0, 0, 0, 0, 0, 0, 0, 41)]
    assert (first.frame_counter, second.frame_counter) == (0, 1)
    det.reset()
    assert det.process(np.zeros((2, 2), np.uint16)).flags == C.FRAME_GLOBAL_FALLBACK


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_local_mode_by_hand(engine):
    # L = 2: window = the 3 columns s..s+2 minus the pixel, s = clamp(x-1, 0, W-3)
    frame = np.array([[10, 20, 30, 100, 30, 20]], dtype=np.uint16)
    cfg = DetectorConfig(width=6, height=1, threshold_mode="local", local_log2_window=1,
                         local_offset=5)
    res = detect_frame(frame, cfg, engine=engine)
    # x=3: s=2, (30 + 30) >> 1 = 30, T = 35 -> lit, w = 70.  x=2: (20+100)>>1 = 60, T 65.
    assert res.blobs == [rec(1, 0, 70, 210, 0, 630, 0, 0, 3, 3, 0, 0, 100)]
    assert (res.threshold, res.background, res.mode) == (5, 0, C.MODE_LOCAL)


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_local_mode_edges(engine):
    # L = 4 in a row of 6: the window slides inward, s = clamp(x-2, 0, 1)
    frame = np.array([[90, 10, 10, 10, 10, 10]], dtype=np.uint16)
    cfg = DetectorConfig(width=6, height=1, threshold_mode="local", local_log2_window=2,
                         local_offset=0)
    res = detect_frame(frame, cfg, engine=engine)
    # x=0: cols 0..4 minus 0: 40 >> 2 = 10 -> lit (90 > 10), w = 80
    # x=1: 90+10+10+10 = 120 >> 2 = 30 -> 10 not lit; x >= 2: means >= 10 -> not lit
    assert res.blobs == [rec(1, 0, 80, 0, 0, 0, 0, 0, 0, 0, 0, 0, 90)]


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_filters_and_record_capacity(engine):
    frame = np.zeros((3, 12), dtype=np.uint16)
    frame[0, 0] = 300                  # n=1, s0 = 300
    frame[0, 3:6] = 100                # n=3, s0 = 300
    frame[0, 8:10] = 200               # n=2, s0 = 400
    frame[2, 0:12] = 50                # n=12, s0 = 600
    base = DetectorConfig(width=12, height=3, threshold=10, background=0)
    by_n = {b.n: b for b in detect_frame(frame, base, engine=engine).blobs}
    assert sorted(by_n) == [1, 2, 3, 12]

    res = detect_frame(frame, base.replace(min_pixels=2, min_sum=350, max_pixels=11),
                       engine=engine)
    assert [b.n for b in res.blobs] == [2]
    assert (res.n_blobs, res.n_filtered, res.dropped_records) == (4, 3, 0)

    res = detect_frame(frame, base.replace(record_capacity=2), engine=engine)
    # emission order: last pixels (0,0), (5,0), (9,0), (11,2)
    assert [b.n for b in res.blobs] == [1, 3]
    assert (res.dropped_records, res.dropped, res.flags) == (2, 2, C.FRAME_RECORD_OVERFLOW)

    res = detect_frame(frame, base.replace(record_capacity=0, min_pixels=3), engine=engine)
    assert (res.blobs, res.n_filtered, res.dropped_records) == ([], 2, 2)


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_label_overflow_drops_untracked_blobs_and_recovers(engine):
    frame = np.array([[9, 0, 9],
                      [9, 0, 9],
                      [0, 9, 0]], dtype=np.uint16)
    cfg = DetectorConfig(width=3, height=3, threshold=1, label_capacity=1)
    res = detect_frame(frame, cfg, engine=engine)
    # A (column 0) takes the only label; B (column 2) starts while A is open: untracked.
    # Both complete on row 2 before C starts at (1, 2), which gets the label back.
    assert res.blobs == [rec(2, 0, 18, 0, 9, 0, 9, 0, 0, 0, 0, 1, 9),
                         rec(1, 0, 9, 9, 18, 9, 36, 18, 1, 1, 2, 2, 9)]
    assert (res.n_blobs, res.dropped_labels, res.flags) == (2, 1, C.FRAME_LABEL_OVERFLOW)


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_merge_with_untracked_blob_is_dropped_whole(engine):
    frame = np.array([[9, 0, 9],
                      [9, 0, 9],
                      [9, 9, 9]], dtype=np.uint16)
    cfg = DetectorConfig(width=3, height=3, threshold=1, label_capacity=1)
    res = detect_frame(frame, cfg, engine=engine)
    assert res.blobs == []
    assert (res.n_blobs, res.dropped_labels, res.dropped_records) == (0, 1, 0)
    # with the capacity that can never overflow, the U is one exact blob
    (u,) = detect_frame(frame, cfg.replace(label_capacity=None), engine=engine).blobs
    assert (u.n, u.s0, u.sx, u.sy) == (7, 63, 63, 72)


@pytest.mark.parametrize("engine", ENGINE_NAMES)
def test_moments_saturate_and_flag(engine):
    # 16-bit pixels, a 65 x 64 = 4160-pixel full-scale blob: s0 = 4160 * 65535 exceeds the
    # 28-bit s0 accumulator sized for 4096 such pixels.
    frame = np.zeros((66, 66), dtype=np.uint16)
    frame[1:66, 1:65] = 65535
    cfg = DetectorConfig(width=66, height=66, pixel_bits=16, threshold=100)
    (blob,) = detect_frame(frame, cfg, engine=engine).blobs
    lim = C.moment_max(16)
    assert blob.flags == C.BLOB_MOMENTS_SATURATED
    assert blob.s0 == lim["s0"] and 4160 * 65535 > lim["s0"]
    assert (blob.n, blob.nsat, blob.xmin, blob.xmax, blob.ymin, blob.ymax) == \
        (4160, 4160, 1, 64, 1, 65)
    xs, ys = np.meshgrid(np.arange(1, 65), np.arange(1, 66))
    assert blob.sxx == min(int((65535 * xs * xs).sum()), lim["sxx"])
    # 4096 pixels stay exact
    frame[65, :] = 0
    (exact,) = detect_frame(frame, cfg, engine=engine).blobs
    assert exact.flags == 0 and exact.s0 == 4096 * 65535
