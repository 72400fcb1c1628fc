"""Integer helpers of the contract (MicroPython-safe, no allocation per call beyond the result)."""


def bits_for(value):
    """Number of bits of an unsigned integer able to hold ``value`` (>= 1 for value 0)."""
    if value < 0:
        raise ValueError("bits_for: value must be >= 0, got {}".format(value))
    n = 1
    while value >> n:
        n += 1
    return n


def isqrt(value):
    """Integer square root: the largest ``r`` with ``r * r <= value`` (``value >= 0``)."""
    if value < 0:
        raise ValueError("isqrt: value must be >= 0, got {}".format(value))
    if value < 2:
        return value
    r = 1 << ((bits_for(value) + 1) // 2)
    while True:
        nr = (r + value // r) // 2
        if nr >= r:
            return r
        r = nr


def field_offsets(fields):
    """``((name, bit_offset, bits), ...)`` of ``(name, bits)`` fields packed MSB first, the
    offsets counted from the start of their section."""
    out = []
    offset = 0
    for name, bits in fields:
        out.append((name, offset, bits))
        offset += bits
    return tuple(out)
