"""The ``lodestar`` command: the detect run prints a table, rejects bad input clearly."""

import json
import math
import subprocess
import sys

import numpy as np
import pytest

from lodestar.cli import main
from lodestar.firmware.camera import Camera


def test_detect_table_on_builtin_frame(capsys):
    assert main(["detect", "--width", "320", "--height", "240", "--stars", "8"]) == 0
    out = capsys.readouterr().out
    assert "frame: 320x240x12" in out and "truth dist px" in out
    rows = [line for line in out.splitlines() if line.strip()[:1].isdigit()]
    assert len(rows) >= 6


def test_detect_json_global_mode_and_streaming_engine(capsys):
    argv = ["detect", "--width", "160", "--height", "120", "--stars", "5", "--mode", "global",
            "--frames", "2", "--engine", "streaming", "--json"]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["summary"]["mode"] == "global" and report["summary"]["flags"] == 0
    assert report["summary"]["records"] == len(report["blobs"]) >= 3
    assert all(b["truth_px"] < 0.5 for b in report["blobs"])


def test_detect_npy_frame(tmp_path, capsys):
    frame = np.zeros((10, 12), np.uint16)
    frame[4:7, 5:8] = 900
    path = tmp_path / "f.npy"
    np.save(path, frame)
    assert main(["detect", "--frame", str(path), "--min-pixels", "1", "--min-sum", "0",
                 "--json"]) == 0
    (blob,) = json.loads(capsys.readouterr().out)["blobs"]
    assert (blob["n"], blob["x"], blob["y"]) == (9, 6.0, 5.0)


