"""Campaign results -> tables: per study, the rows of the CSV and the JSON summary, with the
theses' reference figures side by side.

Every table is computed from the trials' results (:mod:`lodestar.ground.campaign.trials`) in the
order of the task list, never in completion order, so it is the same whatever ran the
tasks.  Conventions of all tables:

* ``trials`` = ``right + wrong + failed``: ``wrong`` solved but judged wrong by
  :func:`lodestar.ground.truth.judge` (a record named as the wrong star, or an error
  beyond :data:`lodestar.ground.truth.WRONG_ARCSEC` that the solution's own covariance
  does not cover: counted apart), ``right`` every other solution, ``failed`` no attitude
  (any firmware status but OK).  ``imprecise`` counts the right solutions more than
  ``WRONG_ARCSEC`` off, within their covariance (few smeared stars, or lohmann's
  143-arcsec pixel at 2 px of added noise); ``wrong_matches`` the solutions that matched
  at least one record to the wrong star.  ``availability_pct`` (``success_pct``) =
  ``100 right / trials``, with the 95 % Wilson interval ``ci_low_pct``..``ci_high_pct``.
* Errors (arcsec, right solutions only): ``cross_1sigma`` = RMS of the two cross-boresight
  axes taken together (``sqrt(mean(x^2 + y^2) / 2)``, the per-axis 1-sigma of the goals),
  ``roll_1sigma`` = RMS of the roll error; ``cross_p50/p90/p99`` and ``roll_p50/p90/p99``
  percentiles of ``hypot(x, y)`` and ``|roll|``; ``sigma_cross_rms``, ``sigma_roll_rms`` =
  RMS of the firmware's reported 1-sigma (Shuster covariance).
* Missing numbers (nothing solved, no crossing) are empty in the CSV and null in the JSON.
"""

import csv
import io
import math

import numpy as np

from lodestar.ground.campaign import trials
from lodestar.ground.files import write_atomic
from lodestar.sim import photometry, presets, scene

DZAMBA_TABLE_4_1 = {1.0: (99.4, 96.8), 1.5: (89.5, 73.6), 2.0: (79.2, 58.7), 3.0: (45.6, 21.0)}
"""ST-16 spatial dynamic availability, %, with N >= 2 and N >= 3 stars, per cross-axis rate
(deg/s): Dzamba 2013 Table 4.1 (L1848-1855; ``/work/shared/notes/seed_004_dzamba.md``)."""
SCHUMANN_5DPS_PCT = 87.0
"""Schumann 2019 (L505): at 5 deg/s about 87 % of the sky shows >= 3 stars of V <= 4.5 to
ESTCube-2 (a sky-coverage fraction, not a measured solve rate)."""
SCHUMANN_SMEAR = {"m_static": 6.1, "k": 927.0, "c": 10.6, "t_s": 0.1, "r_px": 1000.0}
"""Schumann's spin-smear model (2019, L466-490): ``m_rot = m_static - log_2.512(t omega r /
sqrt((k e^-m_rot + c) / pi) + 1)``; ``k`` and ``c`` are the digest's reconstruction from
the quoted 4.5 / 4.0 / 3.5 / 3.0 at 5 / 10 / 20 / 40 deg/s (the thesis prints no values),
``r`` the star's distance from the image centre (px)."""
EQ_5_7_SNR = 10.0
"""Dzamba's R_t (Table 5.1) for Eq 5.7."""
EQ_5_7_RADIUS_SIGMAS = 2.5
"""PSF radius alpha_p of Eq 5.7 in PSF sigmas (the presets read Dzamba's radius as 2.5 to 3
sigma)."""


def wilson(k, n, z=1.96):
    """95 % Wilson score interval of a proportion ``k / n``, in %: ``(low, high)``."""
    if n == 0:
        return None, None
    p = k / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return 100 * max(0.0, centre - half), 100 * min(1.0, centre + half)


def _rms(values):
    return float(np.sqrt(np.mean(np.square(values)))) if len(values) else None


def _pct(values, q):
    return float(np.percentile(values, q)) if len(values) else None


