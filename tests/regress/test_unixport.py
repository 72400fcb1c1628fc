"""The regression set on a real MicroPython 1.27 (:mod:`lodestar.regress.unixport`): the unix
port built 32-bit with single-precision floats in the object word (``MICROPY_OBJ_REPR_C``), as
the STM32F401's flight build, with the MCU image frozen by the repository's ``manifest.py``.

The build, and when its tests skip: ``tests/regress/conftest.py``.  The set's float32
expectations are the Cortex-M4F build's (``tests/regress/test_qemu.py``); the unix port
keeps what the x86 host does better: heap bisection (the heap is a run-time option here, a
build option there), valgrind's instruction counts and fast float32 runs of many frames
(``benchmarks/bench_float32.py``), and is held to the float32 bound of the flight build's
outcomes."""

import pytest

from lodestar.contract.stardb import METHODS
from lodestar.regress import replay, unixport
from tests import REPO

# one worker runs the file: the build's session fixtures run once (pyproject: loadgroup)
pytestmark = pytest.mark.xdist_group("unixport")

HEAP_BUDGET = 68 * 1024
"""Heap (bytes) within which every plain flight loop of the set runs on the 32-bit unix port
with the firmware's own collector setting, the STM32F401's, and a packet buffer for the
flight gateware's record capacity: the plain loop's figure on the Cortex-M4F build, 68,608
bytes (whose flight heap, ``qemu.FLIGHT_HEAP``, is larger for the executive;
``docs/mcu_board.md``).  This port runs the ``@native`` loops as bytecode; estcube2_rest_s0
with Pyramid runs out of heap at 66 KiB here too (fragmentation at the start of the
search)."""


def _runs(manifest, method, camera=None):
    return [(case, method) for case in manifest["cases"]
            if camera is None or case["camera"] == camera]


def _runs_all(manifest):
    return [run for method in manifest["methods"] for run in _runs(manifest, method)]


@pytest.mark.slow
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


def test_the_unix_port_stays_within_the_bound_of_the_flight_build(float32_frozen,
                                                                   regression_set):
    """Every case and method on the x86 unix port: the status and identified stars of the
    flight build's expectations (recorded on the Cortex-M4F build, ``test_qemu.py``), the
    attitude and sigmas within the set's float32 bound (x86 SSE and the ARM FPU with
    MicroPython's libm round differently in the last bits); the same outcomes bit for bit
    in the reverse order at another heap (the outcomes are the arithmetic's)."""
    manifest, db_files = regression_set
    got = unixport.float32_outcomes(float32_frozen, manifest, replay.DEFAULT_SET, db_files)
    bound = manifest["float32"]["bound"]
    problems = [(case["name"], method, d) for case, method in _runs_all(manifest)
                for d in replay.float32_vs_double(got[case["name"], method],
                                                   case["expected_float32"][method], bound)]
    assert problems == []
    runs = _runs_all(manifest)[::-1]
    loop = unixport.flight_loop(float32_frozen, manifest, replay.DEFAULT_SET, db_files, runs,
                                512 * 1024)
    assert loop["finished"]
    assert {key: out for key, (out, _peak) in loop["results"].items()} == got


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


def test_a_native_image_marks_the_same_functions_machine_code(tmp_path):
    """``native=True`` turns each ``@native`` of the firmware into ``@micropython.native``
    and its import into ``import micropython``, line for line, and changes nothing else; a
    plain image keeps the source as it is."""
    plain = unixport.stage_mcu_image(tmp_path / "plain")
    native = unixport.stage_mcu_image(tmp_path / "native", native=True)
    marked = 0
    for path in sorted(plain.rglob("*.py")):
        old = path.read_text().split("\n")
        new = (native / path.relative_to(plain)).read_text().split("\n")
        assert len(new) == len(old)
        for a, b in zip(old, new):
            if a.strip() == "@native":
                marked += 1
                assert b == a.replace("@native", "@micropython.native")
            elif a.endswith("emit import native") and a.startswith("from "):
                assert b == "import micropython"
            else:
                assert b == a
        assert "@native" not in new and "emit import native" not in "\n".join(new)
    assert marked >= 10


def test_native_source_rewrites_only_the_marker_lines():
    src = (b"from .emit import native\nfrom ..emit import natives\n\n@native\ndef f():\n"
           b"    @native\n    def g():\n        return '@native'\n    return g\n")
    assert unixport.native_source(src) == (
        b"import micropython\nfrom ..emit import natives\n\n@micropython.native\ndef f():\n"
        b"    @micropython.native\n    def g():\n        return '@native'\n    return g\n")
