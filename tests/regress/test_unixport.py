"""The regression set on a real MicroPython 1.27 (:mod:`lodestar.regress.unixport`): the unix
port built 32-bit (when the C compiler can target -m32) with single-precision floats, as the
STM32F401 runs it, with the MCU image frozen by the repository's ``manifest.py``.

The build, and when its tests skip: ``tests/regress/conftest.py``."""

import pytest

from lodestar.regress import replay as regress
from lodestar.regress import unixport

FLOAT32_ARCSEC = 2.0
"""Largest rotation between a float32 attitude and the recorded double one (measured: 0.61
arcsec, estcube2_rest_s3; fitting float32 catalogue vectors without renormalising them
gave 2.37)."""

HEAP_BUDGET = 64 * 1024
"""Heap (bytes) within which every flight loop of the set runs on the 32-bit float32 build
with the firmware's own collector setting, the STM32F401's (measured: at most 62 KiB,
Pyramid and hashing on estcube2; ``docs/firmware.md``, Memory)."""


@pytest.fixture
def mcu_words(float32_frozen):
    """The float32 build, when it is 32-bit as the MCU (a 64-bit build, where the C compiler
    cannot target -m32, over-states every heap figure: heap tests skip)."""
    if "-32-" not in float32_frozen.name:
        pytest.skip(f"{float32_frozen.name} is not a 32-bit build (install gcc-multilib)")
    return float32_frozen


def _runs(manifest, method, camera=None):
    return [(case, method) for case in manifest["cases"]
            if camera is None or case["camera"] == camera]


def test_the_set_replays_on_float32_micropython_with_the_firmware_frozen(float32_frozen,
                                                                          regression_set):
    """Every case and method: the status and the identified stars of the recorded (double
    precision) result, the attitude within :data:`FLOAT32_ARCSEC`."""
    manifest, db_files = regression_set
    runs = [run for method in manifest["methods"] for run in _runs(manifest, method)]
    loop = unixport.flight_loop(float32_frozen, manifest, regress.DEFAULT_SET, db_files, runs,
                                4 << 20)
    assert unixport.disagreements(loop, runs) == []
    worst = 0.0
    for case, method in runs:
        want = case["expected"][method]["q"]
        if want is not None:
            worst = max(worst, regress.rotation_angle(loop["results"][(case["name"], method)]
                                                      [0]["q"], want))
    assert worst * 206264.806 < FLOAT32_ARCSEC


@pytest.mark.parametrize("method", ["pyramid", "triangle", "hashing"])
def test_every_flight_loop_runs_within_the_heap_budget(mcu_words, regression_set, method):
    """Each camera's packets one after another in one process, one database open, at
    :data:`HEAP_BUDGET`: the recorded results, no ``OUT_OF_MEMORY``."""
    manifest, db_files = regression_set
    for camera in manifest["cameras"]:
        runs = _runs(manifest, method, camera)
        loop = unixport.flight_loop(mcu_words, manifest, regress.DEFAULT_SET, db_files,
                                    runs, HEAP_BUDGET)
        assert unixport.disagreements(loop, runs) == [], (camera, loop["error"])


def test_min_heap_bisects_to_the_smallest_working_heap(mcu_words, regression_set):
    """The bisection's answer works and 2 KB less does not (on the worst rest frame)."""
    manifest, db_files = regression_set
    runs = [(case, "triangle") for case in manifest["cases"]
            if case["name"] == "estcube2_rest_s0"]
    heap = unixport.min_heap(mcu_words, manifest, regress.DEFAULT_SET, db_files, runs,
                             high=HEAP_BUDGET)
    assert heap is not None and heap <= HEAP_BUDGET
    for size, fits in ((heap, True), (heap - unixport.HEAP_STEP, False)):
        loop = unixport.flight_loop(mcu_words, manifest, regress.DEFAULT_SET, db_files,
                                    runs, size)
        assert (unixport.disagreements(loop, runs) == []) is fits, size


def test_the_frozen_image_is_the_mcu_image(tmp_path):
    """The staged tree holds exactly the MCU image: the root, the contract and the
    firmware, nothing of the ground."""
    staged = unixport.stage_mcu_image(tmp_path)
    files = sorted(str(p.relative_to(staged)) for p in staged.rglob("*.py"))
    assert "lodestar/__init__.py" in files and "lodestar/firmware/pipeline.py" in files
    assert "lodestar/contract/packet.py" in files
    assert all(f.startswith(("lodestar/firmware/", "lodestar/contract/")) or
               f == "lodestar/__init__.py" for f in files)


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
