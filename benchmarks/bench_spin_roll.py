"""What bounds the roll about the boresight in a fast spin: per star and per frame, on the
rate campaign's frames solved by the flight loop, at each exposure.

    .venv/bin/python benchmarks/bench_spin_roll.py [--rate 30] [--trials 50]
        [--ksigma 3.0 2.5 2.0] [--exposures 0.1 0.05] [--registers follow fixed]
        [--margins 1.0 0.5] [--summary] [--workers 1]

Each trial is ``bench_rate_honesty.py``'s ``track`` solve (the rate campaign's frame about
the boresight at ``--rate`` deg/s, estcube2 tuned, the gyro exact, the prior 0.1 s old),
rendered at each ``--exposures`` (s; the same attitude, rate and noise seed) and detected
at each ``--ksigma`` (the fixed threshold ``B + ceil(ksigma sigma)``; the tuned setting is
3.0) with the detector's registers of each ``--registers``: ``follow``, those of the
frame's exposure (``ground.onboard.detector_config``: the background and the noise the
dark current and sky give in that time), or ``fixed``, those of the flight exposure 0.1 s
written once at configuration (what the executive writes; a shorter exposure then meets a
threshold set over a higher background).  ``--summary``: the per-configuration table alone
(statuses, wrong: beyond 5 sigma on an axis at the reported instant or beyond 180",
median reported roll sigma of the identified frames, largest ``OK`` error).

The inputs of the solution's last attitude fit are captured
(``StarTracker.attitude`` wrapped): per matched star its direction, its catalogue
direction and its partly seen track (tangent and ``unseen`` half-track).  Against the true
attitude at the epoch it prints, per configuration (exposure, registers, ksigma):

* the statuses and the median reported roll sigma (arcsec);
* per ``unseen`` class the along-track error (px): RMS and the largest excess over
  ``unseen`` (a track's true middle lies within ``unseen`` of its extent's middle);
* interval constraints: with the cross-boresight axes as fitted, each star bounds the roll
  to ``(a_i +- (unseen_i + m)) / k_i`` (``a_i`` its along-track residual, ``k_i`` the px a
  radian of roll moves it along its track, ``m`` each ``--margins`` px); how many frames'
  intersections are empty, the others' half-width (median, range), and how many hold the
  truth;
* an oracle covariance: each star's along-track sigma the RMS measured for its class,
  across 0.3 px, not scaled by the residuals: the roll sigma (range) and how many frames'
  5-sigma bound ``5 sqrt(2 c^2 + r^2)`` is within 180".
"""

import argparse
import math
import multiprocessing
import statistics

import numpy as np

from lodestar.firmware import pipeline
from lodestar.firmware import quaternion as Q
from lodestar.golden import detect_frame
from lodestar.ground.campaign import trials
from lodestar.ground.onboard import camera_settings, detector_config

ARCSEC = math.degrees(1.0) * 3600.0
UNSEEN_CLASSES_PX = ((0.0, 1.0), (1.0, 2.0), (2.0, 4.0), (4.0, 8.0), (8.0, math.inf))
"""The ``unseen`` classes (px, lower bound inclusive) of the along-track table."""
ACROSS_PX = 0.3
"""The oracle's across-track sigma (px): the measured 0.1-0.8 px RMS (docs/campaigns.md)."""
LIMIT_ARCSEC = 180.0
FRAME_PERIOD_S = 0.1
FLIGHT_EXPOSURE_S = 0.1
"""The exposure the flight registers are computed for (``lodestar.fly.twin.EXPOSURE_S``)."""

_captured = {}


def _capture(self, vectors, star_ids, fluxes=None, floor=True, streaks=None, q0=None,
             fitted=False):
    """``StarTracker.attitude``, keeping its inputs and output for the analysis."""
    out = _original(self, vectors, star_ids, fluxes, floor, streaks, q0, fitted)
    _captured["fit"] = ([vectors[o] for o, _s in star_ids], self._catalogue(star_ids),
                        [streaks[o] if streaks else None for o, _s in star_ids],
                        self.focal_px, out)
    return out


_original = pipeline.StarTracker.attitude


