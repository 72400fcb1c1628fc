"""Tests of ``lodestar.ground.codec``: exact round trips, framing errors, semantic checks,
encode limits and the byte layout, all against ``lodestar.contract``.

Field positions are computed here from ``contract.HEADER_FIELDS``/``RECORD_FIELDS`` with plain
integer arithmetic (not bitstring), so the codec's packing is checked independently.
"""

import zlib

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lodestar import contract as C
from lodestar.golden import Detector, DetectorConfig
from lodestar.ground import codec
from lodestar.ground.codec import PacketError, decode, encode
from tests.ground.packet_samples import (
    base_result,
    field_max,
    field_span,
    results,
    spot_results,
)

HYPOTHESIS = settings(max_examples=100, deadline=None)


# --------------------------------------------------------------------------------------
# Helpers: field positions from the contract, patching with a fresh CRC
# --------------------------------------------------------------------------------------


def read_field(data, name, record=None):
    """Value of a field in packet ``data`` (bytes), read with integer shifts."""
    offset, bits = field_span(name, record)
    shift = 8 * len(data) - offset - bits
    return (int.from_bytes(data, "big") >> shift) & ((1 << bits) - 1)


def with_crc(body):
    """``body`` (header and records) followed by its CRC trailer (zlib CRC-32, big-endian)."""
    return body + zlib.crc32(body).to_bytes(C.CRC_BYTES, "big")


def patch(data, changes):
    """``data`` with fields replaced and the CRC recomputed.

    ``changes`` is a list of ``(name, value, record)``; ``record=None`` names a header field.
    """
    body = data[:-C.CRC_BYTES]
    word = int.from_bytes(body, "big")
    for name, value, record in changes:
        offset, bits = field_span(name, record)
        shift = 8 * len(body) - offset - bits
        mask = ((1 << bits) - 1) << shift
        word = (word & ~mask) | (value << shift)
    return with_crc(word.to_bytes(len(body), "big"))


@pytest.fixture
def base_packet():
    return encode(base_result())


def assert_round_trip(result):
    """Encoding ``result`` gives a packet of the contract length, with every field where the
    contract puts it, that decodes to ``result`` (geometry included)."""
    data = encode(result)
    assert isinstance(data, bytes)
    assert len(data) == C.packet_bytes(len(result.blobs))
    header = dict(result.header(), magic=C.PACKET_MAGIC, version=C.PACKET_VERSION)
    for name in C.HEADER_NAMES:
        assert read_field(data, name) == header[name], name
    for index, blob in enumerate(result.blobs):
        for name in C.RECORD_NAMES:
            assert read_field(data, name, index) == getattr(blob, name), (index, name)
    assert data[-C.CRC_BYTES:] == zlib.crc32(data[:-C.CRC_BYTES]).to_bytes(C.CRC_BYTES, "big")
    back = decode(data)
    assert back == result
    assert (back.width, back.height, back.pixel_bits) == (
        result.width, result.height, result.pixel_bits)
    assert all(isinstance(blob, C.BlobRecord) for blob in back.blobs)


# --------------------------------------------------------------------------------------
# Round trips
# --------------------------------------------------------------------------------------


def golden_results():
    """Results of the golden detector on seeded random frames, 3 frames per configuration."""
    return spot_results(20240611)


def saturated_result():
    """A 8-bit frame whose one blob (5120 px at full scale) saturates every moment."""
    cfg = DetectorConfig(width=80, height=64, pixel_bits=8, threshold=10)
    result = Detector(cfg).process(np.full((64, 80), C.full_scale(8), dtype=np.uint16))
    assert result.blobs[0].flags == C.BLOB_MOMENTS_SATURATED
    assert result.blobs[0].s0 == C.moment_max(8)["s0"]
    return result


def test_round_trip_golden_results():
    results = golden_results() + [saturated_result()]
    for result in results:
        assert_round_trip(result)
    # The sample exercises what the packet must carry.
    assert any(r.flags & C.FRAME_RECORD_OVERFLOW for r in results)
    assert any(r.flags & C.FRAME_LABEL_OVERFLOW for r in results)
    assert any(r.flags & C.FRAME_GLOBAL_FALLBACK for r in results)
    assert any(r.n_filtered for r in results)
    assert {r.mode for r in results} == set(range(len(C.MODE_NAMES)))
    assert {r.pixel_bits for r in results} == set(C.PIXEL_BITS)
    assert max(len(r.blobs) for r in results) >= 3
    assert any(not r.blobs for r in results)


