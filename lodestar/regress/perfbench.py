"""A benchmark call timed as MicroPython's ``run-perfbench.py`` times it, for
:mod:`lodestar.regress.mcutime` (run as a script on any build, nothing frozen needed; CPython
lacks ``time.ticks_us``)::

    micropython perfbench.py BENCHMARK.py CALL [N]

runs the benchmark's source, then evaluates the expression ``CALL`` in its namespace ``N``
times (default 1) and prints the microseconds of the ``N`` calls and the last result."""

import sys
import time


def main(argv):
    namespace = {}
    with open(argv[1]) as f:
        exec(f.read(), namespace)
    exec("def call():\n    return " + argv[2] + "\n", namespace)
    call = namespace["call"]
    n = int(argv[3]) if len(argv) > 3 else 1
    t0 = time.ticks_us()
    for _ in range(n):
        r = call()
    dt = time.ticks_diff(time.ticks_us(), t0)
    print(dt, r)


if __name__ == "__main__":
    main(sys.argv)
