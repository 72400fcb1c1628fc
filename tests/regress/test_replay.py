"""``lodestar regress``: the committed firmware regression set replays on CPython and on
MicroPython with the recorded outputs, and any difference, altered file or stale database
recipe is reported with exit status 1.

MicroPython runs through ``tools/micropython/run.mjs`` (skipped without Node.js and the npm
package unless ``LODESTAR_REQUIRE_MICROPYTHON`` is set, as ``tests/conftest.py`` says).  The
float32 build's replay and recording: ``test_qemu.py`` (these tests pass
``--no-float32``).
"""

import json
import math
import shutil
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.cli import main
from lodestar.contract.stardb import METHODS
from lodestar.firmware.settings import DEFAULT_TRACK_STARS
from lodestar.regress import mcu, micropython, qemu, record, replay, unixport


@pytest.fixture(autouse=True)
def cache_dir(tmp_path_factory, monkeypatch):
    """One database cache for the module (the first replay builds the set's databases)."""
    path = tmp_path_factory.getbasetemp() / "regress-cache"
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(path))
    return path


@pytest.fixture
def set_copy(tmp_path):
    """A writable copy of the committed set."""
    target = tmp_path / "set"
    shutil.copytree(replay.DEFAULT_SET, target)
    return target


def _manifest(path):
    return json.loads((path / "manifest.json").read_text())


def _write_manifest(path, manifest):
    (path / "manifest.json").write_text(json.dumps(manifest, indent=1))


def _case(manifest, name):
    return next(c for c in manifest["cases"] if c["name"] == name)


# --------------------------------------------------------------------------------------
# The committed set
# --------------------------------------------------------------------------------------

def test_committed_set_replays_on_cpython_and_micropython(capsys, require_micropython):
    assert main(["regress", "--no-float32"]) == 0
    out = capsys.readouterr().out
    manifest = _manifest(replay.DEFAULT_SET)
    n = len(manifest["cases"]) * len(manifest["methods"])
    assert f"all {n} replays agree with the recorded outputs on CPython and MicroPython" in out
    assert out.count(" same ") >= 2 * n          # a CPython and a MicroPython verdict per row
    assert "MicroPython heap:" in out


def test_set_covers_the_brief():
    """Several estcube2 attitudes and rates, clean failures, lohmann frames, false stars and
    hot pixels, corrupted packets with their status; every method; small committed data."""
    manifest = replay.load_set(replay.DEFAULT_SET)
    assert manifest["methods"] == list(replay.METHODS) == list(METHODS)
    cases = manifest["cases"]
    solved = [c for c in cases if all(o["status_name"] == "OK" for o in c["expected"].values())]
    est_rest = [c for c in solved if c["camera"] == "estcube2" and c["inputs"]["prior"] is None
                and c["truth"] and not any(c["truth"]["rate_deg_s"])]
    est_moving = [c for c in solved if c["camera"] == "estcube2" and
                  c["truth"] and any(c["truth"]["rate_deg_s"])]
    assert len(est_rest) >= 5 and len({tuple(c["truth"]["q"]) for c in est_rest}) == len(est_rest)
    assert len(est_moving) >= 3
    assert sum(c["camera"] == "lohmann" for c in cases) >= 3
    assert any(c["camera"] == "lohmann" for c in solved)
    assert any(c["expect"] == "fail" for c in cases)
    assert any("false" in c["name"] for c in solved)
    assert any(o["mode"] == "tracking" for c in solved for o in c["expected"].values())
    # the record budget: a solved dense frame asks for fewer blobs, and a frame detected
    # with its min_sum carries them and tracks
    by_name = {c["name"]: c for c in cases}
    dense, budgeted = by_name["estcube2_rest_s0"], by_name["estcube2_tracking_budget"]
    assert dense["expected"]["pyramid"]["min_sum"] > 0
    assert budgeted["truth"] == dense["truth"]
    assert DEFAULT_TRACK_STARS <= budgeted["expected"]["pyramid"]["n_records"] < \
        dense["expected"]["pyramid"]["n_records"] / 3
    statuses = {o["status_name"] for c in cases for o in c["expected"].values()}
    assert {"PACKET_BAD_CRC", "PACKET_TRUNCATED", "PACKET_BAD_LENGTH", "PACKET_BAD_MAGIC",
            "PACKET_BAD_HEADER", "PACKET_BAD_RECORD", "TOO_FEW_STARS", "BAD_INPUT",
            "NO_MATCH"} <= statuses
    for case in solved:
        for method, out in case["expected"].items():
            assert len(out["matches"]) >= 4 and out["sigma_cross_arcsec"] > 0
            err = case["error_arcsec"][method]
            assert math.hypot(err["cross"], err["roll"]) < 180
    size = sum(p.stat().st_size for p in replay.DEFAULT_SET.rglob("*") if p.is_file())
    assert size < 512 * 1024


