"""The regression set on a real MicroPython 1.27 (:mod:`lodestar.regress.unixport`): the unix
port built 32-bit with single-precision floats in the object word (``MICROPY_OBJ_REPR_C``), as
the STM32F401's flight build, with the MCU image frozen by the repository's ``manifest.py``.

The build, and when its tests skip: ``tests/regress/conftest.py``.  The set records the
float32 build's own outcomes (``expected_float32``): the build reproduces them within the
set's ``float32.tolerances`` (bit for bit in effect) and they stay within its
``float32.bound`` of the double ones."""

import copy
import json
import shutil

import pytest
from scipy.spatial.transform import Rotation

from lodestar.cli import main
from lodestar.contract.stardb import METHODS
from lodestar.regress import record, replay, unixport
from tests import REPO

HEAP_BUDGET = 64 * 1024
"""Heap (bytes) within which every flight loop of the set runs on the flight build with the
firmware's own collector setting, the STM32F401's, and a packet buffer for the flight
gateware's record capacity (measured: at most 58 KiB, Pyramid on estcube2 and lohmann;
``docs/mcu_board.md``)."""


def _runs(manifest, method, camera=None):
    return [(case, method) for case in manifest["cases"]
            if camera is None or case["camera"] == camera]


def _runs_all(manifest):
    return [run for method in manifest["methods"] for run in _runs(manifest, method)]


def test_the_flight_build_stores_floats_in_the_object_word(float32_frozen, reference):
    """The flight build is 32-bit with ``MICROPY_OBJ_REPR_C``: float products allocate
    nothing and a float keeps 22 significand bits; the reference build (``A``, the STM32
    port's default) boxes them.  Each has its own build folder, so asking for one again
    after the other reuses it."""
    assert unixport.object_representation(float32_frozen) == "C"
    assert unixport.object_representation(reference) == "A"
    assert "-32-frozen-repr-c-" in float32_frozen.name and "-32-repr-a-" in reference.name
    assert float32_frozen.parent != reference.parent
    assert unixport.float32_build(repo=REPO) == float32_frozen


def test_without_a_32_bit_compiler_the_flight_build_is_unavailable(monkeypatch, tmp_path):
    """Where ``cc -m32`` cannot link (no ``gcc-multilib``), the reason says so with the fix,
    and neither build is attempted; representation C is refused for double floats."""
    script = tmp_path / "build.sh"
    script.write_text("exit 1\n")
    monkeypatch.setenv(unixport.BUILD_ENV, str(script))
    monkeypatch.setattr(unixport.shutil, "which", lambda tool: f"/usr/bin/{tool}")
    monkeypatch.setenv("CC", "false")
    assert unixport.unavailable_reason(REPO) == unixport.NO_32BIT
    assert "gcc-multilib" in unixport.NO_32BIT
    for make in (unixport.float32_build, unixport.reference_build):
        with pytest.raises(unixport.Unavailable, match="gcc-multilib"):
            make(cache_dir=tmp_path, repo=REPO)
    with pytest.raises(unixport.Unavailable, match="gcc-multilib"):
        unixport.build(script, REPO / "manifest.py", tmp_path / "out")
    with pytest.raises(ValueError, match="single-precision"):
        unixport.build(script, None, tmp_path / "out", "double")
    assert not (tmp_path / "out").exists()


def test_the_float32_build_reproduces_its_expectations(float32_frozen, regression_set):
    """Every case and method on the float32 build: its recorded ``expected_float32`` within
    the set's tight ``float32.tolerances``; the same outcomes bit for bit in the reverse
    order at another heap (the expectations are the arithmetic's, not the loop's)."""
    manifest, db_files = regression_set
    got = unixport.float32_outcomes(float32_frozen, manifest, replay.DEFAULT_SET, db_files)
    tol = manifest["float32"]["tolerances"]
    assert tol == replay.FLOAT32_TOLERANCES
    problems = [(case["name"], method, d) for case, method in _runs_all(manifest)
                for d in replay.differences(case["expected_float32"][method],
                                             got[case["name"], method], tol)]
    assert problems == []
    runs = _runs_all(manifest)[::-1]
    loop = unixport.flight_loop(float32_frozen, manifest, replay.DEFAULT_SET, db_files, runs,
                                512 * 1024)
    assert loop["finished"]
    assert {key: out for key, (out, _peak) in loop["results"].items()} == got


