"""Feature engine: blob features per label slot, merged on union, emitted at completion.

Each open tracked component's features are kept in a table of ``slots`` entries in the
compact record layout (``hdl.layouts.record_layout``; ``flags`` is the moment-saturation
flag).  Sums saturate at the contract's moment widths; counts, box and peak are exact.  The
table's read is not transparent: its output goes into a register and the bypass is
explicit, so that it maps to a synchronous-read block RAM and its output starts no long
path.  The op fields, frame tags and the arithmetic: ``docs/gateware.md``.
"""

from amaranth import Cat, Const, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .layouts import FRAME_TAG_BITS, op_layout, record_fields, record_layout

_HEADER_BITS = dict(C.HEADER_FIELDS)
PRODUCT_SPLIT = 18
"""Bits of a second moment's wide factor (``w x``, ``w y``) that one embedded multiplier
takes (18 x 18 on Cyclone IV and on the ECP5 proxy); the rest go to a second one."""


def _sums(m, acc, slot, use, pix, empties, fields):
    """Counts and moments of ``acc (+) slot (+) pix``, the slot taken if ``use`` (the engine
    passes the slot already masked and ``use`` 1, so the sums start at registers), all zero
    if ``empties``; returns ``({name: sum}, saturated)``.  Each sum is one carry-save layer
    and one carry chain; a moment saturates once (``min(a + b + c, max)``: the chain's
    carry-out or the top carry bit), a count never overflows; ``empties`` only masks the
    results (its fan-out comes after the chains).  ``saturated`` is the OR of the operands'
    flags and of every saturating sum (0 if ``empties``)."""
    out = {}
    keep = ~empties
    sat = acc.flags | (use & slot.flags) | pix.flags
    for name, bits in fields:
        if not (name in C.MOMENTS or name in ("n", "nsat")):
            continue
        x, y, z = acc[name], slot[name] & use.replicate(bits), pix[name]
        half = x ^ y ^ z                                 # a + b + c = half + 2 carry
        carry = (x & y) | (x & z) | (y & z)
        high = Signal(bits, name=f"sum_{name}")          # bits 1.. of the sum, carry-out
        m.d.comb += high.eq(half[1:] + carry[:bits - 1])
        if name in C.MOMENTS:
            total = Cat(half[0], high[:bits - 1])
            over = high[bits - 1] | carry[bits - 1]
            out[name] = (total | over.replicate(bits)) & keep.replicate(bits)
            sat = sat | over
        else:                                            # counts never exceed their width
            out[name] = Cat(half[0], high[:bits - 1]) & keep.replicate(bits)
    return out, sat & keep


def _below(value, bound):
    """``value < bound``, compared in ``value``'s width (``bound`` may be wider); strict
    comparisons need only a carry chain's carry-out, no equality term."""
    n = len(value)
    if len(bound) <= n:
        return value < bound
    return (bound[n:] != 0) | (value < bound[:n])


def _above(value, bound):
    """``value > bound``, compared in ``value``'s width (``bound`` may be wider)."""
    n = len(value)
    if len(bound) <= n:
        return value > bound
    return (bound[n:] == 0) & (value > bound[:n])


def empty_features(width, height):
    """The identity of ``(+)``: no pixels, an inverted bounding box."""
    return {"xmin": (1 << C.bits_for(width - 1)) - 1, "ymin": (1 << C.bits_for(height - 1)) - 1}