def stars_of(fit, q_true):
    """Per matched star of a captured fit: ``(unseen px, along error px, along residual px,
    k px/rad, along Jacobian, across Jacobian)`` and the roll (rad) that turns the fitted
    attitude into the truth."""
    b, r, streaks, focal, out = fit
    est = np.array(Q.matrix(out[0])).reshape(3, 3)
    true = np.array(Q.matrix(q_true)).reshape(3, 3)
    turn = true @ est.T
    roll = 0.5 * (turn[1, 0] - turn[0, 1])
    rows = []
    for bi, ri, st in zip(b, r, streaks):
        bi, ri = np.array(bi), np.array(ri)
        about = np.cross([0.0, 0.0, 1.0], bi)
        t = np.array(st[:3]) if st else about / np.linalg.norm(about)
        n = np.cross(bi, t)
        rows.append((st[3] * focal if st else 0.0, float((bi - true @ ri) @ t) * focal,
                     float((bi - est @ ri) @ t) * focal, float(about @ t) * focal,
                     np.cross(bi, t) * focal, np.cross(bi, n) * focal))
    return rows, roll


def trial(task):
    """One frame per exposure, detected at each ksigma and registers: ``{(exposure,
    registers, ksigma): {status, blobs, sigma, error, stars, roll}}`` (``stars`` None when
    no fit was made, ``error`` the ``OK`` frame's error in arcsec: x, y, roll)."""
    rate, i, ksigmas, exposures, registers = task
    pipeline.StarTracker.attitude = _capture
    base = camera_settings("estcube2", "tuned")
    out = {}
    for exposure in exposures:
        frame = trials.Frame("estcube2", dict(base, exposure_s=exposure),
                             trials.trial_seed(0, "rate", "estcube2", i), rate, "roll")
        for mode, k in ((m, k) for m in registers for k in ksigmas):
            settings = dict(base, ksigma=k, exposure_s=exposure)
            cfg = detector_config(frame.cam, settings, FLIGHT_EXPOSURE_S if mode == "fixed"
                                  else exposure)
            out[(exposure, mode, k)] = _solved(frame, detect_frame(frame.image, cfg), i)
    return out


def _solved(frame, det, i):
    """The tracking solve of ``det`` on ``frame`` with its captured last fit."""
    _captured.clear()
    v = frame.solve("pyramid", det=det, track=(FRAME_PERIOD_S, i))
    sigma = v["sigma_arcsec"] or v.get("loose", {}).get("sigma_arcsec")
    fit = _captured.get("fit")
    row = {"status": v["status"], "blobs": len(det.blobs), "stars": None, "roll": None,
           "sigma": sigma, "error": v["error_arcsec"]}
    if fit is not None and fit[4] is not None and sigma is not None:
        row["stars"], row["roll"] = stars_of(fit, list(trials.truth_at(
            frame, v.get("t_epoch_s") or 0.0)))
    return row


def along_table(frames):
    """Per unseen class: ``(label, n, RMS along error px, largest |error| - unseen px)``
    and ``{class index: RMS}``."""
    rows, rms = [], {}
    for c, (lo, hi) in enumerate(UNSEEN_CLASSES_PX):
        s = [(u, e) for f in frames for u, e, *_ in f["stars"] if lo <= u < hi]
        if not s:
            continue
        rms[c] = math.sqrt(statistics.fmean(e * e for _u, e in s))
        rows.append((f"{lo:g}-{hi:g}", len(s), rms[c], max(abs(e) - u for u, e in s)))
    return rows, rms


def interval(stars, margin):
    """The roll interval (rad) every star allows: ``(low, high)``."""
    low, high = -math.inf, math.inf
    for u, _e, a, k, _ja, _jc in stars:
        if abs(k) < 1e-6:               # at the centre: no roll lever
            continue
        ends = sorted(((a - u - margin) / k, (a + u + margin) / k))
        low, high = max(low, ends[0]), min(high, ends[1])
    return low, high


def oracle(stars, rms):
    """Cross and roll sigma (arcsec) with each star's along-track sigma its class's RMS."""
    info = np.zeros((3, 3))
    for u, _e, _a, _k, ja, jc in stars:
        c = next(c for c, (lo, hi) in enumerate(UNSEEN_CLASSES_PX) if lo <= u < hi)
        info += np.outer(ja, ja) / rms.get(c, rms[max(rms)]) ** 2
        info += np.outer(jc, jc) / ACROSS_PX ** 2
    p = np.linalg.inv(info)
    return math.sqrt(0.5 * (p[0, 0] + p[1, 1])) * ARCSEC, math.sqrt(p[2, 2]) * ARCSEC


def beyond(row):
    """Whether a solved frame's error is beyond 5 of its own sigmas on an axis."""
    (ex, ey, er), (sc, sr) = row["error"], row["sigma"]
    return max(abs(ex), abs(ey)) > 5.0 * sc or abs(er) > 5.0 * sr


