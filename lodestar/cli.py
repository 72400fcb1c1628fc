"""The ``lodestar`` command line.  Subcommands:

``detect``     run the golden detector on the built-in synthetic star frame (or a ``.npy``
               frame), send the result through the FPGA->MCU packet codec and print the
               blob table with centroids.
``simulate``   render a star-field frame of a camera preset: 16-bit PNG, truth JSON and a
               preview PNG with the stars marked.
``goldenset``  write a named golden image set (frames, truth, expected detection).
``db``         build a star-identification database image for a camera (``db build``) or
               describe one (``db info``).
``demo``       simulate a frame, detect it, solve it with the flight firmware and check the
               attitude against the truth (``lodestar.demo``).
``solve``      detect, identify and solve a real sky image: PNG, TIFF or FITS
               (``lodestar.imagesolve``).
"""

import argparse
import importlib
import json
import sys
import time

import numpy as np

from lodestar import contract as C

DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_BITS = 2592, 1944, 12  # MT9P031 (estcube2 camera)


def _detect_parser(sub):
    p = sub.add_parser("detect", help="detect blobs in the built-in star frame or a .npy frame",
                       description="Detect blobs with the golden model and print the blob table.")
    src = p.add_argument_group("frame")
    src.add_argument("--frame", metavar="FILE.npy",
                     help="2-D unsigned integer frame saved with numpy.save (default: built-in)")
    src.add_argument("--width", type=int, default=DEFAULT_WIDTH)
    src.add_argument("--height", type=int, default=DEFAULT_HEIGHT)
    src.add_argument("--pixel-bits", type=int, default=DEFAULT_BITS, choices=C.PIXEL_BITS)
    src.add_argument("--stars", type=int, default=100, help="stars in the built-in frame")
    src.add_argument("--seed", type=int, default=0, help="seed of the built-in frame")
    det = p.add_argument_group("detector registers (defaults: ST-16 baseline, Dzamba 2013)")
    det.add_argument("--mode", choices=C.MODE_NAMES, default="fixed")
    det.add_argument("--threshold", type=int, default=120)
    det.add_argument("--background", type=int, default=40)
    det.add_argument("--ksigma", type=float, default=5.0)
    det.add_argument("--local-log2-window", type=int, default=C.LOCAL_LOG2_WINDOW_MAX)
    det.add_argument("--local-offset", type=int, default=40)
    det.add_argument("--min-pixels", type=int, default=6)
    det.add_argument("--min-sum", type=int, default=1000)
    det.add_argument("--max-pixels", type=int, default=None)
    det.add_argument("--record-capacity", type=int, default=C.DEFAULT_RECORD_CAPACITY)
    det.add_argument("--frames", type=int, default=1,
                     help="process the frame N times in a row (global mode learns from the "
                          "previous frame); the last result is printed")
    det.add_argument("--engine", choices=("vectorized", "streaming"), default="vectorized")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.set_defaults(func=_run_detect)


def _load_frame(args):
    from lodestar.golden.starfield import star_frame

    if args.frame:
        frame = np.load(args.frame, allow_pickle=False)
        if frame.ndim != 2:
            raise ValueError(f"{args.frame}: expected a 2-D frame, got shape {frame.shape}")
        return frame, None
    return star_frame(args.width, args.height, args.pixel_bits, n_stars=args.stars,
                      seed=args.seed)


def _nearest(stars, x, y):
    if not stars:
        return None
    return min(((s.x - x) ** 2 + (s.y - y) ** 2) ** 0.5 for s in stars)


