"""Single-pass 4-connected labeller: one pixel per clock, any image content.

The algorithm (a stack of the previous row's straddling components, no ``find``) is
described in ``docs/gateware.md``; its architectural model is ``golden/wavefront.py``, which
takes the same decisions column by column.  Ports, blanking and faults: :class:`Labeller`.
"""

from collections import namedtuple

from amaranth import Cat, Module, Mux, Signal
from amaranth.lib import stream, wiring
from amaranth.lib.memory import Memory
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

from .layouts import (
    FRAME_FLAGS_BITS,
    FRAME_TAG_BITS,
    PixelAction,
    PopAction,
    active_layout,
    held_layout,
    lit_layout,
    node_flags_layout,
    node_label_layout,
    op_layout,
    stack_entry_layout,
)

MIN_HBLANK = 1
"""Idle clocks the labeller needs between two rows."""

MIN_WIDTH = 3
"""Narrowest frame the labeller is built for (the bitmap is read three columns ahead)."""

_DRAIN = 6
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


class _Stack:
    """Previous-row components straddling the scan position: ``top`` and ``second`` in
    registers, the rest (``spilled`` entries, -2 when the stack is empty) in a memory.

    Neither memory port is driven by the decision, and the read data goes straight into a
    register: a spill (``spill_en``: ``second`` goes to entry ``spilled``) is written a
    clock later from registers, and the memory's top entry (``spilled - 1``) is read on
    every clock into ``read``.  In the clock after a pop (``reload``), ``refilled`` is the
    new ``second``: ``read`` (read two clocks ago, before any stack change since: no stack
    change follows a pop at once), unless a spill was decided one or two clocks before
    the pop (not yet in the memory at the read), whose entry is then the memory's top
    (explicit bypass)."""

    def __init__(self, m, entry, depth):
        self.top = Signal(entry, name="stack_top")
        self.second = Signal(entry, name="stack_second")
        self.spilled = Signal(range(-2, depth + 1), name="stack_spilled")
        self.spilled_next = Signal.like(self.spilled, name="stack_spilled_next")
        self.reload = Signal(name="stack_reload")  # second comes from the memory this clock
        self.spill_en = Signal(name="stack_spill")
        self.refilled = Signal(entry, name="stack_refilled")
        m.submodules.stack = memory = Memory(shape=entry, depth=max(depth - 2, 1), init=[])
        spill, refill = memory.write_port(), memory.read_port()
        spill_addr = Signal.like(spill.addr, name="stack_spill_addr")
        spill_data = Signal(entry, name="stack_spill_data")   # the latest spill's entry
        spill_en = Signal(name="stack_spill_en")
        recent = Signal(2, name="stack_spill_recent")  # spills decided 2 and 3 clocks ago
        read = Signal(entry, name="stack_read")
        with m.If(self.spill_en):
            m.d.sync += [spill_addr.eq(self.spilled), spill_data.eq(self.second)]
        m.d.sync += [spill_en.eq(self.spill_en), recent.eq(Cat(spill_en, recent[0])),
                     read.eq(refill.data)]
        m.d.comb += [spill.addr.eq(spill_addr), spill.data.eq(spill_data), spill.en.eq(spill_en),
                     refill.addr.eq(self.spilled - 1),
                     self.refilled.eq(Mux(recent.any(), spill_data, read))]


class _FreeSlots:
    """Feature slots freed by completions and merges: a stack whose top is in a register
    (``head``) and whose entries, the top included, are in a memory.  A slot freed at a
    decision is the head at the next one.  The memory is written a clock after the
    decision and read at ``depth - 2`` on every clock into a register, so neither port
    sits on the decision's path; after a pop (allocations are at least two clocks apart:
    a run end is followed by a dark pixel or a row's end) the new head comes from that
    register two clocks later.  ``fresh`` counts slots never used yet."""

    def __init__(self, m, slots, slot_bits):
        depth = 1 << C.bits_for(slots - 1)
        m.submodules.freelist = memory = Memory(shape=slot_bits, depth=depth, init=[])
        write, read = memory.write_port(), memory.read_port()
        self.depth = Signal(range(depth + 1), name="free_depth")   # entries
        self.ready = self.depth != 0
        self.pop = Signal(name="free_pop")          # allocate ``head`` at this decision
        self.fresh = Signal(range(slots + 1), name="fresh_slots")
        self.free_en = Signal(name="free_en")       # free ``free_slot`` at this decision
        self.free_slot = Signal(slot_bits, name="free_slot")
        self.push = Signal(name="free_push")        # free_en at a decision
        self.start = Signal(name="free_start")      # a frame starts: empty
        self.head = Signal(slot_bits, name="free_head")
        head_reg = Signal(slot_bits, name="free_head_reg")
        below = Signal(slot_bits, name="free_below")   # the entry below the top, read
        refresh1 = Signal(name="free_refresh1")  # popped a clock ago (nothing pushed)
        refresh2 = Signal(name="free_refresh2")  # popped two clocks ago, nothing pushed since
        w_addr = Signal(range(depth), name="free_w_addr")
        w_data = Signal(slot_bits, name="free_w_data")
        w_en = Signal(name="free_w_en")
        popped = self.pop & ~self.push
        m.d.comb += [self.head.eq(Mux(refresh2, below, head_reg)),
                     write.addr.eq(w_addr), write.data.eq(w_data), write.en.eq(w_en),
                     read.addr.eq(self.depth - 2)]
        m.d.sync += [below.eq(read.data), refresh1.eq(popped),
                     refresh2.eq(refresh1 & ~self.push),
                     head_reg.eq(Mux(self.push, self.free_slot, self.head)),
                     # a push with a pop replaces the top entry
                     w_addr.eq(self.depth - self.pop), w_data.eq(self.free_slot),
                     w_en.eq(self.push)]
        with m.If(self.start):
            m.d.sync += [self.depth.eq(0), refresh1.eq(0), refresh2.eq(0), w_en.eq(0)]
        with m.Elif(self.push & ~self.pop):
            m.d.sync += self.depth.eq(self.depth + 1)
        with m.Elif(popped):
            m.d.sync += self.depth.eq(self.depth - 1)


