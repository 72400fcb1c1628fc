"""Campaign tables: outcome accounting (wrong apart from failed), statistics and the
theses' reference models."""

import math

import pytest

from lodestar.ground.campaign import tables
from lodestar.sim import photometry, presets


def v(solved=True, wrong=False, wrong_matches=0, error=(1.0, -1.0, 10.0), sigma=(1.0, 9.0)):
    return {"status": "WRONG" if wrong else ("OK" if solved else "NO_MATCH"),
            "solved": solved, "wrong": wrong, "wrong_matches": wrong_matches,
            "n_matches": 10 if solved else 0, "n_records": 12,
            "error_arcsec": list(error) if solved else None,
            "sigma_arcsec": list(sigma) if solved else None}


def test_wrong_solutions_are_counted_apart_from_failures():
    row = tables.outcome_stats([v(), v(error=(3.0, 3.0, -30.0)), v(wrong=True, wrong_matches=4,
                                                                  error=(900.0, 0.0, 0.0)),
                                v(solved=False), v(wrong_matches=1)])
    assert (row["trials"], row["right"], row["wrong"], row["failed"]) == (5, 3, 1, 1)
    assert row["wrong_matches"] == 2
    assert row["availability_pct"] == pytest.approx(60.0)
    # the wrong attitude stays out of the error statistics
    assert row["cross_1sigma"] == pytest.approx(math.sqrt((1 + 1 + 9 + 9 + 1 + 1) / 6))
    assert row["roll_1sigma"] == pytest.approx(math.sqrt((100 + 900 + 100) / 3))
    assert row["roll_p50"] == pytest.approx(10.0)
    assert row["sigma_roll_rms"] == pytest.approx(9.0)


def test_nothing_solved_leaves_the_errors_empty():
    row = tables.outcome_stats([v(solved=False)] * 3)
    assert row["failed"] == 3 and row["availability_pct"] == 0.0
    assert row["cross_1sigma"] is None and row["cross_p90"] is None
    assert row["mean_matches"] is None


def test_wilson_interval():
    low, high = tables.wilson(200, 200)
    assert high == pytest.approx(100.0) and low == pytest.approx(98.12, abs=0.01)
    low, high = tables.wilson(50, 100)
    assert low == pytest.approx(40.38, abs=0.01) and high == pytest.approx(59.62, abs=0.01)
    assert tables.wilson(0, 0) == (None, None)


def test_schumann_model_reproduces_the_digest_table():
    # seed_003_schumann.md: r = 1000 px column of the reconstructed model
    for rate, m in ((1, 5.46), (3, 4.84), (5, 4.50), (10, 4.00), (20, 3.50), (40, 3.00),
                    (360, 1.43)):
        assert tables.schumann_limiting_magnitude(rate) == pytest.approx(m, abs=0.006)
    assert tables.schumann_limiting_magnitude(5, r_px=100) == pytest.approx(5.72, abs=0.006)


def test_eq_5_7_is_the_photometry_formula_with_the_dark_noise():
    cam = presets.load_preset("estcube2")
    got = tables.eq_5_7_magnitude(cam, 0.1, 1.0)
    noise = math.sqrt(cam.read_noise_e ** 2 + (cam.dark_current_e_per_s + 5.0) * 0.1)
    assert got == pytest.approx(photometry.limiting_magnitude(
        cam.aperture_mm, cam.f_number, 2.2, noise, cam.qe, 0.1, 1.0, 5.0, 10.0))
    assert tables.eq_5_7_magnitude(cam, 0.1, 0.0) > got


def test_half_detection_magnitude():
    centres = [4.125, 4.375, 4.625, 4.875]
    assert tables.half_detection_magnitude(centres, [10, 10, 10, 10], [10, 8, 2, 0]) == \
        pytest.approx(4.375 + 0.25 * 0.3 / 0.6)
    assert tables.half_detection_magnitude(centres, [10, 10, 10, 10], [10] * 4) is None
    # bins with too few stars are skipped
    assert tables.half_detection_magnitude(centres, [10, 1, 10, 10], [10, 0, 0, 0]) == \
        pytest.approx(4.125 + 0.25)


def test_csv_leaves_out_lists_and_blanks_none(tmp_path):
    path = tmp_path / "t.csv"
    tables.write_csv(path, [{"a": 1, "b": None, "c": 0.123456789, "curve": [[1, 2]]}])
    assert path.read_text().splitlines() == ["a,b,c", "1,,0.123457"]


def test_fov_table_counts_times_and_describes_the_camera():
    tasks = [("fov", "estcube2", level, t) for level in ("5", "40") for t in range(3)]
    results = {}
    for (_s, _p, level, t) in tasks:
        out = v(solved=t != 2 or level == "40")
        results[f"fov/estcube2/{level}/{t}"] = dict(out, solve_ms=10.0 * (t + 1),
                                                  db_stars=100 if level == "5" else 7)
    rows = tables.tables("fov", tasks, results, {})
    assert [(r["fov_deg"], r["right"], r["failed"], r["db_stars"]) for r in rows] == [
        (5.0, 2, 1, 100), (40.0, 3, 0, 7)]
    assert rows[0]["solve_ms_p50"] == pytest.approx(20.0)
    assert rows[0]["solve_ms_p95"] == pytest.approx(29.0)
    # the camera: the estcube2 sensor at f/1.2, 5 deg wide, 3.75 deg high
    assert rows[0]["fov_v_deg"] == pytest.approx(3.751, abs=1e-3)
    assert rows[0]["focal_length_mm"] / rows[0]["aperture_mm"] == pytest.approx(
        presets.load_preset("estcube2").f_number)
    assert rows[0]["render_mag"] > rows[1]["render_mag"]
