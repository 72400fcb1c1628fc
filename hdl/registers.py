"""Runtime register bank: the contract's ``REGISTERS``, written one 32-bit word at a time.

A write (``addr``, ``data``, ``en`` for one clock) updates the register at that word
address.  The detector latches the registers at the start of each frame, so writes take
effect on the next frame; writing during a frame is harmless.  A write is refused, the
register keeps its value and ``error`` is raised (sticky until ``error_clear``) when the
address is not a register, the value does not fit the register's field, ``mode`` is not a
mode, ``local_log2_window`` is outside ``LOCAL_LOG2_WINDOW_MIN .. MAX``, or ``threshold``,
``background`` or ``local_offset`` exceed the pixel's full scale.  Reset values are the
contract's.
"""

from amaranth import Module, Signal
from amaranth.lib import wiring
from amaranth.lib.wiring import In, Out

from lodestar import contract as C

_PIXEL_REGISTERS = ("threshold", "background", "local_offset")


def _limit(reg, pixel_bits):
    """Largest value the register accepts."""
    if reg.name == "mode":
        return len(C.MODE_NAMES) - 1
    if reg.name == "local_log2_window":
        return C.LOCAL_LOG2_WINDOW_MAX
    if reg.name in _PIXEL_REGISTERS:
        return C.full_scale(pixel_bits)
    return (1 << reg.bits) - 1


def _lower(reg):
    return C.LOCAL_LOG2_WINDOW_MIN if reg.name == "local_log2_window" else 0


class RegisterBank(wiring.Component):
    """The register bank for ``pixel_bits``-bit pixels; one output port per register."""

    def __init__(self, pixel_bits):
        self.pixel_bits = pixel_bits
        top = max(r.address for r in C.REGISTERS)
        members = {
            "addr": In(C.bits_for(top)),
            "data": In(C.REGISTER_WORD_BITS),
            "en": In(1),
            "error": Out(1),
            "error_clear": In(1),
        }
        for reg in C.REGISTERS:
            members[reg.name] = Out(reg.bits, init=reg.reset)
        super().__init__(members)

    def elaborate(self, platform):
        m = Module()
        known = Signal()
        with m.If(self.error_clear):
            m.d.sync += self.error.eq(0)
        with m.If(self.en):
            for reg in C.REGISTERS:
                with m.If(self.addr == reg.address):
                    m.d.comb += known.eq(1)
                    ok = (self.data >= _lower(reg)) & (self.data <= _limit(reg, self.pixel_bits))
                    with m.If(ok):
                        m.d.sync += getattr(self, reg.name).eq(self.data)
                    with m.Else():
                        m.d.sync += self.error.eq(1)
            with m.If(~known):
                m.d.sync += self.error.eq(1)
        return m
