"""The SPI link between the MCU and the FPGA: opcodes, framing, the status word with its
CRC-8, its overflow bits, and the gateware ID word.  The gateware's slave
(``lodestar.hdl.spi_slave``) and the MCU's master (``lodestar.firmware.link``) both use these
names; the protocol (SPI mode 0, one command per chip-select, timing) is described in
``hdl/spi_slave.py`` and ``docs/sensors_and_link.md``; the sensors and their pixel widths are
in :mod:`lodestar.contract.detection`.  MicroPython-safe (the MCU imports it)."""

from lodestar.contract.detection import REGISTER_BY_NAME, REGISTER_WORD_BITS, REGISTERS, bits_for
from lodestar.contract.packet import HEADER_FIELDS

OP_WRITE_REG = 0x57
"""``'W'``: write one runtime register."""
OP_READ_STATUS = 0x53
"""``'S'``: read the status word."""
OP_READ_STREAM = 0x52
"""``'R'``: read packet bytes until CS rises."""
OP_READ_REG = 0x47
"""``'G'``: read back one runtime register (the register bank's value, after any refusal)."""
OP_READ_ID = 0x49
"""``'I'``: read the gateware ID word (:data:`ID_FIELDS`)."""
OP_SOFT_RESET = 0x5A
"""``'Z'`` + :func:`command_key`: reset the detector datapath (the register bank keeps its
values); the slave pulses ``soft_reset``."""
OP_FLUSH = 0x46
"""``'F'`` + :func:`command_key`: drop every packet byte queued for the MCU; the slave pulses
``flush``."""
OPCODES = (OP_WRITE_REG, OP_READ_STATUS, OP_READ_STREAM, OP_READ_REG, OP_READ_ID,
           OP_SOFT_RESET, OP_FLUSH)
KEYED_OPCODES = (OP_SOFT_RESET, OP_FLUSH)
"""Commands that act only when their second byte is their :func:`command_key`: a bit error
that turns another opcode into one of them does not reset or flush anything (the key is
neither ``0x00`` nor ``0xFF``, the bytes a master clocks out in a read)."""
KEYED_BYTES = 2
"""Bytes of a keyed command: opcode, key (bytes after them are ignored)."""


def command_key(opcode):
    """The key byte that must follow a keyed opcode: its complement."""
    return opcode ^ 0xFF
MCU_SCK_HZ = 10500000
"""The MCU's SCK: the STM32F401's SPI1 at 84 MHz / 8 (its power-of-two prescalers give 42,
21, 10.5 MHz); every board's slave must allow it with a 20 % margin (``hdl.boards``)."""
MCU_MISO_SETUP_NS = 5.0
MCU_MISO_HOLD_NS = 5.0
"""The master's MISO input setup and hold about its sampling SCK edge, tsu(MI) and th(MI):
5 ns each, from the STM32 SPI characteristics table found here (STM32F103x8/B datasheet
DocID13587 Rev 16, Table 42, master mode); the STM32F401's own table (datasheet DS9716) was
not available and must replace them.  The board SDC checks MISO against them."""
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
READ_REG_FIRST_REPLY = 1 + ADDRESS_BYTES + TURNAROUND_BYTES
"""Byte number of a ``READ_REG``'s first value byte (opcode: 0)."""
READ_REG_BYTES = READ_REG_FIRST_REPLY + VALUE_BYTES
"""Bytes of a ``READ_REG`` transaction: opcode, address, turnaround, value (big endian)."""


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


def read_reg_command(name):
    """The MOSI bytes of the ``READ_REG`` transaction of register ``name`` (``READ_REG_BYTES``
    long; the value comes back in the last ``VALUE_BYTES``).  ``ValueError`` for an unknown
    register."""
    reg = REGISTER_BY_NAME.get(name)
    if reg is None:
        raise ValueError("unknown register {!r}".format(name))
    return bytes((OP_READ_REG, reg.address)) + bytes(TURNAROUND_BYTES + VALUE_BYTES)


