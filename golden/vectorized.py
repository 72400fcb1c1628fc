"""Fast golden model: whole-frame numpy + ``scipy.ndimage`` implementation of the contract.

It labels the lit mask at once with exact ``uint64`` moment sums saturated to the contract
widths, and orders records by the raster index of each blob's last pixel: the reference for
large frames and campaigns.  A whole-frame method cannot see label capacity directly, so
``detect`` bounds the open blobs from above; a frame that could exceed the capacity is handed
to the streaming model (:mod:`lodestar.golden.streaming`), so results always match it.  The
bound: ``docs/golden_models.md`` (Vectorized model).
"""

import numpy as np
from scipy import ndimage

from lodestar import contract as C
from lodestar.contract import DetectionResult

from .frame import FrameStats, frame_levels

_FOUR_CONNECTED = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)


def local_levels(frame, cfg):
    """Per-pixel ``(T, B)`` arrays of local mode (``contract`` module docstring)."""
    h, w = frame.shape
    lg = cfg.local_log2_window
    win = 1 << lg
    p = frame.astype(np.int64)
    csum = np.zeros((h, w + 1), dtype=np.int64)
    np.cumsum(p, axis=1, out=csum[:, 1:])
    start = np.clip(np.arange(w) - win // 2, 0, w - 1 - win)
    total = csum[:, start + win + 1] - csum[:, start] - p
    mean = total >> lg
    t = np.minimum(mean + cfg.local_offset, C.full_scale(cfg.pixel_bits))
    return t, mean


def frame_stats(frame):
    """``FrameStats`` of a frame (exact: sums of up to 2**24 values below 2**32 fit uint64)."""
    p = frame.astype(np.uint64)
    return FrameStats(int(frame.size), int(p.sum()), int((p * p).sum()))


def open_blob_bound(lit):
    """Upper bound on blobs open at once over the scan of ``lit`` (0 for an empty mask)."""
    h, w = lit.shape
    left = np.zeros_like(lit)
    left[:, 1:] = lit[:, :-1]
    up = np.zeros_like(lit)
    up[1:, :] = lit[:-1, :]
    births = lit & ~left & ~up
    if not births.any():
        return 0
    run_starts = (lit & ~left).astype(np.int32)
    # prefix[y, k] = run starts in row y at columns < k
    prefix = np.zeros((h, w + 1), dtype=np.int32)
    np.cumsum(run_starts, axis=1, out=prefix[:, 1:])
    ys, xs = np.nonzero(births)
    # runs in row y left of x-1 (x-1 is dark at a birth): starts at columns <= x-2
    cur = prefix[ys, np.maximum(xs - 1, 0)]
    # runs in row y-1 right of x (x is dark above a birth): starts at columns >= x+1
    prev = np.where(ys > 0, prefix[ys - 1, w] - prefix[ys - 1, np.minimum(xs + 1, w)], 0)
    return int((cur + prev).max()) + 1


def _reduce(values, starts, ufunc):
    return ufunc.reduceat(values, starts) if len(starts) else values[:0]


def measure(frame, lit, weight, pixel_bits):
    """Exact features of every 4-connected blob of ``lit``, in emission order.

    Returns a list of ``BlobRecord``.  ``weight`` is the per-pixel weight array.
    """
    labels, count = ndimage.label(lit, structure=_FOUR_CONNECTED)
    if count == 0:
        return []
    h, w = lit.shape
    idx = np.flatnonzero(labels)                 # raster order
    lab = labels.ravel()[idx]
    order = np.argsort(lab, kind="stable")       # group by blob, raster order inside
    idx = idx[order]
    lab = lab[order]
    starts = np.flatnonzero(np.r_[True, lab[1:] != lab[:-1]])

    ys = (idx // w).astype(np.uint64)
    xs = (idx % w).astype(np.uint64)
    p = frame.ravel()[idx]
    wt = weight.ravel()[idx].astype(np.uint64)
    fs = C.full_scale(pixel_bits)

    fields = {
        "n": np.diff(np.r_[starts, len(idx)]),
        "nsat": _reduce((p == fs).astype(np.int64), starts, np.add),
        "s0": _reduce(wt, starts, np.add),
        "sx": _reduce(wt * xs, starts, np.add),
        "sy": _reduce(wt * ys, starts, np.add),
        "sxx": _reduce(wt * xs * xs, starts, np.add),
        "syy": _reduce(wt * ys * ys, starts, np.add),
        "sxy": _reduce(wt * xs * ys, starts, np.add),
        "xmin": _reduce(xs, starts, np.minimum),
        "xmax": _reduce(xs, starts, np.maximum),
        "ymin": ys[starts],                      # first pixel in raster order
        "ymax": _reduce(ys, starts, np.maximum),
        "peak": _reduce(p, starts, np.maximum),
    }
    last = _reduce(idx, starts, np.maximum)

    limits = C.moment_max(pixel_bits)
    saturated = np.zeros(len(starts), dtype=bool)
    for name in C.MOMENTS:
        over = fields[name] > np.uint64(limits[name])
        saturated |= over
        fields[name] = np.where(over, np.uint64(limits[name]), fields[name])
    fields["flags"] = np.where(saturated, C.BLOB_MOMENTS_SATURATED, 0)

    order = np.argsort(last, kind="stable")
    columns = [fields[name][order].tolist() for name in C.RECORD_NAMES]
    return [C.BlobRecord(**dict(zip(C.RECORD_NAMES, values))) for values in zip(*columns)]


def detect(frame, cfg, prev_stats):
    """Detect one checked ``uint16`` frame.  Returns ``(DetectionResult, FrameStats)``.

    ``prev_stats`` are the previous complete frame's statistics (global mode) or None.
    """
    t, b, flags = frame_levels(cfg, prev_stats)
    if cfg.threshold_mode == "local":
        t_px, b_px = local_levels(frame, cfg)
        lit = frame > t_px
        weight = np.maximum(frame.astype(np.int64) - b_px, 0)
    else:
        lit = frame > t
        weight = np.maximum(frame.astype(np.int64) - b, 0)

    if cfg.labels < C.max_open_blobs(cfg.width) and open_blob_bound(lit) > cfg.labels:
        from .streaming import detect as streaming_detect
        return streaming_detect(frame, cfg, prev_stats)

    n_filtered = 0
    dropped_records = 0
    emitted = []
    max_pixels = cfg.max_pixels_reg
    records = measure(frame, lit, weight, cfg.pixel_bits)
    for rec in records:
        if not C.passes_filters(rec.n, rec.s0, cfg.min_pixels, cfg.min_sum, max_pixels):
            n_filtered += 1
        elif len(emitted) < cfg.record_capacity:
            emitted.append(rec)
        else:
            dropped_records += 1
    if dropped_records:
        flags |= C.FRAME_RECORD_OVERFLOW
    result = DetectionResult(
        blobs=emitted, mode=cfg.mode, threshold=t, background=b, n_blobs=len(records),
        n_filtered=n_filtered, dropped_records=dropped_records, dropped_labels=0, flags=flags,
        width=cfg.width, height=cfg.height, pixel_bits=cfg.pixel_bits)
    return result, frame_stats(frame)