def _run_detect(args):
    from lodestar import packet
    from lodestar.golden import Detector, DetectorConfig

    frame, stars = _load_frame(args)
    cfg = DetectorConfig(
        width=frame.shape[1], height=frame.shape[0], pixel_bits=args.pixel_bits,
        threshold_mode=args.mode, threshold=args.threshold, background=args.background,
        ksigma=args.ksigma, local_log2_window=args.local_log2_window,
        local_offset=args.local_offset, min_pixels=args.min_pixels, min_sum=args.min_sum,
        max_pixels=args.max_pixels, record_capacity=args.record_capacity)
    det = Detector(cfg, engine=args.engine)
    if args.frames < 1:
        raise ValueError(f"--frames must be >= 1, got {args.frames}")
    t0 = time.perf_counter()
    for _ in range(args.frames):
        result = det.process(frame)
    dt = (time.perf_counter() - t0) / args.frames
    data = packet.encode(result)
    decoded = packet.decode(data)
    if decoded != result:
        raise AssertionError("packet round trip changed the result")

    rows = []
    for i, b in enumerate(decoded.blobs):
        cx = b.sx / b.s0 if b.s0 else float("nan")
        cy = b.sy / b.s0 if b.s0 else float("nan")
        rows.append({"i": i, "n": b.n, "s0": b.s0, "x": cx, "y": cy, "peak": b.peak,
                     "nsat": b.nsat, "bbox": [b.xmin, b.xmax, b.ymin, b.ymax],
                     "flags": b.flags, "truth_px": _nearest(stars, cx, cy)})
    summary = {
        "frame": f"{cfg.width}x{cfg.height}x{cfg.pixel_bits}",
        "source": args.frame or f"built-in, {args.stars} stars, seed {args.seed}",
        "mode": result.mode_name, "threshold": result.threshold,
        "background": result.background, "n_blobs": result.n_blobs,
        "n_filtered": result.n_filtered, "records": len(result.blobs),
        "dropped_records": result.dropped_records, "dropped_labels": result.dropped_labels,
        "flags": result.flags, "packet_bytes": len(data), "engine": args.engine,
        "ms_per_frame": round(dt * 1e3, 1),
    }
    if args.json:
        print(json.dumps({"summary": summary, "blobs": rows}, indent=1))
        return 0
    for key, value in summary.items():
        print(f"{key:>16}: {value}")
    print()
    print(f"{'#':>4} {'n':>5} {'s0':>8} {'x':>9} {'y':>9} {'peak':>5} {'nsat':>4} "
          f"{'bbox x0-x1,y0-y1':>20} {'flags':>5} {'truth dist px':>13}")
    for r in rows:
        bx = r["bbox"]
        dist = "-" if r["truth_px"] is None else f"{r['truth_px']:.3f}"
        print(f"{r['i']:>4} {r['n']:>5} {r['s0']:>8} {r['x']:>9.3f} {r['y']:>9.3f} "
              f"{r['peak']:>5} {r['nsat']:>4} {f'{bx[0]}-{bx[1]},{bx[2]}-{bx[3]}':>20} "
              f"{r['flags']:>5} {dist:>13}")
    return 0


def _simulate_parser(sub):
    from lodestar.sim.presets import DEFAULT_PRESET, PRESETS

    p = sub.add_parser("simulate", help="render a simulated star frame with its truth",
                       description="Render a frame of a camera preset at an attitude and rates.")
    p.add_argument("--preset", choices=PRESETS, default=DEFAULT_PRESET)
    att = p.add_mutually_exclusive_group()
    att.add_argument("--radec", nargs=3, type=float, metavar=("RA", "DEC", "ROLL"),
                     help="boresight right ascension, declination and roll, degrees")
    att.add_argument("--quaternion", nargs=4, type=float, metavar=("X", "Y", "Z", "W"),
                     help="scalar-last quaternion, inertial -> camera")
    p.add_argument("--rate", nargs=3, type=float, default=(0.0, 0.0, 0.0),
                   metavar=("WX", "WY", "WZ"), help="body rates about camera x y z, deg/s")
    p.add_argument("--exposure", type=float, default=None, help="seconds (default: preset)")
    p.add_argument("--seed", type=int, default=0,
                   help="noise seed; also draws the attitude when none is given")
    p.add_argument("--hot-pixels", action="store_true", help="add a sensor defect map")
    p.add_argument("--cosmic-rays", type=int, default=0)
    p.add_argument("--false-stars", type=int, default=0)
    p.add_argument("-o", "--out", default="frame", help="output prefix (default: frame)")
    p.set_defaults(func=_run_simulate)


def _run_simulate(args):
    import numpy as np

    from lodestar.golden import detect_frame
    from lodestar.sim import attitude, imageio, presets, scene, sensor

    cam = presets.load_preset(args.preset)
    if args.quaternion:
        q = np.asarray(args.quaternion, dtype=np.float64)
    elif args.radec:
        q = attitude.from_radec_roll(*args.radec)
    else:
        q = attitude.random_attitude(np.random.default_rng(args.seed))
    defects = (sensor.SensorDefects.generate(cam.height, cam.width, seed=args.seed)
               if args.hot_pixels else None)
    sim = scene.simulate(cam, q, args.rate, args.exposure, args.seed, defects=defects,
                         extras=scene.Extras(false_stars=args.false_stars,
                                             cosmic_rays=args.cosmic_rays))
    cfg = scene.detector_config(cam, sim.truth["exposure_s"])
    found = detect_frame(sim.frame, cfg)
    imageio.save_frame(f"{args.out}.png", sim.frame)
    with open(f"{args.out}.json", "w") as fh:
        json.dump(sim.truth, fh, indent=1)
    marks = [(s["x"], s["y"], s["name"] or "") for s in sim.truth["sources"]
             if s["vmag"] < 6.5 or s["kind"] != "star"]
    imageio.save_preview(f"{args.out}_preview.png", sim.frame, marks)
    t = sim.truth
    print(f"{args.out}.png: {cam.name} {cam.width}x{cam.height}x{cam.pixel_bits}, "
          f"RA {t['ra_deg']:.3f} Dec {t['dec_deg']:.3f} roll {t['roll_deg']:.3f} deg, "
          f"rates {args.rate} deg/s, exposure {t['exposure_s']} s")
    print(f"{len(t['sources'])} sources on the detector, "
          f"{sum(s['vmag'] < 6 for s in t['sources'])} brighter than V 6; golden detector "
          f"(T={cfg.threshold}, B={cfg.background}): {len(found.blobs)} records")
    print(f"wrote {args.out}.png, {args.out}.json, {args.out}_preview.png")
    return 0