def test_float32_expectations_are_within_the_bound_of_the_double_ones(regression_set):
    """Every case and method: the recorded float32 outcome (of the flight build) has the
    double status and identified stars, the attitude and the sigma figures within the set's
    ``float32.bound`` (:data:`lodestar.regress.replay.FLOAT32_BOUND`)."""
    manifest, _db_files = regression_set
    bound = manifest["float32"]["bound"]
    assert bound == replay.FLOAT32_BOUND
    assert manifest["float32"]["build"] == "micropython-float32-32-frozen-repr-c"
    worst = 0.0
    for case, method in _runs_all(manifest):
        f32, double = case["expected_float32"][method], case["expected"][method]
        assert replay.float32_vs_double(f32, double, bound) == [], (case["name"], method)
        if double["q"] is not None:
            worst = max(worst, replay.rotation_angle(f32["q"], double["q"]))
    assert 0.0 < worst < bound["q_rad"]          # float32 is not double, and within the bound


def test_lodestar_regress_checks_the_float32_build(float32_frozen, tmp_path, capsys):
    """``lodestar regress`` replays the committed set on the float32 build and agrees; a
    float32 expectation tampered with beyond the tight tolerance (an attitude turned by 3e-9
    rad, a sigma by 1e-6, well within the double bound) or an identification is caught."""
    n = len(replay.load_set(replay.DEFAULT_SET)["cases"]) * 3
    assert main(["regress", "--no-micropython"]) == 0
    out = capsys.readouterr().out
    assert f"all {n} replays agree with the recorded outputs on CPython and the float32 " \
           "build" in out and out.count(" same ") >= 2 * n
    target = tmp_path / "set"
    shutil.copytree(replay.DEFAULT_SET, target)
    manifest = json.loads((target / "manifest.json").read_text())
    cases = {case["name"]: case for case in manifest["cases"]}
    moved = cases["estcube2_rest_s1"]["expected_float32"]["triangle"]
    moved["q"] = list((Rotation.from_rotvec([0.0, 3e-9, 0.0]) *
                       Rotation.from_quat(moved["q"])).as_quat())
    cases["estcube2_1dps"]["expected_float32"]["pyramid"]["sigma_cross_arcsec"] *= 1 + 1e-6
    cases["lohmann_orion"]["expected_float32"]["hashing"]["matches"][0][1] += 1
    (target / "manifest.json").write_text(json.dumps(manifest, indent=1))
    assert main(["regress", "--no-micropython", "--set", str(target)]) == 1
    out = capsys.readouterr().out
    assert f"3 of {n} replays differ:" in out and out.count("DIFF") == 3
    assert "estcube2_rest_s1 / triangle: float32 vs expected_float32: attitude differs by " \
           "3e-09 rad" in out
    assert "estcube2_1dps / pyramid: float32 vs expected_float32: sigma_cross_arcsec" in out
    assert "lohmann_orion / hashing: float32 vs expected_float32: matches" in out


def test_the_recorder_refuses_float32_outcomes_beyond_the_bound(float32_frozen, regression_set):
    """:func:`lodestar.regress.record.add_float32` records the build's outcomes (the committed
    ones) and lists every case whose double outcome they do not match within the bound: here
    double outcomes moved by twice the bound and given another star."""
    manifest, db_files = regression_set
    manifest = copy.deepcopy(manifest)
    files = {case["packet"]: (replay.DEFAULT_SET / case["packet"]).read_bytes()
             for case in manifest["cases"]}
    committed = {case["name"]: case.pop("expected_float32") for case in manifest["cases"]}
    cases = {case["name"]: case for case in manifest["cases"]}
    turned = cases["estcube2_rest_s2"]["expected"]["pyramid"]
    turned["q"] = list((Rotation.from_rotvec([2 * replay.FLOAT32_BOUND["q_rad"], 0.0, 0.0]) *
                        Rotation.from_quat(turned["q"])).as_quat())
    cases["lohmann_orion"]["expected"]["triangle"]["matches"][0][1] += 1
    problems = record.add_float32(manifest, files, float32_frozen, db_files)
    assert len(problems) == 2
    assert problems[0].startswith("estcube2_rest_s2 / pyramid: float32 vs double: attitude "
                                  "differs by")
    assert problems[1].startswith("lohmann_orion / triangle: float32 vs double: matches")
    assert {name: case["expected_float32"] for name, case in cases.items()} == committed


@pytest.mark.slow
def test_record_reproduces_the_committed_set(float32_frozen, tmp_path):
    """``lodestar regress --record`` rewrites the committed set byte for byte, the float32
    expectations included (about a minute: every frame is simulated again)."""
    assert main(["regress", "--record", "--set", str(tmp_path)]) == 0
    for path in replay.DEFAULT_SET.rglob("*"):
        if path.is_file():
            assert (tmp_path / path.relative_to(replay.DEFAULT_SET)).read_bytes() == \
                path.read_bytes(), path.name


