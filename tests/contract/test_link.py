"""The SPI link of the contract: opcodes, status word, overflow bits."""

import pytest

from lodestar import contract as C


def test_opcodes_are_distinct_bytes_and_the_status_word_is_whole_bytes():
    assert len(set(C.OPCODES)) == len(C.OPCODES) and all(0 <= op < 256 for op in C.OPCODES)
    assert C.FILLER not in C.OPCODES
    assert C.STATUS_BITS == sum(bits for _, bits in C.STATUS_FIELDS) == 8 * C.STATUS_BYTES
    overflow_bits = [C.OVF_PIXEL_FIFO, C.OVF_TRAILER_LOST, C.OVF_REG_REFUSED, C.OVF_FAULT,
                     C.OVF_LINK_DOWN, C.OVF_LINK_ERROR, C.OVF_CLOCK_LOST]
    assert len(set(overflow_bits)) == len(overflow_bits)
    assert max(overflow_bits) < C.OVERFLOW_BITS == dict(C.STATUS_FIELDS)["overflow"]


def test_register_addresses_fit_the_write_command():
    assert max(r.address for r in C.REGISTERS) < (1 << (8 * C.ADDRESS_BYTES))
    assert C.WRITE_REG_BYTES == 1 + C.ADDRESS_BYTES + C.REGISTER_WORD_BITS // 8


def test_decode_status_round_trips_every_field():
    values = {"frame_counter": 0xDEADBEEF, "errors": 3, "underruns": 255,
              "overflow": 1 << C.OVF_FAULT, "busy": 1}
    word = 0
    for name, bits in C.STATUS_FIELDS:
        word = (word << bits) | values[name]
    assert C.decode_status(word.to_bytes(C.STATUS_BYTES, "big")) == values
    with pytest.raises(ValueError, match="status word"):
        C.decode_status(b"\x00")


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
