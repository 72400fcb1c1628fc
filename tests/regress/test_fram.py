"""The F-RAM model the star database is read through in tests and on the Cortex-M4F build
(:mod:`lodestar.regress.fram`); the reader over it: ``tests/firmware/test_database.py``."""

import io

import pytest

from lodestar.firmware import database
from lodestar.regress import fram


def test_fram_model_counts_reads_and_wire_time():
    """The chip model serves ``READ`` only, wraps at its end, and the wire time is the
    command and data bytes at the clock."""
    chip = fram.Fram(io.BytesIO(bytes(range(256)) * 4), capacity=1024)
    buf = bytearray(6)
    chip.cs.value(0)
    chip.write(bytes([database.FRAM_READ, 0, 0x03, 0xFE]))
    chip.readinto(buf)
    chip.cs.value(1)
    assert bytes(buf) == bytes([254, 255, 0, 1, 2, 3]) and (chip.reads, chip.read_bytes) == (1, 6)
    chip.cs.value(0)
    chip.write(bytes([0x02, 0, 0, 0]))               # a write: refused, reads as 0xFF
    chip.readinto(buf)
    chip.cs.value(1)
    assert bytes(buf) == b"\xff" * 6 and chip.errors == 2
    assert database.FRAM_READ == fram.READ and database.FRAM_BYTES == fram.CAPACITY
    assert fram.wire_us(10, 1000, 8e6) == pytest.approx((40 + 1000) * 8 / 8.0)
