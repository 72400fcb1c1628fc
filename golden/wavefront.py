"""The labeller algorithm of ``hdl/labeller.py`` in plain Python, column by column.

The gateware's algorithm (``docs/gateware.md``, The labeller) with Python lists instead of
memories, so that it can be checked exhaustively against the golden streaming model and a
gateware mismatch traced to the algorithm or to its transcription.  Per row it keeps the
previous row's nodes (``prev``), the current row's (``new``), the stack of straddling
components and the active run; ``events`` lists ``(clock, kind)`` of every memory access,
with one idle clock per row, so tests can check the one-access-per-two-clocks bound.
"""

from lodestar import contract as C

from .features import (
    FLAGS,
    MOMENTS,
    NSAT,
    PEAK,
    S0,
    SLOTS,
    SX,
    SXX,
    SXY,
    SY,
    SYY,
    XMAX,
    XMIN,
    YMAX,
    YMIN,
    N,
    record,
)


class Node:
    __slots__ = ("first", "last", "lab", "tracked")

    def __init__(self, first, last, lab, tracked):
        self.first, self.last, self.lab, self.tracked = first, last, lab, tracked


class Entry:
    __slots__ = ("lab", "tracked", "has_cur", "first_addr", "last_addr", "cont")

    def __init__(self, lab, tracked):
        self.lab, self.tracked = lab, tracked
        self.has_cur, self.first_addr, self.last_addr, self.cont = False, 0, 0, False


def _feat(x, y, p, w, fs):
    """The features of one pixel."""
    f = [0] * SLOTS
    f[N] = 1
    f[NSAT] = int(p == fs)
    wx = w * x
    wy = w * y
    f[S0] = w
    f[SX] = wx
    f[SY] = wy
    f[SXX] = wx * x
    f[SYY] = wy * y
    f[SXY] = wx * y
    f[XMIN] = f[XMAX] = x
    f[YMIN] = f[YMAX] = y
    f[PEAK] = p
    return f


def _combine(a, b, lim):
    """The features of the union of two blobs, moments saturated at ``lim``."""
    out = [0] * SLOTS
    out[N] = a[N] + b[N]
    out[NSAT] = a[NSAT] + b[NSAT]
    flags = a[FLAGS] | b[FLAGS]
    for slot, top in zip(MOMENTS, lim):
        v = a[slot] + b[slot]
        if v > top:
            v = top
            flags |= C.BLOB_MOMENTS_SATURATED
        out[slot] = v
    out[XMIN] = min(a[XMIN], b[XMIN])
    out[XMAX] = max(a[XMAX], b[XMAX])
    out[YMIN] = min(a[YMIN], b[YMIN])
    out[YMAX] = max(a[YMAX], b[YMAX])
    out[PEAK] = max(a[PEAK], b[PEAK])
    out[FLAGS] = flags
    return out


