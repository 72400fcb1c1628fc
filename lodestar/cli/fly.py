"""``lodestar fly``: the whole star tracker in the loop (``lodestar.fly``): a trajectory, the
MT9P031 register model, the gateware (Verilated board top or golden model) and the unchanged
flight executive, frame after frame, with fault scenarios.  What it does and prints:
``docs/fly.md``.  Exit status 1 when any reported attitude is wrong (> 60" from the truth)."""

import json
import math
import os
import sys

import numpy as np

from lodestar.sim import attitude, presets

DEFAULT_OUT = os.path.join("out", "fly")
ENGINES = ("verilator", "golden")
MCUS = ("cpython", "micropython")


def add_parser(sub):
    from lodestar.fly import faults, trajectory

    p = sub.add_parser("fly", help="run the star tracker in the loop (sensor, gateware, MCU)",
                       description=__doc__)
    p.add_argument("--preset", default=presets.DEFAULT_PRESET,
                   help="camera preset with an MT9P031 (default estcube2)")
    p.add_argument("--frames", type=int, default=30, help="sensor frames to run (default 30)")
    p.add_argument("--rate", nargs=3, type=float, default=(0.0, 0.0, 0.0),
                   metavar=("WX", "WY", "WZ"), help="body rate, deg/s, camera frame")
    p.add_argument("--trajectory", choices=trajectory.TRAJECTORIES, default=None,
                   help="rest, slew (the --rate held) or spin about the boresight; default "
                        "slew with a rate, else rest")
    p.add_argument("--ramp", type=float, default=0.0,
                   help="slew: seconds to reach the rate from rest (default 0: under way)")
    p.add_argument("--faults", nargs="+", default=[], choices=tuple(faults.SCENARIOS),
                   metavar="NAME", help="fault scenarios: " + ", ".join(faults.SCENARIOS))
    p.add_argument("--fault-frame", type=int, default=20,
                   help="sensor period at which the first fault starts (default 20)")
    p.add_argument("--mcu", choices=MCUS, default="cpython")
    p.add_argument("--engine", choices=ENGINES, default="verilator")
    p.add_argument("--seed", type=int, default=0, help="attitude, noise and gyro seed")
    p.add_argument("--out", default=DEFAULT_OUT, metavar="DIR",
                   help="folder of telemetry.csv, telemetry.json and fly.png")
    p.add_argument("--json", action="store_true", help="print the run as one JSON object")
    p.set_defaults(func=run)


def _check(args):
    cam = presets.load_preset(args.preset)
    if "mt9p031" not in cam.meta.get("sensor", "").lower():
        raise ValueError(f"--preset {args.preset}: the twin models the MT9P031, not this "
                         f"preset's sensor")
    if not 1 <= args.frames <= 100000:
        raise ValueError(f"--frames {args.frames}: give 1 .. 100000")
    if not (math.isfinite(args.ramp) and args.ramp >= 0):
        raise ValueError(f"--ramp {args.ramp}: give seconds >= 0")
    if os.path.exists(args.out) and not os.path.isdir(args.out):
        raise ValueError(f"--out {args.out} is a file; give a folder")
    parent = os.path.dirname(os.path.abspath(args.out))
    if args.out != DEFAULT_OUT and not os.path.isdir(parent):     # the default is the tool's
        raise ValueError(f"--out {args.out}: the folder {parent} does not exist")
    return cam


def _micropython():
    """The flight MCU's MicroPython (the 32-bit unix port, float32, firmware frozen), built
    once and cached; ``ValueError`` naming why when it cannot be built here."""
    from lodestar.regress import unixport

    try:
        return unixport.float32_build()
    except (unixport.Unavailable, unixport.MicroPythonError) as exc:
        raise ValueError(f"--mcu micropython: {exc}") from None


def run(args):
    from tqdm import tqdm

    from lodestar.fly import report, trajectory, twin

    cam = _check(args)
    kind = args.trajectory or ("slew" if any(args.rate) else "rest")
    q0 = attitude.random_attitude(np.random.default_rng(args.seed))
    path = trajectory.Trajectory(kind, q0, args.rate, args.ramp)
    gyro = trajectory.Gyro(path, args.seed)
    binary = _micropython() if args.mcu == "micropython" else None
    engine = twin.make_engine(args.engine, cam,
                              log=lambda text: print(text, file=sys.stderr, flush=True))
    loop = twin.Twin(cam, engine, path, gyro, args.faults, args.fault_frame, args.seed,
                     micropython=binary)
    try:
        with tqdm(total=args.frames, desc="fly", unit="frame", file=sys.stderr,
                  disable=None) as bar:
            def progress(done):
                bar.update(done - bar.n)
            rows = loop.run(args.frames, progress)
    finally:
        loop.close()
    summary = twin.summary(rows, loop)
    meta = {"preset": cam.name, "trajectory": kind, "rate_deg_s": [float(w) for w in args.rate],
            "ramp_s": args.ramp, "faults": args.faults, "seed": args.seed,
            "frames_asked": args.frames}
    doc = report.document(rows, summary, args.engine, args.mcu, meta)
    title = (f"lodestar fly: {cam.name}, {kind} {' '.join(f'{w:g}' for w in args.rate)} deg/s, "
             f"{args.engine}, faults {', '.join(args.faults) or 'none'}")
    paths = report.write(args.out, rows, doc, title, parents=args.out == DEFAULT_OUT)
    if args.json:
        print(json.dumps(doc))
    else:
        print(report.summary_text(summary, args.engine, args.mcu, meta))
        print("  wrote         " + ", ".join(str(p) for p in paths))
    return 1 if summary["wrong"] else 0
