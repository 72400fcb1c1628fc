"""FPGA->MCU blob packet: ``encode`` a frame's ``DetectionResult`` to bytes, ``decode`` it back.

The layout is ``lodestar.contract``'s and nothing here restates it: header, ``n_records``
records and a CRC-32 (``zlib.crc32``) trailer, every field an unsigned integer, MSB first,
no padding; ``HEADER_LAYOUT`` and ``RECORD_LAYOUT`` list each field's bit offset within its
section.  ``encode`` raises ``ValueError`` naming the field when a value is not an integer that
fits its field (it never truncates); ``decode`` raises :class:`PacketError` (a ``ValueError``)
naming the first failed check.  The checks are the flight decoder's
(``lodestar.firmware.packet``, the one home of the packet's rules), in the order listed in
``docs/contract.md`` (Packet checks).  A section is packed into and read from one Python
integer at the contract's offsets (``contract.field_offsets``).
"""

import operator
import zlib

from lodestar import contract as C
from lodestar.contract import DetectionResult
from lodestar.firmware import packet


class PacketError(ValueError):
    """The bytes are not a valid packet; the message names the failed check and the values."""


HEADER_LAYOUT = C.field_offsets(C.HEADER_FIELDS)
"""``(name, bit_offset, bits)`` of each header field; offsets from the packet start."""
RECORD_LAYOUT = C.field_offsets(C.RECORD_FIELDS)
"""``(name, bit_offset, bits)`` of each record field; offsets from the record start."""

_PACKET_ONLY = ("magic", "version", "n_records")
"""Header fields that describe the packet, not the frame (``n_records`` is ``len(blobs)``)."""


def _pack(fields, values):
    """The bytes of a section: ``values`` (each fits its field) in ``(name, bits)`` fields,
    MSB first."""
    word = 0
    bits = 0
    for (_, width), value in zip(fields, values):
        word = (word << width) | value
        bits += width
    return word.to_bytes(bits // 8, "big")


def _unpack(layout, data):
    """Fields by name of the section ``data`` (bytes) laid out as ``layout``
    (``HEADER_LAYOUT`` or ``RECORD_LAYOUT``)."""
    word = int.from_bytes(data, "big")
    end = 8 * len(data)
    return {name: (word >> (end - offset - bits)) & ((1 << bits) - 1)
            for name, offset, bits in layout}


def _crc(body):
    """The CRC trailer of ``body`` (header and records): ``zlib.crc32``, big-endian."""
    return zlib.crc32(body).to_bytes(C.CRC_BYTES, "big")


# --------------------------------------------------------------------------------------
# Encoding
# --------------------------------------------------------------------------------------


def _checked_values(where, fields, values):
    """``values`` as ints after checking each fits its ``(name, bits)`` field, or ValueError.

    ``where`` prefixes the message ("header" or "record <index>").
    """
    out = []
    for (name, bits), value in zip(fields, values):
        try:
            number = operator.index(value)
        except TypeError:
            raise ValueError("{} field {}={!r} is not an integer".format(
                where, name, value)) from None
        if not 0 <= number < (1 << bits):
            raise ValueError("{} field {}={} does not fit its {}-bit field (0..{})".format(
                where, name, number, bits, (1 << bits) - 1))
        out.append(number)
    return out


def encode(result):
    """The packet (bytes) of a ``DetectionResult``: header, ``result.blobs`` records, CRC.

    Header values come from ``result.header()`` plus the contract's magic and version.
    Raises ``ValueError`` naming the field when a value does not fit its width.  No semantic
    check is made here: ``decode`` is the gatekeeper.
    """
    header = dict(result.header(), magic=C.PACKET_MAGIC, version=C.PACKET_VERSION)
    values = _checked_values("header", C.HEADER_FIELDS, [header[name] for name in C.HEADER_NAMES])
    parts = [_pack(C.HEADER_FIELDS, values)]
    for index, blob in enumerate(result.blobs):
        values = _checked_values("record {}".format(index), C.RECORD_FIELDS,
                                 [getattr(blob, name) for name in C.RECORD_NAMES])
        parts.append(_pack(C.RECORD_FIELDS, values))
    body = b"".join(parts)
    return body + _crc(body)


# --------------------------------------------------------------------------------------
# Decoding: framing checks, then header and record semantics
# --------------------------------------------------------------------------------------


def _as_bytes(data):
    """``data`` as ``bytes`` if it is bytes-like (bytes, bytearray, memoryview)."""
    if not isinstance(data, (bytes, bytearray, memoryview)):
        raise PacketError("packet must be bytes-like (bytes, bytearray or memoryview), "
                          "got {}".format(type(data).__name__))
    return bytes(data)


def _unpack_header(data):
    """Header fields by name from the first ``contract.HEADER_BYTES`` of ``data``."""
    return _unpack(HEADER_LAYOUT, data[:C.HEADER_BYTES])


def _unpack_record(data, index):
    """Record ``index`` of a framed packet as a ``contract.BlobRecord``."""
    start = C.HEADER_BYTES + index * C.RECORD_BYTES
    return C.BlobRecord(**_unpack(RECORD_LAYOUT, data[start:start + C.RECORD_BYTES]))


def decode(data):
    """The ``DetectionResult`` carried by a packet (bytes-like), or ``PacketError``.

    Blobs are ``contract.BlobRecord``; ``width``, ``height`` and ``pixel_bits`` are restored
    too, so ``decode(encode(r))`` equals ``r`` field for field.  The checks and their order
    are listed in ``docs/contract.md`` (Packet checks).
    """
    data = _as_bytes(data)
    minimum = C.packet_bytes(0)
    if len(data) < minimum:
        raise PacketError("truncated: {} bytes, a packet needs at least {}".format(
            len(data), minimum))
    header = _unpack_header(data)
    problem = packet.framing_problem(data, header)
    if problem:
        raise PacketError(problem[1])
    reason = packet.header_problem(header)
    if reason:
        raise PacketError(reason)
    limits = packet.moment_limits(header["pixel_bits"])
    blobs = []
    for index in range(header["n_records"]):
        rec = _unpack_record(data, index)
        reason = packet.record_problem(rec, header, limits)
        if reason:
            raise PacketError("record {}: {}".format(index, reason))
        blobs.append(rec)
    frame = {name: value for name, value in header.items() if name not in _PACKET_ONLY}
    return DetectionResult(blobs=blobs, **frame)
