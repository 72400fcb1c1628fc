"""FPGA->MCU packet: frame and blob flags, header and record layout (fields MSB first,
big-endian), CRC-32, :class:`BlobRecord` and :class:`DetectionResult`.  MicroPython-safe."""

from lodestar.contract.detection import (
    MAX_HEIGHT,
    MAX_PIXEL_BITS,
    MAX_WIDTH,
    MODE_NAMES,
    moment_widths,
)
from lodestar.contract.integers import bits_for

try:
    from binascii import crc32 as _binascii_crc32
except ImportError:  # a MicroPython port without MICROPY_PY_BINASCII_CRC32
    _binascii_crc32 = None

# Blob record flags
BLOB_MOMENTS_SATURATED = 1 << 0
"""At least one moment of this blob saturated (true value above the accumulator maximum)."""
BLOB_FLAGS_DEFINED = BLOB_MOMENTS_SATURATED
BLOB_FLAGS_BITS = 6
"""Width of a record's ``flags`` field in the packet: the defined flags, room for more, and
the padding that makes the record whole bytes (the gateware carries the defined ones only)."""


# --------------------------------------------------------------------------------------
# Frame flags
# --------------------------------------------------------------------------------------

FRAME_LABEL_OVERFLOW = 1 << 0
"""More blobs were open at once than ``label_capacity``; see ``dropped_labels``."""
FRAME_RECORD_OVERFLOW = 1 << 1
"""More blobs passed the filters than ``record_capacity``; see ``dropped_records``."""
FRAME_GLOBAL_FALLBACK = 1 << 2
"""Global mode without statistics from a complete previous frame: fixed registers used."""
FRAME_TRUNCATED = 1 << 3
"""Gateware only: the frame ended (or was reset) before its last pixel; records are partial."""
FRAME_LINE_ERROR = 1 << 4
"""Gateware only: a line arrived shorter or longer than the frame width."""
FRAME_TIMEOUT = 1 << 5
"""Gateware only: the sensor stopped sending inside the frame; the capture front end
completed it with dark (0) pixels after its stall timeout, so records are partial."""
FRAME_TAIL_DROPPED = 1 << 6
"""Gateware only, local mode: since the previous trailer, the threshold unit discarded
pixels still in its delay line (an early ``sof`` or a frame cut short).  Normally this
frame's own tail (it also says ``FRAME_TRUNCATED``); without ``FRAME_TRUNCATED``, pixels of
a frame that left no trailer of its own (none of them had come out yet) or whose trailer
was already sent (``FRAME_LINE_ERROR``)."""
FRAME_FLAGS_BITS = 8
"""Width of the header's ``flags`` field."""
FRAME_FLAGS_DEFINED = (FRAME_LABEL_OVERFLOW | FRAME_RECORD_OVERFLOW | FRAME_GLOBAL_FALLBACK
                       | FRAME_TRUNCATED | FRAME_LINE_ERROR | FRAME_TIMEOUT
                       | FRAME_TAIL_DROPPED)


# --------------------------------------------------------------------------------------
# Blob record and packet layout
# --------------------------------------------------------------------------------------

def record_fields(width, height, pixel_bits, flags_bits=None):
    """One blob record, ``((field, bits), ...)`` in record order, for ``width x height``
    frames of ``pixel_bits``-bit pixels: each field as wide as its values can be there (the
    gateware's compact record).  ``flags_bits`` (default: the defined flags) widens ``flags``.

    The one list of the record's fields: a new field is a row here (and its value in the
    gateware's and the golden models' accumulation).
    """
    moments = moment_widths(pixel_bits)
    count = bits_for(width * height)
    x = bits_for(width - 1)
    y = bits_for(height - 1)
    return (
        ("n", count),
        ("nsat", count),
        ("s0", moments["s0"]),
        ("sx", moments["sx"]),
        ("sy", moments["sy"]),
        ("sxx", moments["sxx"]),
        ("syy", moments["syy"]),
        ("sxy", moments["sxy"]),
        ("xmin", x),
        ("xmax", x),
        ("ymin", y),
        ("ymax", y),
        ("peak", pixel_bits),
        ("flags", bits_for(BLOB_FLAGS_DEFINED) if flags_bits is None else flags_bits),
    )


RECORD_FIELDS = record_fields(MAX_WIDTH, MAX_HEIGHT, MAX_PIXEL_BITS, BLOB_FLAGS_BITS)
"""One blob record in the packet: (field, bits), MSB first, big-endian bit order.

:func:`record_fields` of the largest frame and the widest pixels (16 bits), ``flags``
``BLOB_FLAGS_BITS`` wide; narrower sensors and smaller frames leave high bits zero.  The
record is a whole number of bytes (``RECORD_BYTES``)."""