class _Nodes:
    """Node memories, two banks (the row being written, the row being read), each with a
    flags memory and a label memory: a sequential write port, a patch port and a read
    port.  The previous row's nodes are prefetched into registers (``flags``/``label``:
    the next node to start, ``fetched`` when it is there; one more behind it), so no read
    port drives the decision.  Every write (sequential and patches) is registered and
    reaches its memory a clock after the decision, so no write port is on the decision's
    path either.  A row's nodes 0 and 1 are also kept in registers, loaded from the
    registered writes and patches (read with the write landing in that clock bypassed), so
    node 0 is there a clock after the row's last decision (one idle clock between rows) and
    node 1 a clock later; nodes 2 on are read from the memory (``_prefetch``)."""

    def __init__(self, m, nodes, node_bits, label, bank_written):
        flags = node_flags_layout()
        self.write_ptr = Signal(range(nodes + 1), name="node_write_ptr")
        self.read_ptr = Signal(range(nodes + 1), name="node_read_ptr")  # next to read
        self.consume = Signal(name="node_consume")   # a decision takes the head node
        self.restart = Signal(name="node_restart")   # a row's last decision: swap banks
        self.start = Signal(name="node_start")       # a frame starts: nothing to read
        self.fetched = Signal(name="node_fetched")   # the head node is valid
        self.flags = Signal(flags, name="prev_node_flags")
        self.label = Signal(label, name="prev_node_label")
        self.write_en = Signal(name="node_write_en")
        self.write_flags = Signal(flags, name="node_write_flags")
        self.write_label = Signal(label, name="node_write_label")
        # a first/last patch (never both kinds in one clock) and an untracking patch, both
        # to nodes written before this clock, never to ``write_ptr``
        self.flags_patch_req = Signal(name="flags_patch_req")
        self.flags_patch_en = Signal(name="flags_patch_en")
        self.flags_patch_addr = Signal(node_bits, name="flags_patch_addr")
        self.flags_patch = Signal(flags, name="flags_patch")
        self.untrack_req = Signal(name="untrack_req")
        self.untrack_en = Signal(name="untrack_en")
        self.untrack_addr = Signal(node_bits, name="untrack_addr")
        self.last_reg = Signal(name="prev_node_last")  # last flag of the node under the scan

        issue = Signal(name="node_issue")           # read read_ptr this clock
        # the decision's writes, registered: they reach the memories a clock later
        w_bank = Signal(name="node_w_bank")
        w_addr = Signal.like(self.write_ptr, name="node_w_addr")
        w_en = Signal(name="node_w_en")
        w_flags = Signal(flags, name="node_w_flags")
        w_label = Signal(label, name="node_w_label")
        p_en, u_en = Signal(name="node_p_en"), Signal(name="node_u_en")
        p_addr = Signal(node_bits, name="node_p_addr")
        u_addr = Signal(node_bits, name="node_u_addr")
        p_flags = Signal(flags, name="node_p_flags")
        self.written_label = w_label
        m.d.sync += [w_bank.eq(bank_written), w_addr.eq(self.write_ptr), w_en.eq(self.write_en),
                     w_flags.eq(self.write_flags), w_label.eq(self.write_label),
                     p_en.eq(self.flags_patch_en), p_addr.eq(self.flags_patch_addr),
                     p_flags.eq(self.flags_patch), u_en.eq(self.untrack_en),
                     u_addr.eq(self.untrack_addr)]
        banks = []
        for b in range(2):
            flag_mem = Memory(shape=flags, depth=nodes, init=[])
            label_mem = Memory(shape=label, depth=nodes, init=[])
            m.submodules[f"flags{b}"] = flag_mem
            m.submodules[f"labels{b}"] = label_mem
            ports = {"flags_seq": flag_mem.write_port(), "flags_patch": flag_mem.write_port(),
                     "label_seq": label_mem.write_port(),
                     "label_patch": label_mem.write_port(),
                     "flags_read": flag_mem.read_port(), "label_read": label_mem.read_port()}
            writing = w_bank == b
            # the read port shares its address with the sequential write port (one
            # block-RAM port each way): it reads only the bank not being written
            addr = Mux(writing, w_addr, self.read_ptr)
            m.d.comb += [ports[name].addr.eq(addr) for name in
                         ("flags_seq", "label_seq", "flags_read", "label_read")]
            m.d.comb += [ports["flags_read"].en.eq(issue & ~writing),
                         ports["label_read"].en.eq(issue & ~writing)]
            banks.append((writing, ports))
        for writing, ports in banks:
            m.d.comb += [
                ports["flags_seq"].data.eq(w_flags),
                ports["flags_seq"].en.eq(writing & w_en),
                ports["label_seq"].data.eq(w_label),
                ports["label_seq"].en.eq(writing & w_en),
                ports["flags_patch"].addr.eq(p_addr),
                ports["flags_patch"].data.eq(p_flags),
                ports["flags_patch"].en.eq(writing & p_en),
                ports["label_patch"].addr.eq(u_addr),
                ports["label_patch"].data.eq(0),
                ports["label_patch"].en.eq(writing & u_en),
            ]
        writes = _Writes(w_en=w_en, w_addr=w_addr, w_flags=w_flags, w_label=w_label,
                         p_en=p_en, p_addr=p_addr, p_flags=p_flags, u_en=u_en, u_addr=u_addr)
        self._prefetch(m, nodes, (flags, label), bank_written, banks, (issue, writes))

    @staticmethod
    def _kept(m, flags, label, writes):
        """Nodes 0 and 1 of the row being written, kept in registers loaded from the
        registered writes (``writes``, a ``_Writes``): returns each node's ``(flags,
        label)`` with the writes landing this clock applied (the bypass the prefetch reads
        a clock after a row's last decision)."""
        w = writes
        kept = []
        for k in range(2):
            kept_flags = Signal(flags, name=f"node{k}_flags")
            kept_label = Signal(label, name=f"node{k}_label")
            now_flags = Signal(flags, name=f"node{k}_flags_now")
            now_label = Signal(label, name=f"node{k}_label_now")
            m.d.comb += [
                now_flags.eq(Mux(w.p_en & (w.p_addr == k), w.p_flags,
                                 Mux(w.w_en & (w.w_addr == k), w.w_flags, kept_flags))),
                now_label.eq(Mux(w.u_en & (w.u_addr == k), 0,
                                 Mux(w.w_en & (w.w_addr == k), w.w_label, kept_label)))]
            m.d.sync += [kept_flags.eq(now_flags), kept_label.eq(now_label)]
            kept.append((now_flags, now_label))
        return kept

    def _prefetch(self, m, nodes, shapes, bank_written, banks, issue_writes):
        """Two node registers (head, behind it) fed from the read ports two clocks after
        the read: each bank's read data goes straight into a register (no logic after a
        block RAM's output), the bank is selected after it.  Reads are issued from
        registered state only, while fewer than two nodes are held or in flight (a
        decision takes at most one node per two clocks).  At a bank swap nodes 0 and 1
        of the swapped bank come from registers kept as they were written and patched
        (there in the two clocks after the swap); the memory is read from node 2 on, from
        the third clock after the swap, when the bank's last writes have landed."""
        flags, label = shapes
        issue, writes = issue_writes
        flight1 = Signal(name="node_flight1")   # a node's read data is on the read port
        flight2 = Signal(name="node_flight2")   # a node is in ``in_flags``/``in_label``
        # where the node of each flight stage comes from: 0 the memory, 1 node 0's
        # registers, 2 node 1's
        source1 = Signal(2, name="node_source1")
        source2 = Signal(2, name="node_source2")
        behind = Signal(name="node_behind_valid")
        behind_flags = Signal(flags, name="node_behind_flags")
        behind_label = Signal(label, name="node_behind_label")
        kept = self._kept(m, flags, label, writes)
        read = []
        for b, (_, ports) in enumerate(banks):
            read_flags = Signal(flags, name=f"node_read{b}_flags")
            read_label = Signal(label, name=f"node_read{b}_label")
            m.d.sync += [read_flags.eq(ports["flags_read"].data),
                         read_label.eq(ports["label_read"].data)]
            read.append((read_flags, read_label))
        in_flags = Signal(flags, name="node_in_flags")
        in_label = Signal(label, name="node_in_label")
        for i, target in enumerate((in_flags, in_label)):
            m.d.comb += target.eq(Mux(source2 == 1, kept[0][i],
                                      Mux(source2 == 2, kept[1][i],
                                          Mux(bank_written, read[0][i], read[1][i]))))
        # fewer than two nodes held or in flight (``behind`` implies ``fetched``)
        m.d.comb += issue.eq(~(self.fetched & (behind | flight1 | flight2)) &
                             ~(flight1 & flight2) & (self.read_ptr != nodes))
        m.d.sync += [flight1.eq(issue), flight2.eq(flight1), source1.eq(0),
                     source2.eq(source1)]
        with m.If(issue):
            m.d.sync += self.read_ptr.eq(self.read_ptr + 1)
        with m.If(self.consume):
            m.d.sync += [self.flags.eq(Mux(behind, behind_flags, in_flags)),
                         self.label.eq(Mux(behind, behind_label, in_label)),
                         self.fetched.eq(behind | flight2),
                         behind_flags.eq(in_flags), behind_label.eq(in_label),
                         behind.eq(behind & flight2)]
        with m.Elif(flight2 & self.fetched):
            m.d.sync += [behind_flags.eq(in_flags), behind_label.eq(in_label), behind.eq(1)]
        with m.Elif(flight2):
            m.d.sync += [self.flags.eq(in_flags), self.label.eq(in_label),
                         self.fetched.eq(1)]
        with m.If(self.restart):
            m.d.sync += [self.read_ptr.eq(2), flight2.eq(1), source2.eq(1), flight1.eq(1),
                         source1.eq(2), self.fetched.eq(0), behind.eq(0)]
        with m.If(self.start):
            m.d.sync += [self.read_ptr.eq(nodes), flight1.eq(0), flight2.eq(0),
                         self.fetched.eq(0), behind.eq(0)]


