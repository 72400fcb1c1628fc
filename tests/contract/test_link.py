"""The SPI link of the contract: opcodes, keyed commands, status word and its CRC-8, overflow
bits, ID word."""

from itertools import combinations

import pytest

from lodestar import contract as C


def test_opcodes_are_distinct_bytes_and_the_status_word_is_whole_bytes():
    assert len(set(C.OPCODES)) == len(C.OPCODES) and all(0 <= op < 256 for op in C.OPCODES)
    assert C.FILLER not in C.OPCODES
    assert C.STATUS_DATA_BITS == sum(bits for _, bits in C.STATUS_FIELDS)
    assert C.STATUS_BITS == C.STATUS_DATA_BITS + 8 == 8 * C.STATUS_BYTES
    overflow_bits = [C.OVF_PIXEL_FIFO, C.OVF_TRAILER_LOST, C.OVF_REG_REFUSED, C.OVF_FAULT,
                     C.OVF_LINK_DOWN, C.OVF_LINK_ERROR, C.OVF_CLOCK_LOST]
    assert len(set(overflow_bits)) == len(overflow_bits)
    assert max(overflow_bits) < C.OVERFLOW_BITS == dict(C.STATUS_FIELDS)["overflow"]


def test_register_addresses_fit_the_write_command():
    assert max(r.address for r in C.REGISTERS) < (1 << (8 * C.ADDRESS_BYTES))
    assert C.WRITE_REG_BYTES == 1 + C.ADDRESS_BYTES + C.REGISTER_WORD_BITS // 8


def test_decode_status_round_trips_every_field():
    values = {"frame_counter": 0xDEADBEEF, "errors": 3, "underruns": 255,
              "overflow": 1 << C.OVF_FAULT, "busy": 1, "trained": 1, "eye_width": 9}
    word = 0
    for name, bits in C.STATUS_FIELDS:
        word = (word << bits) | values[name]
    data = word.to_bytes(C.STATUS_DATA_BYTES, "big")
    assert C.encode_status(values) == data + bytes([C.crc8(data)])
    assert C.decode_status(C.encode_status(values)) == values
    with pytest.raises(ValueError, match="status word"):
        C.decode_status(b"\x00")
    with pytest.raises(ValueError, match="holds"):
        C.encode_status(dict(values, errors=256))
    # a build without phase training: its fields are the defaults (0)
    untrained = {k: v for k, v in values.items() if k not in C.STATUS_DEFAULTS}
    assert C.decode_status(C.encode_status(untrained)) == dict(untrained, trained=0,
                                                                eye_width=0)
    with pytest.raises(KeyError):
        C.encode_status({k: v for k, v in values.items() if k != "busy"})


def test_write_reg_command_sets_a_register_by_name():
    reg = C.REGISTER_BY_NAME["min_sum"]
    value = (1 << reg.bits) - 1
    data = C.write_reg_command("min_sum", value)
    assert len(data) == C.WRITE_REG_BYTES
    assert data == bytes([C.OP_WRITE_REG, reg.address]) + value.to_bytes(4, "big")
    assert C.write_reg_command("mode", 0)[1] == C.REGISTER_BY_NAME["mode"].address
    for name, bad in (("min_sum", 1 << reg.bits), ("min_sum", -1), ("min_sum", 1.0),
                      ("min_sum", True), ("nonsense", 0)):
        with pytest.raises(ValueError):
            C.write_reg_command(name, bad)


def bitwise_crc8(data):
    crc = C.CRC8_INIT
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ C.CRC8_POLY) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc ^ C.CRC8_XOROUT


def test_crc8_is_autosar_and_a_floating_miso_never_passes():
    assert C.crc8(b"123456789") == 0xDF                    # CRC-8/AUTOSAR check value
    rng = __import__("random").Random(5)
    for n in (0, 1, 7, 64):
        data = bytes(rng.randrange(256) for _ in range(n))
        assert C.crc8(data) == bitwise_crc8(data)          # the table is the bitwise CRC
    for stuck in (0x00, 0xFF):
        reply = bytes([stuck] * C.STATUS_BYTES)
        assert not C.status_ok(reply)
        with pytest.raises(ValueError, match="CRC"):
            C.decode_status(reply)
    # MISO stuck after k good bits (a slave that stops driving mid-reply)
    good = C.encode_status({"frame_counter": 12345, "errors": 0, "underruns": 0,
                            "overflow": 0, "busy": 1})
    value = int.from_bytes(good, "big")
    n = 8 * C.STATUS_BYTES
    for k in range(n):
        for level in (0, 1):
            low = (1 << (n - k)) - 1
            stuck = (value & ~low) | (low if level else 0)
            if stuck != value:
                assert not C.status_ok(stuck.to_bytes(C.STATUS_BYTES, "big")), (k, level)


def test_crc8_detects_every_error_of_up_to_three_bits():
    good = C.encode_status({"frame_counter": 0xDEADBEEF, "errors": 3, "underruns": 1,
                            "overflow": 0x41, "busy": 0})
    value = int.from_bytes(good, "big")
    n = 8 * C.STATUS_BYTES
    for k in (1, 2, 3):
        for bits in combinations(range(n), k):
            flip = 0
            for b in bits:
                flip |= 1 << b
            assert not C.status_ok((value ^ flip).to_bytes(C.STATUS_BYTES, "big")), bits


def test_read_reg_keyed_commands_and_id():
    reg = C.REGISTER_BY_NAME["min_sum"]
    cmd = C.read_reg_command("min_sum")
    assert len(cmd) == C.READ_REG_BYTES == 1 + C.ADDRESS_BYTES + C.TURNAROUND_BYTES + 4
    assert cmd[:2] == bytes([C.OP_READ_REG, reg.address]) and not any(cmd[2:])
    with pytest.raises(ValueError):
        C.read_reg_command("nonsense")
    for op in C.KEYED_OPCODES:
        key = C.command_key(op)
        assert C.keyed_command(op) == bytes([op, key])
        assert key not in (0x00, 0xFF, C.FILLER) and key not in C.OPCODES
    with pytest.raises(ValueError):
        C.keyed_command(C.OP_READ_STREAM)
    ident = C.gateware_id(7)
    data = ident.to_bytes(C.ID_BYTES, "big")
    assert C.decode_id(data) == {"magic": C.ID_MAGIC, "link_version": C.LINK_VERSION,
                                 "build": 7}
    for bad in (bytes(C.ID_BYTES), b"\xff" * C.ID_BYTES, data[:-1]):
        with pytest.raises(ValueError):
            C.decode_id(bad)
    assert sum(bits for _, bits in C.ID_FIELDS) == 8 * C.ID_BYTES