class FeatureEngine(wiring.Component):
    """Feature table, accumulator and record emission for ``width x height`` frames.  An
    op entering at clock ``c`` writes its slot and record at ``c + 4``; a slot is read back
    correctly two or more clocks after its write.

    Parameters
    ----------
    width, height : int
        Frame size in pixels.
    pixel_bits : int
        Bits per pixel.
    slots : int
        Entries of the feature table (``labeller.slots_for``).
    record_capacity : int
        Most records emitted per frame (``1 .. contract.MAX_RECORD_CAPACITY``).

    Members
    -------
    ops : ``In(stream.Signature(op_layout(...), always_ready=True))``
        The labeller's ops: one per decided column, at most one per clock, in raster order.
    wr_slot : ``In(bits_for(slots - 1))``
        The write slot of the op of the previous clock (its ``wr``): a clock late, so the
        labeller delivers it from a register (its column decision ends at fewer flip-flops);
        the slot is written at stage 4 only.
    tag : ``In(FRAME_TAG_BITS)``
        The current frame's tag: ops with another tag are stale and ignored.
    clear : ``In(1)``
        A frame starts: the counters and the accumulator restart.
    min_pixels, min_sum, max_pixels : ``In``
        The filter registers (contract ``passes_filters``), for the current frame.
    records : ``Out(stream.Signature(record_layout(width, height, pixel_bits)))``
        A completed blob's record, if it passes the filters and fewer than
        ``record_capacity`` records left this frame; not taken at once, it is dropped.
    n_blobs, n_filtered, dropped_records, n_records : ``Out``
        This frame's counts (trailer fields): blobs completed, filtered out, dropped for
        lack of room or of ``ready``, and emitted.
    busy : ``Out(1)``
        Ops are in the pipeline.
    """

    def __init__(self, width, height, pixel_bits, slots, record_capacity):
        if not 1 <= record_capacity <= C.MAX_RECORD_CAPACITY:
            raise ValueError(f"record_capacity={record_capacity} is out of range "
                             f"1..{C.MAX_RECORD_CAPACITY}")
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.slots, self.record_capacity = slots, record_capacity
        reg = C.REGISTER_BY_NAME
        super().__init__({
            "ops": In(stream.Signature(op_layout(width, height, pixel_bits, slots),
                                       always_ready=True)),
            "wr_slot": In(C.bits_for(slots - 1)),
            "tag": In(FRAME_TAG_BITS),
            "clear": In(1),
            "min_pixels": In(reg["min_pixels"].bits),
            "min_sum": In(reg["min_sum"].bits),
            "max_pixels": In(reg["max_pixels"].bits),
            "records": Out(stream.Signature(record_layout(width, height, pixel_bits))),
            "n_blobs": Out(_HEADER_BITS["n_blobs"]),
            "n_filtered": Out(_HEADER_BITS["n_filtered"]),
            "dropped_records": Out(_HEADER_BITS["dropped_records"]),
            "n_records": Out(_HEADER_BITS["n_records"]),
            "busy": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        W, H, pb = self.width, self.height, self.pixel_bits
        layout = record_layout(W, H, pb)
        fs = C.full_scale(pb)
        empty = layout.const(empty_features(W, H))

        m.submodules.table = table = Memory(shape=layout, depth=self.slots, init=[])
        wp = table.write_port()
        rp = table.read_port()          # not transparent: the bypass is written below

        # ---- stage 1: op registered, slot read issued, first products --------------
        # a clock without an op with a pixel has weight 0: its products and terms are 0
        op1 = Signal.like(self.ops.payload, reset_less=True)
        v1 = Signal()
        m.d.sync += [op1.eq(self.ops.payload), v1.eq(self.ops.valid)]
        m.d.comb += [rp.addr.eq(op1.rd_addr), rp.en.eq(v1 & op1.rd)]
        w1 = Signal(pb)
        m.d.comb += w1.eq(Mux(v1 & op1.pix, op1.w, 0))
        w2 = Signal(pb, reset_less=True)
        wx1 = Signal(pb + len(op1.x), reset_less=True)
        wy1 = Signal(pb + len(op1.y), reset_less=True)
        op2 = Signal.like(op1, reset_less=True)
        v2 = Signal()
        # the op's write slot comes a clock after it (``wr_slot``), for stage 4
        wr_slot2, wr_slot3, wr_slot4 = (Signal(len(self.wr_slot), reset_less=True,
                                               name=f"wr_slot{k}") for k in (2, 3, 4))
        m.d.sync += [op2.eq(op1), v2.eq(v1), w2.eq(w1), wx1.eq(w1 * op1.x),
                     wy1.eq(w1 * op1.y), wr_slot2.eq(self.wr_slot), wr_slot3.eq(wr_slot2),
                     wr_slot4.eq(wr_slot3)]
        # read-during-write bypass (read at stage 1, written at stage 4): a read sees the
        # writes of its clock (``hit_a``) and of the next (``hit_b``, which wins), i.e. at
        # stage 3 ``acc`` (``hit_b3``) or ``acc`` a clock before: no adder feeds the bypass
        hit_a2 = Signal(reset_less=True)
        hit3 = Signal(reset_less=True)
        hit_b3 = Signal(reset_less=True)
        acc_prev3 = Signal(layout, reset_less=True)
        acc = Signal(layout, reset_less=True)
        acc_next = Signal(layout)
        m.d.sync += hit_a2.eq(wp.en & (wp.addr == op1.rd_addr))
        hit_b2 = wp.en & (wp.addr == op2.rd_addr)
        # ---- stage 2: second products, the pixel's terms, slot data registered -------
        # pixf: the pixel's record (empty without an op with a pixel), its second moments
        # as registered partial products (``parts``), added at stage 3
        pix2 = v2 & op2.pix
        pixf = Signal(layout, reset_less=True)
        parts = self._partial_products(m, wx1, wy1, op2)
        op3 = Signal.like(op1, reset_less=True)
        v3 = Signal()
        raw3 = Signal(layout, reset_less=True)
        m.d.sync += [
            op3.eq(op2), v3.eq(v2), raw3.eq(rp.data),
            hit3.eq(hit_a2 | hit_b2), hit_b3.eq(hit_b2), acc_prev3.eq(acc),
            pixf.n.eq(pix2), pixf.nsat.eq(pix2 & (op2.p == fs)),
            pixf.s0.eq(w2), pixf.sx.eq(wx1), pixf.sy.eq(wy1),
            pixf.flags.eq(0),
        ]
        # ---- stage 3: slot data, filters, box and peak terms -------------------------
        # slot4: the slot read (a completed record); term4: it if used, else 0; best4: box and
        # peak terms, the better of the slot (if used; the upper neighbour's) and the pixel
        slot3 = Signal(layout)
        m.d.comb += slot3.eq(Mux(hit3, Mux(hit_b3, acc, acc_prev3), raw3))
        pix3 = v3 & op3.pix
        use3 = v3 & op3.rd
        pix4 = Signal(layout, reset_less=True)
        op4 = Signal.like(op1, reset_less=True)
        v4 = Signal()
        slot4 = Signal(layout, reset_less=True)
        term4 = Signal(layout, reset_less=True)
        best4 = Signal(layout, reset_less=True)
        passes = Signal(reset_less=True)  # the slot read passes the filters
        m.d.sync += [
            op4.eq(op3), v4.eq(v3), slot4.eq(slot3), pix4.eq(pixf),
            term4.eq(Mux(use3, slot3.as_value(), 0)),
            *[pix4[name].eq(lo + (hi << PRODUCT_SPLIT)) for name, (lo, hi) in parts.items()],
            passes.eq(~_below(slot3.n, self.min_pixels) & ~_above(slot3.n, self.max_pixels) &
                      ~_below(slot3.s0, self.min_sum)),
        ]
        for name, value in (("xmin", op3.x), ("xmax", op3.x), ("ymin", op3.y)):
            m.d.sync += best4[name].eq(Mux(use3, slot3[name], Mux(pix3, value, empty[name])))
        better = slot3.peak > op3.p
        m.d.sync += best4.peak.eq(Mux(use3 & better, slot3.peak, Mux(pix3, op3.p, 0)))
        # ---- stage 4: accumulator, slot write, completion ---------------------------
        # acc (+) term4 (+) pix4.  A dark op, a stale op, and a clock without an op after
        # the row's last column or a clear empty the accumulator; any other clock without
        # an op adds nothing to it (term4 zero, pix4 empty)
        live = v4 & (op4.tag == self.tag)
        run_open = Signal()           # the last op was a pixel that may continue its run
        with m.If(self.clear):
            m.d.sync += run_open.eq(0)
        with m.Elif(v4):
            m.d.sync += run_open.eq(live & op4.pix & (op4.x != W - 1))
        empties = Mux(v4, ~(live & op4.pix), ~run_open)
        self._accumulate(m, acc, acc_next, term4, pix4, best4, empties,
                         Mux(v4, op4.y, acc.ymax))
        m.d.comb += [wp.addr.eq(wr_slot4), wp.data.eq(acc_next),
                     wp.en.eq(live & op4.wr)]
        self._complete(m, live & op4.complete, passes, slot4)
        m.d.comb += self.busy.eq(v1 | v2 | v3 | v4)
        return m

    @staticmethod
    def _partial_products(m, wx1, wy1, op2):
        """``{moment: (lo, hi)}``: the second moments' products split at the wide factor's
        bit PRODUCT_SPLIT, each part one 18 x 18 multiplier with its output registered (the
        moment is ``lo + (hi << PRODUCT_SPLIT)``, a plain adder a stage later)."""
        parts = {}
        for name, a, b in (("sxx", wx1, op2.x), ("syy", wy1, op2.y), ("sxy", wx1, op2.y)):
            split = min(PRODUCT_SPLIT, len(a))
            lo = Signal(split + len(b), reset_less=True, name=f"{name}_lo")
            hi = Signal(max(1, len(a) - split + len(b)), reset_less=True, name=f"{name}_hi")
            m.d.sync += lo.eq(a[:split] * b)
            if len(a) > split:          # a narrow factor (a small frame) needs one part
                m.d.sync += hi.eq(a[split:] * b)
            parts[name] = (lo, hi)
        return parts

    def _accumulate(self, m, acc, acc_next, term4, pix4, best4, empties, ymax):
        """``acc_next = acc (+) term4 (+) pix4`` (``term4``: the slot if used; ``best4``: the
        box and peak terms; the row ``ymax``), empty if ``empties``; ``acc`` registers it."""
        W, H, pb = self.width, self.height, self.pixel_bits
        empty = record_layout(W, H, pb).const(empty_features(W, H))
        sums, sat = _sums(m, acc, term4, Const(1, 1), pix4, empties,
                          record_fields(W, H, pb))
        for name, total in sums.items():
            m.d.comb += acc_next[name].eq(total)
        for name, smaller in (("xmin", True), ("xmax", False), ("ymin", True),
                              ("peak", False)):
            a, b = acc[name], best4[name]
            m.d.comb += acc_next[name].eq(Mux(empties, empty[name],
                                              Mux((a < b) if smaller else (a > b), a, b)))
        m.d.comb += [acc_next.ymax.eq(Mux(empties, 0, ymax)), acc_next.flags.eq(sat)]
        m.d.sync += acc.eq(acc_next)

    def _complete(self, m, done, passes, record):
        """A blob completes (``done``): counted, filtered (``passes``: its ``record``
        passes the filters) and emitted while there is room, else counted as dropped.
        The counters are as wide as the frame needs (at most one blob per two pixels),
        widened at the ports."""
        blob_bits = C.bits_for((self.width * self.height + 1) // 2)
        n_blobs = Signal(blob_bits)
        n_filtered = Signal(blob_bits)
        dropped = Signal(blob_bits)
        n_records = Signal(range(self.record_capacity + 1))
        room = n_records != self.record_capacity     # it never exceeds the capacity
        emit = done & passes & room
        taken = emit & self.records.ready
        m.d.comb += [self.records.payload.eq(record), self.records.valid.eq(emit),
                     self.n_blobs.eq(n_blobs), self.n_filtered.eq(n_filtered),
                     self.dropped_records.eq(dropped), self.n_records.eq(n_records)]
        with m.If(self.clear):
            m.d.sync += [n_blobs.eq(0), n_filtered.eq(0), dropped.eq(0), n_records.eq(0)]
        with m.Else():
            m.d.sync += [n_blobs.eq(n_blobs + done),
                         n_filtered.eq(n_filtered + (done & ~passes)),
                         n_records.eq(n_records + taken),
                         dropped.eq(dropped + (done & passes & ~taken))]