_Writes = namedtuple("_Writes", ["w_en", "w_addr", "w_flags", "w_label", "p_en", "p_addr",
                                 "p_flags", "u_en", "u_addr"])
_Writes.__doc__ = """The node memories' writes of the last decision, registered: the
sequential write (``w_*``), the first/last patch (``p_*``) and the untracking patch
(``u_*``)."""

_Registers = namedtuple("_Registers", [
    "active", "prev_lit", "open_tracked", "dropped", "drop_pending", "dropped_sum",
    "row_parity", "line_error", "fault"])
_Registers.__doc__ = """The registers a column decision updates (beside the node, stack and
free-slot parts): the current run's component ``active`` (``active_layout``), ``prev_lit``
(the decided pixel's left neighbour was lit), ``open_tracked`` (tracked blobs open),
``dropped_sum`` = ``dropped`` + ``drop_pending`` (untracked blobs completed this frame;
the last decision's drop is added a clock later, off the decision's path, by the adder
that is also the port's value), ``row_parity`` (the node bank of the
row decided next), ``line_error`` (a row started before its first node was fetched) and
``fault`` (sticky)."""

_Parts = namedtuple("_Parts", ["held", "nodes", "stack", "free"])
_Parts.__doc__ = """The decision's state: the held pixel (``held_layout``), the node
memories (``_Nodes``), the stack (``_Stack``) and the free slots (``_FreeSlots``)."""

