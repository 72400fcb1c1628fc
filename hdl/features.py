"""Feature engine: blob features per label slot, merged on union, emitted at completion.

The labeller (``hdl/labeller.py``) sends one *op* per column it decides, at most one per
clock.  An op says what happens to the accumulator of the *active* component (the one the
current run belongs to) and to the feature table, a memory of ``slots`` entries holding
each open tracked component's features in the compact record layout
(``hdl.layouts.record_layout``; its ``flags`` bit is the moment-saturation flag):

* ``pix``: the lit pixel ``(x, y, p, w)`` joins the active component;
* ``base``: what the accumulator starts from before the pixel is added: ``KEEP`` (itself),
  ``NEW`` (empty: a birth), ``LOAD`` (the slot read by this op: the run continues a
  component of the previous row) or ``MERGE`` (itself plus the slot read: a union);
* ``rd``/``rd_addr``: read a slot (for ``LOAD``, ``MERGE`` or ``complete``);
* ``complete``: the slot read is a completed blob: count it, filter it (contract
  ``passes_filters``) and emit its record if fewer than ``record_capacity`` records were
  emitted this frame and the record stream takes it (otherwise ``dropped_records``);
* ``wr``/``wr_addr``: the run ends; write the accumulator (with this op's pixel) to a slot.

Sums saturate at the contract's moment widths and set the saturation flag; counts, the
bounding box and the peak are exact (``lodestar.contract``).  Order of accumulation does not
matter, so the result equals the golden model's whatever the merge order.  The accumulator
adds its three terms (itself, the slot read, the pixel; each the empty record when the op
leaves it out) in one step: a carry-save layer and one carry chain per sum, one saturation.

Timing: the op enters at clock ``c``; pixel products and the slot read take two clocks; the
accumulator, the slot write and the record are at ``c + 3``.  A slot written by an op is
read back correctly by any op entering two or more clocks later (the read port is
transparent for the write port); the labeller never reads a slot sooner.  Ops carry the
frame ``tag``; an op whose tag differs from the ``tag`` input (the frame was aborted) has no
effect.  ``clear`` resets the per-frame counters.  The pipeline's data registers and the
accumulator have no reset (only the valid bits do): they are read only under a valid op, and
every component starts from ``NEW`` or ``LOAD``.
"""

from amaranth import Cat, Module, Mux, Signal
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .layouts import record_fields, record_layout

KEEP, NEW, LOAD, MERGE = range(4)

_HEADER_BITS = dict(C.HEADER_FIELDS)


def op_layout(width, height, pixel_bits, slots):
    """One labeller decision for the feature engine."""
    sb = C.bits_for(slots - 1)
    return data.StructLayout({
        "tag": 2, "pix": 1, "x": C.bits_for(width - 1), "y": C.bits_for(height - 1),
        "p": pixel_bits, "w": pixel_bits, "base": 2,
        "rd": 1, "rd_addr": sb, "complete": 1, "wr": 1, "wr_addr": sb,
    })


def _select(a, b, c, first):
    """The operand of ``a``, ``b``, ``c`` that ``first(u, v)`` (``u < v`` or ``u > v``)
    ranks first, from three comparisons made side by side (ties: any of the equal ones)."""
    return Mux(first(a, b) & first(a, c), a, Mux(first(b, c), b, c))


def _combine(m, a, b, c, fields):
    """``a (+) b (+) c`` of three feature records (the empty record, :func:`empty_features`,
    is the identity): saturating sums, exact counts, box and peak.

    Each sum is one carry-save layer (a sum and a carry bit per bit) and one carry chain
    instead of two chains in series.  Saturating once, ``min(a + b + c, max)``, equals
    saturating after each of two additions because every term is non-negative; the
    saturation flag is the OR of the records' flags and of every sum that saturates."""
    out = Signal(a.shape())
    sat = a.flags | b.flags | c.flags
    for name, bits in fields:
        x, y, z = a[name], b[name], c[name]
        if name in C.MOMENTS or name in ("n", "nsat"):
            half = x ^ y ^ z                             # a + b + c = half + 2 carry
            carry = (x & y) | (x & z) | (y & z)
            # one chain adds half and carry from weight 2 up; its carry-out has weight
            # 2**bits.  The top carry bit alone reaches 2**bits: for a moment it forces
            # both operands so that the chain carries out, which makes the carry-out the
            # saturation bit (the low bits do not matter then)
            low, top = half[1:], carry[:bits - 1]
            if name in C.MOMENTS:
                force = carry[bits - 1]
                low = low | force.replicate(bits - 1)
                top = Cat(top[0] | force, top[1:])
            high = Signal(bits, name=f"sum_{name}")
            m.d.comb += high.eq(low + top)
            total = Cat(half[0], high[:bits - 1])
            if name in C.MOMENTS:
                over = high[bits - 1]
                m.d.comb += out[name].eq(Mux(over, (1 << bits) - 1, total))
                sat = sat | over
            else:                                        # counts never exceed their width
                m.d.comb += out[name].eq(total)
        elif name in ("xmin", "ymin"):
            m.d.comb += out[name].eq(_select(x, y, z, lambda u, v: u < v))
        elif name in ("xmax", "ymax", "peak"):
            m.d.comb += out[name].eq(_select(x, y, z, lambda u, v: u > v))
    m.d.comb += out.flags.eq(sat)
    return out