def keyed_command(opcode):
    """The bytes of a keyed command (``OP_SOFT_RESET`` or ``OP_FLUSH``)."""
    if opcode not in KEYED_OPCODES:
        raise ValueError("opcode 0x{:02X} is not a keyed command".format(opcode))
    return bytes((opcode, command_key(opcode)))


ID_MAGIC = 0x4C44
"""``"LD"``: the first two bytes of the ID word, so a floating MISO never reads as an ID."""
LINK_VERSION = 2
"""Version of this protocol (1: the three commands of the first slave, no status CRC)."""
ID_FIELDS = (("magic", 16), ("link_version", 8), ("build", 8))
"""The ``READ_ID`` reply, MSB first, big endian: :data:`ID_MAGIC`, :data:`LINK_VERSION` and
the gateware's ``build`` byte (a board top level's number; 0: not given)."""
ID_BYTES = 4
ID_FIRST_REPLY = 1 + TURNAROUND_BYTES
"""Byte number of the ID word's first byte."""


def gateware_id(build=0):
    """The ID word (an int) of a gateware with ``build`` (0 .. 255)."""
    if not 0 <= build <= 0xFF:
        raise ValueError("build {!r} is not a byte".format(build))
    return (ID_MAGIC << 16) | (LINK_VERSION << 8) | build


BUILD_FIELDS = ("sensor", "width", "height", "pixel_bits", "label_capacity",
                "record_capacity", "record_depth")
"""The build parameters :func:`build_id` digests, in this order."""


def build_id(sensor, width, height, pixel_bits, label_capacity, record_capacity,
             record_depth):
    """The ``build`` byte of the ID word of a gateware built with these parameters (the
    board top level's :data:`BUILD_FIELDS`): the :func:`crc8` of their ASCII text
    ``"sensor:width:height:pixel_bits:label_capacity:record_capacity:record_depth"``, 1 in
    place of 0 (0 means "not given").  The MCU computes it from the configuration it
    expects and compares it with ``READ_ID``'s: a gateware of another sensor, frame or
    record capacity differs with probability 254/255 (a checksum, not a unique number)."""
    text = ":".join(str(v) for v in (sensor, width, height, pixel_bits, label_capacity,
                                     record_capacity, record_depth))
    return crc8(text.encode()) or 1


def decode_id(data):
    """``{"magic", "link_version", "build"}`` of an ID word given as ``ID_BYTES`` bytes;
    ``ValueError`` if the length or the magic is wrong."""
    if len(data) != ID_BYTES:
        raise ValueError("an ID word is {} bytes, got {}".format(ID_BYTES, len(data)))
    word = (data[0] << 24) | (data[1] << 16) | (data[2] << 8) | data[3]
    if word >> 16 != ID_MAGIC:
        raise ValueError("ID word 0x{:08X} has no magic 0x{:04X}".format(word, ID_MAGIC))
    return {"magic": word >> 16, "link_version": (word >> 8) & 0xFF, "build": word & 0xFF}


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
"""The sensor delivers no frames (live, not sticky): its RESET_BAR is held low (the
``sensor_reset`` register, or the board's power-up hold), or, LVDS front end, not
word-locked or the LVDS receiver's PLL not locked."""
OVF_LINK_ERROR = 5
"""LVDS front end: framing errors since the last status read."""
OVF_CLOCK_LOST = 6
"""The board's PLL lost lock since the last status read.  The detector datapath was held in
reset until the PLL had relocked and stayed locked (the frame under way and the queued
packets are lost, the frame counter restarts at 0); registers and the sensor's
configuration keep their values (only power-up resets them)."""

FRAME_COUNTER_BITS = dict(HEADER_FIELDS)["frame_counter"]
"""Width of the frame counter (the packet header's)."""
TIMESTAMP_HZ = 1000000
"""The packet header's ``timestamp`` counts microseconds: a free-running counter of
``contract.TIMESTAMP_BITS`` (wrapping after 71.6 min; differences modulo ``2**TIMESTAMP_BITS``) in
the gateware's ``sync`` domain, one count every ``timestamp_divider(sync_hz)`` clocks,
started at power-up and never reset by a soft reset or a PLL loss, latched when a frame's
first pixel enters the detector.  The MCU dates frames by its differences; the frame
counter numbers them."""