_Sequence = namedtuple("_Sequence", ["decide", "next_lit", "start"])
_Sequence.__doc__ = """What the frame state machine tells the stages: ``decide`` (a column
decision this clock, the held pixel's), ``next_lit`` (the lookahead: pixel ``x + 1`` is lit)
and ``start`` (this beat starts a frame)."""

_Above = namedtuple("_Above", ["left", "here", "right", "node_starts", "last_col"])
_Above.__doc__ = """The previous row's pixels around the decided column, all from
registers, ``node_starts`` (a previous-row node starts at the column) and ``last_col`` (the
column is the row's last)."""

_PushStage = namedtuple("_PushStage", ["top", "second", "push"])
_PushStage.__doc__ = """The stack's ``top`` and ``second`` entries after the push stage, and
``push`` (a previous-row component's first node starts here)."""

_PixelStage = namedtuple("_PixelStage", ["active", "top", "tracked_birth", "merge_closes"])
_PixelStage.__doc__ = """The active component and the top entry after the pixel stage;
``tracked_birth`` (a tracked blob is born) and ``merge_closes`` (a merge lowers the
open-tracked count)."""

_PopStage = namedtuple("_PopStage", ["active", "top", "pop", "completes", "drops"])
_PopStage.__doc__ = """The active component and the top entry after the pop stage; ``pop``
(a component's last previous-row node ends here), ``completes`` (a tracked blob is
complete) and ``drops`` (an untracked one is)."""

_RunEndStage = namedtuple("_RunEndStage", ["top", "run_end", "allocate"])
_RunEndStage.__doc__ = """The top entry after the run-end stage; ``run_end`` (the current run
ends at the column) and ``allocate`` (its component takes a slot)."""


