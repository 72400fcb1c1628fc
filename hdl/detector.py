"""The detection gateware: pixels in, blob records and one trailer per frame out.

``Detector(width, height, pixel_bits, label_capacity, record_capacity, record_depth)`` chains
the threshold unit, the labeller and the feature engine with the register bank and two output
buffers.  ``pixels``: one pixel per clock while ``valid`` (no backpressure), ``sof`` on a
frame's first pixel, ``eol`` on each line's last; rows need ``MIN_HBLANK`` idle clocks and
frames :func:`min_vblank`.  ``records`` and ``trailer`` (valid/ready): compact records in the
contract's order, then the frame's trailer (``hdl.layouts.TRAILER_NAMES``); a frame's records
are the ``n_records`` before its trailer.  Registers written between frames are latched at a
frame's first pixel, and so is the ``timestamp`` input (the frame's time tag in its
trailer).  The record buffer, the held trailer and lost trailers are the output
stage's (:class:`lodestar.hdl.output.OutputStage`); these, ``reg_error`` and the status
outputs are described in ``docs/gateware.md``.
"""

from amaranth import Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.wiring import In, Out, connect

from lodestar import contract as C

from .features import FeatureEngine
from .labeller import Labeller, vblank_cycles
from .layouts import (
    check_frame,
    frame_registers_layout,
    pixel_layout,
    record_layout,
    trailer_layout,
)
from .output import TRAILER_LOST_BITS, OutputStage
from .registers import RegisterBank
from .threshold import ThresholdUnit, global_cycles, local_blanking


def min_vblank(width, height, pixel_bits, mode, log2_window=C.LOCAL_LOG2_WINDOW_MAX):
    """Idle clocks a frame in ``mode`` (a ``contract.MODE_*``) needs after its last pixel:
    the labeller's virtual row and drain, after the local delay line's drain, and not less
    than the global-levels computation."""
    need = vblank_cycles(width)
    if mode == C.MODE_LOCAL:
        need += local_blanking(log2_window) + 1
    if mode == C.MODE_GLOBAL:
        need = max(need, global_cycles(width, height, pixel_bits) + 1)
    return need

_FILTERS = ("min_pixels", "min_sum", "max_pixels")