RECORD_NAMES = tuple(name for name, _ in RECORD_FIELDS)
RECORD_BITS = sum(bits for _, bits in RECORD_FIELDS)
RECORD_BYTES = RECORD_BITS // 8

PACKET_MAGIC = 0x4C53  # "LS"
PACKET_VERSION = 2
"""2: the header's ``timestamp`` (1: no time tag)."""
TIMESTAMP_BITS = 32
"""Width of the header's ``timestamp`` (its unit and meaning: ``contract.link``)."""

HEADER_FIELDS = (
    ("magic", 16),
    ("version", 8),
    ("mode", 8),
    ("frame_counter", 32),
    ("timestamp", TIMESTAMP_BITS),
    ("width", 16),
    ("height", 16),
    ("pixel_bits", 8),
    ("flags", FRAME_FLAGS_BITS),
    ("threshold", MAX_PIXEL_BITS),
    ("background", MAX_PIXEL_BITS),
    ("n_blobs", 32),
    ("n_filtered", 32),
    ("dropped_records", 32),
    ("dropped_labels", 32),
    ("n_records", 16),
)
"""Frame header, first in the packet: (field, bits), MSB first.

``timestamp`` is the gateware's free-running microsecond counter latched when the frame's
first pixel entered the detector (``contract.link.TIMESTAMP_HZ``): the frame's time tag.
``threshold``/``background`` are T and B in effect for the frame (in local mode, where they
vary per pixel, ``threshold`` carries the ``local_offset`` register and ``background`` 0).
``n_blobs`` counts tracked blobs that completed (measured), ``n_filtered`` those of them the
filters rejected, ``dropped_records`` those that passed but found the record buffer full,
``dropped_labels`` the untracked blobs lost to label overflow, ``n_records`` the records that
follow.  So ``n_records == n_blobs - n_filtered - dropped_records``."""

HEADER_NAMES = tuple(name for name, _ in HEADER_FIELDS)
HEADER_BITS = sum(bits for _, bits in HEADER_FIELDS)
HEADER_BYTES = HEADER_BITS // 8

CRC_BITS = 32
"""Trailer: CRC-32 (ISO-HDLC / zlib) over header and records, stored big-endian."""
CRC_BYTES = CRC_BITS // 8
CRC_POLY = 0xEDB88320
"""Reflected CRC-32 polynomial (ISO-HDLC; the gateware's CRC and the database's use it too)."""
CRC_INIT = 0xFFFFFFFF
"""Initial value and final XOR of the CRC."""


def packet_bytes(n_records):
    """Total length in bytes of a packet carrying ``n_records`` records."""
    return HEADER_BYTES + n_records * RECORD_BYTES + CRC_BYTES


class BlobRecord(object):
    """One blob as the gateware reports it: integer fields named by ``RECORD_NAMES``.

    Records compare equal when every field is equal, and hash alike, so sets of records can
    be compared as multisets (``collections.Counter``).
    """

    __slots__ = RECORD_NAMES

    def __init__(self, **fields):
        """Every field of ``RECORD_NAMES`` by name; a missing one raises ``TypeError`` (or
        ``KeyError`` naming it when an unknown name stands in for it).  No field at all: a
        record of zeros for a decoder to fill (on MicroPython, without a dict of fields)."""
        if not fields:
            for name in RECORD_NAMES:
                setattr(self, name, 0)
            return
        if len(fields) != len(RECORD_NAMES):
            raise TypeError("BlobRecord takes the fields {}, got {}".format(
                ", ".join(RECORD_NAMES), ", ".join(sorted(fields))))
        for name in RECORD_NAMES:
            setattr(self, name, fields[name])

    def as_tuple(self):
        """Field values in ``RECORD_NAMES`` order."""
        return tuple(getattr(self, name) for name in RECORD_NAMES)

    def __eq__(self, other):
        return isinstance(other, BlobRecord) and self.as_tuple() == other.as_tuple()

    def __ne__(self, other):
        return not self.__eq__(other)

    def __hash__(self):
        return hash(self.as_tuple())

    def __repr__(self):
        return "BlobRecord({})".format(
            ", ".join("{}={}".format(name, getattr(self, name)) for name in RECORD_NAMES))


# The layouts must be whole bytes; checked at import so a bad edit fails everywhere at once.
if RECORD_BITS % 8 or HEADER_BITS % 8:
    raise AssertionError("contract: record and header layouts must be whole bytes")


