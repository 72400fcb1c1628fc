"""Single-pass 4-connected labeller: one pixel per clock, any image content, no find.

The algorithm is described in ``hdl/DESIGN.md`` and written out in plain Python in
``golden/wavefront.py``; the two take the same decisions column by column.  In short:
each row is a sequence of *nodes* (runs of lit pixels).  The previous row's nodes are read
back in order with two flags, ``first``/``last`` (first/last node of its component in that
row), and, on first nodes, the component's feature slot and tracked bit.  Components never
cross, so the previous row's components that straddle the scan position form a stack
(innermost on top); the current run's component is the *active* one.  Every column takes a
constant number of register and memory operations: the push of a node starting here, the
current pixel (birth, contact, or merge with a node starting under the run), the pop of a
component's last node (completion: its record is emitted), and the end of the current run
(its node written, its features stored).  Merges only relabel registers; flags that a merge
makes stale are patched in the current row's node memory (at most one patch of each kind
per two columns).  Features live in ``hdl/features.py``'s feature engine, driven by one op
per column.

Input: the threshold unit's ``out`` stream (``x``, ``y``, ``lit``, ``data``, ``weight``), one
pixel per beat in raster order, no backpressure.  The column decision for ``x`` is taken
when pixel ``x + 1`` arrives (it needs to know whether the run ends), or in the clock after
the row's last pixel.

Blanking and latency (clocks of the labeller's input):

* **horizontal**: at least ``MIN_HBLANK`` = 1 idle clock between the last pixel of a row
  and the first of the next (the previous row's first node is fetched in that clock);
* **vertical**: after the frame's last pixel, ``vblank_cycles(width)`` = ``width + 6``
  clocks: a virtual dark row of ``width`` clocks completes the last row's blobs, then the
  feature pipeline drains and ``done`` is raised;
* a blob's record leaves the feature engine ``4`` clocks after the column decision of its
  completion, which is the column of its last pixel in the row below (or the virtual row):
  about ``width + 5`` clocks after its last pixel plus the horizontal blanking of a row.

Frame integrity: pixels must arrive at the expected positions.  A pixel at ``(0, 0)``
starts a frame; if the previous frame was not finished (it ended early, or the vertical
blanking was too short) that frame ends with ``done`` and ``FRAME_TRUNCATED``.  A pixel
at any other unexpected position, or a row started before the previous row's first node
was fetched (horizontal blanking below the minimum), ends the frame with ``done`` and
``FRAME_TRUNCATED | FRAME_LINE_ERROR``; pixels are then ignored until the next ``(0, 0)``.
Records already emitted stay valid; the next frame is exact.  Pixels that arrive before
any ``(0, 0)`` (after a reset in the middle of a frame) are ignored.

Capacities: ``label_capacity`` tracked blobs open at once (contract semantics: a blob
starting while that many are open is untracked, a merge with an untracked blob untracks
it, an untracked blob is counted in ``dropped_labels`` when it completes).  The node and
stack memories are sized for any image (``max_nodes``, ``max_stack``); the feature table
has ``label_capacity + 2`` slots, allocated fresh until the free-slot FIFO offers one (a
slot freed at a decision is on offer at the next).  ``fault`` (sticky, for verification)
would flag an internal bound being exceeded; it cannot happen.
"""

from amaranth import Cat, Module, Mux, Signal
from amaranth.lib import data, stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .features import op_layout
from .threshold import lit_layout

MIN_HBLANK = 1
"""Idle clocks the labeller needs between two rows."""

MIN_WIDTH = 2
"""Narrowest frame the labeller is built for."""

_DRAIN = 5
"""Clocks from the virtual row's last decision until the feature engine is idle."""


def vblank_cycles(width):
    """Idle clocks the labeller needs between a frame's last pixel and the next frame."""
    return width + _DRAIN + 1


def max_nodes(width):
    """Most runs a row of ``width`` pixels can hold."""
    return (width + 1) // 2


def max_stack(width):
    """Most previous-row components straddling the scan position (each has >= 2 nodes),
    plus one for a single-node component pushed and popped in the same clock."""
    return max_nodes(width) // 2 + 1


def slots_for(label_capacity):
    """Feature-table slots for ``label_capacity`` tracked open blobs."""
    return label_capacity + 2


def _entry_layout(sb, nb):
    return data.StructLayout({"lab": sb, "tracked": 1, "has_cur": 1, "fa": nb, "la": nb,
                              "cont": 1})


