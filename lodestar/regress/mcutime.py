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

Two ways to scale: by wall time (:func:`calibrate`: the ratio differs between the two
benchmarks and with the machine's load) or by instructions (:func:`calibrate_instructions`:
the x86 instructions the build executes, counted by valgrind, are the same on any machine
under any load, and the F401's microseconds per instruction agree within a few per cent
between the two benchmarks).  :func:`frame_instructions` counts a pipeline frame's
instructions stage by stage.  Either way an estimate, and labelled so: the F401 runs Thumb-2
code of another compiler from flash.

The published run is the STM32 port's default build, object representation ``A`` (every
float a heap object), while the flight build stores floats in the object word
(``MICROPY_OBJ_REPR_C``, :data:`lodestar.regress.unixport.FLIGHT_REPR`), which runs
``bm_float`` in fewer instructions (measured: 2.44 M against 3.54 M, while ``bm_nqueens``
takes 35.4 M in both; calibrated on C, the two would disagree on the F401's time per
instruction by 47 %).  So the calibration runs on a representation-``A``
build of the same sources (:func:`lodestar.regress.unixport.reference_build`; the
calibration functions refuse another) and its scale is applied to the flight build's times
and counts: this assumes that the F401 spends the same time per instruction counted here
in both representations, which is an estimate too (no F401 has run a representation-``C``
build for this project).
"""

import glob
import json
import math
import re
import shutil
import subprocess
import tempfile
from pathlib import Path

from lodestar.regress import perfbench, unixport
from lodestar.regress.micropython import write_runs

F401_SOURCE = ("micropython/micropython pull request #18069 (NUCLEO-F401RE, 84 MHz, "
               "run-perfbench.py N=84 M=80, 2025-09-14)")
"""Where :data:`F401_US` comes from."""

F401_US = {"bm_float": 37841.00, "bm_nqueens": 375490.00}
"""Published time of one run on the NUCLEO-F401RE, microseconds (:data:`F401_SOURCE`)."""

CALLS = {"bm_float": ("benchmark(150)", "<Point: x=0.89387"),
          "bm_nqueens": ("len(list(n_queens(6)))", "4")}
"""Per benchmark: the call the suite times at ``N=84 M=80``, and the start of its printed
result (a check that the workload is the published one, in single or double precision)."""

HEAP = "80K"
"""The heap the calibration runs get: the ``M=80`` (kilobytes of heap) of the published run."""

_PERFBENCH = str(Path(perfbench.__file__).resolve())
"""The timing script of a calibration run (:mod:`lodestar.regress.perfbench`)."""

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


def _check_reference(binary):
    """Raise :class:`CalibrationError` unless ``binary`` has the published run's object
    representation, ``A`` (:func:`lodestar.regress.unixport.object_representation`)."""
    found = unixport.object_representation(binary)
    if found != "A":
        raise CalibrationError(f"{binary} has object representation {found}: the F401 "
                               "figures were measured on representation A (calibrate on "
                               "lodestar.regress.unixport.reference_build)")


def calibrate(binary, runs=7, timeout=120):
    """Run each calibration benchmark ``runs`` times on MicroPython ``binary`` (a fresh
    process each time; object representation ``A``, as the published run:
    :func:`lodestar.regress.unixport.reference_build`) and return ``{"runs": {name: [us,
    ...]}, "ratio": {name: F401 us / fastest us here}, "scale": geometric mean of the
    ratios}``: an F401's time for a piece of code is about ``scale`` times its time here on
    a build of the same sources (the flight build included, an estimate: see the module).
    Each run is :mod:`lodestar.regress.perfbench` of the benchmark's source and call."""
    _check_reference(binary)
    times = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (call, expect) in CALLS.items():
            source = Path(tmp) / f"{name}.py"
            source.write_text(benchmark_source(name), encoding="utf-8")
            times[name] = []
            for _ in range(runs):
                proc = subprocess.run([str(binary), "-X", f"heapsize={HEAP}", _PERFBENCH,
                                       str(source), call], capture_output=True,
                                      text=True, timeout=timeout, cwd=tmp)
                out = proc.stdout.strip().split(" ", 1)
                if proc.returncode != 0 or len(out) != 2 or not out[1].startswith(expect):
                    raise CalibrationError(f"{name} on {binary}: "
                                           f"{(proc.stdout + proc.stderr)[-300:]}")
                times[name].append(int(out[0]))
    ratio = {name: F401_US[name] / min(us) for name, us in times.items()}
    scale = math.exp(sum(math.log(r) for r in ratio.values()) / len(ratio))
    return {"runs": times, "ratio": ratio, "scale": scale}