def outcome_stats(verdicts):
    """The counts and error statistics of the module docstring over ``verdicts``."""
    n = len(verdicts)
    right = [v for v in verdicts if v["solved"] and not v["wrong"]]
    wrong = sum(v["wrong"] for v in verdicts)
    low, high = wilson(len(right), n)
    row = {"trials": n, "right": len(right), "wrong": wrong, "failed": n - len(right) - wrong,
           "imprecise": sum(bool(v.get("imprecise")) for v in right),
           "wrong_matches": sum(v["wrong_matches"] > 0 for v in verdicts),
           "availability_pct": 100 * len(right) / n if n else None,
           "ci_low_pct": low, "ci_high_pct": high}
    err = np.array([v["error_arcsec"] for v in right]).reshape(-1, 3)
    sig = np.array([v["sigma_arcsec"] for v in right]).reshape(-1, 2)
    cross = np.hypot(err[:, 0], err[:, 1])
    row["cross_1sigma"] = _rms(err[:, :2].ravel())
    row["roll_1sigma"] = _rms(err[:, 2])
    for q in (50, 90, 99):
        row[f"cross_p{q}"] = _pct(cross, q)
        row[f"roll_p{q}"] = _pct(np.abs(err[:, 2]), q)
    row["sigma_cross_rms"] = _rms(sig[:, 0])
    row["sigma_roll_rms"] = _rms(sig[:, 1])
    row["mean_matches"] = float(np.mean([v["n_matches"] for v in right])) if right else None
    return row


def _grouped(tasks, results):
    """``{(preset, level): [result, ...]}`` in task order."""
    groups = {}
    for task in tasks:
        _study, preset, level, _trial = task
        groups.setdefault((preset, level), []).append(results[trials.task_key(task)])
    return groups


def rate_table(tasks, results):
    """``rate``: one row per preset and rate, with Dzamba's and Schumann's figures."""
    rows = []
    for (preset, level), verdicts in _grouped(tasks, results).items():
        rate = float(level)
        dz = DZAMBA_TABLE_4_1.get(rate, (None, None))
        row = {"preset": preset, "rate_deg_s": rate}
        row.update(outcome_stats(verdicts))
        row.update({"dzamba_st16_n2_pct": dz[0], "dzamba_st16_n3_pct": dz[1],
                    "schumann_sky_pct": SCHUMANN_5DPS_PCT if rate == 5.0 else None})
        rows.append(row)
    return rows


def falsestars_table(tasks, results):
    """``falsestars``: one row per preset, sweep (``false_stars`` or ``noise_px``), level
    and method."""
    rows = []
    for (preset, level), outs in _grouped(tasks, results).items():
        if level.startswith("false="):
            for method in trials.METHODS:
                row = {"preset": preset, "sweep": "false_stars", "level": int(level[6:]),
                       "method": method}
                row.update(outcome_stats([o[method] for o in outs]))
                rows.append(row)
        else:
            for method in trials.METHODS:
                for sigma in trials.NOISE_PX:
                    row = {"preset": preset, "sweep": "noise_px", "level": sigma,
                           "method": method}
                    row.update(outcome_stats([o[method][f"{sigma:g}"] for o in outs]))
                    rows.append(row)
    return rows


def schumann_limiting_magnitude(rate_deg_s, m_static=None, k=None, c=None, t_s=None,
                                r_px=None):
    """Schumann's spin-limited magnitude (:data:`SCHUMANN_SMEAR`, whose values are the
    defaults), solved by bisection: V mag."""
    p = dict(SCHUMANN_SMEAR)
    p.update({name: value for name, value in (("m_static", m_static), ("k", k), ("c", c),
                                              ("t_s", t_s), ("r_px", r_px))
              if value is not None})
    trail = p["t_s"] * math.radians(rate_deg_s) * p["r_px"]

    def excess(m):
        radius = math.sqrt((p["k"] * math.exp(-m) + p["c"]) / math.pi)
        return m - (p["m_static"] - math.log(trail / radius + 1.0, 2.512))

    lo, hi = -10.0, p["m_static"]
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if excess(mid) < 0 else (lo, mid)
    return 0.5 * (lo + hi)


def eq_5_7_magnitude(cam, exposure_s, rate_deg_s):
    """Dzamba's Eq 5.7 (1/4 restored: :func:`lodestar.sim.photometry.limiting_magnitude`)
    for the preset ``cam`` at ``exposure_s``: R_t = :data:`EQ_5_7_SNR`, alpha_p =
    :data:`EQ_5_7_RADIUS_SIGMAS` PSF sigmas, sigma_e the read noise with the dark and sky
    shot noise of the exposure folded in (the model of
    :func:`lodestar.sim.scene.detector_config`)."""

    dark_e = (cam.dark_current_e_per_s + scene.SKY_E_PER_PX_S) * exposure_s
    noise = math.sqrt(cam.read_noise_e ** 2 + dark_e)
    return float(photometry.limiting_magnitude(
        cam.aperture_mm, cam.f_number, cam.pixel_pitch_um, noise, cam.qe, exposure_s,
        rate_deg_s, EQ_5_7_RADIUS_SIGMAS * cam.psf_sigma_px, EQ_5_7_SNR))