def timestamp_divider(sync_hz):
    """``sync`` clocks per timestamp count: ``sync_hz / TIMESTAMP_HZ``, which must be a whole
    number (``ValueError`` otherwise: the time tags would drift)."""
    div = int(round(sync_hz / TIMESTAMP_HZ))
    if div < 1 or abs(div * TIMESTAMP_HZ - sync_hz) > 1e-6 * sync_hz:
        raise ValueError("sync clock {} Hz is not a whole number of {} Hz".format(
            sync_hz, TIMESTAMP_HZ))
    return div

EYE_WIDTH_BITS = 7
"""Width of the status word's ``eye_width`` (phase steps; a bit is at most 127 steps)."""

STATUS_FIELDS = (
    ("frame_counter", FRAME_COUNTER_BITS),
    ("errors", LINK_COUNT_BITS),
    ("underruns", LINK_COUNT_BITS),
    ("overflow", OVERFLOW_BITS),
    ("busy", 1),
    ("trained", 1),
    ("eye_width", EYE_WIDTH_BITS),
)
"""The status word's data fields, MSB first: ``(field, bits)``; sent big endian and followed
by its CRC-8 byte (:func:`crc8`).  The overflow bits are sticky until the next status read
(except ``OVF_LINK_DOWN``), and ``errors``/``underruns`` count since the previous status
read.  ``trained`` and ``eye_width`` are the LVDS receiver's phase training (live): it
samples at the centre of an error-free run of ``eye_width`` phase steps of the bit found
by its last training (``eye_width`` holds the last result while ``trained`` is low); a
build without phase training sends both 0 (:data:`STATUS_DEFAULTS`)."""
STATUS_DEFAULTS = {"trained": 0, "eye_width": 0}
"""Status fields a build without the unit that reports them sends as these values
(:func:`status_word` uses them for fields missing from its dict)."""
STATUS_DATA_BITS = 0
for _name, _bits in STATUS_FIELDS:
    STATUS_DATA_BITS += _bits
if STATUS_DATA_BITS % 8:
    raise ValueError("the status word must be a whole number of bytes")
STATUS_DATA_BYTES = STATUS_DATA_BITS // 8
STATUS_CHECK_BYTES = 1
"""The CRC-8 byte after the status word's data."""
STATUS_BYTES = STATUS_DATA_BYTES + STATUS_CHECK_BYTES
"""Bytes of the status reply: the data fields, then their CRC-8."""
STATUS_BITS = 8 * STATUS_BYTES

CRC8_POLY = 0x2F
"""CRC-8 of the status word: CRC-8/AUTOSAR (polynomial 0x2F, MSB first, initial value and
final XOR 0xFF; check value 0xDF for ``b"123456789"``).  Neither an all-zeros nor an all-ones
reply (a floating or stuck MISO) has a valid CRC, and it detects every error of up to 3 bits
in the 7 data bytes."""
CRC8_INIT = 0xFF
CRC8_XOROUT = 0xFF