class Detector(wiring.Component):
    """Threshold, labelling and features for ``width x height`` frames."""

    def __init__(self, width, height, pixel_bits, label_capacity=None,
                 record_capacity=C.DEFAULT_RECORD_CAPACITY, record_depth=None):
        check_frame(width, height, pixel_bits)
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.label_capacity = label_capacity or C.max_open_blobs(width)
        self.record_capacity = record_capacity
        self.record_depth = record_depth or record_capacity
        top = max(r.address for r in C.REGISTERS)
        super().__init__({
            "pixels": In(stream.Signature(pixel_layout(pixel_bits), always_ready=True)),
            "records": Out(stream.Signature(record_layout(width, height, pixel_bits))),
            "trailer": Out(stream.Signature(trailer_layout())),
            "reg_addr": In(C.bits_for(top)),
            "reg_data": In(C.REGISTER_WORD_BITS),
            "reg_en": In(1),
            "reg_error": Out(1),
            "reg_error_clear": In(1),
            "busy": Out(1),
            "frame_counter": Out(dict(C.HEADER_FIELDS)["frame_counter"]),
            "timestamp": In(C.TIMESTAMP_BITS),
            "trailer_lost": Out(TRAILER_LOST_BITS),
            "fault": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        W, H, pb = self.width, self.height, self.pixel_bits
        m.submodules.regs = regs = RegisterBank(pb)
        m.submodules.threshold = thr = ThresholdUnit(W, H, pb)
        m.submodules.labeller = lab = Labeller(W, H, pb, self.label_capacity)
        m.submodules.features = feat = FeatureEngine(W, H, pb, lab.slots, self.record_capacity)
        rec_layout = record_layout(W, H, pb)
        tr_layout = trailer_layout()

        m.d.comb += [regs.addr.eq(self.reg_addr), regs.data.eq(self.reg_data),
                     regs.en.eq(self.reg_en), self.reg_error.eq(regs.error),
                     regs.error_clear.eq(self.reg_error_clear)]
        connect(m, wiring.flipped(self.pixels), thr.pixels)
        for name in ("mode", "threshold", "background", "ksigma",
                     "local_log2_window", "local_offset"):
            m.d.comb += getattr(thr, name).eq(getattr(regs, name))
        connect(m, thr.out, lab.pixels)
        connect(m, lab.ops, feat.ops)
        m.d.comb += feat.wr_slot.eq(lab.wr_slot)
        m.d.comb += [feat.tag.eq(lab.tag), feat.clear.eq(lab.clear),
                     lab.feat_busy.eq(feat.busy), self.fault.eq(lab.fault),
                     self.busy.eq(lab.busy)]

        # registers and the time latched when a frame enters, then handed to the labeller's
        # frame (the timestamp from a register: no path from the counter's carry chain)
        entry = Signal(frame_registers_layout(("mode",) + _FILTERS), reset_less=True)
        frame = Signal.like(entry, reset_less=True)
        entry_time = Signal(C.TIMESTAMP_BITS, reset_less=True)
        with m.If(self.pixels.valid & self.pixels.payload.sof):
            m.d.sync += entry_time.eq(self.timestamp)
            m.d.sync += entry.mode.eq(regs.mode)
            m.d.sync += [entry[n].eq(getattr(regs, n)) for n in _FILTERS]
        m.d.comb += [getattr(feat, n).eq(frame[n]) for n in _FILTERS]

        # trailer of the frame: latched at the labeller's frame start, completed at done
        head = Signal(tr_layout, reset_less=True)
        fallback = Signal(reset_less=True)
        with m.If(lab.frame_start):
            m.d.sync += [
                frame.eq(entry),
                head.mode.eq(entry.mode),
                head.frame_counter.eq(self.frame_counter),
                head.timestamp.eq(entry_time),
                head.threshold.eq(thr.frame_threshold),
                head.background.eq(thr.frame_background),
                fallback.eq(thr.frame_fallback | thr.frame_local_fallback),
                self.frame_counter.eq(self.frame_counter + 1),
            ]
        tail_dropped = self._tail_dropped(m, thr, lab)
        trailer = Signal(tr_layout)
        flags = lab.done_flags | Mux(fallback, C.FRAME_GLOBAL_FALLBACK, 0) | \
            Mux(lab.dropped_labels != 0, C.FRAME_LABEL_OVERFLOW, 0) | \
            Mux(feat.dropped_records != 0, C.FRAME_RECORD_OVERFLOW, 0) | \
            Mux(tail_dropped, C.FRAME_TAIL_DROPPED, 0)
        m.d.comb += [
            trailer.eq(head), trailer.flags.eq(flags),
            trailer.n_blobs.eq(feat.n_blobs), trailer.n_filtered.eq(feat.n_filtered),
            trailer.dropped_records.eq(feat.dropped_records),
            trailer.dropped_labels.eq(lab.dropped_labels),
            trailer.n_records.eq(feat.n_records),
        ]

        # ---- output: the record buffer, the held trailer, orphan records ----------------
        m.submodules.output = out = OutputStage(rec_layout, self.record_depth)
        connect(m, feat.records, out.records_in)
        connect(m, out.records, wiring.flipped(self.records))
        connect(m, out.trailer, wiring.flipped(self.trailer))
        m.d.comb += [out.done.eq(lab.done), out.trailer_in.eq(trailer),
                     self.trailer_lost.eq(out.trailer_lost)]
        return m

    def _tail_dropped(self, m, thr, lab):
        """``FRAME_TAIL_DROPPED`` of the trailer ending now: the threshold unit discarded
        pixels (``frame_tail_dropped``, latched at a ``sof`` and read a clock later) since
        the previous trailer.  Normally the frame the labeller ends at that ``sof``'s
        ``(0, 0)``; a frame none of whose pixels came out has no trailer, so its drop goes
        to the next one (``contract.FRAME_TAIL_DROPPED``)."""
        sof_seen = Signal()                  # a sof entered the threshold unit a clock ago
        owed = Signal()                      # a drop not yet in a trailer
        m.d.sync += sof_seen.eq(self.pixels.valid & self.pixels.payload.sof)
        dropped = owed | (sof_seen & thr.frame_tail_dropped)
        with m.If(lab.done):
            m.d.sync += owed.eq(0)
        with m.Else():
            m.d.sync += owed.eq(dropped)
        return dropped
