"""Runtime register bank: the contract's ``REGISTERS``, written one 32-bit word at a time.

A write (``addr``, ``data``, ``en`` for one clock) updates the register at that word
address.  The detector latches the registers at the start of each frame, so writes take
effect on the next frame; writing during a frame is harmless.  A write is refused, the
register keeps its value and ``error`` is raised (sticky until ``error_clear``) when the
address is not a register or the value is outside ``contract.register_range`` (the field,
a mode number, the local window's bounds, a pixel's full scale).  Reset values are the
contract's.

Cost: the registers' flip-flops (a register keeps only the bits its limit can set: a pixel
register ``pixel_bits``, the others' upper bits are constant 0).  The domain's reset is
written like a value (the flip-flops are ``reset_less`` and load the contract's reset value
while ``ResetSignal()`` is high), so the select "reset value bit or data bit" is one LUT per
data bit and reset value bit shared by all registers, not one per flip-flop.  Every limit
but ``mode``'s is ``2**k - 1`` (``local_log2_window``'s also has a lower bound), so the
range checks are "the bits above ``k`` are zero", not comparators.

Read-back: ``raddr`` selects a register whose value appears on ``rdata`` one clock later
(0 for an address that is not a register); a bank whose read port is unused (the
detector's) loses the multiplexer in synthesis.
"""

from amaranth import Module, Mux, ResetSignal, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from lodestar import contract as C


def _in_range(data, low, high):
    """``low <= data <= high`` for an unsigned ``data``, as bit tests: the bits above
    ``high``'s are zero, and below them a comparison only where ``high`` is not all ones
    or ``low`` is not zero."""
    k = C.bits_for(high)
    ok = data[k:] == 0 if k < len(data) else 1
    if high != (1 << k) - 1:
        ok = ok & (data[:k] <= high)
    if low:
        ok = ok & (data[:k] >= low)
    return ok


class RegisterBank(wiring.Component):
    """The register bank for ``pixel_bits``-bit pixels; one output port per register.

    Parameters
    ----------
    pixel_bits : int
        The pixels' width (the pixel registers' limit).

    Members
    -------
    addr, data, en : ``In``
        The write port: word address, value, strobe.
    error : ``Out(1)``
        A write was refused (sticky until ``error_clear``).
    error_clear : ``In(1)``
        Clears ``error``.
    raddr : ``In``; rdata : ``Out(REGISTER_WORD_BITS)``
        The read port: the value at ``raddr``, one clock later.
    (one ``Out`` per register of ``contract.REGISTERS``)
        The values.
    """

    def __init__(self, pixel_bits):
        self.pixel_bits = pixel_bits
        top = max(r.address for r in C.REGISTERS)
        members = {
            "addr": In(C.bits_for(top)),
            "data": In(C.REGISTER_WORD_BITS),
            "en": In(1),
            "error": Out(1),
            "error_clear": In(1),
            "raddr": In(C.bits_for(top)),
            "rdata": Out(C.REGISTER_WORD_BITS),
        }
        for reg in C.REGISTERS:
            members[reg.name] = Out(reg.bits, init=reg.reset)
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        refused = Signal()
        m.d.comb += refused.eq(1)
        reset = ResetSignal()
        for reg in C.REGISTERS:
            low, high = C.register_range(reg.name, self.pixel_bits)
            value = Signal(C.bits_for(high), init=reg.reset, reset_less=True, name=reg.name)
            m.d.comb += getattr(self, reg.name).eq(value)
            hit = (self.addr == reg.address) & _in_range(self.data, low, high)
            with m.If(hit):
                m.d.comb += refused.eq(0)
            # the domain's reset taken as an ordinary write of the reset value: the data
            # bit or reset bit select is then shared by every register, not one per bit
            with m.If(reset | (self.en & hit)):
                m.d.sync += value.eq(Mux(reset, reg.reset, self.data))
        with m.Switch(self.raddr):
            for reg in C.REGISTERS:
                with m.Case(reg.address):
                    m.d.sync += self.rdata.eq(getattr(self, reg.name))
            with m.Default():
                m.d.sync += self.rdata.eq(0)
        with m.If(self.en & refused):
            m.d.sync += self.error.eq(1)
        with m.Elif(self.error_clear):
            m.d.sync += self.error.eq(0)
        return m
