"""``lodestar demo``: the chain solves a simulated frame right, says so, and says when not."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.cli import demo, main
from lodestar.ground import onboard


@pytest.fixture(autouse=True)
def cache_dir(tmp_path_factory, monkeypatch):
    """One database cache for this module (the first demo builds it)."""
    path = tmp_path_factory.getbasetemp() / "demo-cache"
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(path))
    return path


def test_attitude_error_components():
    q = np.array([0.1, -0.2, 0.3, 0.9])
    q /= np.linalg.norm(q)
    tiny = math.radians(10 / 3600)
    for axis, key in ((0, "x"), (1, "y"), (2, "roll")):
        rotvec = np.zeros(3)
        rotvec[axis] = tiny
        moved = (Rotation.from_rotvec(rotvec) * Rotation.from_quat(q)).as_quat()
        err = demo.attitude_error_arcsec(moved, q)
        assert err[key] == pytest.approx(10.0, abs=1e-6)
        assert err["total"] == pytest.approx(10.0, abs=1e-6)
        assert err["cross"] == pytest.approx(0.0 if key == "roll" else 10.0, abs=1e-6)


def test_default_demo_solves_right_and_writes_the_picture(tmp_path, capsys, monkeypatch):
    cache_dir = tmp_path / "fresh-cache"
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(cache_dir))
    out = tmp_path / "demo.png"
    assert main(["demo", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "the first run builds it" in captured.err
    assert "built the star database for estcube2" in captured.err
    assert f"cached in {cache_dir}" in captured.err
    text = captured.out
    assert "status     OK" in text and "cross-boresight" in text and "Alderamin" in text
    assert out.stat().st_size > 100_000
    assert main(["demo", "--out", str(out), "--json", "--force"]) == 0
    captured = capsys.readouterr()
    assert f"read the star database from the cache {cache_dir}" in captured.err
    r = json.loads(captured.out)
    assert r["status"] == r["solver_status"] == "OK" and r["preset"] == "estcube2"
    assert r["error_arcsec"]["cross"] < 3 and abs(r["error_arcsec"]["roll"]) < 30
    assert r["matches_wrong"] == 0 and r["matches_right"] == len(r["matches"]) >= 10
    assert {m["hip"] for m in r["matches"]} >= {105199}            # Alderamin
    assert all(m["right"] and m["truth_offset_px"] < 1 for m in r["matches"])
    s = r["solution"]
    assert 0 < s["sigma_cross_arcsec"] < 3 and 0 < s["sigma_roll_arcsec"] < 30
    assert set(r["timings_ms"]) == {"simulate", "detect", "packet", "database", "solve",
                                    "annotate", "total"}
    assert {"decode", "identify", "total"} <= set(r["firmware_ms"])
    assert r["detector"]["packet_bytes"] > 0 and r["annotated"] == str(out)


def test_turning_frame_is_rate_compensated():
    r = demo.run_demo(seed=3, rate_deg_s=(0.5, 0.3, 0.2), out=None, log=None)
    assert r["status"] == "OK" and r["annotated"] is None
    assert r["error_arcsec"]["cross"] < 10 and abs(r["error_arcsec"]["roll"]) < 60
    assert r["rate_deg_s"] == [0.5, 0.3, 0.2]


def test_the_default_picture_is_the_demos_own(tmp_path, capsys, monkeypatch):
    """Without --out the demo makes its folder and replaces its own picture on every run
    (a file the user names follows the --force rule: tests/ground/test_files.py)."""
    monkeypatch.chdir(tmp_path)
    for _run in range(2):
        assert main(["demo", "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["annotated"] == demo.DEFAULT_OUT
    assert (tmp_path / demo.DEFAULT_OUT).stat().st_size > 100_000


def test_no_stars_fails_with_exit_1(tmp_path, capsys):
    out = tmp_path / "dark.png"
    assert main(["demo", "--exposure", "0.0001", "--out", str(out)]) == 1
    text = capsys.readouterr().out
    assert "solution   none: TOO_FEW_STARS" in text and "no attitude" in text
    assert out.exists()                       # the picture still shows what was seen


def test_a_wrong_solution_is_reported_and_fails(monkeypatch, capsys, tmp_path):
    real = onboard.process

    def off_by_a_tenth_of_a_degree(*args, **kwargs):
        data, res, timings = real(*args, **kwargs)
        res.q = list((Rotation.from_rotvec([math.radians(0.1), 0, 0]) *
                      Rotation.from_quat(res.q)).as_quat())
        return data, res, timings

    monkeypatch.setattr(onboard, "process", off_by_a_tenth_of_a_degree)
    assert main(["demo", "--json", "--out", str(tmp_path / "wrong.png")]) == 1
    r = json.loads(capsys.readouterr().out)
    assert r["status"] == "WRONG" and r["solver_status"] == "OK"
    assert r["error_arcsec"]["total"] == pytest.approx(360.0, abs=5.0)


def test_cosim_detects_through_lodestar_cosim(monkeypatch):
    from lodestar.golden import detect_frame

    calls = []

    def run_frames(frames, cfg, log=None):
        calls.append((len(frames), frames[0].shape, cfg.threshold_mode))
        return [detect_frame(f, cfg) for f in frames]

    monkeypatch.setattr("lodestar.cosim.runner.run_frames", run_frames)
    r = demo.run_demo(cosim=True, out=None, log=None)
    assert calls == [(1, (1944, 2592), "fixed")]
    assert r["detector"]["engine"] == "cosim" and r["status"] == "OK"


def test_cosim_unavailable_is_a_clear_error(monkeypatch):
    monkeypatch.setitem(sys.modules, "lodestar.cosim.runner", None)      # import fails
    monkeypatch.delattr("lodestar.cosim.runner", raising=False)
    with pytest.raises(ValueError, match="--cosim needs the co-simulation"):
        demo._detect(np.zeros((4, 4), np.uint16), None, cosim=True)


@pytest.mark.slow
def test_cosim_demo_on_the_verilated_gateware(tmp_path, capsys, cache_dir):
    assert main(["demo", "--cosim", "--json", "--out", str(tmp_path / "d.png")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["detector"]["engine"] == "cosim" and report["status"] == "OK"


def test_bad_arguments_exit_2(capsys):
    assert main(["demo", "--rate", "nan", "0", "0"]) == 2
    assert "--rate must be 3 finite numbers" in capsys.readouterr().err
    assert main(["demo", "--exposure", "-1"]) == 2
    assert "exposure_s must be > 0" in capsys.readouterr().err


def test_entry_point_exit_status(tmp_path, cache_dir):
    proc = subprocess.run([sys.executable, "-m", "lodestar", "demo", "--seed", "1", "--json",
                           "--out", str(tmp_path / "d.png")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["status"] == "OK"
