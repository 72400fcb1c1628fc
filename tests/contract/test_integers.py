"""Integer helpers of the contract."""

import math

import pytest

from lodestar import contract as C


@pytest.mark.parametrize("value", [0, 1, 2, 3, 4095, 4096, 2**52 - 1, 2**52, 10**30])
def test_bits_for_and_isqrt(value):
    assert C.bits_for(value) == max(value.bit_length(), 1)
    assert C.isqrt(value) == math.isqrt(value)


def test_field_offsets_pack_msb_first():
    assert C.field_offsets((("a", 3), ("b", 5), ("c", 8))) == (("a", 0, 3), ("b", 3, 5),
                                                               ("c", 8, 8))