def half_detection_magnitude(centres, total, found, min_stars=5):
    """The magnitude where the detected fraction first falls through 50 % (from the bright
    side), linear between bin centres with at least ``min_stars`` stars; None when it never
    does."""
    pts = [(m, f / t) for m, t, f in zip(centres, total, found) if t >= min_stars]
    for (m0, f0), (m1, f1) in zip(pts, pts[1:]):
        if f0 >= 0.5 > f1:
            return m0 + (f0 - 0.5) / (f0 - f1) * (m1 - m0)
    return None


def limiting_table(tasks, results, config):
    """``limiting``: per preset and rate the stars counted, the simulated 50 % detection
    magnitude (``m50_sim``), Eq 5.7 (``eq57_m_t``) and Schumann's spin model at
    ``r = 1000 px`` (``schumann_m_rot``; None at rest, where it gives its ``m_static``),
    and the detection curve (``curve``: bin centre, stars, detected; JSON only)."""

    lo, _hi = trials.LIMITING_MAG_RANGE
    rows = []
    for (preset, level), outs in _grouped(tasks, results).items():
        total = np.sum([o["total"] for o in outs], axis=0)
        found = np.sum([o["found"] for o in outs], axis=0)
        centres = lo + trials.LIMITING_BIN_MAG * (np.arange(len(total)) + 0.5)
        cam = presets.load_preset(preset)
        exposure = config["camera"][preset]["exposure_s"] or cam.exposure_s
        rate = float(level)
        m50 = half_detection_magnitude(centres, total, found)
        rows.append({
            "preset": preset, "rate_deg_s": rate, "frames": len(outs),
            "stars": int(total.sum()), "detected": int(found.sum()), "m50_sim": m50,
            "eq57_m_t": eq_5_7_magnitude(cam, exposure, rate),
            "schumann_m_rot": schumann_limiting_magnitude(rate) if rate > 0 else None,
            "curve": [[float(m), int(t), int(f)] for m, t, f in zip(centres, total, found)
                      if t]})
    return rows


def accuracy_table(tasks, results):
    """``accuracy``: per preset and star cap, the errors against the firmware's reported
    sigmas; ``ratio_cross``, ``ratio_roll`` = measured 1-sigma / reported RMS sigma (1 for a
    consistent covariance)."""
    rows = []
    for (preset, _level), outs in _grouped(tasks, results).items():
        for cap in trials.STAR_CAPS:
            row = {"preset": preset, "stars_kept": cap}
            row.update(outcome_stats([o[str(cap)] for o in outs]))
            for axis in ("cross", "roll"):
                measured, reported = row[f"{axis}_1sigma"], row[f"sigma_{axis}_rms"]
                row[f"ratio_{axis}"] = measured / reported if measured and reported else None
            rows.append(row)
    return rows


def fov_table(tasks, results):
    """``fov``: one row per preset and horizontal FOV: the camera of
    :func:`lodestar.ground.campaign.trials.fov_camera` (vertical FOV, focal length,
    aperture, rendered depth), the database's star count, the outcomes and the CPython
    solve time (p50, p95 over every frame, ms)."""
    rows = []
    for (preset, level), verdicts in _grouped(tasks, results).items():
        cam = trials.fov_camera(preset, float(level))
        fov_h, fov_v, _diag = cam.fov_deg()
        row = {"preset": preset, "fov_deg": float(level), "fov_v_deg": float(fov_v),
               "focal_length_mm": cam.focal_length_mm, "aperture_mm": cam.aperture_mm,
               "render_mag": trials.fov_render_limit(preset, cam),
               "db_stars": verdicts[0]["db_stars"]}
        row.update(outcome_stats(verdicts))
        ms = [v["solve_ms"] for v in verdicts]
        row.update({"solve_ms_p50": _pct(ms, 50), "solve_ms_p95": _pct(ms, 95)})
        rows.append(row)
    return rows


def tables(study, tasks, results, config):
    """The rows of ``study``'s table (one dict per row, the CSV's columns in order)."""
    if study == "rate":
        return rate_table(tasks, results)
    if study == "falsestars":
        return falsestars_table(tasks, results)
    if study == "limiting":
        return limiting_table(tasks, results, config)
    if study == "accuracy":
        return accuracy_table(tasks, results)
    if study == "fov":
        return fov_table(tasks, results)
    raise ValueError(f"unknown study {study!r}")


def write_csv(path, rows):
    """Rows as CSV (columns of the first row; lists such as ``curve`` are left out)."""
    columns = [k for k, v in rows[0].items() if not isinstance(v, list)] if rows else []
    text = io.StringIO(newline="")
    writer = csv.writer(text)
    writer.writerow(columns)
    for row in rows:
        writer.writerow(["" if row[c] is None else
                         (f"{row[c]:.6g}" if isinstance(row[c], float) else row[c])
                         for c in columns])
    write_atomic(path, text.getvalue())