_CRC8_TABLE = (
    b"\x00\x2f\x5e\x71\xbc\x93\xe2\xcd\x57\x78\x09\x26\xeb\xc4\xb5\x9a"
    b"\xae\x81\xf0\xdf\x12\x3d\x4c\x63\xf9\xd6\xa7\x88\x45\x6a\x1b\x34"
    b"\x73\x5c\x2d\x02\xcf\xe0\x91\xbe\x24\x0b\x7a\x55\x98\xb7\xc6\xe9"
    b"\xdd\xf2\x83\xac\x61\x4e\x3f\x10\x8a\xa5\xd4\xfb\x36\x19\x68\x47"
    b"\xe6\xc9\xb8\x97\x5a\x75\x04\x2b\xb1\x9e\xef\xc0\x0d\x22\x53\x7c"
    b"\x48\x67\x16\x39\xf4\xdb\xaa\x85\x1f\x30\x41\x6e\xa3\x8c\xfd\xd2"
    b"\x95\xba\xcb\xe4\x29\x06\x77\x58\xc2\xed\x9c\xb3\x7e\x51\x20\x0f"
    b"\x3b\x14\x65\x4a\x87\xa8\xd9\xf6\x6c\x43\x32\x1d\xd0\xff\x8e\xa1"
    b"\xe3\xcc\xbd\x92\x5f\x70\x01\x2e\xb4\x9b\xea\xc5\x08\x27\x56\x79"
    b"\x4d\x62\x13\x3c\xf1\xde\xaf\x80\x1a\x35\x44\x6b\xa6\x89\xf8\xd7"
    b"\x90\xbf\xce\xe1\x2c\x03\x72\x5d\xc7\xe8\x99\xb6\x7b\x54\x25\x0a"
    b"\x3e\x11\x60\x4f\x82\xad\xdc\xf3\x69\x46\x37\x18\xd5\xfa\x8b\xa4"
    b"\x05\x2a\x5b\x74\xb9\x96\xe7\xc8\x52\x7d\x0c\x23\xee\xc1\xb0\x9f"
    b"\xab\x84\xf5\xda\x17\x38\x49\x66\xfc\xd3\xa2\x8d\x40\x6f\x1e\x31"
    b"\x76\x59\x28\x07\xca\xe5\x94\xbb\x21\x0e\x7f\x50\x9d\xb2\xc3\xec"
    b"\xd8\xf7\x86\xa9\x64\x4b\x3a\x15\x8f\xa0\xd1\xfe\x33\x1c\x6d\x42")
"""CRC-8 of each byte value (``CRC8_POLY``, from a zero register): a constant, so a frozen
image keeps it in flash; ``tests/contract/test_link.py`` checks it against the bitwise CRC."""


def crc8(data, n=None):
    """CRC-8 (:data:`CRC8_POLY`) of the first ``n`` bytes of ``data`` (all of them if None);
    one table look-up per byte."""
    if n is None:
        n = len(data)
    table = _CRC8_TABLE
    crc = CRC8_INIT
    for i in range(n):
        crc = table[crc ^ data[i]]
    return crc ^ CRC8_XOROUT


def status_word(fields):
    """The ``STATUS_DATA_BITS``-bit data word (an int) of a dict of :data:`STATUS_FIELDS`
    (those of :data:`STATUS_DEFAULTS` may be missing)."""
    word = 0
    for name, bits in STATUS_FIELDS:
        value = fields[name] if name in fields else STATUS_DEFAULTS[name]
        if value < 0 or value >> bits:
            raise ValueError("status field {} holds {} bits, got {!r}".format(name, bits, value))
        word = (word << bits) | value
    return word


def encode_status(fields):
    """The ``STATUS_BYTES`` bytes the slave sends for a dict of :data:`STATUS_FIELDS`."""
    data = status_word(fields).to_bytes(STATUS_DATA_BYTES, "big")
    return data + bytes((crc8(data),))


def status_ok(data):
    """True if ``data`` is ``STATUS_BYTES`` long and its CRC-8 byte matches its data."""
    return len(data) == STATUS_BYTES and crc8(data, STATUS_DATA_BYTES) == data[-1]


def decode_status(data):
    """The fields of a status reply given as ``STATUS_BYTES`` bytes (data MSB first, then the
    CRC-8), as a dict; ``ValueError`` if the length or the CRC is wrong."""
    if len(data) != STATUS_BYTES:
        raise ValueError("a status word is {} bytes, got {}".format(STATUS_BYTES, len(data)))
    if not status_ok(data):
        raise ValueError("status word CRC-8 0x{:02X} does not match its data (0x{:02X})".format(
            data[-1], crc8(data, STATUS_DATA_BYTES)))
    value = 0
    for i in range(STATUS_DATA_BYTES):
        value = (value << 8) | data[i]
    out = {}
    for name, bits in reversed(STATUS_FIELDS):
        out[name] = value & ((1 << bits) - 1)
        value >>= bits
    return out
