"""The SPI link between the MCU and the FPGA: opcodes, framing, the status word and its
overflow bits.  The gateware's slave
(``lodestar.hdl.spi_slave``) and the MCU both use these names; the protocol (SPI mode 0,
one command per chip-select, timing) is described in ``hdl/spi_slave.py``; the sensors
and their pixel widths are in :mod:`lodestar.contract.detection`."""

from lodestar.contract.detection import REGISTER_BY_NAME, REGISTER_WORD_BITS, REGISTERS, bits_for
from lodestar.contract.packet import HEADER_FIELDS

OP_WRITE_REG = 0x57
"""``'W'``: write one runtime register."""
OP_READ_STATUS = 0x53
"""``'S'``: read the status word."""
OP_READ_STREAM = 0x52
"""``'R'``: read packet bytes until CS rises."""
OPCODES = (OP_WRITE_REG, OP_READ_STATUS, OP_READ_STREAM)
FILLER = 0x00
"""MISO byte wherever no reply byte is defined, and in place of missing packet bytes."""
TURNAROUND_BYTES = 1
"""Bytes between a read's opcode and its first reply byte."""

ADDRESS_BYTES = 1
"""Register address bytes of ``WRITE_REG``."""
VALUE_BYTES = REGISTER_WORD_BITS // 8
"""Register value bytes of ``WRITE_REG`` (big endian)."""
WRITE_REG_BYTES = 1 + ADDRESS_BYTES + VALUE_BYTES
REG_ADDR_BITS = bits_for(max(r.address for r in REGISTERS))
"""Width of the write port's address: the contract's largest word address."""
if max(r.address for r in REGISTERS) >> (8 * ADDRESS_BYTES):
    raise ValueError("a register address does not fit the SPI address byte")



def write_reg_command(name, value):
    """The bytes of the ``WRITE_REG`` transaction (one chip-select) that sets the runtime
    register ``name`` (:data:`lodestar.contract.detection.REGISTERS`) to ``value``: opcode,
    word address, value big endian.  ``ValueError`` for an unknown register or a value that
    is not an int within its ``bits``."""
    reg = REGISTER_BY_NAME.get(name)
    if reg is None:
        raise ValueError("unknown register {!r}".format(name))
    if isinstance(value, bool) or not isinstance(value, int) or value < 0 or value >> reg.bits:
        raise ValueError("register {} holds {} bits, got {!r}".format(name, reg.bits, value))
    return bytes((OP_WRITE_REG, reg.address)) + value.to_bytes(VALUE_BYTES, "big")


LINK_COUNT_BITS = 8
"""Width of the saturating ``errors`` and ``underruns`` counts of the status word."""
OVERFLOW_BITS = 7
"""Overflow flags in the status word (unassigned flags read 0)."""

OVF_PIXEL_FIFO = 0
"""A pixel found the clock-crossing FIFO full (its frame is truncated)."""
OVF_TRAILER_LOST = 1
"""The detector lost a frame trailer (its trailer buffer was full)."""
OVF_REG_REFUSED = 2
"""The register bank refused a write."""
OVF_FAULT = 3
"""The detector's internal-bound fault (never expected)."""
OVF_LINK_DOWN = 4
"""LVDS front end: not word-locked or the LVDS receiver's PLL not locked (live, not sticky);
parallel front end: 0."""
OVF_LINK_ERROR = 5
"""LVDS front end: framing errors since the last status read."""
OVF_CLOCK_LOST = 6
"""The board's PLL lost lock since the last status read.  Registers keep their values (only
power-up resets them); the frame under way may be truncated or timed out."""

FRAME_COUNTER_BITS = dict(HEADER_FIELDS)["frame_counter"]
"""Width of the frame counter (the packet header's)."""

STATUS_FIELDS = (
    ("frame_counter", FRAME_COUNTER_BITS),
    ("errors", LINK_COUNT_BITS),
    ("underruns", LINK_COUNT_BITS),
    ("overflow", OVERFLOW_BITS),
    ("busy", 1),
)
"""The status word, MSB first: ``(field, bits)``; sent big endian.  The overflow bits are
sticky until the next status read (except ``OVF_LINK_DOWN``), and ``errors``/``underruns``
count since the previous status read."""
STATUS_BITS = 0
for _name, _bits in STATUS_FIELDS:
    STATUS_BITS += _bits
STATUS_BYTES = STATUS_BITS // 8
if STATUS_BITS % 8:
    raise ValueError("the status word must be a whole number of bytes")


def decode_status(data):
    """The fields of a status word given as ``STATUS_BYTES`` bytes (MSB first), as a dict."""
    if len(data) != STATUS_BYTES:
        raise ValueError("a status word is {} bytes, got {}".format(STATUS_BYTES, len(data)))
    value = 0
    for byte in data:
        value = (value << 8) | byte
    out = {}
    for name, bits in reversed(STATUS_FIELDS):
        out[name] = value & ((1 << bits) - 1)
        value >>= bits
    return out
