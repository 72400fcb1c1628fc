"""The MCU time calibration (:mod:`lodestar.regress.mcutime`): the published benchmarks run
unchanged on the flight build and give the published results."""

import pytest

from lodestar.regress import mcutime
from lodestar.regress import replay as regress


def test_sources_are_pyperformance_functions_without_the_runner():
    for name in mcutime.F401_US:
        src = mcutime.benchmark_source(name)
        assert "pyperf" not in src.replace("pyperformance", "")
        namespace = {}
        exec(compile(src, name, "exec"), namespace)
    assert len(list(namespace["n_queens"](6))) == 4


def test_calibration_on_the_flight_build(float32_frozen):
    cal = mcutime.calibrate(float32_frozen, runs=2)
    assert set(cal["ratio"]) == set(mcutime.F401_US)
    for us in cal["runs"].values():
        assert len(us) == 2 and all(t > 0 for t in us)
    # an F401 at 84 MHz is far slower than any machine that builds MicroPython
    assert 10 < cal["scale"] < 2000
    lo, hi = sorted(cal["ratio"].values())
    assert cal["scale"] == pytest.approx((lo * hi) ** 0.5)


def test_a_wrong_workload_is_refused(float32_frozen, monkeypatch):
    monkeypatch.setitem(mcutime._CALLS, "bm_nqueens", ("len(list(n_queens(5)))", "4"))
    with pytest.raises(mcutime.CalibrationError, match="bm_nqueens"):
        mcutime.calibrate(float32_frozen, runs=1)


@pytest.fixture
def valgrind():
    if mcutime.valgrind() is None:
        pytest.skip("valgrind is not installed (Debian package valgrind)")


def test_instruction_calibration_agrees_between_the_benchmarks(float32_frozen, valgrind):
    cal = mcutime.calibrate_instructions(float32_frozen)
    lo, hi = sorted(cal["us_per_ir"].values())
    assert hi / lo < 1.25              # measured: 1.03 on the 32-bit build
    assert lo <= cal["us_per_ir_mean"] <= hi


def test_frame_instructions_split_a_frame_by_stage(float32_frozen, valgrind, regression_set):
    manifest, files = regression_set
    case = next(c for c in manifest["cases"] if c["inputs"].get("prior") is not None)
    camera = manifest["cameras"][case["camera"]]
    status, stages = mcutime.frame_instructions(
        float32_frozen, case, "pyramid", files[camera["database"]], camera,
        regress.DEFAULT_SET / case["packet"], 64 * 1024)
    assert status == case["expected"]["pyramid"]["status"]
    assert set(stages) == {"decode", "centroids", "directions", "identify", "attitude",
                           "process"}
    assert all(stages[k] > 0 for k in stages)
    assert stages["process"] == sum(v for k, v in stages.items() if k != "process")
