"""The MCU time calibration (:mod:`lodestar.regress.mcutime`): the published benchmarks run
unchanged on the reference build (the published run's object representation) and give the
published results; the flight build is refused for calibration and counts its frames.  The
x86 reference build's calibration is opt-in (``--runslow``): the F401 figures come from the
Cortex-M4F build (``tests/regress/test_qemu.py``)."""

import pytest

from lodestar.regress import mcutime, replay

# one worker runs the file: the build's session fixtures run once (pyproject: loadgroup)
pytestmark = pytest.mark.xdist_group("unixport")


def test_sources_are_pyperformance_functions_without_the_runner():
    for name in mcutime.F401_US:
        src = mcutime.benchmark_source(name)
        assert "pyperf" not in src.replace("pyperformance", "")
        namespace = {}
        exec(compile(src, name, "exec"), namespace)
    assert len(list(namespace["n_queens"](6))) == 4


@pytest.mark.slow
def test_calibration_on_the_reference_build(reference):
    cal = mcutime.calibrate(reference, runs=2)
    assert set(cal["ratio"]) == set(mcutime.F401_US)
    for us in cal["runs"].values():
        assert len(us) == 2 and all(t > 0 for t in us)
    # an F401 at 84 MHz is far slower than any machine that builds MicroPython
    assert 10 < cal["scale"] < 2000
    lo, hi = sorted(cal["ratio"].values())
    assert cal["scale"] == pytest.approx((lo * hi) ** 0.5)


@pytest.mark.slow
def test_a_wrong_workload_is_refused(reference, monkeypatch):
    monkeypatch.setitem(mcutime.CALLS, "bm_nqueens", ("len(list(n_queens(5)))", "4"))
    with pytest.raises(mcutime.CalibrationError, match="bm_nqueens"):
        mcutime.calibrate(reference, runs=1)


def test_the_flight_build_is_refused_for_calibration(float32_frozen):
    """The F401 ran object representation A: the flight build's (C) would calibrate another
    configuration."""
    for calibrate in (mcutime.calibrate, mcutime.calibrate_instructions):
        with pytest.raises(mcutime.CalibrationError, match="representation C"):
            calibrate(float32_frozen)


@pytest.fixture
def valgrind():
    if mcutime.valgrind() is None:
        pytest.skip("valgrind is not installed (Debian package valgrind)")


@pytest.mark.slow
def test_instruction_calibration_agrees_between_the_benchmarks(reference, valgrind):
    cal = mcutime.calibrate_instructions(reference)
    lo, hi = sorted(cal["us_per_ir"].values())
    assert hi / lo < 1.25   # measured: 1.01 (the flight build's representation C: 1.47)
    assert lo <= cal["us_per_ir_mean"] <= hi


def test_frame_instructions_split_a_frame_by_stage(float32_frozen, valgrind, regression_set):
    manifest, files = regression_set
    case = next(c for c in manifest["cases"] if c["inputs"].get("prior") is not None)
    camera = manifest["cameras"][case["camera"]]
    status, stages = mcutime.frame_instructions(
        float32_frozen, case, "pyramid", files[camera["database"]], camera,
        replay.DEFAULT_SET / case["packet"], 64 * 1024)
    assert status == case["expected"]["pyramid"]["status"]
    assert set(stages) == {"decode", "centroids", "directions", "identify", "attitude",
                           "process"}
    assert all(stages[k] > 0 for k in stages)
    assert stages["process"] == sum(v for k, v in stages.items() if k != "process")
