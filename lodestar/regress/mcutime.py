"""Time on the flight MCU, estimated: a time on the unix port (:mod:`lodestar.regress.unixport`)
scaled by how much slower a published STM32F401 ran the same MicroPython benchmarks.

The reference is MicroPython's own performance suite (``tests/perf_bench``,
``run-perfbench.py``) on a NUCLEO-F401RE (STM32F401RE, 84 MHz, flash latency 2 wait
states), run at ``N=84 M=80`` and published in micropython/micropython pull request #18069
("stm32: Change flash latency for NUCLEO-F401RE", 14 September 2025, merged).  Two of its
benchmarks come unchanged from pyperformance (MIT): ``bm_float`` (float arithmetic, objects
and attribute access) and ``bm_nqueens`` (integers, tuples, sets and generators).  At
``N=84 M=80`` the suite's parameter rule picks ``benchmark(150)`` once and
``len(list(n_queens(6)))`` once.  :func:`calibrate` runs those functions, taken from the
installed ``pyperformance`` wheel's sources (never restated here), on a given interpreter,
each run in a fresh process as ``run-perfbench.py`` does, and returns the ratios.

An estimate, and labelled so: the two machines' interpreters differ in build options (the
unix port here is 32-bit x86, the F401's Thumb-2 with its flash accelerator), and the ratio
differs between the two benchmarks; :func:`calibrate` reports both and their geometric mean.
"""

import math
import subprocess
import tempfile
from pathlib import Path

F401_SOURCE = ("micropython/micropython pull request #18069 (NUCLEO-F401RE, 84 MHz, "
               "run-perfbench.py N=84 M=80, 2025-09-14)")
"""Where :data:`F401_US` comes from."""

F401_US = {"bm_float": 37841.00, "bm_nqueens": 375490.00}
"""Published time of one run on the NUCLEO-F401RE, microseconds (:data:`F401_SOURCE`)."""

_CALLS = {"bm_float": ("benchmark(150)", "<Point: x=0.89387"),
          "bm_nqueens": ("len(list(n_queens(6)))", "4")}
"""Per benchmark: the call the suite times at ``N=84 M=80``, and the start of its printed
result (a check that the workload is the published one, in single or double precision)."""

_HARNESS = """
import time
t0 = time.ticks_us()
r = {call}
dt = time.ticks_diff(time.ticks_us(), t0)
print(dt, r)
"""


class CalibrationError(RuntimeError):
    """A calibration benchmark is missing or gave another result than the published run."""


def benchmark_source(name):
    """The module source of pyperformance's benchmark ``name`` without its ``pyperf``
    runner (the function definitions the MicroPython suite uses unchanged)."""
    try:
        import pyperformance
    except ImportError:
        raise CalibrationError("pyperformance is not installed (a dev dependency)") from None
    path = (Path(pyperformance.__file__).parent / "data-files" / "benchmarks" / name /
            "run_benchmark.py")
    if not path.is_file():
        raise CalibrationError(f"pyperformance has no {name} at {path}")
    text = path.read_text(encoding="utf-8")
    body, sep, _ = text.partition('if __name__ == "__main__":')
    if not sep or "import pyperf\n" not in body:
        raise CalibrationError(f"{path} is not laid out as expected")
    return body.replace("import pyperf\n", "")


def calibrate(binary, runs=7, timeout=120):
    """Run each calibration benchmark ``runs`` times on MicroPython ``binary`` (a fresh
    process each time) and return ``{"runs": {name: [us, ...]}, "ratio": {name: F401 us /
    fastest us here}, "scale": geometric mean of the ratios}``: an F401's time for a piece
    of code is about ``scale`` times its time on ``binary`` here."""
    times = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (call, expect) in _CALLS.items():
            script = Path(tmp) / f"{name}.py"
            script.write_text(benchmark_source(name) + _HARNESS.format(call=call),
                              encoding="utf-8")
            times[name] = []
            for _ in range(runs):
                proc = subprocess.run([str(binary), str(script)], capture_output=True,
                                      text=True, timeout=timeout, cwd=tmp)
                out = proc.stdout.strip().split(" ", 1)
                if proc.returncode != 0 or len(out) != 2 or not out[1].startswith(expect):
                    raise CalibrationError(f"{name} on {binary}: "
                                           f"{(proc.stdout + proc.stderr)[-300:]}")
                times[name].append(int(out[0]))
    ratio = {name: F401_US[name] / min(us) for name, us in times.items()}
    scale = math.exp(sum(math.log(r) for r in ratio.values()) / len(ratio))
    return {"runs": times, "ratio": ratio, "scale": scale}
