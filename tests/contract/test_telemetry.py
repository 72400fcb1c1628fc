"""The telemetry record's layout (``lodestar.contract.telemetry``): one value per field,
the health counters in it, and the ground decoder refusing a record of another length,
magic, version or CRC."""

import struct

from lodestar.contract import crc32, telemetry


def _record(**values):
    fields = dict.fromkeys(telemetry.FIELDS, 0)
    fields.update(magic=telemetry.MAGIC, version=telemetry.VERSION, **values)
    data = bytearray(struct.pack(telemetry.FORMAT, *(fields[f] for f in telemetry.FIELDS)))
    struct.pack_into(">I", data, telemetry.BYTES - 4, crc32(bytes(data[:-4])))
    return data


def test_layout_has_one_value_per_field():
    values = struct.unpack(telemetry.FORMAT, bytes(telemetry.BYTES))
    assert len(values) == len(telemetry.FIELDS) == 22 + telemetry.N_HEALTH
    assert telemetry.FIELDS[telemetry.HEALTH_AT:telemetry.HEALTH_AT + telemetry.N_HEALTH] == \
        telemetry.HEALTH_NAMES
    assert telemetry.BYTES == 110


def test_decode_round_trip_and_refusals():
    data = _record(sequence=7, epoch_us=0xFFFFFFFF, missed=3, time_ms=2 ** 40)
    got = telemetry.decode(data)
    assert got["sequence"] == 7 and got["epoch_us"] == 0xFFFFFFFF and got["missed"] == 3
    assert got["time_ms"] == 2 ** 40
    assert telemetry.decode(data[:-1]) is None
    for at, value in ((0, 0x00), (2, telemetry.VERSION - 1)):   # magic, version (CRC redone)
        other = bytearray(data)
        other[at] = value
        struct.pack_into(">I", other, telemetry.BYTES - 4, crc32(bytes(other[:-4])))
        assert telemetry.decode(other) is None
    data[30] ^= 0x01
    assert telemetry.decode(data) is None


def test_the_mcus_format_packs_the_same_bytes():
    """``PACK_FORMAT`` (the 32-bit stamps as 16-bit halves, small ints on the MCU) lays out
    the bytes of ``FORMAT``."""
    values = [telemetry.MAGIC, telemetry.VERSION, 3, 7, 2 ** 40, 9, 0xC0012345, 0xBFFF0001]
    values += [0] * (len(telemetry.FIELDS) - len(values))
    halves = values[:6] + [0xC001, 0x2345, 0xBFFF, 0x0001] + values[8:]
    assert struct.calcsize(telemetry.PACK_FORMAT) == telemetry.BYTES
    assert struct.pack(telemetry.PACK_FORMAT, *halves) == struct.pack(telemetry.FORMAT, *values)