def valgrind():
    """The ``valgrind`` program, or None (Debian package ``valgrind``)."""
    return shutil.which("valgrind")


def _instructions(argv, cwd, dump_before=None, timeout=900):
    """Instructions (x86, user space) of running ``argv`` under callgrind: ``[total]``, or
    one count per part between entries into the C function ``dump_before``."""
    tool = valgrind()
    if tool is None:
        raise CalibrationError("valgrind is not installed (Debian package valgrind)")
    out = Path(cwd) / "callgrind.out"
    cmd = [tool, "--tool=callgrind", f"--callgrind-out-file={out}"]
    if dump_before:
        cmd.append(f"--dump-before={dump_before}")
    proc = subprocess.run(cmd + [str(a) for a in argv], capture_output=True, text=True,
                          timeout=timeout, cwd=cwd)
    if proc.returncode != 0:
        raise CalibrationError(f"{argv[0]} under valgrind: {(proc.stdout + proc.stderr)[-300:]}")
    if not dump_before:
        found = re.search(r"Collected : (\d+)", proc.stderr)
        if found is None:
            raise CalibrationError(f"no instruction count from valgrind: {proc.stderr[-300:]}")
        return [int(found.group(1))], proc.stdout
    counts = []
    for part in sorted(glob.glob(f"{out}.*"), key=lambda f: int(f.rsplit(".", 1)[1])):
        with open(part, encoding="utf-8") as f:
            counts.append(next(int(line.split()[1]) for line in f
                               if line.startswith(("totals:", "summary:"))))
    return counts, proc.stdout


def calibrate_instructions(binary):
    """``{"ir": {name: instructions of one run here}, "us_per_ir": {name: F401 us per
    instruction}, "us_per_ir_mean": their geometric mean}`` on MicroPython ``binary``
    (object representation ``A``, as the published run:
    :func:`lodestar.regress.unixport.reference_build`): an F401's time for a piece of code
    is about its instruction count on a build of the same sources (the flight build's
    :func:`frame_instructions` included, an estimate: see the module) times
    ``us_per_ir_mean``.  One run's count is the difference between a process running it
    three times and once (:mod:`lodestar.regress.perfbench`)."""
    _check_reference(binary)
    ir = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name, (call, expect) in CALLS.items():
            source = Path(tmp) / f"{name}.py"
            source.write_text(benchmark_source(name), encoding="utf-8")
            argv = [binary, "-X", f"heapsize={HEAP}", _PERFBENCH, source, call]
            once, out = _instructions(argv + [1], tmp)
            if not out.partition(" ")[2].startswith(expect):
                raise CalibrationError(f"{name} on {binary}: {out[-300:]}")
            thrice, _ = _instructions(argv + [3], tmp)
            ir[name] = (thrice[0] - once[0]) / 2
    per = {name: F401_US[name] / ir[name] for name in ir}
    mean = math.exp(sum(math.log(v) for v in per.values()) / len(per))
    return {"ir": ir, "us_per_ir": per, "us_per_ir_mean": mean}


def frame_instructions(binary, case, method, database_file, camera, packet, heapsize):
    """Instructions of one :meth:`StarTracker.process` of the regression ``case`` (a
    manifest case, its ``camera`` settings, ``database_file`` and ``packet`` path) with
    ``method`` on ``binary`` at ``heapsize`` bytes of heap, the second of two calls (the
    first warms up): ``(status, {stage: instructions, "process": all stages})``, stages as
    the pipeline's ``timings`` (``decode``, ``centroids``, ``directions``, ``identify``,
    ``attitude``; fewer when the frame ends early): :func:`lodestar.regress.loop.stages`,
    frozen in ``binary``."""
    with tempfile.TemporaryDirectory() as tmp:
        write_runs(Path(tmp) / "runs.jsonl", {"cameras": {case["camera"]: camera}},
                   [(case, method)], lambda _name: str(Path(database_file).resolve()),
                   lambda _case: str(Path(packet).resolve()))
        (Path(tmp) / "frame.json").write_text(json.dumps({
            "runs": "runs.jsonl", "buffer_bytes": Path(packet).stat().st_size}),
            encoding="utf-8")
        parts, out = _instructions([binary, "-X", f"heapsize={int(heapsize)}", "-m",
                                    "lodestar.regress.loop", "--stages", "frame.json"], tmp,
                                   dump_before="__clock_gettime64")
    status, timings = json.loads(out.strip().splitlines()[-1])
    stages = {}
    for name, value in timings:
        if name != "total":
            stages[name] = parts[int(value).bit_length() - 1]   # the part ending at its tick
    stages["process"] = sum(stages.values())
    return status, stages
