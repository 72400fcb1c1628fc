"""The outputs: CSV and JSON of every step and the plot, written whole, and the summary."""

import csv
import json

from lodestar.fly import report

ROWS = [{"index": 0, "t_s": 0.0, "status": "NO_FRAME", "mode": "CONFIGURE",
         "error_arcsec": None, "mcu_ms": 0.1, "records": 0, "faults": [], "frame": None,
         "solve": None, "level": 0, "wrong": False, "reported": None,
         "reported_error_arcsec": None, "sigma_cross_arcsec": None, "sigma_roll_arcsec": None,
         "beyond_5sigma": False, "beyond_180": False},
        {"index": 1, "t_s": 0.4, "status": "OK", "mode": "TRACK", "error_arcsec": 3.2,
         "mcu_ms": 350.0, "records": 60, "faults": ["miso-flip"], "frame": 0,
         "solve": "lost_in_space", "level": 0, "wrong": False, "reported": "fused",
         "reported_error_arcsec": {"x": 1.0, "y": -1.0, "roll": 2.9, "total": 3.2},
         "sigma_cross_arcsec": 0.5, "sigma_roll_arcsec": 0.5, "beyond_5sigma": True,
         "beyond_180": False}]
SUMMARY = {"frames_played": 4, "steps": 2, "first_solve_step": 1, "first_solve_t_s": 0.4,
           "solved": 1, "lost_in_space_solves": 1, "tracking_solves": 0,
           "availability_after_first": 1.0, "wrong": 0, "max_error_arcsec": 3.2,
           "rms_error_arcsec": 3.2, "mcu_ms_mean": 175.0, "watchdog_max_gap_ms": 350.0,
           "reboots": 0, "recovery": {}, "health": {"ok": 1}, "link": {"packets": 1},
           "reported": 1, "reported_fused": 1, "reported_availability_after_first": 1.0,
           "reported_max_error_arcsec": 3.2, "reported_beyond_5sigma": 1,
           "reported_beyond_180": 0}
META = {"preset": "estcube2", "trajectory": "rest", "rate_deg_s": [0.0, 0.0, 0.0]}


def test_files_and_json_document(tmp_path):
    doc = report.document(ROWS, SUMMARY, "golden", "cpython", META)
    paths = report.write(tmp_path / "run", ROWS, doc, "title")
    assert [p.name for p in paths] == ["telemetry.csv", "telemetry.json", "fly.png"]
    got = json.loads(paths[1].read_text())
    assert got["engine"] == "golden" and got["mcu"] == "cpython"
    assert set(got["frames"][1]) >= {"index", "t_s", "status", "mode", "error_arcsec",
                                     "mcu_ms", "records", "faults"}
    assert got["frames"][0]["error_arcsec"] is None
    assert got["frames"][1]["reported"] == "fused" and got["frames"][1]["beyond_5sigma"]
    assert got["frames"][1]["reported_error_arcsec"]["roll"] == 2.9
    table = list(csv.DictReader(paths[0].open()))
    assert table[1]["faults"] == "miso-flip" and table[0]["error_arcsec"] == ""
    assert paths[2].read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not [p for p in (tmp_path / "run").iterdir() if p.name.startswith(".")]


def test_summary_text():
    text = report.summary_text(SUMMARY, "golden", "cpython", META)
    assert "wrong         0" in text and "1 lost in space" in text
    assert "reported      1 (1 fused)" in text and "beyond 5 sigma 1" in text