class DetectionResult(object):
    """Records and frame header of one frame, the outcome of the golden models, the
    co-simulation and the packet decoder.

    ``blobs`` are :class:`BlobRecord` in emission order (raster order of each blob's last
    pixel).  ``threshold``/``background`` are T and B in effect (see :data:`HEADER_FIELDS`
    for local mode).  Counts as the header's.  Results compare equal when the records and
    every header field but the geometry (``width``, ``height``, ``pixel_bits``) and the
    ``timestamp`` (the gateware's clock, which no model of the detection predicts) are
    equal.
    """

    FIELDS = ("blobs", "mode", "threshold", "background", "n_blobs", "n_filtered",
              "dropped_records", "dropped_labels", "flags", "frame_counter", "width", "height",
              "pixel_bits", "timestamp")
    COMPARED = FIELDS[:10]

    def __init__(self, blobs, mode, threshold, background, n_blobs, n_filtered,
                 dropped_records, dropped_labels, flags, frame_counter=0, width=0, height=0,
                 pixel_bits=0, timestamp=0):
        self.blobs = blobs
        self.mode = mode
        self.threshold = threshold
        self.background = background
        self.n_blobs = n_blobs
        self.n_filtered = n_filtered
        self.dropped_records = dropped_records
        self.dropped_labels = dropped_labels
        self.flags = flags
        self.frame_counter = frame_counter
        self.width = width
        self.height = height
        self.pixel_bits = pixel_bits
        self.timestamp = timestamp

    def replace(self, **changes):
        """A copy with ``changes`` (field names) applied."""
        values = {}
        for name in self.FIELDS:
            values[name] = changes.pop(name, getattr(self, name))
        if changes:
            raise TypeError("DetectionResult has no field " + ", ".join(changes))
        return DetectionResult(**values)

    def __eq__(self, other):
        if not isinstance(other, DetectionResult):
            return NotImplemented
        for name in self.COMPARED:
            if getattr(self, name) != getattr(other, name):
                return False
        return True

    def __ne__(self, other):
        equal = self.__eq__(other)
        return equal if equal is NotImplemented else not equal

    __hash__ = None

    def __repr__(self):
        return "DetectionResult({})".format(
            ", ".join("{}={!r}".format(name, getattr(self, name)) for name in self.FIELDS))

    @property
    def dropped(self):
        """Blobs lost to capacity limits: ``dropped_records + dropped_labels``."""
        return self.dropped_records + self.dropped_labels

    @property
    def mode_name(self):
        return MODE_NAMES[self.mode]

    def header(self):
        """Header fields by name as :data:`HEADER_FIELDS` orders them (no magic/version)."""
        header = {}
        for name in HEADER_NAMES[2:-1]:
            header[name] = getattr(self, name)
        header["n_records"] = len(self.blobs)
        return header


_TABLE_HI = None
_TABLE_LO = None


def _make_tables():
    """The 256-entry CRC-32 table of :data:`CRC_POLY` split in 16-bit halves."""
    hi = []
    lo = []
    for n in range(256):
        c = n
        for _ in range(8):
            c = (c >> 1) ^ CRC_POLY if c & 1 else c >> 1
        hi.append(c >> 16)
        lo.append(c & 0xFFFF)
    return hi, lo


def crc32_table(data, crc=0):
    """CRC-32 of ``data`` (bytes-like), continuing from ``crc``: the value ``zlib.crc32`` and
    ``binascii.crc32`` give, from a table with 16-bit intermediates only (no long ints on
    MicroPython)."""
    global _TABLE_HI, _TABLE_LO
    if _TABLE_HI is None:
        _TABLE_HI, _TABLE_LO = _make_tables()
    table_hi = _TABLE_HI
    table_lo = _TABLE_LO
    crc ^= CRC_INIT
    hi = crc >> 16
    lo = crc & 0xFFFF
    for b in data:
        i = (lo ^ b) & 0xFF
        lo = table_lo[i] ^ (((hi & 0xFF) << 8) | (lo >> 8))
        hi = table_hi[i] ^ (hi >> 8)
    return ((hi << 16) | lo) ^ CRC_INIT


crc32_native = _binascii_crc32
"""``binascii.crc32`` when the port has it, else None; :func:`crc32` uses :func:`crc32_table`
when this is None (tests set it to None to exercise the fallback)."""


def crc32(data, crc=0):
    """CRC-32 (ISO-HDLC / zlib) of ``data`` continuing from ``crc``, unsigned: the one CRC of
    the packet trailer and the star database."""
    if crc32_native is None:
        return crc32_table(data, crc)
    return crc32_native(data, crc) & 0xFFFFFFFF
