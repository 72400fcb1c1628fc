"""The packet layout, flags, CRC-32 and result types of the contract."""

import subprocess
import sys
import zlib

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.contract import packet


def test_record_and_header_layout():
    assert C.RECORD_BITS == sum(b for _, b in C.RECORD_FIELDS) == 8 * C.RECORD_BYTES
    assert C.HEADER_BITS == 8 * C.HEADER_BYTES
    assert len(set(C.RECORD_NAMES)) == len(C.RECORD_NAMES)
    assert C.RECORD_NAMES[:2] == ("n", "nsat")
    widths = dict(C.RECORD_FIELDS)
    for name, bits in C.moment_widths(C.MAX_PIXEL_BITS).items():
        assert widths[name] == bits
    assert widths["n"] == C.COUNT_BITS and (1 << C.COUNT_BITS) > C.MAX_WIDTH * C.MAX_HEIGHT
    assert (1 << widths["flags"]) > C.BLOB_FLAGS_DEFINED
    assert (1 << dict(C.HEADER_FIELDS)["flags"]) > C.FRAME_FLAGS_DEFINED
    assert (1 << dict(C.HEADER_FIELDS)["n_records"]) > C.MAX_RECORD_CAPACITY
    assert C.packet_bytes(3) == C.HEADER_BYTES + 3 * C.RECORD_BYTES + C.CRC_BYTES


def record(values):
    """A ``BlobRecord`` of ``values`` in ``RECORD_NAMES`` order."""
    return C.BlobRecord(**dict(zip(C.RECORD_NAMES, values)))


def test_blob_record_is_a_value():
    count = len(C.RECORD_NAMES)
    a = record(range(count))
    b = record(range(count))
    assert a == b and hash(a) == hash(b) and a != record(range(1, count + 1))
    assert a.as_tuple() == tuple(range(count))


def test_blob_record_takes_every_field_by_name():
    fields = dict.fromkeys(C.RECORD_NAMES, 0)
    with pytest.raises(TypeError):
        C.BlobRecord(*fields.values())
    with pytest.raises(TypeError, match="n, nsat"):
        C.BlobRecord(**dict(fields, colour=1))
    del fields["peak"]
    with pytest.raises(TypeError):
        C.BlobRecord(**fields)
    with pytest.raises(KeyError, match="peak"):
        C.BlobRecord(**dict(fields, colour=1))
    assert C.BlobRecord().as_tuple() == (0,) * len(C.RECORD_NAMES)


def test_record_fields_are_the_packet_record_at_the_largest_frame():
    largest = C.record_fields(C.MAX_WIDTH, C.MAX_HEIGHT, C.MAX_PIXEL_BITS, C.BLOB_FLAGS_BITS)
    assert largest == C.RECORD_FIELDS
    small = dict(C.record_fields(64, 48, 10))
    assert list(small) == list(C.RECORD_NAMES)
    assert small["n"] == small["nsat"] == C.bits_for(64 * 48)
    assert small["xmin"] == small["xmax"] == 6 and small["ymin"] == small["ymax"] == 6
    assert small["peak"] == 10 and small["flags"] == C.bits_for(C.BLOB_FLAGS_DEFINED)
    for name, bits in C.moment_widths(10).items():
        assert small[name] == bits


@pytest.mark.parametrize("size", [0, 1, 2, 3, 4, 7, 36, 100, 1000])
def test_crc_table_matches_zlib(size):
    rng = np.random.default_rng(size)
    data = rng.integers(0, 256, size, dtype=np.uint8).tobytes()
    assert packet.crc32_table(data) == zlib.crc32(data)
    assert packet.crc32(data) == zlib.crc32(data)
    cut = size // 3
    assert packet.crc32_table(data[cut:], packet.crc32_table(data[:cut])) == zlib.crc32(data)
    assert packet.crc32_table(bytearray(data)) == packet.crc32_table(memoryview(data))


def test_crc_known_values():
    assert packet.crc32_table(b"") == 0
    assert packet.crc32_table(b"123456789") == 0xCBF43926      # CRC-32/ISO-HDLC check value
    assert packet.crc32_table(b"\xff" * 64) == zlib.crc32(b"\xff" * 64)


def test_fallback_selected_without_binascii():
    """Where ``binascii`` cannot be imported (a fresh interpreter, so that no class of this
    one is replaced) the contract selects the table CRC."""
    script = ("import sys; sys.modules['binascii'] = None\n"
              "from lodestar.contract import packet\n"
              "assert packet.crc32_native is None and packet.crc32(b'123456789') == 0xCBF43926\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    assert packet.crc32_native is not None


def test_flag_widths_hold_every_defined_flag():
    assert C.BLOB_FLAGS_DEFINED < (1 << C.BLOB_FLAGS_BITS)
    assert C.FRAME_FLAGS_DEFINED < (1 << C.FRAME_FLAGS_BITS)
    assert dict(C.RECORD_FIELDS)["flags"] == C.BLOB_FLAGS_BITS
    assert dict(C.HEADER_FIELDS)["flags"] == C.FRAME_FLAGS_BITS


def test_crc_constants_are_zlibs():
    assert packet.crc32_table(b"\x00") == zlib.crc32(b"\x00")
    assert C.CRC_POLY == 0xEDB88320 and C.CRC_INIT == 0xFFFFFFFF


def test_detection_result_equality_ignores_geometry_and_replace_copies():
    rec = C.BlobRecord(n=1, nsat=0, s0=5, sx=0, sy=0, sxx=0, syy=0, sxy=0, xmin=0, xmax=0,
                       ymin=0, ymax=0, peak=5, flags=0)
    a = C.DetectionResult([rec], C.MODE_FIXED, 10, 2, 1, 0, 0, 0, 0, width=8, height=4,
                          pixel_bits=12)
    b = a.replace(width=16)
    assert a == b and b.width == 16 and a.width == 8
    assert a != a.replace(threshold=11)
    assert a.dropped == 0 and a.mode_name == "fixed"
    assert a.header()["n_records"] == 1 and list(a.header()) == list(C.HEADER_NAMES[2:])
    with pytest.raises(TypeError):
        a.replace(colour=1)