def test_bad_input_exits_2_with_message(tmp_path, capsys):
    path = tmp_path / "f.npy"
    np.save(path, np.full((4, 4), 5000, np.uint16))
    assert main(["detect", "--frame", str(path)]) == 2
    assert "exceeds full scale 4095" in capsys.readouterr().err
    assert main(["detect", "--width", "5000"]) == 2
    assert "--width must be in 1..4096, got 5000" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["detect", "--width", "0"], "--width must be in 1..4096, got 0"),
    (["detect", "--height", "-5"], "--height must be in 1..4096, got -5"),
    (["detect", "--stars", "-1"], "--stars must be in 0..100000"),
    (["detect", "--ksigma", "nan"], "ksigma must be a finite number"),
    (["detect", "--frame", "{npz}"], "not a .npy array file"),
    (["detect", "--frame", "{json}"], "not a .npy array file"),
    (["db", "build", "--fov", "20", "--aspect", "0", "-o", "{out}"], "aspect"),
    (["db", "build", "--fov", "20", "--aspect", "1e-9", "-o", "{out}"], "aspect"),
    # issue 33: one FOV range for every camera, a deep camera file, a missing folder
    (["db", "build", "--fov", "0.05", "-o", "{out}"], "--fov 0.05 deg is outside the 1 .. 90"),
    (["db", "build", "--fov", "95", "-o", "{out}"], "--fov 95 deg is outside the 1 .. 90"),
    (["db", "build", "--fov", "179.99", "-o", "{out}"], "--fov 180 deg is outside the 1 .. 90"),
    (["db", "build", "--camera", "{wide}", "-o", "{out}"], "horizontal FOV 164.9 deg is "
     "outside the 1 .. 90 deg"),
    (["db", "build", "--camera", "{deep}", "-o", "{out}"], "(nested too deep)"),
    (["db", "build", "-o", "{nowhere}"], "nowhere does not exist"),
    (["db", "build", "--fov", "20", "--density", "nan", "5", "-o", "{out}"],
     "stars per field must be in 1..1000, got nan"),
    (["simulate", "-o", ""], "-o '' must name the files' prefix"),
    (["solve", "{png}", "--camera", "{wide}"], "horizontal FOV 164.9 deg is outside"),
    (["solve", "{png}", "--camera", "{deep}"], "(nested too deep)"),
    (["calibrate", "{png}", "--camera", "{wide}", "-o", "{cam}"], "horizontal FOV 164.9 deg"),
    (["cosim", "{png}", "--config", "{list}"], "expected an object of DetectorConfig"),
    (["cosim", "{png}", "--config", "{unknown}"], "unknown fields colour"),
    (["cosim", "{png}", "--config", "{partial}"], "missing fields height"),
])
def test_bad_arguments_name_themselves_and_exit_2(tmp_path, capsys, argv, message):
    """Issue 19, item 9: one line naming the argument and its range, exit 2, no traceback,
    and no output file."""
    files = {"npz": tmp_path / "x.npz", "json": tmp_path / "x.json", "out": tmp_path / "db.bin",
             "png": tmp_path / "f.png", "list": tmp_path / "list.json",
             "unknown": tmp_path / "unknown.json", "partial": tmp_path / "partial.json"}
    np.savez(files["npz"], a=np.zeros((4, 4), np.uint16))
    files["json"].write_text('{"a": 1}')
    np.save(tmp_path / "f.npy", np.zeros((8, 8), np.uint16))
    files["png"] = tmp_path / "f.npy"
    files["list"].write_text("[1, 2]")
    files["unknown"].write_text('{"width": 8, "height": 8, "colour": 1}')
    files["partial"].write_text('{"width": 8}')
    files.update(wide=tmp_path / "wide.json", deep=tmp_path / "deep.json",
                 cam=tmp_path / "cam.json", nowhere=tmp_path / "nowhere" / "db.bin")
    files["wide"].write_text(json.dumps({"lodestar_camera": 1,
                                         "camera": Camera(752, 480, 50.0, 50.0).as_dict()}))
    files["deep"].write_text('{"lodestar_camera": 1, "camera": ' + "[" * 100000 +
                             "]" * 100000 + "}")
    code = main([a.format(**files) for a in argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "Traceback" not in err
    assert len(err.strip().splitlines()) == 1, err
    assert not files["out"].exists()


def test_detector_config_refuses_a_float_pixel_width():
    from lodestar.golden import DetectorConfig

    with pytest.raises(ValueError, match="pixel_bits=16.0 is not one of"):
        DetectorConfig(width=8, height=8, pixel_bits=16.0)


def test_python_dash_m():
    proc = subprocess.run([sys.executable, "-m", "lodestar", "detect", "--width", "64",
                           "--height", "48", "--stars", "2", "--json"],
                          capture_output=True, text=True, check=True)
    assert json.loads(proc.stdout)["summary"]["frame"] == "64x48x12"


def test_simulate_writes_frame_truth_and_preview(tmp_path, capsys):
    out = tmp_path / "orion"
    assert main(["simulate", "--preset", "lohmann", "--radec", "83.8", "-5.4", "10",
                 "--rate", "0.5", "0", "0", "--cosmic-rays", "2", "--seed", "3",
                 "-o", str(out)]) == 0
    from lodestar.sim import imageio
    frame = imageio.load_frame(f"{out}.png")
    truth = json.loads((tmp_path / "orion.json").read_text())
    assert frame.shape == (480, 752) and truth["preset"] == "lohmann"
    assert truth["omega_deg_s"] == [0.5, 0.0, 0.0] and len(truth["cosmic_rays"]) == 2
    assert {"Rigel", "Alnilam"} <= {s["name"] for s in truth["sources"]}
    assert (tmp_path / "orion_preview.png").stat().st_size > 1000
    assert "records" in capsys.readouterr().out


def test_simulate_bad_input(tmp_path, capsys):
    assert main(["simulate", "--quaternion", "0", "0", "0", "2", "-o", str(tmp_path / "x")]) == 2
    assert "error" in capsys.readouterr().err
    assert main(["simulate", "--exposure", "-1", "-o", str(tmp_path / "x")]) == 2
    assert "exposure_s must be > 0" in capsys.readouterr().err
    assert main(["simulate", "--time", "noon", "-o", str(tmp_path / "x")]) == 2
    assert "observation time 'noon'" in capsys.readouterr().err


def test_simulate_draws_aberrated_stars(tmp_path, capsys):
    """--time (the Earth's velocity) moves every star by the aberration: 20" across the
    apex, 0.7 px of estcube2."""
    args = ["simulate", "--radec", "90", "20", "0", "--seed", "4"]
    assert main(args + ["-o", str(tmp_path / "still")]) == 0
    assert main(args + ["--time", "2026-06-21T00:00:00", "-o", str(tmp_path / "moving")]) == 0
    capsys.readouterr()
    still = json.loads((tmp_path / "still.json").read_text())
    moving = json.loads((tmp_path / "moving.json").read_text())
    assert "velocity_km_s" not in still and 29 < math.hypot(*moving["velocity_km_s"]) < 31
    pos = {s["hip"]: (s["x"], s["y"]) for s in still["sources"] if s["kind"] == "star"}
    shifts = [math.hypot(s["x"] - pos[s["hip"]][0], s["y"] - pos[s["hip"]][1])
              for s in moving["sources"] if s["hip"] in pos]
    # (a star cut by the frame edge keeps the centroid of its part inside)
    assert len(shifts) > 20 and 0.6 < np.percentile(shifts, 5) and max(shifts) < 0.8


def test_db_build_and_info(tmp_path, capsys):
    out = tmp_path / "db.bin"
    assert main(["db", "build", "--fov", "15", "--mag", "5.5", "-o", str(out)]) == 0
    built = capsys.readouterr().out
    assert "total" in built and out.stat().st_size < 1 << 20
    assert main(["db", "info", str(out)]) == 0
    assert "fov_h: 15.000 deg" in capsys.readouterr().out
    from lodestar.firmware.database import Database
    from lodestar.sim.catalogue import load
    db = Database(out.read_bytes())
    assert db.n_stars == int((load().vmag <= 5.5).sum())
    assert main(["db", "build", "--fov", "15", "--mag", "4.0", "--method", "pyramid",
                 "triangle", "-o", str(tmp_path / "two.bin")]) == 0
    assert Database((tmp_path / "two.bin").read_bytes()).methods == 3
    data = bytearray(out.read_bytes())
    data[500] ^= 1
    (tmp_path / "bad.bin").write_bytes(bytes(data))
    assert main(["db", "info", str(tmp_path / "bad.bin")]) == 2
    assert "CRC" in capsys.readouterr().err
    assert main(["db", "build", "--fov", "0", "-o", str(out), "--force"]) == 2


def test_db_build_by_density(tmp_path, capsys):
    """``--density V P`` (as deep as each region needs with ``--mag none``) and ``--flight``
    (the flight database, within the 256 KiB budget); ``--mag none`` alone or with
    ``--flight`` is refused."""
    from lodestar.firmware.database import Database
    from lodestar.ground.onboard import FLIGHT_DENSITY
    out = tmp_path / "dense.bin"
    assert main(["db", "build", "--fov", "30", "--density", "20", "8", "--mag", "none",
                 "-o", str(out)]) == 0
    db = Database(out.read_bytes())
    assert db.mag_limit > 8.0                   # past the shipped catalogue where sparse
    per_fov = db.n_stars * (30 * 22.6) / 41253      # the sky holds 41,253 square degrees
    assert 16 < per_fov < 24, per_fov
    flight = tmp_path / "flight.bin"
    assert main(["db", "build", "--flight", "-o", str(flight)]) == 0
    db = Database(flight.read_bytes())
    assert flight.stat().st_size <= 256 * 1024 and db.mag_limit == 6.0
    assert db.pattern_per_region == FLIGHT_DENSITY["pattern_stars_per_fov"]
    capsys.readouterr()
    assert main(["db", "build", "--fov", "20", "--mag", "none", "-o", str(out), "--force"]) == 2
    assert "needs --density" in capsys.readouterr().err
    assert main(["db", "build", "--flight", "--mag", "5", "-o", str(out), "--force"]) == 2


def _minimal_args(command):
    return {"goldenset": ["goldenset", "small", "--out", "x"], "db": ["db", "info", "x"],
            "solve": ["solve", "x.png"], "cosim": ["cosim", "x.json"],
            "calibrate": ["calibrate", "x.png", "-o", "cam.json"],
            "campaign": ["campaign", "rate"]}.get(command, [command])


def test_command_modules_register_their_subcommands(capsys):
    import importlib

    from lodestar.cli import COMMANDS, build_parser

    parser = build_parser()
    for name in COMMANDS:
        module = importlib.import_module("lodestar.cli." + name)
        assert callable(module.add_parser) and callable(module.run)
        assert parser.parse_args(_minimal_args(name)).func.__module__ == module.__name__
    args = parser.parse_args(["demo", "--seed", "4"])
    assert args.func.__module__ == "lodestar.cli.demo" and args.seed == 4
    args = parser.parse_args(["solve", "sky.fits", "--fov", "12"])
    assert args.func.__module__ == "lodestar.cli.solve" and args.fov == 12.0
    with pytest.raises(SystemExit):
        main(["--help"])
    out = capsys.readouterr().out
    assert "demo" in out and "solve" in out