class Labeller(wiring.Component):
    """Labeller for ``width x height`` frames of ``pixel_bits`` pixels.  ``elaborate``
    builds the state (held pixel, previous-row bitmap, node memories, stack, free slots),
    the frame state machine and then the four stages of a column decision in the model's
    order: push, pixel, pop, run end; each stage returns what it decides.

    The decision for column ``x`` is taken when pixel ``x + 1`` is out of the input
    register (it needs to know whether the run ends), or in the clock after the row's last
    pixel.  No block-RAM read port drives a decision (node and stack reads prefetched into
    registers, bitmap read three columns ahead; ``docs/gateware.md``).

    Parameters
    ----------
    width, height : int
        Frame size in pixels (``width >= MIN_WIDTH``).
    pixel_bits : int
        Bits per pixel.
    label_capacity : int
        Tracked open blobs (contract semantics); ``slots_for(label_capacity)`` feature
        slots.

    Members
    -------
    pixels : ``In(stream.Signature(lit_layout(width, height, pixel_bits), always_ready=True))``
        The threshold unit's ``out``: one pixel per beat in raster order, no backpressure,
        registered on the way in.  Rows need ``MIN_HBLANK`` idle clocks between them, and a
        frame ``vblank_cycles(width)`` after its last pixel (a virtual dark row completes the
        last row's blobs, then the feature pipeline drains).  A pixel at ``(0, 0)`` starts a
        frame (and ends an unfinished one, ``FRAME_TRUNCATED``); any other unexpected
        position, or a row started before its first previous-row node was fetched, ends it
        with ``FRAME_TRUNCATED | FRAME_LINE_ERROR``, and pixels are ignored until the next
        ``(0, 0)``.  The next frame is exact.
    ops : ``Out(stream.Signature(op_layout(...), always_ready=True))``
        One op per column decision, to the feature engine (``hdl/features.py``).
    wr_slot : ``Out(bits_for(slots - 1))``
        The slot the op of the previous clock writes (``wr``), from the register of the
        node write (the decision's slot ends there, not at the engine's op register).
    tag : ``Out(FRAME_TAG_BITS)``
        The frame's tag: ops of an aborted frame carry an older one.
    clear, frame_start : ``Out(1)``
        A frame starts (the feature engine restarts; the detector latches the frame's
        registers).
    feat_busy : ``In(1)``
        The feature engine still has ops in flight: a frame is done once it is idle.
    done : ``Out(1)``
        A frame ended, with ``done_flags``.
    done_flags : ``Out(FRAME_FLAGS_BITS)``
        ``contract.FRAME_*`` of the frame that ends (0, or truncated, line error).
    dropped_labels : ``Out``
        Untracked blobs that completed this frame (beyond ``label_capacity`` open).
    busy : ``Out(1)``
        A frame is in progress.
    fault : ``Out(1)``
        Sticky, for verification: an internal bound was exceeded (it cannot happen).
    """

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
            "wr_slot": Out(C.bits_for(self.slots - 1)),
            "tag": Out(FRAME_TAG_BITS),
            "clear": Out(1),
            "feat_busy": In(1),
            "frame_start": Out(1),
            "done": Out(1),
            "done_flags": Out(FRAME_FLAGS_BITS),
            "dropped_labels": Out(dict(C.HEADER_FIELDS)["dropped_labels"]),
            "busy": Out(1),
            "fault": Out(1),
        })

    def elaborate(self, platform):
        m = Module()
        W, H = self.width, self.height
        slot_bits = C.bits_for(self.slots - 1)
        node_bits = C.bits_for(max_nodes(W) - 1)
        held = Signal(held_layout(C.bits_for(W - 1), C.bits_for(H), self.pixel_bits),
                      name="held")
        regs = _Registers(
            active=Signal(active_layout(slot_bits, node_bits), name="active"),
            prev_lit=Signal(name="prev_lit"),
            open_tracked=Signal(range(self.label_capacity + 1), name="open_tracked"),
            # at most one blob per two pixels: the count is that wide, widened at the port
            dropped=Signal(C.bits_for((W * H + 1) // 2), name="dropped"),
            drop_pending=Signal(name="drop_pending"),
            dropped_sum=Signal(C.bits_for((W * H + 1) // 2), name="dropped_sum"),
            row_parity=Signal(name="row_parity"), line_error=Signal(name="line_error"),
            fault=Signal(name="fault_reg"))
        parts = _Parts(held=held,
                       nodes=_Nodes(m, max_nodes(W), node_bits, node_label_layout(slot_bits),
                                    regs.row_parity),
                       stack=_Stack(m, stack_entry_layout(slot_bits, node_bits),
                                    max_stack(W)),
                       free=_FreeSlots(m, self.slots, slot_bits))
        m.d.comb += [self.fault.eq(regs.fault), self.dropped_labels.eq(regs.dropped_sum),
                     self.wr_slot.eq(parts.nodes.written_label.slot)]

        seq = self._frames(m, held, regs.line_error)
        above = self._previous_row(m, held, seq.decide)
        push = self._push(m, above, parts)
        pixel = self._pixel(m, above, push.top, parts, regs)
        pop = self._pop(m, above, pixel, push, parts)
        run = self._run_end(m, pop, parts, seq)
        self._update(m, above, push, pixel, pop, run, parts, regs, seq)
        return m

    # ---- previous row ---------------------------------------------------------------
    def _previous_row(self, m, held, decide):
        """The previous row's pixels around the decided column ``x``, all from registers
        (an ``_Above``).  The bitmap is read at column ``x + 3`` (wrapping into the next
        row: those columns of this row are written, the read is transparent for ``W`` = 3)
        and its read data only shifts into the registers at each decision."""
        W = self.width
        m.submodules.bitmap = bitmap = Memory(shape=1, depth=W, init=[])
        write = bitmap.write_port()
        read = bitmap.read_port(transparent_for=(write,))
        left_reg, here_reg = Signal(name="above_left_reg"), Signal(name="above_reg")
        right_reg = Signal(name="above_right_reg")
        first_row, last_col = held.first_row, held.last_col
        here = here_reg & ~first_row
        left = left_reg & ~first_row
        ahead = Signal(C.bits_for(W - 1), name="ahead")  # x + 3, wrapped into the row
        m.d.comb += ahead.eq(Mux(held.x >= W - 3, held.x - (W - 3), held.x + 3))
        m.d.comb += [
            write.addr.eq(held.x), write.data.eq(held.lit), write.en.eq(decide),
            read.addr.eq(ahead), read.en.eq(decide),
        ]
        with m.If(decide):
            m.d.sync += [left_reg.eq(Mux(last_col, 0, here_reg)), here_reg.eq(right_reg),
                         right_reg.eq(read.data)]
        return _Above(left=left, here=here, right=right_reg & ~first_row & ~last_col,
                      node_starts=here & ~left, last_col=last_col)

    # ---- the four stages of a column decision ---------------------------------------
    def _push(self, m, above, parts):
        """A previous-row node starting here that is its component's first is pushed
        (a ``_PushStage``)."""
        nodes, stack = parts.nodes, parts.stack
        push = above.node_starts & nodes.flags.first
        pushed = Signal.like(stack.top, name="pushed")
        m.d.comb += [pushed.slot.eq(nodes.label.slot), pushed.tracked.eq(nodes.label.tracked)]
        top = Signal.like(stack.top, name="top_after_push")
        second = Signal.like(stack.top, name="second_after_push")
        m.d.comb += [top.eq(Mux(push, pushed, stack.top)),
                     second.eq(Mux(push, stack.top, stack.second))]
        return _PushStage(top=top, second=second, push=push)

    def _pixel(self, m, above, under, parts, regs):
        """The decided pixel: a run starting under a node continues its component (the
        top entry ``under``), a run starting over dark pixels is a birth, a node of another
        component starting under the run is a merge (a ``_PixelStage``)."""
        held, nodes, free, op = parts.held, parts.nodes, parts.free, self.ops.payload
        act = regs.active
        active = Signal.like(act, name="active_after_pixel")
        top = Signal.like(under, name="top_after_pixel")
        action = Signal(PixelAction, name="pixel_action")
        m.d.comb += [active.eq(act), top.eq(under)]
        run_starts = held.lit & ~regs.prev_lit
        tracked_birth = Signal()
        merge_closes = Signal()       # a merge lowers the open-tracked count
        m.d.comb += [op.tag.eq(self.tag), op.pix.eq(held.lit), op.x.eq(held.x),
                     op.y.eq(held.y), op.p.eq(held.data), op.w.eq(held.weight)]
        both_tracked = act.tracked & under.tracked
        merge = held.lit & ~run_starts & above.node_starts & \
            ~(act.on_stack & ~nodes.flags.first)
        with m.If(run_starts & above.here):
            m.d.comb += [active.slot.eq(under.slot), active.tracked.eq(under.tracked),
                         active.has_slot.eq(under.tracked), active.in_row.eq(under.in_row),
                         active.first_node.eq(under.first_node),
                         active.last_node.eq(under.last_node), active.on_stack.eq(1),
                         op.rd.eq(under.tracked), op.rd_addr.eq(under.slot),
                         action.eq(PixelAction.CONTINUE)]
        with m.Elif(run_starts):
            tracked = regs.open_tracked != self.label_capacity  # it never exceeds it
            m.d.comb += [active.eq(0), active.tracked.eq(tracked),
                         tracked_birth.eq(tracked), action.eq(PixelAction.BIRTH)]
        with m.Elif(merge):
            m.d.comb += [merge_closes.eq(act.tracked | under.tracked),
                         active.tracked.eq(both_tracked), active.on_stack.eq(1),
                         op.rd.eq(both_tracked), op.rd_addr.eq(under.slot),
                         action.eq(PixelAction.MERGE)]
            self._merge(m, act, under, active, top, nodes, free)
        return _PixelStage(active=active, top=top, tracked_birth=tracked_birth,
                           merge_closes=merge_closes)

    def _merge(self, m, act, under, active, top, nodes, free):
        """A merge of the active component ``act`` with the top entry ``under``: the slot
        the survivor keeps is one a first node names already; the other is freed (both,
        when the merge untracks the survivor)."""
        both_tracked = act.tracked & under.tracked
        either_slot = Mux(act.has_slot, act.slot, under.slot)
        with m.If(under.in_row):        # case (i): the active run nests inside ``under``
            m.d.comb += [nodes.flags_patch_req.eq(act.in_row),
                         nodes.flags_patch_addr.eq(act.first_node),
                         nodes.flags_patch.eq(0),
                         active.in_row.eq(1), active.first_node.eq(under.first_node),
                         active.last_node.eq(Mux(act.in_row, act.last_node,
                                                 under.last_node))]
            with m.If(both_tracked):
                m.d.comb += [active.slot.eq(under.slot), active.has_slot.eq(1),
                             free.free_en.eq(act.has_slot), free.free_slot.eq(act.slot)]
            with m.Else():
                m.d.comb += [active.has_slot.eq(0),
                             free.free_en.eq(act.has_slot | under.tracked),
                             free.free_slot.eq(either_slot)]
        with m.Else():                  # case (ii): ``under`` has no node in this row yet
            m.d.comb += top.continues.eq(act.on_stack | under.continues)
            with m.If(both_tracked):
                m.d.comb += [active.slot.eq(either_slot), active.has_slot.eq(1),
                             free.free_en.eq(act.has_slot), free.free_slot.eq(under.slot)]
            with m.Else():
                m.d.comb += [active.has_slot.eq(0),
                             free.free_en.eq(act.has_slot | under.tracked),
                             free.free_slot.eq(either_slot)]
        with m.If(~both_tracked & (under.in_row | act.in_row)):  # the survivor's first node
            m.d.comb += [nodes.untrack_req.eq(1),
                         nodes.untrack_addr.eq(Mux(under.in_row, under.first_node,
                                                   act.first_node))]

    def _pop(self, m, above, pixel, push, parts):
        """The component whose last previous-row node ends here is popped: the run carries
        it on, its information moves to the entry below, its last node in this row is
        patched, or it is complete (a ``_PopStage``)."""
        held, nodes, free, op = parts.held, parts.nodes, parts.free, self.ops.payload
        active_in, popped, second = pixel.active, pixel.top, push.second
        node_last = Mux(above.node_starts, nodes.flags.last, nodes.last_reg)
        pop = above.here & ~above.right & node_last
        active = Signal.like(active_in, name="active_after_pop")
        top = Signal.like(popped, name="top_after_pop")
        action = Signal(PopAction, name="pop_action")
        completes = Signal()
        drops = Signal()
        m.d.comb += active.eq(active_in)
        carried = held.lit & active_in.on_stack      # the current run belongs to it
        with m.If(pop):
            with m.If(carried):
                m.d.comb += [active.on_stack.eq(popped.continues),
                             action.eq(PopAction.CARRY_ON)]
            with m.Elif(popped.continues):
                m.d.comb += action.eq(PopAction.MOVE_DOWN)          # see ``moved`` below
            with m.Elif(popped.in_row):
                m.d.comb += [nodes.flags_patch_req.eq(1),
                             nodes.flags_patch_addr.eq(popped.last_node),
                             nodes.flags_patch.first.eq(popped.last_node == popped.first_node),
                             nodes.flags_patch.last.eq(1), action.eq(PopAction.PATCH_LAST)]
            with m.Elif(popped.tracked):
                m.d.comb += [completes.eq(1), op.complete.eq(1), op.rd.eq(1),
                             op.rd_addr.eq(popped.slot), free.free_en.eq(1),
                             free.free_slot.eq(popped.slot), action.eq(PopAction.COMPLETE)]
            with m.Else():
                m.d.comb += [drops.eq(1), action.eq(PopAction.DROP)]
        moved = Signal.like(popped, name="moved")   # the entry below, with the popped information
        m.d.comb += [moved.eq(popped), moved.continues.eq(second.continues)]
        with m.If(pop & push.push):
            m.d.comb += top.eq(parts.stack.top)
        with m.Elif(pop):
            m.d.comb += top.eq(Mux(popped.continues & ~carried, moved, second))
        with m.Else():
            m.d.comb += top.eq(popped)
        return _PopStage(active=active, top=top, pop=pop, completes=completes, drops=drops)

    def _run_end(self, m, pop, parts, seq):
        """The current run ends (``x + 1`` dark or the row's last column): its node is
        written, its slot allocated if it has none (a ``_RunEndStage``)."""
        held, nodes, free, op = parts.held, parts.nodes, parts.free, self.ops.payload
        active, top_in, decide = pop.active, pop.top, seq.decide
        run_end = held.lit & ~seq.next_lit
        allocate = run_end & active.tracked & ~active.has_slot
        slot = Signal.like(active.slot, name="run_slot")
        m.d.comb += slot.eq(active.slot)
        with m.If(allocate):
            with m.If(free.ready):
                m.d.comb += [slot.eq(free.head), free.pop.eq(decide)]
            with m.Else():
                m.d.comb += slot.eq(free.fresh)
        m.d.comb += free.push.eq(decide & free.free_en)
        top = Signal.like(top_in, name="top_after_run")
        m.d.comb += top.eq(top_in)
        with m.If(run_end):
            m.d.comb += [nodes.write_en.eq(decide),
                         nodes.write_flags.first.eq(~active.in_row),
                         nodes.write_flags.last.eq(~active.on_stack),
                         nodes.write_label.slot.eq(slot),
                         nodes.write_label.tracked.eq(active.tracked),
                         op.wr.eq(active.tracked)]
            with m.If(active.on_stack):
                m.d.comb += [top.slot.eq(slot), top.tracked.eq(active.tracked),
                             top.in_row.eq(1),
                             top.first_node.eq(Mux(active.in_row, active.first_node,
                                                   nodes.write_ptr)),
                             top.last_node.eq(nodes.write_ptr)]
        m.d.comb += [nodes.flags_patch_en.eq(nodes.flags_patch_req & decide),
                     nodes.untrack_en.eq(nodes.untrack_req & decide)]
        m.d.comb += self.ops.valid.eq(decide)
        return _RunEndStage(top=top, run_end=run_end, allocate=allocate)

    # ---- state updated by a decision -------------------------------------------------
    def _update(self, m, above, push, pixel, pop, run, parts, regs, seq):
        """The registers ``regs``, the stack, node pointers and counts after a decision
        (from the four stages' results); their frame-start values."""
        nodes, stack, free, decide = parts.nodes, parts.stack, parts.free, seq.decide
        last_col, count = above.last_col, regs.open_tracked
        pushed, popped = push.push, pop.pop
        closes = pixel.merge_closes | pop.completes
        # the refill port reads the entry below the memory's top on every clock, from
        # registers only: after a pop it is the new second (no push follows a pop at once)
        m.d.comb += [stack.spill_en.eq(0),
                     stack.spilled_next.eq(stack.spilled + Mux(pushed & ~popped, 1,
                                                               Mux(popped & ~pushed, -1, 0)))]
        with m.If(stack.reload):
            m.d.sync += [stack.second.eq(stack.refilled), stack.reload.eq(0)]
        m.d.comb += regs.dropped_sum.eq(regs.dropped + regs.drop_pending)
        m.d.sync += [regs.dropped.eq(regs.dropped_sum), regs.drop_pending.eq(decide & pop.drops)]
        with m.If(decide):
            m.d.sync += [regs.active.eq(pop.active), stack.top.eq(run.top),
                         # a birth, a merge and a completion exclude each other: +1 or -1
                         count.eq(count + Cat(pixel.tracked_birth | closes,
                                              closes.replicate(len(count) - 1))),
                         regs.prev_lit.eq(parts.held.lit & ~last_col)]
            with m.If(run.allocate & ~free.ready):
                m.d.sync += free.fresh.eq(free.fresh + 1)
                with m.If(free.fresh == self.slots):
                    m.d.sync += regs.fault.eq(1)
            m.d.sync += stack.spilled.eq(stack.spilled_next)
            with m.If(pushed & ~popped):
                m.d.sync += stack.second.eq(stack.top)
                m.d.comb += stack.spill_en.eq(~stack.spilled[-1])
                with m.If(stack.spilled == max_stack(self.width) - 2):
                    m.d.sync += regs.fault.eq(1)
            with m.Elif(popped & ~pushed):       # the new second is the memory's last entry
                m.d.sync += stack.reload.eq(~stack.spilled_next[-1])
            with m.If(above.node_starts):
                m.d.sync += nodes.last_reg.eq(nodes.flags.last)
                with m.If(~nodes.fetched):
                    m.d.sync += regs.line_error.eq(1)
            with m.If(run.run_end):
                m.d.sync += nodes.write_ptr.eq(nodes.write_ptr + 1)
            with m.If(last_col):
                m.d.sync += [nodes.write_ptr.eq(0), stack.spilled.eq(-2),
                             regs.row_parity.eq(~regs.row_parity)]
                # the stack is empty at every row end (spilled_next == -2)
                with m.If(~(Mux(pushed == popped, stack.spilled == -2,
                                popped & (stack.spilled == -1)))):
                    m.d.sync += regs.fault.eq(1)
        m.d.comb += [nodes.consume.eq(decide & above.node_starts),
                     nodes.restart.eq(decide & last_col), nodes.start.eq(seq.start)]

        with m.If(seq.start):
            m.d.comb += free.start.eq(1)
            m.d.sync += [count.eq(0), free.fresh.eq(0), regs.dropped.eq(0),
                         regs.drop_pending.eq(0),
                         regs.row_parity.eq(0), regs.prev_lit.eq(0), stack.spilled.eq(-2),
                         nodes.write_ptr.eq(0), regs.line_error.eq(0), stack.reload.eq(0)]

    # ---- frame sequencing --------------------------------------------------------------
    def _input(self, m):
        """The input beat, registered with its position checks (one clock of latency):
        ``(beat, valid, at_origin, same_row, successor)``, the last two against the
        previous valid beat (``successor``: the next position in raster order).  In
        ``RUN`` every valid beat is held or ends the frame, so there the previous valid
        beat is the held pixel, and the checks take no logic from the decision's clock."""
        W, H = self.width, self.height
        p, p_valid = self.pixels.payload, self.pixels.valid
        beat = Signal(lit_layout(W, H, self.pixel_bits), name="in_beat")
        valid, at_origin = Signal(name="in_valid"), Signal(name="in_origin")
        same_row, successor = Signal(name="in_same_row"), Signal(name="in_successor")
        prev_y = Signal.like(p.y, name="prev_y")
        prev_next_x = Signal.like(p.x, name="prev_next_x")   # x + 1, y + 1
        # y + 1 one bit wider than y: (0, 0) after (W - 1, H - 1) is no successor, even for
        # a power-of-two H (the frame ends by its virtual row, or truncated; docs/formal.md)
        prev_next_y = Signal(range(H + 1), name="prev_next_y")
        prev_last = Signal(name="prev_last_col")
        m.d.sync += [beat.eq(p), valid.eq(p_valid),
                     at_origin.eq((p.x == 0) & (p.y == 0)), same_row.eq(p.y == prev_y),
                     successor.eq(Mux(prev_last, (p.x == 0) & (p.y == prev_next_y),
                                      (p.x == prev_next_x) & (p.y == prev_y)))]
        with m.If(p_valid):
            m.d.sync += [prev_y.eq(p.y), prev_next_x.eq(p.x + 1), prev_next_y.eq(p.y + 1),
                         prev_last.eq(p.x == W - 1)]
        return beat, valid, at_origin, same_row, successor

    def _frames(self, m, held, line_error):
        """Frame state machine: takes pixels at their expected positions into the ``held``
        register, decides the virtual row, drains, and ends frames (done, faults; a
        ``line_error`` ends the frame).  Returns a ``_Sequence``."""
        W, H = self.width, self.height
        beat, valid, at_origin, same_row, expected = self._input(m)
        start = Signal(name="start")          # this beat starts a frame
        decide = Signal(name="decide")        # a column decision this clock: the held pixel's
        next_lit = Signal(name="next_lit")    # lookahead: pixel x + 1 is lit
        drain = Signal(range(_DRAIN + 2))
        tag = Signal(FRAME_TAG_BITS, name="frame_tag")
        abort = Signal()              # the frame in progress ends early
        abort_flags = Signal(FRAME_FLAGS_BITS)
        take = Signal()               # this beat is held
        finished = Signal()
        row_end_held = held.valid & held.last_col  # the next pixel starts the next row
        m.d.comb += [self.tag.eq(tag), self.frame_start.eq(start), self.clear.eq(start),
                     self.done_flags.eq(abort_flags),
                     # outside RUN no decision takes a lit pixel (the virtual row is dark)
                     next_lit.eq(~row_end_held & beat.lit)]
        with m.If(start | abort):
            m.d.sync += tag.eq(tag + 1)

        def start_frame(flags=None):
            m.d.comb += [start.eq(1), take.eq(1)]
            if flags is not None:
                m.d.comb += [abort.eq(1), abort_flags.eq(flags)]

        def restart_if_new_frame():
            """A frame starting before this one finished: end it truncated, start anew."""
            with m.If(valid & at_origin):
                start_frame(C.FRAME_TRUNCATED)
                m.next = "RUN"

        with m.FSM():
            with m.State("IDLE"):
                with m.If(valid & at_origin):
                    start_frame()
                    m.next = "RUN"
            with m.State("RUN"):
                m.d.comb += self.busy.eq(1)
                right = valid & expected & same_row & held.valid
                m.d.comb += decide.eq(row_end_held | right)
                with m.If(valid & ~expected):
                    m.d.comb += abort.eq(1)
                    with m.If(at_origin):
                        start_frame(C.FRAME_TRUNCATED)
                    with m.Else():
                        m.d.comb += abort_flags.eq(C.FRAME_TRUNCATED | C.FRAME_LINE_ERROR)
                        m.next = "SKIP"
                with m.Elif(line_error):
                    m.d.comb += [abort.eq(1),
                                 abort_flags.eq(C.FRAME_TRUNCATED | C.FRAME_LINE_ERROR)]
                    m.next = "SKIP"
                with m.Else():
                    m.d.comb += take.eq(valid)
                    with m.If(row_end_held & (held.y == H - 1)):
                        m.d.sync += [held.x.eq(0), held.y.eq(H), held.lit.eq(0),
                                     held.valid.eq(0), held.first_row.eq(0),
                                     held.last_col.eq(0)]
                        m.next = "GAP"
            with m.State("GAP"):              # one clock: the last row's first node
                m.d.comb += self.busy.eq(1)
                m.next = "VROW"
                restart_if_new_frame()
            with m.State("VROW"):             # the virtual dark row
                m.d.comb += [self.busy.eq(1), decide.eq(1)]
                m.d.sync += [held.x.eq(held.x + 1), held.last_col.eq(held.x == W - 2)]
                with m.If(held.last_col):
                    m.d.sync += drain.eq(0)
                    m.next = "DRAIN"
                restart_if_new_frame()
            with m.State("DRAIN"):
                m.d.comb += self.busy.eq(1)
                m.d.sync += drain.eq(drain + 1)
                with m.If((drain >= _DRAIN - 1) & ~self.feat_busy & ~valid):
                    m.d.comb += finished.eq(1)
                    m.next = "IDLE"
                restart_if_new_frame()
            with m.State("SKIP"):
                with m.If(valid & at_origin):
                    start_frame()
                    m.next = "RUN"
        m.d.comb += self.done.eq(finished | abort)

        with m.If(take):
            m.d.sync += [held.valid.eq(1), held.x.eq(beat.x), held.y.eq(beat.y),
                         held.lit.eq(beat.lit), held.data.eq(beat.data),
                         held.weight.eq(beat.weight), held.first_row.eq(beat.y == 0),
                         held.last_col.eq(beat.x == W - 1)]
        with m.Elif(decide & ~(valid & expected)):
            m.d.sync += held.valid.eq(0)
        with m.If(abort & ~start):
            m.d.sync += held.valid.eq(0)
        return _Sequence(decide=decide, next_lit=next_lit, start=start)