def summary(key, rows):
    """One table row of a configuration ``(exposure, registers, ksigma)``: exposure ms,
    registers, ksigma, ``OK`` / ``IMPRECISE`` / other (the other statuses), wrong (``WRONG``
    verdicts and ``OK`` frames beyond 180" or beyond 5 sigma on an axis), median reported
    roll sigma of the identified frames, largest ``OK`` error (arcsec, total)."""
    ok = [r for r in rows if r["status"] == "OK"]
    imprecise = sum(r["status"] == "IMPRECISE" for r in rows)
    other = {}
    for r in rows:
        if r["status"] not in ("OK", "IMPRECISE", "WRONG"):
            other[r["status"]] = other.get(r["status"], 0) + 1
    errors = [math.sqrt(sum(e * e for e in r["error"])) for r in ok]
    wrong = sum(r["status"] == "WRONG" for r in rows) + sum(
        e > LIMIT_ARCSEC or beyond(r) for e, r in zip(errors, ok))
    sig = [r["sigma"][1] for r in rows if r["sigma"]]
    return (f"| {1e3 * key[0]:g} | {key[1]} | {key[2]:g} | {len(ok)} / {imprecise} / "
            f"{len(rows) - len(ok) - imprecise} | {wrong} | "
            f"{statistics.median(sig) if sig else math.nan:.0f}\" | "
            f"{max(errors) if errors else math.nan:.0f}\" | "
            + ", ".join(f"{n} {s}" for s, n in sorted(other.items())) + " |")


def report(key, rows, margins):
    """Print the analysis of one configuration's frames."""
    statuses = {}
    for r in rows:
        statuses[r["status"]] = statuses.get(r["status"], 0) + 1
    frames = [r for r in rows if r["stars"]]
    sig = [r["sigma"][1] for r in frames]
    print(f"\n{1e3 * key[0]:g} ms, {key[1]} registers, ksigma {key[2]:g}: {len(rows)} "
          f"frames, blobs {min(r['blobs'] for r in rows)}-{max(r['blobs'] for r in rows)}, " +
          ", ".join(f"{s} {n}" for s, n in sorted(statuses.items())))
    if not frames:
        return
    print(f"  reported roll sigma: median {statistics.median(sig):.0f}\", "
          f"{min(sig):.0f}-{max(sig):.0f}\"")
    table, rms = along_table(frames)
    print("  unseen px   stars  along RMS px  largest |err| - unseen px")
    for label, n, value, excess in table:
        print(f"  {label:<10} {n:>6}  {value:>12.2f}  {excess:>10.2f}")
    for m in margins:
        spans = [interval(f["stars"], m) for f in frames]
        half = [0.5 * (h - lo) * ARCSEC for lo, h in spans if h >= lo]
        held = sum(lo <= f["roll"] <= h for (lo, h), f in zip(spans, frames))
        print(f"  intervals, margin {m:g} px: {len(frames) - len(half)} empty, half-width "
              f"median {statistics.median(half):.0f}\" ({min(half):.0f}-{max(half):.0f}\"), "
              f"hold the truth in {held} of {len(frames)}")
    sigmas = [oracle(f["stars"], rms) for f in frames]
    within = sum(5.0 * math.sqrt(2 * c * c + r * r) <= LIMIT_ARCSEC for c, r in sigmas)
    roll = [r for _c, r in sigmas]
    print(f"  oracle covariance: roll sigma {min(roll):.0f}-{max(roll):.0f}\" (median "
          f"{statistics.median(roll):.0f}\"), 5-sigma bound within {LIMIT_ARCSEC:g}\" in "
          f"{within} of {len(frames)}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--trials", type=int, default=50)
    ap.add_argument("--ksigma", type=float, nargs="+", default=[3.0])
    ap.add_argument("--exposures", type=float, nargs="+", default=[FLIGHT_EXPOSURE_S])
    ap.add_argument("--registers", nargs="+", choices=("follow", "fixed"),
                    default=["follow"])
    ap.add_argument("--margins", type=float, nargs="+", default=[1.0, 0.5])
    ap.add_argument("--summary", action="store_true")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    tasks = [(args.rate, i, args.ksigma, args.exposures, args.registers)
             for i in range(args.trials)]
    with multiprocessing.Pool(args.workers) as pool:
        results = pool.map(trial, tasks)
    print(f"roll {args.rate:g} deg/s, {args.trials} trials, tracking with the gyro")
    keys = list(results[0])
    if not args.summary:
        for key in keys:
            report(key, [r[key] for r in results], args.margins)
    print("\n| exposure ms | registers | ksigma | OK / IMPRECISE / other | wrong | "
          "median roll sigma | largest OK error | other |\n|---|---|---|---|---|---|---|---|")
    for key in keys:
        print(summary(key, [r[key] for r in results]))


if __name__ == "__main__":
    main()