def _goldenset_parser(sub):
    from lodestar.sim.goldenset import SETS

    p = sub.add_parser("goldenset", help="write a named golden image set",
                       description="Write frames (16-bit PNG), truth and expected detection.")
    p.add_argument("name", choices=sorted(SETS))
    p.add_argument("--out", required=True, help="output folder")
    p.set_defaults(func=_run_goldenset)


def _run_goldenset(args):
    from lodestar.sim import goldenset

    names = goldenset.generate(args.name, args.out, progress=lambda n: print("wrote", n))
    print(f"{len(names)} frames in {args.out}")
    return 0


def _db_parser(sub):
    from lodestar.sim.presets import DEFAULT_PRESET, PRESETS

    p = sub.add_parser("db", help="build or describe a star-identification database",
                       description="Star-identification database images for the firmware.")
    dsub = p.add_subparsers(dest="db_command", required=True)
    b = dsub.add_parser("build", help="build a database image for a camera")
    src = b.add_mutually_exclusive_group()
    src.add_argument("--preset", choices=PRESETS, default=None,
                     help=f"camera preset (default {DEFAULT_PRESET})")
    src.add_argument("--fov", type=float, metavar="DEG", help="horizontal field of view")
    b.add_argument("--aspect", type=float, default=4 / 3,
                   help="width/height with --fov (default 4/3)")
    b.add_argument("--mag", type=float, default=6.0, help="limiting V magnitude")
    b.add_argument("--method", nargs="+", default=["pyramid"],
                   choices=("pyramid", "triangle", "hashing"),
                   help="identification method(s) the image serves (default: pyramid)")
    b.add_argument("-o", "--out", required=True, help="output file")
    b.set_defaults(func=_run_db_build)
    i = dsub.add_parser("info", help="validate and describe a database image")
    i.add_argument("file")
    i.set_defaults(func=_run_db_info)


def _print_db(info):
    for key in ("n_stars", "n_pattern_stars", "n_pairs", "mag_limit", "epoch"):
        if key in info:
            print(f"{key:>16}: {info[key]}")
    for key in ("fov_h", "fov_v"):
        print(f"{key:>16}: {info[key] * 57.29577951308232:.3f} deg")
    for name, length in info["section_bytes"].items():
        print(f"{name:>16}: {length} B")
    print(f"{'total':>16}: {info['total_bytes']} B = {info['total_bytes'] / 1024:.1f} KiB")


def _run_db_build(args):
    import math

    from lodestar.ground.database import build_database, describe
    from lodestar.sim.presets import DEFAULT_PRESET, load_preset

    if args.fov is not None:
        if not 0 < args.fov < 180 or not math.isfinite(args.fov):
            raise ValueError(f"--fov must be in (0, 180) degrees, got {args.fov}")
        image = build_database(fov_h_deg=args.fov, aspect=args.aspect, mag_limit=args.mag,
                               methods=tuple(args.method))
    else:
        image = build_database(camera=load_preset(args.preset or DEFAULT_PRESET),
                               mag_limit=args.mag, methods=tuple(args.method))
    with open(args.out, "wb") as fh:
        fh.write(image)
    print(f"wrote {args.out}")
    _print_db(describe(image))
    return 0


def _run_db_info(args):
    from lodestar.firmware.database import DatabaseError
    from lodestar.ground.database import describe

    with open(args.file, "rb") as fh:
        image = fh.read()
    try:
        info = describe(image)
    except DatabaseError as exc:
        raise ValueError(f"{args.file}: {exc}") from None
    _print_db(info)
    return 0


COMMAND_MODULES = ("lodestar.demo", "lodestar.imagesolve", "lodestar.cosim", "lodestar.regress",
                   "lodestar.campaign", "lodestar.synth")
"""Modules that each provide one subcommand: ``add_parser(subparsers)`` registers it and
sets ``func`` (``run(args)`` -> exit code).  A new command is a module added here."""


def build_parser():
    parser = argparse.ArgumentParser(prog="lodestar", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    _detect_parser(sub)
    _simulate_parser(sub)
    _goldenset_parser(sub)
    _db_parser(sub)
    for name in COMMAND_MODULES:
        importlib.import_module(name).add_parser(sub)
    return parser


def main(argv=None):
    """Entry point; returns the process exit code (2 on bad input, with a message)."""
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except BrokenPipeError:  # output piped into e.g. head
        sys.stderr.close()
        return 0
    except (ValueError, OSError, NotImplementedError) as exc:
        print(f"lodestar {args.command}: error: {exc}", file=sys.stderr)
        return 2