@HYPOTHESIS
@given(results())
def test_round_trip_random_results(result):
    assert_round_trip(result)


def test_decode_accepts_bytearray_and_memoryview(base_packet):
    assert decode(bytearray(base_packet)) == base_result()
    assert decode(memoryview(base_packet)) == base_result()


def test_encode_accepts_numpy_integers():
    result = base_result()
    result.blobs = [C.BlobRecord(**{name: np.int64(getattr(blob, name)) for name in C.RECORD_NAMES})
                    for blob in result.blobs]
    result.threshold = np.uint16(result.threshold)
    assert encode(result) == encode(base_result())


# --------------------------------------------------------------------------------------
# Framing: every corruption of the bytes is detected
# --------------------------------------------------------------------------------------


def test_every_single_bit_flip_is_rejected(base_packet):
    for bit in range(8 * len(base_packet)):
        corrupt = bytearray(base_packet)
        corrupt[bit // 8] ^= 0x80 >> (bit % 8)
        with pytest.raises(PacketError):
            decode(bytes(corrupt))


def test_every_truncation_is_rejected(base_packet):
    for length in range(len(base_packet)):
        with pytest.raises(PacketError, match="truncated"):
            decode(base_packet[:length])


@pytest.mark.parametrize("extra", [b"\x00", b"\xff", b"\x00" * C.RECORD_BYTES])
def test_trailing_bytes_are_rejected(base_packet, extra):
    with pytest.raises(PacketError, match="trailing bytes"):
        decode(base_packet + extra)


@pytest.mark.parametrize("data", ["LS", 0x4C53, None, [1, 2, 3]])
def test_non_bytes_rejected(data):
    with pytest.raises(PacketError, match="bytes-like.*got {}".format(type(data).__name__)):
        decode(data)


def test_framing_messages(base_packet):
    n = len(base_packet)
    minimum = C.packet_bytes(0)
    with pytest.raises(PacketError, match="truncated: 0 bytes, a packet needs at least {}$"
                       .format(minimum)):
        decode(b"")
    with pytest.raises(PacketError, match="truncated: {} bytes, a packet needs at least {}$"
                       .format(minimum - 1, minimum)):
        decode(base_packet[:minimum - 1])
    with pytest.raises(PacketError, match="bad magic 0x{:04X}, expected 0x{:04X}".format(
            C.PACKET_MAGIC + 1, C.PACKET_MAGIC)):
        decode(patch(base_packet, [("magic", C.PACKET_MAGIC + 1, None)]))
    with pytest.raises(PacketError, match="unsupported version {}".format(C.PACKET_VERSION + 1)):
        decode(patch(base_packet, [("version", C.PACKET_VERSION + 1, None)]))
    with pytest.raises(PacketError, match="truncated: {} bytes, a packet with 3 records is {} "
                       "bytes".format(n - 1, n)):
        decode(base_packet[:-1])
    with pytest.raises(PacketError, match="trailing bytes: {} bytes, a packet with 2 records is "
                       "{} bytes".format(n, n - C.RECORD_BYTES)):
        decode(patch(base_packet, [("n_records", 2, None)]))
    good = base_packet[-C.CRC_BYTES:].hex().upper()
    bad_crc = (int.from_bytes(base_packet[-C.CRC_BYTES:], "big") ^ 1).to_bytes(C.CRC_BYTES, "big")
    with pytest.raises(PacketError, match="CRC mismatch: packet carries 0x{}.* 0x{}$".format(
            bad_crc.hex().upper(), good)):
        decode(base_packet[:-C.CRC_BYTES] + bad_crc)


def _broken_crc(data):
    """``data`` with the last CRC bit flipped."""
    return data[:-1] + bytes([data[-1] ^ 1])


def test_check_order(base_packet):
    """A packet with several faults reports the first in the documented order; fixing the
    faults one at a time walks through the checks."""
    faults = [("magic", 0, None), ("version", 0, None), ("mode", 255, None), ("xmin", 63, 0)]
    fixes = [("magic", C.PACKET_MAGIC, None), ("version", C.PACKET_VERSION, None),
             ("mode", C.MODE_GLOBAL, None)]

    def fixed(count):
        return patch(base_packet, faults + fixes[:count])

    steps = [
        (fixed(0)[:C.packet_bytes(0) - 1], "^truncated: .* at least"),
        (_broken_crc(fixed(0)) + b"\x00", "^bad magic"),
        (_broken_crc(fixed(1)) + b"\x00", "^unsupported version"),
        (_broken_crc(fixed(2)) + b"\x00", "^trailing bytes"),
        (_broken_crc(fixed(2)), "^CRC mismatch"),
        (fixed(2), "^mode 255 "),
        (fixed(3), "^record 0: xmin=63 "),
    ]
    for data, message in steps:
        with pytest.raises(PacketError, match=message):
            decode(data)


_FRAME_HEADER_NAMES = [name for name in C.HEADER_NAMES
                       if name not in ("magic", "version", "n_records")]
"""Header fields that describe the frame (the others frame the packet)."""


@HYPOTHESIS
@given(data=st.data())
def test_accepted_packets_re_encode_identically(data):
    """Any field value (correct CRC) is either rejected or decoded to a result that encodes
    back to the same bytes: the decoder never accepts what it cannot represent."""
    record = data.draw(st.sampled_from([None, 0, 1, 2]))
    fields = C.HEADER_FIELDS if record is None else C.RECORD_FIELDS
    names = _FRAME_HEADER_NAMES if record is None else C.RECORD_NAMES
    name = data.draw(st.sampled_from(names))
    value = data.draw(st.integers(0, field_max(fields, name)))
    modified = patch(encode(base_result()), [(name, value, record)])
    try:
        result = decode(modified)
    except PacketError:
        return
    assert encode(result) == modified


# --------------------------------------------------------------------------------------
# Semantic checks: a correct CRC does not make a packet valid
# --------------------------------------------------------------------------------------

_FS12 = C.full_scale(12)
_MOMENT_MAX12 = C.moment_max(12)


def _undefined_bits(defined, fields, name):
    """Each single bit of field ``name`` that ``defined`` does not define."""
    return [1 << b for b in range(dict(fields)[name]) if not (1 << b) & defined]


SEMANTIC_CASES = [
    ("mode", [("mode", len(C.MODE_NAMES), None)],
     "^mode {} is not a mode number".format(len(C.MODE_NAMES))),
    ("mode-max", [("mode", 255, None)], "^mode 255 is not a mode number"),
    ("pixel_bits", [("pixel_bits", 9, None)], r"^pixel_bits 9 is not one of \(8, 10, 12, 16\)"),
    ("pixel_bits-0", [("pixel_bits", 0, None)], "^pixel_bits 0 is not one of"),
    ("width-0", [("width", 0, None)], r"^width 0 is out of range 1\.\.{}".format(C.MAX_WIDTH)),
    ("width-max", [("width", C.MAX_WIDTH + 1, None)],
     r"^width {} is out of range 1\.\.{}".format(C.MAX_WIDTH + 1, C.MAX_WIDTH)),
    ("height-0", [("height", 0, None)], r"^height 0 is out of range 1\.\.{}".format(C.MAX_HEIGHT)),
    ("height-max", [("height", C.MAX_HEIGHT + 1, None)],
     r"^height {} is out of range".format(C.MAX_HEIGHT + 1)),
] + [
    ("frame-flag-0x{:02x}".format(bit), [("flags", C.FRAME_RECORD_OVERFLOW | bit, None)],
     "^undefined frame flag bits 0x{:02X} set".format(bit))
    for bit in _undefined_bits(C.FRAME_FLAGS_DEFINED, C.HEADER_FIELDS, "flags")
] + [
    ("count-n_blobs", [("n_blobs", 6, None)],
     "^count mismatch: n_records=3 but n_blobs - n_filtered - dropped_records = 6 - 1 - 1 = 4"),
    ("count-n_filtered", [("n_filtered", 0, None)], "^count mismatch: n_records=3 .* = 4$"),
    ("count-underflow", [("n_blobs", 1, None)], "^count mismatch: .* = -1$"),
    ("record-overflow-without-drops", [("dropped_records", 0, None), ("n_blobs", 4, None)],
     "^FRAME_RECORD_OVERFLOW is set but dropped_records=0"),
    ("drops-without-record-overflow", [("flags", 0, None)],
     "^FRAME_RECORD_OVERFLOW is clear but dropped_records=1"),
    ("label-overflow-without-drops",
     [("flags", C.FRAME_RECORD_OVERFLOW | C.FRAME_LABEL_OVERFLOW, None)],
     "^FRAME_LABEL_OVERFLOW is set but dropped_labels=0"),
    ("drops-without-label-overflow", [("dropped_labels", 2, None)],
     "^FRAME_LABEL_OVERFLOW is clear but dropped_labels=2"),
] + [
    ("blob-flag-0x{:02x}".format(bit), [("flags", bit, 1)],
     "^record 1: undefined blob flag bits 0x{:02X} set".format(bit))
    for bit in _undefined_bits(C.BLOB_FLAGS_DEFINED, C.RECORD_FIELDS, "flags")
] + [
    ("xmin>xmax", [("xmin", 12, 1)], "^record 1: xmin=12 > xmax=11$"),
    ("ymin>ymax", [("ymin", 22, 1)], "^record 1: ymin=22 > ymax=21$"),
    ("xmax-beyond-width", [("xmax", 64, 1)],
     "^record 1: bounding box beyond the frame: xmax=64 but the frame width is 64$"),
    ("ymax-beyond-height", [("ymax", 48, 1)],
     "^record 1: bounding box beyond the frame: ymax=48 but the frame height is 48$"),
    ("bbox-beyond-narrowed-frame", [("width", 12, None)],
     "^record 2: bounding box beyond the frame: xmax=62 but the frame width is 12$"),
    ("peak", [("peak", _FS12 + 1, 1)],
     "^record 1: peak={} is above full scale {} of 12-bit pixels$".format(_FS12 + 1, _FS12)),
    ("peak-narrower-pixels", [("pixel_bits", 10, None)],
     "^record 1: peak={} is above full scale {} of 10-bit pixels$".format(
         _FS12, C.full_scale(10))),
    ("nsat>n", [("nsat", 5, 1)], "^record 1: nsat=5 > n=4$"),
    ("nsat-without-full-scale-peak", [("peak", _FS12 - 1, 1)],
     "^record 1: nsat=1 but peak={} is below full scale {}$".format(_FS12 - 1, _FS12)),
    ("threshold-above-full-scale", [("threshold", _FS12 + 1, None)],
     "^threshold {} is above full scale {} of 12-bit pixels$".format(_FS12 + 1, _FS12)),
    ("background-above-full-scale", [("background", _FS12 + 1, None)],
     "^background {} is above full scale".format(_FS12 + 1)),
    ("saturated-flag-without-saturated-moment", [("flags", C.BLOB_MOMENTS_SATURATED, 1)],
     "^record 1: BLOB_MOMENTS_SATURATED is set but no moment is at its maximum$"),
    ("n=0", [("n", 0, 1), ("nsat", 0, 1)], "^record 1: n=0"),
    ("n>area", [("n", 5, 1)], "^record 1: n=5 exceeds the bounding box area 4$"),
] + [
    ("moment-" + name, [(name, _MOMENT_MAX12[name] + 1, 1)],
     "^record 1: moment {}={} is above its maximum {} for 12-bit pixels$".format(
         name, _MOMENT_MAX12[name] + 1, _MOMENT_MAX12[name]))
    for name in C.MOMENTS
]


@pytest.mark.parametrize("changes, message", [case[1:] for case in SEMANTIC_CASES],
                         ids=[case[0] for case in SEMANTIC_CASES])
def test_semantic_check(base_packet, changes, message):
    with pytest.raises(PacketError, match=message):
        decode(patch(base_packet, changes))


BOUNDARY_CASES = [
    [("mode", len(C.MODE_NAMES) - 1, None)],
    [("width", C.MAX_WIDTH, None), ("height", C.MAX_HEIGHT, None)],
    [("width", 63, None), ("height", 48, None)],
    [("flags", C.FRAME_FLAGS_DEFINED, None), ("dropped_labels", 1, None)],
    [("xmax", 63, 1), ("ymax", 47, 1)],
    [("nsat", 4, 1)],
    [("flags", C.BLOB_FLAGS_DEFINED, 1), ("sxy", _MOMENT_MAX12["sxy"], 1)],
    [("threshold", _FS12, None), ("background", _FS12, None)],
    [(name, _MOMENT_MAX12[name], 1) for name in C.MOMENTS],
]


@pytest.mark.parametrize("changes", BOUNDARY_CASES)
def test_boundary_values_are_accepted(base_packet, changes):
    """The semantic limits are inclusive where the contract says so (no off-by-one)."""
    modified = patch(base_packet, changes)
    assert encode(decode(modified)) == modified


# --------------------------------------------------------------------------------------
# Encoding limits
# --------------------------------------------------------------------------------------


def _with_record_field(name, value):
    result = base_result()
    values = dict(zip(C.RECORD_NAMES, result.blobs[0].as_tuple()), **{name: value})
    result.blobs[0] = C.BlobRecord(**values)
    return result


@pytest.mark.parametrize("name, bits", C.RECORD_FIELDS)
def test_encode_rejects_record_value_too_wide(name, bits):
    with pytest.raises(ValueError, match="^record 0 field {}={} does not fit its {}-bit field"
                       .format(name, 1 << bits, bits)):
        encode(_with_record_field(name, 1 << bits))


def test_encode_rejects_negative_and_non_integer():
    with pytest.raises(ValueError, match="^record 0 field peak=-1 does not fit its"):
        encode(_with_record_field("peak", -1))
    with pytest.raises(ValueError, match="^record 0 field s0=1.5 is not an integer"):
        encode(_with_record_field("s0", 1.5))


@pytest.mark.parametrize("name", _FRAME_HEADER_NAMES)
def test_encode_rejects_header_value_too_wide(name):
    bits = dict(C.HEADER_FIELDS)[name]
    result = base_result()
    setattr(result, name, 1 << bits)
    with pytest.raises(ValueError, match="^header field {}={} does not fit its {}-bit field"
                       .format(name, 1 << bits, bits)):
        encode(result)


def test_encode_rejects_too_many_records():
    result = base_result()
    count = field_max(C.HEADER_FIELDS, "n_records") + 1
    result.blobs = result.blobs[:1] * count
    with pytest.raises(ValueError, match="^header field n_records={} does not fit".format(count)):
        encode(result)


# --------------------------------------------------------------------------------------
# Layout
# --------------------------------------------------------------------------------------


@pytest.mark.parametrize("layout, fields, size", [
    (codec.HEADER_LAYOUT, C.HEADER_FIELDS, C.HEADER_BYTES),
    (codec.RECORD_LAYOUT, C.RECORD_FIELDS, C.RECORD_BYTES),
])
def test_layout_is_contiguous_whole_bytes(layout, fields, size):
    assert [(name, bits) for name, _, bits in layout] == list(fields)
    end = 0
    for name, offset, bits in layout:
        assert offset == end, name
        assert bits > 0, name
        end = offset + bits
    assert end == 8 * size


def test_header_starts_with_magic_and_version_and_fields_hold_their_ranges():
    assert C.HEADER_NAMES[:2] == ("magic", "version")
    assert field_max(C.HEADER_FIELDS, "magic") >= C.PACKET_MAGIC
    assert field_max(C.HEADER_FIELDS, "version") >= C.PACKET_VERSION
    assert field_max(C.HEADER_FIELDS, "n_records") >= C.MAX_RECORD_CAPACITY
    assert field_max(C.HEADER_FIELDS, "mode") >= len(C.MODE_NAMES) - 1
    assert field_max(C.HEADER_FIELDS, "pixel_bits") >= max(C.PIXEL_BITS)
    assert field_max(C.HEADER_FIELDS, "width") >= C.MAX_WIDTH
    assert field_max(C.HEADER_FIELDS, "height") >= C.MAX_HEIGHT
    assert field_max(C.HEADER_FIELDS, "flags") >= C.FRAME_FLAGS_DEFINED
    assert field_max(C.RECORD_FIELDS, "flags") >= C.BLOB_FLAGS_DEFINED
    assert C.packet_bytes(0) == C.HEADER_BYTES + C.CRC_BYTES
    assert C.CRC_BYTES * 8 == C.CRC_BITS