def _active_layout(sb, nb):
    return data.StructLayout({"lab": sb, "tracked": 1, "has_slot": 1, "has_cur": 1,
                              "fa": nb, "la": nb, "group": 1})


_FLAGS = data.StructLayout({"first": 1, "last": 1})


def _label_layout(sb):
    return data.StructLayout({"lab": sb, "tracked": 1})


class Labeller(wiring.Component):
    """Labeller for ``width x height`` frames of ``pixel_bits`` pixels."""

    def __init__(self, width, height, pixel_bits, label_capacity):
        if width < MIN_WIDTH:
            raise ValueError(f"width={width}: the labeller needs at least {MIN_WIDTH} columns")
        if label_capacity < 1:
            raise ValueError(f"label_capacity={label_capacity} must be >= 1")
        self.width, self.height, self.pixel_bits = width, height, pixel_bits
        self.label_capacity = label_capacity
        self.slots = slots_for(label_capacity)
        super().__init__({
            "pixels": In(stream.Signature(lit_layout(width, height, pixel_bits),
                                          always_ready=True)),
            "ops": Out(stream.Signature(op_layout(width, height, pixel_bits, self.slots),
                                        always_ready=True)),
            "tag": Out(2),
            "clear": Out(1),
            "feat_busy": In(1),
            "frame_start": Out(1),
            "done": Out(1),
            "done_flags": Out(8),
            "dropped_labels": Out(dict(C.HEADER_FIELDS)["dropped_labels"]),
            "busy": Out(1),
            "fault": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        W, H, pb = self.width, self.height, self.pixel_bits
        sb = C.bits_for(self.slots - 1)
        nodes = max_nodes(W)
        nb = C.bits_for(nodes - 1)
        depth = max_stack(W)
        entry_l = _entry_layout(sb, nb)
        active_l = _active_layout(sb, nb)
        label_l = _label_layout(sb)
        xb, yb = C.bits_for(W - 1), C.bits_for(H)
        beat = self.pixels.payload
        op = self.ops.payload

        # ---- input: held pixel, expected position, frame state -----------------------
        hv = Signal()                 # a pixel is held, waiting for its right neighbour
        hx = Signal(xb)               # its position (in the virtual row: the column decided)
        hy = Signal(yb)
        hlit = Signal()
        hp = Signal(pb)
        hw = Signal(pb)
        hx1 = Signal(xb)              # hx + 1 and hy + 1, the next pixel's position
        hy1 = Signal(yb)
        drain = Signal(range(_DRAIN + 2))
        tag = Signal(2)               # frame tag: ops of an aborted frame are ignored
        m.d.comb += self.tag.eq(tag)
        row_par = Signal()            # parity of the row decided next: its node bank

        at_origin = (beat.x == 0) & (beat.y == 0)
        row_end = hx == W - 1         # the next pixel must start the next row
        same_row = beat.y == hy
        expected = Mux(row_end, (beat.x == 0) & (beat.y == hy1), (beat.x == hx1) & same_row)
        row_end_held = hv & row_end

        dv = Signal()                 # a column decision this clock: the held pixel's
        dx, dy, dlit, dp, dw = hx, hy, hlit, hp, hw
        dla = Signal()                # lookahead: pixel x + 1 is lit

        start = Signal()              # this beat starts a frame
        abort = Signal()              # the frame in progress ends early
        abort_flags = Signal(8)
        take = Signal()               # this beat is held

        # ---- previous-row bitmap ------------------------------------------------------
        m.submodules.bitmap = bitmap = Memory(shape=1, depth=W, init=[])
        bm_w = bitmap.write_port()
        bm_r = bitmap.read_port(transparent_for=(bm_w,))
        r_m1 = Signal()
        r_0 = Signal()
        first_row = dy == 0
        last_col = dx == W - 1
        pl0 = r_0 & ~first_row
        plm1 = r_m1 & ~first_row
        plp1 = bm_r.data & ~first_row & ~last_col
        ahead = Signal(xb)            # dx + 2 unless that wraps to column 0 or 1
        m.d.comb += ahead.eq(dx + 2)
        m.d.comb += [
            bm_w.addr.eq(dx), bm_w.data.eq(dlit), bm_w.en.eq(dv),
            bm_r.addr.eq(Mux(last_col | (dx == W - 2), last_col, ahead)), bm_r.en.eq(dv),
        ]

        # ---- node memories (two banks: the row being written, the row being read) -------
        wptr = Signal(range(nodes + 1))
        rptr = Signal(range(nodes + 1))
        load = Signal()               # read rptr this clock
        loaded = Signal()             # the node at rptr - 1 is on the read ports
        wbank = row_par
        banks = []
        for b in range(2):
            f_mem = Memory(shape=_FLAGS, depth=nodes, init=[])
            l_mem = Memory(shape=label_l, depth=nodes, init=[])
            m.submodules[f"flags{b}"] = f_mem
            m.submodules[f"labels{b}"] = l_mem
            ports = {
                "fa": f_mem.write_port(), "fb": f_mem.write_port(),
                "la": l_mem.write_port(), "lb": l_mem.write_port(),
            }
            ports["fr"] = f_mem.read_port()
            ports["lr"] = l_mem.read_port()
            writing = wbank == b
            addr_a = Mux(writing, wptr, rptr)
            m.d.comb += [ports["fa"].addr.eq(addr_a), ports["la"].addr.eq(addr_a),
                         ports["fr"].addr.eq(addr_a), ports["lr"].addr.eq(addr_a),
                         ports["fr"].en.eq(load & ~writing),
                         ports["lr"].en.eq(load & ~writing)]
            banks.append((writing, ports))
        nf = Signal(_FLAGS)
        nl = Signal(label_l)
        m.d.comb += [nf.eq(Mux(wbank, banks[0][1]["fr"].data, banks[1][1]["fr"].data)),
                     nl.eq(Mux(wbank, banks[0][1]["lr"].data, banks[1][1]["lr"].data))]
        seq_en = Signal()
        seq_f = Signal(_FLAGS)
        seq_l = Signal(label_l)
        fpatch_req = Signal()         # first/last patch (never both kinds in one clock)
        fpatch_en = Signal()
        fpatch_addr = Signal(nb)
        fpatch = Signal(_FLAGS)
        lpatch_req = Signal()         # tracked patch
        lpatch_en = Signal()
        lpatch_addr = Signal(nb)
        for writing, ports in banks:
            m.d.comb += [
                ports["fa"].data.eq(seq_f), ports["fa"].en.eq(writing & seq_en),
                ports["la"].data.eq(seq_l), ports["la"].en.eq(writing & seq_en),
                ports["fb"].addr.eq(fpatch_addr), ports["fb"].data.eq(fpatch),
                ports["fb"].en.eq(writing & fpatch_en),
                ports["lb"].addr.eq(lpatch_addr), ports["lb"].data.eq(0),
                ports["lb"].en.eq(writing & lpatch_en),
            ]
        cur_last = Signal()           # last flag of the previous-row node under the scan

        # ---- stack: top and second in registers, the rest in memory ------------------
        top = Signal(entry_l)
        sec = Signal(entry_l)
        below = Signal(range(-2, depth + 1))   # entries in the stack memory (entries - 2)
        below_next = Signal.like(below)
        reload = Signal()             # sec comes from the stack memory this clock
        m.submodules.stack = stack = Memory(shape=entry_l, depth=max(depth - 2, 1), init=[])
        st_w = stack.write_port()
        st_r = stack.read_port()

        # ---- active component, label count, free slots --------------------------------
        act = Signal(active_l)
        count = Signal(range(self.label_capacity + 1))
        lit_prev = Signal()
        fresh = Signal(range(self.slots + 1))
        # free slots: a FIFO in a memory (a power of two deep, so the pointers wrap by
        # themselves); its head is on the read port, a slot freed at a decision is
        # reusable at the next one
        fl_depth = 1 << C.bits_for(self.slots - 1)
        m.submodules.freelist = freelist = Memory(shape=sb, depth=fl_depth, init=[])
        fl_w = freelist.write_port()
        fl_r = freelist.read_port(transparent_for=(fl_w,))
        fl_wp = Signal(range(2 * fl_depth))
        fl_rp = Signal(range(2 * fl_depth))
        fl_rdy = fl_wp != fl_rp
        fl_pop = Signal()
        fl_head = Signal.like(fl_rp)  # the head after this clock's pop
        m.d.comb += [fl_head.eq(fl_rp + fl_pop), fl_r.addr.eq(fl_head), fl_r.en.eq(1)]
        m.d.sync += fl_rp.eq(fl_head)
        fault = Signal()
        m.d.comb += self.fault.eq(fault)
        # at most one blob per two pixels: the count is that wide, widened at the port
        dropped_labels = Signal(C.bits_for((W * H + 1) // 2))
        line_error = Signal()         # a row started before its first node was fetched

        # ==== the column decision ========================================================
        is_first = nf.first
        node_last = Mux(pl0 & ~plm1, nf.last, cur_last)
        ps = pl0 & ~plm1
        pop = pl0 & ~plp1 & node_last
        push = ps & is_first
        new_entry = Signal(entry_l)
        m.d.comb += [new_entry.lab.eq(nl.lab), new_entry.tracked.eq(nl.tracked)]
        t1 = Signal(entry_l)
        s1 = Signal(entry_l)
        m.d.comb += [t1.eq(Mux(push, new_entry, top)), s1.eq(Mux(push, top, sec))]

        # step 2: the pixel
        a2 = Signal(active_l)
        t2 = Signal(entry_l)
        m.d.comb += [a2.eq(act), t2.eq(t1)]
        rs = dlit & ~lit_prev
        cstart = rs & pl0
        birth = rs & ~pl0
        merge = dlit & ~rs & ps & ~(act.group & ~is_first)
        count_up = Signal()
        merge_down = Signal()
        pop_down = Signal()
        drop_label = Signal()
        free_en = Signal()
        free_lab = Signal(sb)
        m.d.comb += [op.tag.eq(tag), op.pix.eq(dlit), op.x.eq(dx), op.y.eq(dy),
                     op.p.eq(dp), op.w.eq(dw)]
        b = t1
        trk = act.tracked & b.tracked
        with m.If(cstart):
            m.d.comb += [a2.lab.eq(b.lab), a2.tracked.eq(b.tracked), a2.has_slot.eq(b.tracked),
                         a2.has_cur.eq(b.has_cur), a2.fa.eq(b.fa), a2.la.eq(b.la),
                         a2.group.eq(1), op.rd.eq(b.tracked),
                         op.rd_addr.eq(b.lab)]
        with m.Elif(birth):
            tracked_birth = count != self.label_capacity  # it never exceeds it
            m.d.comb += [a2.eq(0), a2.tracked.eq(tracked_birth), count_up.eq(tracked_birth)]
        with m.Elif(merge):
            m.d.comb += [merge_down.eq(act.tracked | b.tracked), a2.tracked.eq(trk),
                         a2.group.eq(1), op.rd.eq(trk),
                         op.rd_addr.eq(b.lab)]
            with m.If(b.has_cur):             # case (i): the active run nests inside b
                m.d.comb += [fpatch_req.eq(act.has_cur), fpatch_addr.eq(act.fa),
                             fpatch.eq(0),
                             a2.has_cur.eq(1), a2.fa.eq(b.fa),
                             a2.la.eq(Mux(act.has_cur, act.la, b.la))]
                with m.If(trk):
                    m.d.comb += [a2.lab.eq(b.lab), a2.has_slot.eq(1),
                                 free_en.eq(act.has_slot), free_lab.eq(act.lab)]
                with m.Else():
                    m.d.comb += [a2.has_slot.eq(0),
                                 free_en.eq(act.has_slot | b.tracked),
                                 free_lab.eq(Mux(act.has_slot, act.lab, b.lab))]
            with m.Else():                    # case (ii): b has no node in this row yet
                m.d.comb += t2.cont.eq(act.group | t1.cont)
                with m.If(trk):
                    m.d.comb += [a2.lab.eq(Mux(act.has_slot, act.lab, b.lab)),
                                 a2.has_slot.eq(1),
                                 free_en.eq(act.has_slot), free_lab.eq(b.lab)]
                with m.Else():
                    m.d.comb += [a2.has_slot.eq(0),
                                 free_en.eq(act.has_slot | b.tracked),
                                 free_lab.eq(Mux(act.has_slot, act.lab, b.lab))]
            with m.If(~trk & (b.has_cur | act.has_cur)):   # the survivor's first node
                m.d.comb += [lpatch_req.eq(1),
                             lpatch_addr.eq(Mux(b.has_cur, b.fa, act.fa))]

        # step 3: the pop of a component's last node
        a3 = Signal(active_l)
        t3 = Signal(entry_l)
        m.d.comb += a3.eq(a2)
        e = t2
        with m.If(pop):
            with m.If(dlit & a2.group):
                m.d.comb += a3.group.eq(e.cont)
            with m.Elif(e.cont):
                pass                          # the group's information moves down (below)
            with m.Elif(e.has_cur):
                m.d.comb += [fpatch_req.eq(1), fpatch_addr.eq(e.la),
                             fpatch.first.eq(e.la == e.fa), fpatch.last.eq(1)]
            with m.Elif(e.tracked):
                m.d.comb += [pop_down.eq(1), op.complete.eq(1), op.rd.eq(1),
                             op.rd_addr.eq(e.lab), free_en.eq(1), free_lab.eq(e.lab)]
            with m.Else():
                m.d.comb += drop_label.eq(1)
        moved = Signal(entry_l)               # s1 with the popped entry's information
        m.d.comb += [moved.eq(e), moved.cont.eq(s1.cont)]
        with m.If(pop & push):
            m.d.comb += t3.eq(top)
        with m.Elif(pop):
            m.d.comb += t3.eq(Mux(e.cont & ~(dlit & a2.group), moved, s1))
        with m.Else():
            m.d.comb += t3.eq(t2)

        # step 4: the end of the current run
        run_end = dlit & ~dla
        alloc = run_end & a3.tracked & ~a3.has_slot
        lab4 = Signal(sb)
        m.d.comb += lab4.eq(a3.lab)
        with m.If(alloc):
            with m.If(fl_rdy):
                m.d.comb += [lab4.eq(fl_r.data), fl_pop.eq(dv)]
            with m.Else():
                m.d.comb += lab4.eq(fresh)
        m.d.comb += [fl_w.addr.eq(fl_wp), fl_w.data.eq(free_lab), fl_w.en.eq(dv & free_en)]
        m.d.sync += fl_wp.eq(fl_wp + fl_w.en)
        t4 = Signal(entry_l)
        m.d.comb += t4.eq(t3)
        with m.If(run_end):
            m.d.comb += [seq_en.eq(dv), seq_f.first.eq(~a3.has_cur), seq_f.last.eq(~a3.group),
                         seq_l.lab.eq(lab4), seq_l.tracked.eq(a3.tracked),
                         op.wr.eq(a3.tracked), op.wr_addr.eq(lab4)]
            with m.If(a3.group):
                m.d.comb += [t4.lab.eq(lab4), t4.tracked.eq(a3.tracked), t4.has_cur.eq(1),
                             t4.fa.eq(Mux(a3.has_cur, a3.fa, wptr)), t4.la.eq(wptr)]
        m.d.comb += [fpatch_en.eq(fpatch_req & dv), lpatch_en.eq(lpatch_req & dv)]
        m.d.comb += self.ops.valid.eq(dv)

        # ---- state updates of a decision ----------------------------------------------
        down = merge_down | pop_down
        m.d.comb += [st_w.en.eq(0), st_r.en.eq(0),
                     below_next.eq(below + Mux(push & ~pop, 1, Mux(pop & ~push, -1, 0)))]
        with m.If(reload):
            m.d.sync += [sec.eq(st_r.data), reload.eq(0)]
        with m.If(load):
            m.d.sync += load.eq(0)
        with m.If(dv):
            m.d.sync += [act.eq(a3), top.eq(t4),
                         # a birth, a merge and a completion exclude each other: +1 or -1
                         count.eq(count + Cat(count_up | down, down.replicate(len(count) - 1))),
                         dropped_labels.eq(dropped_labels + drop_label),
                         lit_prev.eq(dlit & ~last_col),
                         r_m1.eq(Mux(last_col, 0, r_0)), r_0.eq(bm_r.data)]
            with m.If(alloc & ~fl_rdy):
                m.d.sync += fresh.eq(fresh + 1)
                with m.If(fresh == self.slots):
                    m.d.sync += fault.eq(1)
            m.d.sync += below.eq(below_next)
            with m.If(push & ~pop):
                m.d.sync += sec.eq(top)
                m.d.comb += [st_w.addr.eq(below), st_w.data.eq(sec), st_w.en.eq(~below[-1])]
                with m.If(below == depth - 2):
                    m.d.sync += fault.eq(1)
            with m.Elif(pop & ~push):      # the new sec is the memory's last entry
                m.d.comb += [st_r.addr.eq(below_next), st_r.en.eq(~below_next[-1])]
                m.d.sync += reload.eq(~below_next[-1])
            with m.If(ps):
                m.d.sync += [cur_last.eq(nf.last), rptr.eq(rptr + 1), load.eq(1)]
                with m.If(~loaded):
                    m.d.sync += line_error.eq(1)
            with m.If(run_end):
                m.d.sync += wptr.eq(wptr + 1)
            with m.If(last_col):
                m.d.sync += [wptr.eq(0), rptr.eq(0), load.eq(1), below.eq(-2),
                             row_par.eq(~row_par)]
                # the stack is empty at every row end (below_next == -2, from below itself)
                with m.If(~(Mux(push == pop, below == -2, pop & (below == -1)))):
                    m.d.sync += fault.eq(1)
        with m.If(dv & (ps | last_col)):
            m.d.sync += loaded.eq(0)
        with m.Elif(load):
            m.d.sync += loaded.eq(1)

        # ---- frame sequencing -----------------------------------------------------------
        m.d.comb += [self.frame_start.eq(start), self.clear.eq(start),
                     self.dropped_labels.eq(dropped_labels)]
        with m.If(start):
            m.d.sync += [count.eq(0), fresh.eq(0), fl_wp.eq(0), fl_rp.eq(0),
                         dropped_labels.eq(0), row_par.eq(0),
                         lit_prev.eq(0), below.eq(-2), wptr.eq(0), rptr.eq(0), load.eq(0),
                         loaded.eq(0), line_error.eq(0), reload.eq(0)]
        m.d.comb += self.done_flags.eq(abort_flags)
        finished = Signal()
        with m.If(start | abort):
            m.d.sync += tag.eq(tag + 1)

        def restart_if_new_frame():
            """A frame starting before this one finished: end it truncated, start anew."""
            with m.If(self.pixels.valid & at_origin):
                m.d.comb += [abort.eq(1), abort_flags.eq(C.FRAME_TRUNCATED),
                             start.eq(1), take.eq(1)]
                m.next = "RUN"

        with m.FSM():
            with m.State("IDLE"):
                with m.If(self.pixels.valid & at_origin):
                    m.d.comb += [start.eq(1), take.eq(1)]
                    m.next = "RUN"
            with m.State("RUN"):
                m.d.comb += self.busy.eq(1)
                right = self.pixels.valid & expected & same_row & hv
                m.d.comb += [dv.eq(row_end_held | right), dla.eq(~row_end_held & beat.lit)]
                with m.If(self.pixels.valid & ~expected):
                    m.d.comb += abort.eq(1)
                    with m.If(at_origin):
                        m.d.comb += [abort_flags.eq(C.FRAME_TRUNCATED), start.eq(1),
                                     take.eq(1)]
                    with m.Else():
                        m.d.comb += abort_flags.eq(C.FRAME_TRUNCATED | C.FRAME_LINE_ERROR)
                        m.next = "SKIP"
                with m.Elif(line_error):
                    m.d.comb += [abort.eq(1),
                                 abort_flags.eq(C.FRAME_TRUNCATED | C.FRAME_LINE_ERROR)]
                    m.next = "SKIP"
                with m.Else():
                    m.d.comb += take.eq(self.pixels.valid)
                    with m.If(row_end_held & (hy == H - 1)):
                        m.d.sync += [hx.eq(0), hy.eq(H), hlit.eq(0), hv.eq(0)]
                        m.next = "GAP"
            with m.State("GAP"):              # one clock: the last row's first node
                m.d.comb += self.busy.eq(1)
                m.next = "VROW"
                restart_if_new_frame()
            with m.State("VROW"):
                m.d.comb += [self.busy.eq(1), dv.eq(1)]
                m.d.sync += hx.eq(hx + 1)
                with m.If(hx == W - 1):
                    m.d.sync += drain.eq(0)
                    m.next = "DRAIN"
                restart_if_new_frame()
            with m.State("DRAIN"):
                m.d.comb += self.busy.eq(1)
                m.d.sync += drain.eq(drain + 1)
                with m.If((drain >= _DRAIN - 1) & ~self.feat_busy & ~self.pixels.valid):
                    m.d.comb += finished.eq(1)
                    m.next = "IDLE"
                restart_if_new_frame()
            with m.State("SKIP"):
                with m.If(self.pixels.valid & at_origin):
                    m.d.comb += [start.eq(1), take.eq(1)]
                    m.next = "RUN"
        m.d.comb += self.done.eq(finished | abort)

        with m.If(take):
            m.d.sync += [hv.eq(1), hx.eq(beat.x), hy.eq(beat.y), hlit.eq(beat.lit),
                         hp.eq(beat.data), hw.eq(beat.weight),
                         hx1.eq(beat.x + 1), hy1.eq(beat.y + 1)]
        with m.Elif(dv & ~(self.pixels.valid & expected)):
            m.d.sync += hv.eq(0)
        with m.If(abort & ~start):
            m.d.sync += hv.eq(0)
        return m