@pytest.mark.parametrize("method", METHODS)
def test_every_flight_loop_runs_within_the_heap_budget(float32_frozen, regression_set, method):
    """Each camera's packets one after another in one process, one database open, one
    packet buffer of the flight size (:data:`lodestar.regress.unixport.FLIGHT_BUFFER`), at
    :data:`HEAP_BUDGET`: the recorded results, no ``OUT_OF_MEMORY``."""
    manifest, db_files = regression_set
    for camera in manifest["cameras"]:
        runs = _runs(manifest, method, camera)
        loop = unixport.flight_loop(float32_frozen, manifest, replay.DEFAULT_SET, db_files,
                                    runs, HEAP_BUDGET, buffer_bytes=unixport.FLIGHT_BUFFER)
        assert unixport.disagreements(loop, runs) == [], (camera, loop["error"])


def test_min_heap_bisects_to_the_smallest_working_heap(float32_frozen, regression_set):
    """The bisection's answer works and 2 KB less does not (on the worst rest frame)."""
    manifest, db_files = regression_set
    runs = [(case, "triangle") for case in manifest["cases"]
            if case["name"] == "estcube2_rest_s0"]
    heap = unixport.min_heap(float32_frozen, manifest, replay.DEFAULT_SET, db_files, runs,
                             high=HEAP_BUDGET)
    assert heap is not None and heap <= HEAP_BUDGET
    for size, fits in ((heap, True), (heap - unixport.HEAP_STEP, False)):
        loop = unixport.flight_loop(float32_frozen, manifest, replay.DEFAULT_SET, db_files,
                                    runs, size)
        assert (unixport.disagreements(loop, runs) == []) is fits, size


def test_a_bigger_packet_buffer_takes_its_size_from_the_heap(float32_frozen, regression_set):
    """The loop's buffer is the given size: a loop that fits with the longest packet's
    buffer does not with one 8 KiB larger (the heap it takes is the firmware's), and a
    buffer smaller than a packet is refused."""
    manifest, db_files = regression_set
    runs = [(case, "triangle") for case in manifest["cases"]
            if case["name"] == "estcube2_rest_s0"]
    heap = unixport.min_heap(float32_frozen, manifest, replay.DEFAULT_SET, db_files, runs,
                             high=HEAP_BUDGET)
    longest = (replay.DEFAULT_SET / runs[0][0]["packet"]).stat().st_size
    loop = unixport.flight_loop(float32_frozen, manifest, replay.DEFAULT_SET, db_files, runs,
                                heap, buffer_bytes=longest + 8192)
    assert unixport.disagreements(loop, runs) != []
    with pytest.raises(unixport.MicroPythonError, match="cannot hold"):
        unixport.flight_loop(float32_frozen, manifest, replay.DEFAULT_SET, db_files, runs, heap,
                             buffer_bytes=longest - 1)


def test_the_frozen_image_is_the_mcu_image(tmp_path):
    """The staged tree holds exactly the MCU image: the root, the contract, the firmware and
    the MCU side of the regression, nothing of the ground; a checkout's source tree stages
    the same image."""
    staged = unixport.stage_mcu_image(tmp_path / "installed")
    files = sorted(str(p.relative_to(staged)) for p in staged.rglob("*.py"))
    assert "lodestar/__init__.py" in files and "lodestar/firmware/pipeline.py" in files
    assert "lodestar/contract/packet.py" in files
    regress_files = ["lodestar/regress/__init__.py", "lodestar/regress/loop.py",
                     "lodestar/regress/mcu.py"]
    assert all(f.startswith(("lodestar/firmware/", "lodestar/contract/")) or
               f == "lodestar/__init__.py" or f in regress_files for f in files)
    assert set(regress_files) <= set(files)
    checkout = unixport.stage_mcu_image(tmp_path / "checkout", checkout=REPO)
    assert sorted(str(p.relative_to(checkout)) for p in checkout.rglob("*.py")) == files


def test_restaging_rewrites_only_what_changed(tmp_path):
    """An unchanged file keeps its time (the incremental build does not re-freeze it), a
    changed one is rewritten and a file no longer in the image is removed."""
    staged = unixport.stage_mcu_image(tmp_path)
    keep = staged / "lodestar/firmware/pipeline.py"
    changed = staged / "lodestar/firmware/status.py"
    stale = staged / "lodestar/firmware/gone/old.py"
    stale.parent.mkdir()
    stale.write_text("x = 1\n")
    changed.write_text("edited\n")
    before = keep.stat().st_mtime_ns
    unixport.stage_mcu_image(tmp_path)
    assert keep.stat().st_mtime_ns == before
    assert changed.read_text() != "edited\n"
    assert not stale.exists() and not stale.parent.exists()