def empty_features(width, height):
    """The identity of ``(+)``: no pixels, an inverted bounding box."""
    return {"xmin": (1 << C.bits_for(width - 1)) - 1, "ymin": (1 << C.bits_for(height - 1)) - 1}


class FeatureEngine(wiring.Component):
    """Feature table, accumulator and record emission for ``width x height`` frames."""

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
            "tag": In(2),
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
        fields = record_fields(W, H, pb)
        layout = record_layout(W, H, pb)
        fs = C.full_scale(pb)

        m.submodules.table = table = Memory(shape=layout, depth=self.slots, init=[])
        wp = table.write_port()
        rp = table.read_port(transparent_for=(wp,))

        # ---- stage 1: op registered, slot read issued, first products --------------
        # a column without a pixel has weight 0: its products, and so its terms, are 0
        op1 = Signal.like(self.ops.payload, reset_less=True)
        v1 = Signal()
        m.d.sync += [op1.eq(self.ops.payload), v1.eq(self.ops.valid)]
        m.d.comb += [rp.addr.eq(op1.rd_addr), rp.en.eq(v1 & op1.rd)]
        w1 = Mux(op1.pix, op1.w, 0)
        wx1 = Signal(pb + len(op1.x), reset_less=True)
        wy1 = Signal(pb + len(op1.y), reset_less=True)
        op2 = Signal.like(op1, reset_less=True)
        v2 = Signal()
        m.d.sync += [op2.eq(op1), v2.eq(v1), wx1.eq(w1 * op1.x), wy1.eq(w1 * op1.y)]

        # ---- stage 2: second products, slot data, the terms of the accumulator -------
        # pixf is the pixel's record (empty without a pixel); slot3 the slot read if the op
        # adds it (LOAD, MERGE), else empty; rd3 the slot read as it is, for completion
        empty = layout.const(empty_features(W, H))
        pixf = Signal(layout, reset_less=True)
        op3 = Signal.like(op1, reset_less=True)
        v3 = Signal()
        rd3 = Signal(layout, reset_less=True)
        slot3 = Signal(layout, reset_less=True)
        keep3 = Signal(reset_less=True)
        pix2 = op2.pix
        m.d.sync += [
            op3.eq(op2), v3.eq(v2), rd3.eq(rp.data),
            slot3.eq(Mux((op2.base == LOAD) | (op2.base == MERGE), rp.data, empty)),
            keep3.eq((op2.base == KEEP) | (op2.base == MERGE)),
            pixf.n.eq(pix2), pixf.nsat.eq(pix2 & (op2.p == fs)),
            pixf.s0.eq(Mux(pix2, op2.w, 0)), pixf.sx.eq(wx1), pixf.sy.eq(wy1),
            pixf.sxx.eq(wx1 * op2.x), pixf.syy.eq(wy1 * op2.y), pixf.sxy.eq(wx1 * op2.y),
            pixf.xmin.eq(Mux(pix2, op2.x, empty.xmin)), pixf.xmax.eq(Mux(pix2, op2.x, 0)),
            pixf.ymin.eq(Mux(pix2, op2.y, empty.ymin)), pixf.ymax.eq(Mux(pix2, op2.y, 0)),
            pixf.peak.eq(Mux(pix2, op2.p, 0)), pixf.flags.eq(0),
        ]

        # ---- stage 3: accumulator, slot write, completion ---------------------------
        # acc (+) slot3 (+) pixf, acc taken for KEEP and MERGE; without a live op the
        # accumulator keeps itself (no enable logic on its registers)
        live = v3 & (op3.tag == self.tag)
        acc = Signal(layout, reset_less=True)
        kept = Signal(layout)
        m.d.comb += kept.eq(Mux(keep3, acc, empty))
        added = _combine(m, kept, slot3, pixf, fields)
        acc_next = Signal(layout)
        m.d.comb += acc_next.eq(Mux(live, added, acc))
        m.d.sync += acc.eq(acc_next)
        m.d.comb += [wp.addr.eq(op3.wr_addr), wp.data.eq(acc_next),
                     wp.en.eq(live & op3.wr)]

        passes = (rd3.n >= self.min_pixels) & (rd3.n <= self.max_pixels) & \
            (rd3.s0 >= self.min_sum)
        room = self.n_records < self.record_capacity
        emit = live & op3.complete & passes & room
        m.d.comb += [self.records.payload.eq(rd3), self.records.valid.eq(emit)]
        with m.If(self.clear):
            m.d.sync += [self.n_blobs.eq(0), self.n_filtered.eq(0),
                         self.dropped_records.eq(0), self.n_records.eq(0)]
        with m.Elif(live & op3.complete):
            m.d.sync += self.n_blobs.eq(self.n_blobs + 1)
            with m.If(~passes):
                m.d.sync += self.n_filtered.eq(self.n_filtered + 1)
            with m.Elif(emit & self.records.ready):
                m.d.sync += self.n_records.eq(self.n_records + 1)
            with m.Else():
                m.d.sync += self.dropped_records.eq(self.dropped_records + 1)
        m.d.comb += self.busy.eq(v1 | v2 | v3)
        return m