def test_cpython_only_and_missing_micropython(monkeypatch, capsys):
    assert main(["regress", "--no-micropython", "--no-float32"]) == 0
    out = capsys.readouterr().out
    assert "agree with the recorded outputs on CPython\n" in out and "MicroPy" not in out
    monkeypatch.setattr(micropython, "unavailable_reason",
                        lambda: "node is not installed")
    assert main(["regress", "--no-float32"]) == 2
    assert "MicroPython unavailable: node is not installed" in capsys.readouterr().err


def test_missing_float32_build(monkeypatch, capsys, tmp_path):
    """Without the Cortex-M4F build (the float32 expectations' build) the replay stops with
    one line (exit status 2) unless told ``--no-float32``, and recording writes nothing."""
    monkeypatch.setattr(qemu, "unavailable_reason", lambda repo=None: "make is not installed")
    assert main(["regress", "--no-micropython"]) == 2
    err = capsys.readouterr().err
    assert err == ("lodestar regress: the Cortex-M4F build is unavailable: make is not "
                   "installed (or run with --no-float32)\n")
    assert main(["regress", "--record", "--set", str(tmp_path / "set")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "make is not installed; nothing recorded" in err
    assert not (tmp_path / "set").exists()


# --------------------------------------------------------------------------------------
# Differences are found
# --------------------------------------------------------------------------------------

def test_differences_fail_the_run(set_copy, capsys):
    manifest = _manifest(set_copy)
    moved = _case(manifest, "estcube2_rest_s1")["expected"]["triangle"]
    turn = Rotation.from_rotvec([0.0, 3e-9, 0.0])
    moved["q"] = list((turn * Rotation.from_quat(moved["q"])).as_quat())
    ids = _case(manifest, "lohmann_orion")["expected"]["pyramid"]
    ids["matches"][0][1] += 1
    status = _case(manifest, "corrupt_bit_flip")["expected"]["hashing"]
    status["status"] = 0
    sigma = _case(manifest, "estcube2_1dps")["expected"]["pyramid"]
    sigma["sigma_roll_arcsec"] *= 1 + 1e-6
    _write_manifest(set_copy, manifest)
    assert main(["regress", "--no-micropython", "--no-float32", "--set", str(set_copy)]) == 1
    out = capsys.readouterr().out
    n = len(manifest["cases"]) * len(manifest["methods"])
    assert f"4 of {n} replays differ:" in out
    assert "estcube2_rest_s1 / triangle: CPython vs expected: attitude differs by 3e-09 rad" \
        in out
    assert "lohmann_orion / pyramid: CPython vs expected: matches" in out
    assert "corrupt_bit_flip / hashing: CPython vs expected: status 0 vs" in out
    assert "estcube2_1dps / pyramid: CPython vs expected: sigma_roll_arcsec" in out
    assert out.count("DIFF") == 4


def test_differences_within_tolerance():
    tol = replay.TOLERANCES
    manifest = replay.load_set(replay.DEFAULT_SET)
    out = _case(manifest, "estcube2_rest_s0")["expected"]["pyramid"]
    assert replay.differences(out, out, tol) == []
    other = json.loads(json.dumps(out))
    other["q"] = [-c for c in out["q"]]                       # the same rotation
    other["sigma_cross_arcsec"] *= 1 + 0.5 * tol["sigma_relative"]
    assert replay.differences(out, other, tol) == []
    for angle, differs in ((0.5 * tol["q_rad"], False), (2 * tol["q_rad"], True)):
        turn = Rotation.from_rotvec([angle, 0.0, 0.0])
        other["q"] = list((turn * Rotation.from_quat(out["q"])).as_quat())
        assert bool(replay.differences(out, other, tol)) is differs
    other = json.loads(json.dumps(out))
    other["reason"] = "reworded"                              # text is not compared
    other["q"] = None
    assert replay.differences(out, other, tol) == [f"q {out['q']!r} vs None"]


def test_float32_bound():
    """A float32 outcome matches the double one when its status and identified stars are the
    same and its attitude and sigma figures are within :data:`FLOAT32_BOUND`."""
    bound = replay.FLOAT32_BOUND
    manifest = replay.load_set(replay.DEFAULT_SET)
    double = _case(manifest, "estcube2_rest_s0")["expected"]["pyramid"]
    f32 = json.loads(json.dumps(double))
    for angle, differs in ((0.9 * bound["q_rad"], False), (1.1 * bound["q_rad"], True)):
        f32["q"] = list((Rotation.from_rotvec([0.0, angle, 0.0]) *
                         Rotation.from_quat(double["q"])).as_quat())
        assert bool(replay.float32_vs_double(f32, double, bound)) is differs
    f32 = json.loads(json.dumps(double))
    f32["sigma_roll_arcsec"] *= 1 + 0.5 * bound["sigma_relative"]
    f32["patterns_tried"] += 1                     # not an identification: not compared
    assert replay.float32_vs_double(f32, double, bound) == []
    f32["sigma_roll_arcsec"] = double["sigma_roll_arcsec"] * (1 + 2 * bound["sigma_relative"])
    f32["matches"] = f32["matches"][:-1]
    f32["status"] = 1
    found = replay.float32_vs_double(f32, double, bound)
    assert [text.split()[0] for text in found] == ["status", "matches:", "sigma_roll_arcsec"]


def test_rotation_angle_matches_scipy():
    rng = np.random.default_rng(5)
    for scale in (1e-12, 1e-9, 1e-4, 1.0, 3.0):
        a = Rotation.random(random_state=rng)
        d = Rotation.from_rotvec(rng.normal(size=3) * scale / math.sqrt(3))
        b = d * a
        expected = d.magnitude()
        got = replay.rotation_angle(list(a.as_quat()), list(-b.as_quat()))
        assert got == pytest.approx(expected, rel=1e-6, abs=1e-15)


# --------------------------------------------------------------------------------------
# An unusable set is refused
# --------------------------------------------------------------------------------------

def test_altered_or_missing_packet(set_copy, capsys):
    packet = set_copy / "packets" / "estcube2_rest_s2.bin"
    data = bytearray(packet.read_bytes())
    data[9] ^= 1
    packet.write_bytes(bytes(data))
    assert main(["regress", "--no-micropython", "--no-float32", "--set", str(set_copy)]) == 1
    assert "estcube2_rest_s2: packets/estcube2_rest_s2.bin is not the recorded packet" in \
        capsys.readouterr().err
    packet.unlink()
    assert main(["regress", "--no-micropython", "--set", str(set_copy / "nowhere")]) == 2
    assert "no regression set in" in capsys.readouterr().err
    with pytest.raises(replay.RegressionError, match="case estcube2_rest_s2"):
        replay.load_set(set_copy)
    with pytest.raises(replay.RegressionError, match="no regression set"):
        replay.load_set(set_copy / "nowhere")
    manifest = _manifest(set_copy)
    manifest["format"] = 99
    _write_manifest(set_copy, manifest)
    with pytest.raises(replay.RegressionError, match="set format 99"):
        replay.load_set(set_copy)


def test_database_cache_and_recipe(tmp_path):
    """The database is rebuilt from its recipe into the cache, a damaged cache file is
    rebuilt, and a recipe that no longer gives the recorded image is refused."""
    manifest = replay.load_set(replay.DEFAULT_SET)
    entry = manifest["databases"]["lohmann"]
    one = {"databases": {"lohmann": entry}}
    path = replay.database_files(one, tmp_path)["lohmann"]
    assert path.parent == tmp_path and path.stat().st_size == entry["bytes"]
    path.write_bytes(b"garbage")
    assert replay.sha256(replay.database_files(one, tmp_path)["lohmann"].read_bytes()) == \
        entry["sha256"]
    path.unlink()
    entry["recipe"]["methods"] = ["pyramid"]
    with pytest.raises(replay.RegressionError, match="database lohmann: the recipe"):
        replay.database_files(one, tmp_path)


# --------------------------------------------------------------------------------------
# Recording
# --------------------------------------------------------------------------------------

def _tracker(manifest, camera, method):
    db = mcu.open_database(str(replay.database_files(manifest)[camera]))
    return mcu.make_tracker(db, manifest["cameras"][camera], method)


def test_recorder_remakes_a_committed_packet_and_checks_truth():
    """A frame of the set is simulated and detected again into the committed bytes; its
    replay is right against the truth, and a moved attitude or a wrong star is refused."""
    manifest = replay.load_set(replay.DEFAULT_SET)
    spec = next(c for c in record.CASES if c.name == "lohmann_cygnus")
    det, truth, data, inputs, truth_doc = record.frame_entry(spec)
    case = _case(manifest, spec.name)
    assert data == (replay.DEFAULT_SET / case["packet"]).read_bytes()
    assert inputs == case["inputs"] and truth_doc == case["truth"]
    out = mcu.replay(_tracker(manifest, "lohmann", "pyramid"), data, inputs)
    assert replay.differences(case["expected"]["pyramid"], out, replay.TOLERANCES) == []
    error, problem = record.check_truth(out, det, truth)
    assert problem is None and error == pytest.approx(case["error_arcsec"]["pyramid"])
    turned = dict(out, q=list((Rotation.from_rotvec([0.0, 0.0, math.radians(0.1)]) *
                               Rotation.from_quat(out["q"])).as_quat()))
    error, problem = record.check_truth(turned, det, truth)
    assert problem.startswith("WRONG solution") and math.hypot(error["cross"],
                                                               error["roll"]) > 300
    swapped = dict(out, matches=[[out["matches"][0][0], out["matches"][1][1]]] +
                   out["matches"][1:])
    assert "1 of" in record.check_truth(swapped, det, truth)[1]


def test_recorder_expectations():
    ok, fail = {"status_name": "OK"}, {"status_name": "NO_MATCH"}
    check = record.check_expect
    assert check("solve", {"a": ok, "b": ok}) is None
    assert "expected 'solve'" in check("solve", {"a": ok, "b": fail})
    assert check("fail", {"a": fail}) is None and check("fail", {"a": ok}) is not None
    assert check("any", {"a": ok, "b": fail}) is None
    assert check("NO_MATCH", {"a": fail}) is None and check("NO_MATCH", {"a": ok}) is not None
    with pytest.raises(ValueError, match="unknown derivation"):
        record.derive("melted", None)


# --------------------------------------------------------------------------------------
# The MicroPython harness
# --------------------------------------------------------------------------------------

def test_micropython_run_file_and_output_parsing(tmp_path):
    """The replay's run file holds every case with each method, the files as MicroPython
    opens them; the runner's output parses, and an unfinished replay raises."""
    manifest = replay.load_set(replay.DEFAULT_SET)
    runs = [(case, "hashing") for case in manifest["cases"]]
    micropython.write_runs(tmp_path / "runs.jsonl", manifest, runs,
                                   lambda name: f"/db/{name}", lambda case: case["packet"])
    lines = [json.loads(line) for line in (tmp_path / "runs.jsonl").read_text().splitlines()]
    case = manifest["cases"][0]
    camera = manifest["cameras"][case["camera"]]
    assert len(lines) == len(manifest["cases"])
    assert lines[0] == [case["name"], "hashing", case["camera"], camera["database"],
                        f"/db/{camera['database']}", camera, case["packet"], case["inputs"]]
    with pytest.raises(micropython.MicroPythonError, match="exit status 1"):
        micropython.parse_output(1, "RESIDENT {}\n", "Traceback: MemoryError")
    parsed = micropython.parse_output(
        0, 'RESIDENT {"code": 1}\nRESULT {"case": "c", "out": {}}\nLIVE_END 7\nDONE\n', "")
    assert parsed == {"resident": {"code": 1}, "results": [{"case": "c", "out": {}}],
                      "live_end": 7}


def test_the_mcu_loop_runs_on_cpython():
    """The loop both MicroPython runners run (:mod:`lodestar.regress.loop`) is plain Python:
    the flight loop on CPython (``python -m``, no heap figures) gives the recorded
    outcomes."""
    manifest = replay.load_set(replay.DEFAULT_SET)
    db_files = replay.database_files(manifest)
    runs = [(case, method) for method in manifest["methods"] for case in manifest["cases"]
            if case["camera"] == "lohmann"]
    loop = unixport.flight_loop(sys.executable, manifest, replay.DEFAULT_SET, db_files, runs,
                                64 * 1024, timeout=300)
    assert loop["finished"], loop["error"]
    assert set(loop["resident"]) == {manifest["cameras"]["lohmann"]["database"]}
    for case, method in runs:
        out, peak = loop["results"][case["name"], method]
        assert peak is None
        assert replay.differences(case["expected"][method], out, manifest["tolerances"]) == []


def test_runner_copies_files(tmp_path, require_micropython):
    """``run.mjs --copy HOST=TARGET`` puts host files into MicroPython's filesystem."""
    import subprocess

    data = tmp_path / "data.bin"
    data.write_bytes(b"\x00\x01lodestar")
    script = tmp_path / "s.py"
    script.write_text("print(open('/regress/x/data.bin', 'rb').read())\n")
    run = ["node", str(micropython.tool_dir() / "run.mjs")]
    proc = subprocess.run(run + ["--copy", f"{data}=/regress/x/data.bin", str(script)],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0 and "b'\\x00\\x01lodestar'" in proc.stdout
    for bad in (f"{data}=relative", f"{tmp_path / 'missing'}=/a"):
        proc = subprocess.run(run + ["--copy", bad, str(script)], capture_output=True,
                              text=True, timeout=60)
        assert proc.returncode == 2 and "--copy" in proc.stderr