class WavefrontLabeller:
    """``run(lit, pixels, weights)`` -> dict of records and counts, as the gateware."""

    def __init__(self, width, height, pixel_bits, label_capacity, record_capacity,
                 min_pixels=1, min_sum=0, max_pixels=C.MAX_PIXELS_UNLIMITED):
        self.w, self.h = width, height
        self.fs = C.full_scale(pixel_bits)
        lim = C.moment_max(pixel_bits)
        self.lim = [lim[n] for n in C.MOMENTS]
        self.cap, self.rcap = label_capacity, record_capacity
        self.filters = (min_pixels, min_sum, max_pixels)

    # ---- slots ---------------------------------------------------------------------
    def _ev(self, kind):
        self.events.append((self.t, kind))

    def _alloc(self):
        self._ev("alloc")
        if self.free:
            return self.free.pop(0)
        self.fresh += 1
        return self.fresh - 1

    def _free(self, lab):
        self._ev("free")
        self.slot.pop(lab, None)
        self.free.append(lab)

    # ---- events --------------------------------------------------------------------
    def _merge(self, b):
        self._ev("merge")
        a = self.act
        if a["tracked"] or b.tracked:
            self.count -= 1
        tracked = a["tracked"] and b.tracked
        if b.has_cur:                                    # case (i): a nests inside b
            if a["has_cur"]:
                self.new[a["first_addr"]].first = False
                self._ev("first_patch")
                last = a["last_addr"]
            else:
                last = b.last_addr
            if tracked:
                self._ev("feat_read")
                self.acc = _combine(self.acc, self.slot[b.lab], self.lim)
                if a["has_slot"]:
                    self._free(a["lab"])
                a["lab"], a["has_slot"] = b.lab, True
            else:
                self._free_untracked(a, b)
            a.update(has_cur=True, first_addr=b.first_addr, last_addr=last)
        else:                                            # case (ii): b has no node yet
            if tracked:
                self._ev("feat_read")
                self.acc = _combine(self.acc, self.slot[b.lab], self.lim)
                if a["has_slot"]:
                    self._free(b.lab)
                else:
                    a["lab"], a["has_slot"] = b.lab, True
            else:
                self._free_untracked(a, b)
            if a["group"]:
                b.cont = True
        if not tracked and a["has_cur"]:
            self.new[a["first_addr"]].tracked = False   # the survivor's first node
            self._ev("tracked_patch")
        a["tracked"] = tracked
        a["group"] = True

    def _free_untracked(self, a, b):
        """A merge untracks the component: free the one slot either side held."""
        if a["has_slot"]:
            self._free(a["lab"])
        if b.tracked:
            self._free(b.lab)
        a["has_slot"] = False

    def _pop(self):
        self._ev("pop")
        e = self.stack.pop()
        if self.act is not None and self.act["group"]:
            self.act["group"] = e.cont
        elif e.cont:
            t = self.stack[-1]
            t.lab, t.tracked, t.has_cur = e.lab, e.tracked, e.has_cur
            t.first_addr, t.last_addr = e.first_addr, e.last_addr
        elif e.has_cur:
            self.new[e.last_addr].last = True
            self._ev("last_patch")
        elif e.tracked:
            self.count -= 1
            self._ev("feat_read")
            self._ev("complete")
            self._complete(self.slot[e.lab])
            self._free(e.lab)
        else:
            self.dropped_labels += 1

    def _complete(self, f):
        self.n_blobs += 1
        if not C.passes_filters(f[N], f[S0], *self.filters):
            self.n_filtered += 1
        elif len(self.records) < self.rcap:
            self.records.append(record(f))
        else:
            self.dropped_records += 1

    def _run_end(self):
        a = self.act
        if a["tracked"] and not a["has_slot"]:
            a["lab"], a["has_slot"] = self._alloc(), True
        self._ev("node_write")
        n = len(self.new)
        self.new.append(Node(not a["has_cur"], not a["group"], a["lab"], a["tracked"]))
        if a["tracked"]:
            self._ev("feat_write")
            self.slot[a["lab"]] = self.acc
        if a["group"]:
            t = self.stack[-1]
            t.lab, t.tracked, t.has_cur = a["lab"], a["tracked"], True
            t.first_addr = a["first_addr"] if a["has_cur"] else n
            t.last_addr = n
        self.act = None

    # ---- one frame -----------------------------------------------------------------
    def run(self, lit, pixels, weights):
        w = self.w
        self.slot, self.free, self.fresh = {}, [], 0
        self.count = self.peak = 0
        self.records, self.events = [], []
        self.n_blobs = self.n_filtered = self.dropped_records = self.dropped_labels = 0
        prev_lit = [False] * w
        prev = []
        for y in range(self.h + 1):
            cur = [bool(v) for v in lit[y]] if y < self.h else [False] * w
            self.new, self.stack, self.act = [], [], None
            k = 0                                        # next node of ``prev``
            for x in range(w):
                self.t = y * (w + 1) + x                 # one idle clock per row
                pl = prev_lit[x]
                ps = pl and (x == 0 or not prev_lit[x - 1])
                pe = pl and (x == w - 1 or not prev_lit[x + 1])
                pe = pe and prev[k - 1 + ps].last         # the node is its component's last
                c = cur[x]
                left = x > 0 and cur[x - 1]
                if ps:
                    node = prev[k]
                    k += 1
                    self._ev("node_read")
                    if node.first:
                        self._ev("push")
                        self.stack.append(Entry(node.lab, node.tracked))
                if c:
                    f = _feat(x, y, int(pixels[y][x]), int(weights[y][x]), self.fs)
                    if not left and pl:                  # run starts under a node
                        t = self.stack[-1]
                        self.act = dict(lab=t.lab, tracked=t.tracked, has_slot=t.tracked,
                                        has_cur=t.has_cur, first_addr=t.first_addr,
                                        last_addr=t.last_addr, group=True)
                        self._ev("continue")
                        self.acc = f
                        if t.tracked:
                            self._ev("feat_read")
                            self.acc = _combine(self.slot[t.lab], f, self.lim)
                    elif not left:                       # birth
                        self._ev("birth")
                        tracked = self.count < self.cap
                        self.count += tracked
                        self.act = dict(lab=None, tracked=tracked, has_slot=False,
                                        has_cur=False, first_addr=0, last_addr=0,
                                        group=False)
                        self.acc = f
                    else:
                        if ps and not (self.act["group"] and not prev[k - 1].first):
                            self._merge(self.stack[-1])
                        self.acc = _combine(self.acc, f, self.lim)
                    self.peak = max(self.peak, self.count)
                if pe:
                    self._pop()
                if c and (x == w - 1 or not cur[x + 1]):
                    self._run_end()
            assert not self.stack and self.act is None and k == len(prev)
            prev, prev_lit = self.new, cur
        assert self.count == 0 and not self.slot
        return self
