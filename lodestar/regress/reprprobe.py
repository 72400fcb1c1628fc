"""Which object representation a MicroPython binary has, observed: run as a script by
:func:`lodestar.regress.unixport.object_representation` (on any build, nothing frozen
needed), it prints the bytes that 100 more float products allocate and whether
``1 + 2**-22`` is 1 (a 22-bit significand).  MicroPython only (``gc.mem_alloc``)."""

import gc


def allocated(n):
    """Bytes allocated (after a collection) by ``n`` float products."""
    gc.collect()
    start = gc.mem_alloc()
    x = 1.5
    for _ in range(n):
        x = x * 1.0001
    return gc.mem_alloc() - start


def main():
    print(allocated(101) - allocated(1), 1.0 + 2.0 ** -22 == 1.0)


if __name__ == "__main__":
    main()
