"""MCU-side decoder of the FPGA->MCU blob packet; never raises on bad bytes.

    st, header, records, reason = packet.decode(data)   # header None, records [] on failure

Layout: ``lodestar.contract`` (``HEADER_FIELDS``, ``RECORD_FIELDS``, ``CRC_BYTES``; CRC
:func:`lodestar.contract.packet.crc32`).  The checks, their order and their messages are the
ground codec's (``docs/contract.md``, Packet checks): a failure returns its ``PACKET_*``
status (``BAD_INPUT`` for non-bytes) and the message the codec raises.  Fields are read MSB
first through byte windows precomputed at import, so a field that fits a MicroPython small
int never allocates a long int (``docs/firmware.md``, Packet decoder).
Pure Python for CPython and MicroPython: no numpy, typing, dataclasses or itertools.
"""

from lodestar import contract as C
from lodestar.firmware import status as S
from lodestar.firmware.emit import native

# --------------------------------------------------------------------------------------
# Layout: each field as a byte window, from the contract
# --------------------------------------------------------------------------------------

def _plan(fields):
    """``(name, first, last, head_mask, tail_drop)`` per ``(name, bits)`` field of a section
    whose fields are packed MSB first: the field occupies bytes ``first .. last`` (from the
    section start), ``head_mask`` keeps its bits of byte ``first`` and its last bit is
    ``tail_drop`` bits above the least significant bit of byte ``last``."""
    out = []
    for name, offset, bits in C.field_offsets(fields):
        end = offset + bits - 1                 # the field's last bit
        out.append((name, offset // 8, end // 8, 0xFF >> (offset % 8), 7 - end % 8))
    return tuple(out)


_HEADER_PLAN = _plan(C.HEADER_FIELDS)
_RECORD_PLAN = _plan(C.RECORD_FIELDS)
SMALL_BITS = 30
"""Bits of the widest unsigned value a MicroPython small int holds on a 32-bit MCU (31-bit
signed small ints): a field wider than this is *wide*, read by :func:`checked_records` as
15-bit limbs (:class:`WideRecord`)."""
WIDE = tuple(name for name, bits in C.RECORD_FIELDS if bits > SMALL_BITS)
"""The wide record fields (the moments but ``s0``), in record order."""
_NARROW_PLAN = tuple(entry for entry in _RECORD_PLAN if entry[0] not in WIDE)
_WIDE_PLAN = tuple(entry[1:] for entry in _RECORD_PLAN if entry[0] in WIDE)
_MIN_BYTES = C.packet_bytes(0)
_CRC_HEX = "{:0" + str(2 * C.CRC_BYTES) + "X}"
_CRC_MASK = (1 << (8 * C.CRC_BYTES)) - 1


@native
def _read(data, base, plan, into):
    """Set each field of ``plan`` (:func:`_plan`) as an attribute of ``into`` from the
    section starting at byte ``base`` of ``data``; returns ``into``.  Bytes are accumulated
    MSB first with the neighbouring fields' bits removed before they are shifted in, so no
    intermediate exceeds the field's value: a value that fits a MicroPython small int is read
    without allocating a long int (``int.from_bytes`` of a window would allocate the window
    and often a long int: on the MCU's heap that costs collections).  One loop without
    calls but ``setattr``, bound locally, the field's name in its plan entry: it runs for
    every field of every record."""
    put = setattr
    for name, first, last, head_mask, tail_drop in plan:
        i = base + first
        end = base + last
        value = data[i] & head_mask
        if i == end:
            value >>= tail_drop
        else:
            i += 1
            while i < end:
                value = (value << 8) | data[i]
                i += 1
            value = (value << (8 - tail_drop)) | (data[end] >> tail_drop)
        put(into, name, value)
    return into


@native
def _read_wide(data, base, plan, limbs):
    """Each wide field of ``plan`` (``(first, last, head_mask, tail_drop)`` per field,
    :data:`WIDE` order) from the record starting at byte ``base`` of ``data`` as three limbs
    ``h, m, l`` (``value = h 2**30 + m 2**15 + l``) stored at ``limbs[3k:3k + 3]``: the
    field's last three bytes and the bytes before them are accumulated apart, so a value
    below ``2**30`` at least (every moment of a star) is read without a long int (a long
    int is two heap blocks, and every record has five such fields)."""
    k = 0
    for first, last, head_mask, tail_drop in plan:
        i = base + first
        tail = base + last - 2              # the last three bytes: 24 bits
        hi = data[i] & head_mask
        i += 1
        while i < tail:
            hi = (hi << 8) | data[i]
            i += 1
        lo = ((data[tail] << 16) | (data[tail + 1] << 8) | data[tail + 2]) >> tail_drop
        rest = (lo >> 15) | (hi << (9 - tail_drop))     # value >> 15
        limbs[k] = rest >> 15
        limbs[k + 1] = rest & 0x7FFF
        limbs[k + 2] = lo & 0x7FFF
        k += 3
    return limbs


class WideRecord(C.BlobRecord):
    """A ``contract.BlobRecord`` whose :data:`WIDE` fields are held as 15-bit limbs in
    ``limbs`` (:func:`_read_wide`) and read as ints (long ones allocated) when asked: what
    :func:`checked_records` yields, so that the flight pipeline reads a packet without long
    ints (``centroids.moments`` reads the limbs)."""

    __slots__ = ("limbs",)

    def __init__(self):
        for name in C.RECORD_NAMES:
            if name not in WIDE:
                setattr(self, name, 0)
        self.limbs = [0] * (3 * len(WIDE))

    def __getattr__(self, name):
        """A wide field's value from its limbs (called for the attributes not held)."""
        if name not in WIDE:
            raise AttributeError(name)
        k = 3 * WIDE.index(name)
        limbs = self.limbs
        return (limbs[k] << 30) | (limbs[k + 1] << 15) | limbs[k + 2]


class _Header:
    """Attributes :func:`_read` sets, turned into the header dict."""


def _unpack_header(data):
    """Header fields by name from the first ``contract.HEADER_BYTES`` of ``data``."""
    fields = _read(data, 0, _HEADER_PLAN, _Header())
    header = {}
    for name in C.HEADER_NAMES:
        header[name] = getattr(fields, name)
    return header


def record(data, index, into=None):
    """Record ``index`` (0-based) of a packet :func:`check` accepted, as a
    ``contract.BlobRecord`` (decoded on each call: the flight pipeline keeps no record list).
    ``into``: a ``BlobRecord`` to overwrite and return instead of a new one (reading record
    after record into one object allocates nothing but large moments)."""
    if into is None:
        into = C.BlobRecord()
    return _read(data, C.HEADER_BYTES + index * C.RECORD_BYTES, _RECORD_PLAN, into)


# --------------------------------------------------------------------------------------
# Checks (messages identical to lodestar.ground.codec's PacketError messages)
# --------------------------------------------------------------------------------------

_MOMENT_LIMITS = {}


def moment_limits(pixel_bits):
    """``contract.moment_max(pixel_bits)``, cached (pixel_bits already validated)."""
    limits = _MOMENT_LIMITS.get(pixel_bits)
    if limits is None:
        limits = C.moment_max(pixel_bits)
        _MOMENT_LIMITS[pixel_bits] = limits
    return limits


def framing_problem(data, header):
    """``(status, message)`` of the first failed framing check after the minimum length, or
    None: magic, version, length, CRC."""
    if header["magic"] != C.PACKET_MAGIC:
        return S.PACKET_BAD_MAGIC, "bad magic 0x{:04X}, expected 0x{:04X}".format(
            header["magic"], C.PACKET_MAGIC)
    if header["version"] != C.PACKET_VERSION:
        return S.PACKET_BAD_VERSION, \
            "unsupported version {}: this decoder reads version {}".format(
                header["version"], C.PACKET_VERSION)
    expected = C.packet_bytes(header["n_records"])
    if len(data) != expected:
        if len(data) < expected:
            code, what = S.PACKET_TRUNCATED, "truncated"
        else:
            code, what = S.PACKET_BAD_LENGTH, "trailing bytes"
        return code, "{}: {} bytes, a packet with {} records is {} bytes".format(
            what, len(data), header["n_records"], expected)
    body_bytes = expected - C.CRC_BYTES
    carried = int.from_bytes(data[body_bytes:], "big")
    computed = C.crc32(memoryview(data)[:body_bytes]) & _CRC_MASK
    if carried != computed:
        return S.PACKET_BAD_CRC, \
            "CRC mismatch: packet carries 0x{}, header and records give 0x{}".format(
                _CRC_HEX.format(carried), _CRC_HEX.format(computed))
    return None


def _overflow_problem(header, flag, flag_name, count_name):
    is_set = bool(header["flags"] & flag)
    if is_set != (header[count_name] > 0):
        return "{} is {} but {}={}: the flag is set iff {} > 0".format(
            flag_name, "set" if is_set else "clear", count_name, header[count_name],
            count_name)
    return None


def header_problem(header):
    """What is wrong with a CRC-verified header (None if nothing)."""
    if header["mode"] >= len(C.MODE_NAMES):
        return "mode {} is not a mode number (0..{}: {})".format(
            header["mode"], len(C.MODE_NAMES) - 1, ", ".join(C.MODE_NAMES))
    if header["pixel_bits"] not in C.PIXEL_BITS:
        return "pixel_bits {} is not one of {}".format(header["pixel_bits"], C.PIXEL_BITS)
    for name, limit in (("width", C.MAX_WIDTH), ("height", C.MAX_HEIGHT)):
        if not 1 <= header[name] <= limit:
            return "{} {} is out of range 1..{}".format(name, header[name], limit)
    full_scale = C.full_scale(header["pixel_bits"])
    for name in ("threshold", "background"):
        if header[name] > full_scale:
            return "{} {} is above full scale {} of {}-bit pixels".format(
                name, header[name], full_scale, header["pixel_bits"])
    undefined = header["flags"] & ~C.FRAME_FLAGS_DEFINED
    if undefined:
        return "undefined frame flag bits 0x{:02X} set (defined: 0x{:02X})".format(
            undefined, C.FRAME_FLAGS_DEFINED)
    emitted = header["n_blobs"] - header["n_filtered"] - header["dropped_records"]
    if header["n_records"] != emitted:
        return ("count mismatch: n_records={} but n_blobs - n_filtered - "
                "dropped_records = {} - {} - {} = {}").format(
                    header["n_records"], header["n_blobs"], header["n_filtered"],
                    header["dropped_records"], emitted)
    problem = _overflow_problem(header, C.FRAME_RECORD_OVERFLOW, "FRAME_RECORD_OVERFLOW",
                                "dropped_records")
    if problem:
        return problem
    return _overflow_problem(header, C.FRAME_LABEL_OVERFLOW, "FRAME_LABEL_OVERFLOW",
                             "dropped_labels")


def record_problem(rec, header, limits):
    """What is wrong with one record of the frame ``header`` describes (None if nothing)."""
    undefined = rec.flags & ~C.BLOB_FLAGS_DEFINED
    if undefined:
        return "undefined blob flag bits 0x{:02X} set (defined: 0x{:02X})".format(
            undefined, C.BLOB_FLAGS_DEFINED)
    if rec.xmin > rec.xmax:
        return "xmin={} > xmax={}".format(rec.xmin, rec.xmax)
    if rec.ymin > rec.ymax:
        return "ymin={} > ymax={}".format(rec.ymin, rec.ymax)
    if rec.xmax >= header["width"]:
        return "bounding box beyond the frame: xmax={} but the frame width is {}".format(
            rec.xmax, header["width"])
    if rec.ymax >= header["height"]:
        return "bounding box beyond the frame: ymax={} but the frame height is {}".format(
            rec.ymax, header["height"])
    full_scale = C.full_scale(header["pixel_bits"])
    if rec.peak > full_scale:
        return "peak={} is above full scale {} of {}-bit pixels".format(
            rec.peak, full_scale, header["pixel_bits"])
    if rec.nsat > rec.n:
        return "nsat={} > n={}".format(rec.nsat, rec.n)
    if rec.nsat and rec.peak != full_scale:
        return "nsat={} but peak={} is below full scale {}".format(rec.nsat, rec.peak,
                                                                    full_scale)
    if rec.n == 0:
        return "n=0: a blob has at least one pixel"
    area = (rec.xmax - rec.xmin + 1) * (rec.ymax - rec.ymin + 1)
    if rec.n > area:
        return "n={} exceeds the bounding box area {}".format(rec.n, area)
    at_limit = False
    for name in C.MOMENTS:
        value = getattr(rec, name)
        if value > limits[name]:
            return "moment {}={} is above its maximum {} for {}-bit pixels".format(
                name, value, limits[name], header["pixel_bits"])
        if value == limits[name]:
            at_limit = True
    if rec.flags & C.BLOB_MOMENTS_SATURATED and not at_limit:
        return "BLOB_MOMENTS_SATURATED is set but no moment is at its maximum"
    return None


# --------------------------------------------------------------------------------------
# Public entry point
# --------------------------------------------------------------------------------------

class BadRecord(Exception):
    """A record :func:`checked_records` read failed its check; ``args``: ``(status, reason)``
    (``PACKET_BAD_RECORD`` and the message :func:`check` gives)."""


@native
def checked_records(data, header, into=None):
    """The records of a packet whose framing and header :func:`check` accepted (with
    ``records=False``), in order, each checked as it is read and yielded in one
    ``contract.BlobRecord`` overwritten for each (``into``, or a new one).  Raises
    :class:`BadRecord` at the first bad record, so a consumer that reads them all has
    checked the packet as :func:`check` does, with one decoding of each record."""
    limits = moment_limits(header["pixel_bits"])
    bounds = _record_bounds(header, limits)
    if into is None:
        into = WideRecord()
    limbs = into.limbs
    base = C.HEADER_BYTES
    for index in range(header["n_records"]):
        _read(data, base, _NARROW_PLAN, into)
        _read_wide(data, base, _WIDE_PLAN, limbs)
        base += C.RECORD_BYTES
        if not _record_good(into, limbs, bounds):
            reason = record_problem(into, header, limits)
            if reason:
                raise BadRecord(S.PACKET_BAD_RECORD, "record {}: {}".format(index, reason))
        yield into


def _record_bounds(header, limits):
    """What :func:`_record_good` compares a record of the frame ``header`` describes with:
    ``(width, height, full scale, the limit of s0, the limits of the wide moments shifted
    down by 30 bits)``: a wide moment's limit is ``2**k - 1`` with ``k >= 30``, so the
    moment is within it exactly when its top limb is within the shifted limit."""
    return (header["width"], header["height"], C.full_scale(header["pixel_bits"]),
            limits["s0"], tuple(limits[name] >> 30 for name in WIDE))


@native
def _record_good(rec, limbs, bounds):
    """True when :func:`record_problem` finds nothing, with no saturated moments: the
    common case in one expression, without the messages (any other record goes through
    :func:`record_problem`, which names its problem).  ``limbs``: the record's wide moments
    (:func:`_read_wide`)."""
    width, height, full, l0, (l1, l2, l3, l4, l5) = bounds
    n, nsat, peak = rec.n, rec.nsat, rec.peak
    xmin, xmax, ymin, ymax = rec.xmin, rec.xmax, rec.ymin, rec.ymax
    return (not rec.flags and xmin <= xmax < width and ymin <= ymax < height and
            peak <= full and nsat <= n and (not nsat or peak == full) and
            0 < n <= (xmax - xmin + 1) * (ymax - ymin + 1) and rec.s0 <= l0 and
            limbs[0] <= l1 and limbs[3] <= l2 and limbs[6] <= l3 and limbs[9] <= l4 and
            limbs[12] <= l5)


def check(data, records=True):
    """Check one packet without keeping its records: ``(status, header, reason)``; never
    raises on bad bytes.  The checks and results of :func:`decode`, one record on the heap at
    a time; read the records of an accepted packet with :func:`record`.  ``records=False``:
    the framing and the header only (then read the records with :func:`checked_records`)."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        return S.BAD_INPUT, None, \
            "packet must be bytes-like (bytes, bytearray or memoryview), got {}".format(
                type(data).__name__)
    if len(data) < _MIN_BYTES:
        return S.PACKET_TRUNCATED, None, \
            "truncated: {} bytes, a packet needs at least {}".format(len(data), _MIN_BYTES)
    header = _unpack_header(data)
    problem = framing_problem(data, header)
    if problem:
        return problem[0], None, problem[1]
    reason = header_problem(header)
    if reason:
        return S.PACKET_BAD_HEADER, None, reason
    if records:
        try:
            for _rec in checked_records(data, header):
                pass
        except BadRecord as exc:
            return exc.args[0], None, exc.args[1]
    return S.OK, header, ""



def decode(data):
    """Decode one packet: ``(status, header, records, reason)``; never raises on bad bytes.

    On success ``status`` is ``status.OK``, ``header`` a dict of every
    ``contract.HEADER_NAMES`` field (``magic``, ``version`` and ``n_records`` included),
    ``records`` a list of ``contract.BlobRecord`` in packet order and ``reason`` ``""``.
    On failure ``header`` is None, ``records`` is ``[]`` and ``reason`` names the first failed
    check with the message ``lodestar.ground.codec.decode`` raises for the same bytes.
    """
    code, header, reason = check(data)
    if code != S.OK:
        return code, None, [], reason
    return S.OK, header, [record(data, i) for i in range(header["n_records"])], ""
