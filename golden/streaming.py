"""Streaming reference model: a pixel-by-pixel executable spec of the detection contract.

It consumes pixels in raster order, one at a time (``docs/conventions.md``), with a
threshold unit, label row buffer, merge table, feature table, completion test and label
reuse, with the gateware's capacities (``cfg.labels`` open blobs,
``cfg.record_capacity`` records).  Its results are the contract's (``docs/contract.md``),
capacity limits included; ``peak_labels`` and ``peak_open`` report the merge-table and
feature-table depths a frame needed.  The structures and the completion rule:
``docs/golden_models.md`` (Streaming model).
"""

import numpy as np

from lodestar import contract as C
from lodestar.contract import DetectionResult

from .features import FLAGS, MOMENTS, NSAT, PEAK, S0, SLOTS, XMAX, XMIN, YMAX, YMIN, N, record
from .frame import FrameStats, frame_levels

# feature-table slots: the record's (.features), then the blob's last raster index and
# whether it is tracked
_LAST = SLOTS
_TRACKED = SLOTS + 1
_TABLE_SLOTS = SLOTS + 2


class StreamingModel:
    """Detects frames pixel by pixel.  ``run(frame, prev_stats) -> (result, stats)``."""

    def __init__(self, cfg):
        self.cfg = cfg
        self.fs = C.full_scale(cfg.pixel_bits)
        lim = C.moment_max(cfg.pixel_bits)
        self.lim = [lim[name] for name in C.MOMENTS]
        self.peak_labels = 0
        self.peak_open = 0

    # -- merge table and label pool ----------------------------------------------------
    def _new_label(self):
        if self.free:
            lab = self.free.pop()
        else:
            self.parent.append(0)
            self.refs.append(0)
            self.feat.append(None)
            lab = len(self.parent) - 1
        self.parent[lab] = lab
        self.refs[lab] = 0
        self.alive += 1
        if self.alive > self.peak_labels:
            self.peak_labels = self.alive
        return lab

    def _find(self, lab):
        parent = self.parent
        while parent[lab] != lab:
            lab = parent[lab]
        return lab

    def _release(self, lab):
        """Drop one reference to ``lab``; free it (and its ancestors) when none is left."""
        refs = self.refs
        parent = self.parent
        while True:
            refs[lab] -= 1
            if refs[lab]:
                return
            up = parent[lab]
            if up == lab:
                if self.feat[lab] is not None:
                    raise AssertionError("streaming model: freed the root of an open blob")
                self.free.append(lab)
                self.alive -= 1
                return
            self.free.append(lab)
            self.alive -= 1
            lab = up

    # -- feature table -----------------------------------------------------------------
    def _start(self, x, y, p, w, raster):
        lab = self._new_label()
        if self.open_tracked < self.cfg.labels:
            self.open_tracked += 1
            if self.open_tracked > self.peak_open:
                self.peak_open = self.open_tracked
            f = [0] * _TABLE_SLOTS
            f[XMIN] = f[XMAX] = x
            f[YMIN] = f[YMAX] = y
            f[_TRACKED] = True
        else:
            f = [0] * _TABLE_SLOTS
            f[_TRACKED] = False
        self.feat[lab] = f
        self._add(f, x, y, p, w, raster)
        return lab

    def _add(self, f, x, y, p, w, raster):
        f[_LAST] = raster
        if not f[_TRACKED]:
            return
        f[N] += 1
        if p == self.fs:
            f[NSAT] += 1
        if p > f[PEAK]:
            f[PEAK] = p
        if x < f[XMIN]:
            f[XMIN] = x
        if x > f[XMAX]:
            f[XMAX] = x
        f[YMAX] = y
        if w:
            lim = self.lim
            terms = (w, w * x, w * y, w * x * x, w * y * y, w * x * y)   # C.MOMENTS
            for k in range(6):
                slot = MOMENTS[k]
                v = f[slot] + terms[k]
                if v > lim[k]:
                    v = lim[k]
                    f[FLAGS] |= C.BLOB_MOMENTS_SATURATED
                f[slot] = v

    def _union(self, keep, gone):
        """Merge root ``gone`` into root ``keep`` (``parent[gone] = keep``)."""
        fk = self.feat[keep]
        fg = self.feat[gone]
        self.parent[gone] = keep
        self.refs[keep] += 1
        self.feat[gone] = None
        if fk[_LAST] < fg[_LAST]:
            fk[_LAST] = fg[_LAST]
        if not (fk[_TRACKED] and fg[_TRACKED]):
            if fk[_TRACKED] or fg[_TRACKED]:
                self.open_tracked -= 1
            fk[_TRACKED] = False
            return
        self.open_tracked -= 1
        fk[N] += fg[N]
        fk[NSAT] += fg[NSAT]
        lim = self.lim
        for k in range(6):
            slot = MOMENTS[k]
            v = fk[slot] + fg[slot]
            if v > lim[k]:
                v = lim[k]
                fk[FLAGS] |= C.BLOB_MOMENTS_SATURATED
            fk[slot] = v
        fk[FLAGS] |= fg[FLAGS]
        fk[XMIN] = min(fk[XMIN], fg[XMIN])
        fk[XMAX] = max(fk[XMAX], fg[XMAX])
        fk[YMIN] = min(fk[YMIN], fg[YMIN])
        fk[YMAX] = max(fk[YMAX], fg[YMAX])
        fk[PEAK] = max(fk[PEAK], fg[PEAK])

    def _complete(self, root):
        f = self.feat[root]
        self.feat[root] = None
        if not f[_TRACKED]:
            self.dropped_labels += 1
            return
        self.open_tracked -= 1
        self.n_blobs += 1
        cfg = self.cfg
        if not C.passes_filters(f[N], f[S0], cfg.min_pixels, cfg.min_sum, cfg.max_pixels_reg):
            self.n_filtered += 1
        elif len(self.records) < cfg.record_capacity:
            self.records.append(record(f))
        else:
            self.dropped_records += 1

    # -- threshold unit ----------------------------------------------------------------
    def _local_row(self, row):
        """Per-pixel (T, B) of one row by a running window sum, as the gateware computes."""
        cfg = self.cfg
        lg = cfg.local_log2_window
        win = 1 << lg
        w = len(row)
        # window [s, s + win] inclusive; s advances by at most one column per pixel
        s = C.local_window_start(0, w, lg)
        acc = 0
        for c in range(s, s + win + 1):
            acc += row[c]
        ts, bs = [0] * w, [0] * w
        for x in range(w):
            ns = C.local_window_start(x, w, lg)
            if ns != s:
                acc += row[ns + win] - row[s]
                s = ns
            m = (acc - row[x]) >> lg
            bs[x] = m
            t = m + cfg.local_offset
            ts[x] = t if t < self.fs else self.fs
        return ts, bs

    # -- one frame -----------------------------------------------------------------------
    def run(self, frame, prev_stats):
        cfg = self.cfg
        width, height = cfg.width, cfg.height
        # label 0 means "no label"; real labels start at 1
        self.parent, self.refs, self.feat, self.free = [0], [0], [None], []
        self.alive = 0
        self.open_tracked = 0
        self.records = []
        self.n_blobs = self.n_filtered = self.dropped_records = self.dropped_labels = 0
        t_frame, b_frame, flags = frame_levels(cfg, prev_stats)
        local = cfg.threshold_mode == "local"

        rowbuf = [0] * width
        s1 = s2 = 0
        for y in range(height + 1):
            if y < height:
                row_np = frame[y]
                row = row_np.tolist()
                r64 = row_np.astype(np.int64)
                s1 += int(r64.sum())
                s2 += int((r64 * r64).sum())
                if local:
                    ts, bs = self._local_row(row)
                    lit_cols = [x for x in range(width) if row[x] > ts[x]]
                else:
                    lit_cols = np.flatnonzero(row_np > t_frame).tolist()
            else:  # virtual dark row: completes the blobs of the last row
                lit_cols = []
            lit_set = set(lit_cols)
            cols = sorted(lit_set.union(x for x in range(width) if rowbuf[x]))
            cur = 0
            prev_x = -2
            for x in cols:
                if x != prev_x + 1:
                    cur = 0
                prev_x = x
                u = rowbuf[x]
                if x in lit_set:
                    p = row[x]
                    b = bs[x] if local else b_frame
                    w = p - b if p > b else 0
                    raster = y * width + x
                    ru = self._find(u) if u else 0
                    if cur and ru and ru != cur:
                        self._union(cur, ru)
                        r = cur
                    else:
                        r = cur or ru
                    if r:
                        self._add(self.feat[r], x, y, p, w, raster)
                    else:
                        r = self._start(x, y, p, w, raster)
                    cur = r
                    self.refs[r] += 1
                    rowbuf[x] = r
                else:
                    cur = 0
                    rowbuf[x] = 0
                if u:
                    root = self._find(u)
                    if self.feat[root] is not None and \
                            self.feat[root][_LAST] == (y - 1) * width + x:
                        self._complete(root)
                    self._release(u)
        if self.alive:
            raise AssertionError("streaming model: labels still alive at frame end")

        if self.dropped_records:
            flags |= C.FRAME_RECORD_OVERFLOW
        if self.dropped_labels:
            flags |= C.FRAME_LABEL_OVERFLOW
        result = DetectionResult(
            blobs=self.records, mode=cfg.mode, threshold=t_frame, background=b_frame,
            n_blobs=self.n_blobs, n_filtered=self.n_filtered,
            dropped_records=self.dropped_records, dropped_labels=self.dropped_labels,
            flags=flags, width=width, height=height, pixel_bits=cfg.pixel_bits)
        return result, FrameStats(width * height, s1, s2)


def detect(frame, cfg, prev_stats):
    """Detect one checked ``uint16`` frame.  Returns ``(DetectionResult, FrameStats)``."""
    return StreamingModel(cfg).run(frame, prev_stats)
