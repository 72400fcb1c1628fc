"""``lodestar calibrate FRAMES... --out camera.json``: fit focal lengths, principal point and
Brown-Conrady distortion to solved sky frames of one camera and write a camera file
(:mod:`lodestar.ground.calibrate`, :mod:`lodestar.ground.camerafile`, ``docs/calibration.md``)."""

import json
import math
import sys

from lodestar import contract as C
from lodestar.ground import calibrate
from lodestar.ground.camerafile import SUFFIXES, read_camera_file, write_camera_file
from lodestar.ground.files import check_output
from lodestar.ground.imagesolve import (
    DEFAULT_KSIGMA,
    DEFAULT_MIN_PIXELS,
    image_camera,
    read_image,
)
from lodestar.sim.presets import PRESETS


def add_parser(sub):
    """Register ``calibrate`` on an argparse subparsers object."""
    p = sub.add_parser("calibrate", help="fit a camera's lens model to solved sky frames",
                       description="Solve each frame, then fit focal lengths, principal "
                                   "point and Brown-Conrady distortion with one attitude per "
                                   "frame (least squares, outliers rejected) and write a "
                                   "camera file for solve --camera, db build --camera and the "
                                   "flight software.  See docs/calibration.md.")
    p.add_argument("frames", nargs="+", metavar="FRAME",
                   help="PNG, TIFF or FITS frames of one camera (the detector's size)")
    p.add_argument("-o", "--out", required=True, metavar="CAMERA.json",
                   help="camera file to write (JSON)")
    p.add_argument("--force", action="store_true", help="replace an existing --out file")
    cam = p.add_argument_group("starting camera (one of)")
    cam.add_argument("--preset", choices=PRESETS, default=None)
    cam.add_argument("--fov", type=float, metavar="DEG",
                     help="horizontal field of view edge to edge, degrees")
    cam.add_argument("--distortion", nargs=5, type=float, metavar=("K1", "K2", "K3", "P1", "P2"),
                     help="Brown-Conrady coefficients (with --fov)")
    cam.add_argument("--camera", metavar="FILE", help="a camera file")
    fit = p.add_argument_group("fit")
    fit.add_argument("--free", nargs="+", choices=calibrate.INTRINSICS, default=None,
                     metavar="PARAM", help="parameters to fit, of "
                     f"{' '.join(calibrate.INTRINSICS)} "
                     f"(default: {' '.join(calibrate.DEFAULT_FREE)})")
    fit.add_argument("--one-focal", action="store_true",
                     help="square pixels: one focal length (fy = fx)")
    fit.add_argument("--rounds", type=int, default=2,
                     help="solve -> fit repetitions (default 2, at most "
                          f"{calibrate.MAX_ROUNDS}; fewer once the camera settles)")
    fit.add_argument("--skip-unsolved", action="store_true",
                     help="leave out frames that do not solve instead of stopping")
    det = p.add_argument_group("detection and identification (as lodestar solve)")
    det.add_argument("--bits", type=int, choices=C.PIXEL_BITS, default=None)
    det.add_argument("--ksigma", type=float, default=DEFAULT_KSIGMA)
    det.add_argument("--min-pixels", type=int, default=DEFAULT_MIN_PIXELS)
    det.add_argument("--mag", type=float, default=None)
    det.add_argument("--tolerance", type=float, default=None, metavar="PX")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


def run(args):
    """The ``calibrate`` command: 0 when the camera file is written; 2 with one line for a
    bad file, frames that do not solve, too few matched stars or an existing ``--out``."""
    if args.tolerance is not None and not (math.isfinite(args.tolerance) and
                                           args.tolerance > 0):
        raise ValueError(f"--tolerance must be a positive number of pixels, got "
                         f"{args.tolerance}")
    inputs = list(args.frames) + ([args.camera] if args.camera else [])
    check_output(args.out, SUFFIXES, inputs=inputs, what="--out", force=args.force)
    given = read_camera_file(args.camera) if args.camera else None
    images = [(path, read_image(path, args.bits)) for path in args.frames]
    for path, image in images:
        for note in image.notes:
            print(f"lodestar calibrate: note: {path}: {note}", file=sys.stderr)
    first = images[0][1]
    for path, image in images[1:]:
        if (image.width, image.height) != (first.width, first.height):
            raise ValueError(f"{path} is {image.width}x{image.height}, {args.frames[0]} "
                             f"{first.width}x{first.height}: frames of one camera needed")
    camera0, what = image_camera(first, args.preset, args.fov, args.distortion, camera=given)
    if given is not None:
        what = f"camera file {args.camera}"
    result = calibrate.calibrate(images, camera0, rounds=args.rounds,
                           free=tuple(args.free or calibrate.DEFAULT_FREE),
                           one_focal=args.one_focal, mag=args.mag,
                           tolerance_px=args.tolerance, ksigma=args.ksigma,
                           min_pixels=args.min_pixels, skip_unsolved=args.skip_unsolved,
                           log=sys.stderr)
    summary = dict(result.as_dict(), start=what)
    write_camera_file(args.out, result.camera, result.sigma, summary, force=args.force)
    if args.json:
        print(json.dumps({"camera": result.camera.as_dict(), "start_camera":
                          camera0.as_dict(), "sigma": result.sigma, "calibration": summary,
                          "out": args.out}, indent=1))
    else:
        print(format_result(result, camera0, what, args.out))
    return 0


def format_result(result, camera0, what, out):
    """The calibration as text for people."""
    lines = [f"start: {what}; {len(result.fit.frames)} frames, {result.fit.n_pairs} star "
             f"pairs, {result.fit.n_rejected} rejected as outliers, {result.rounds} rounds",
             f"  {'param':>5} {'start':>12} {'fitted':>12} {'1-sigma':>10}"]
    for name in calibrate.INTRINSICS:
        sigma = result.sigma.get(name)
        lines.append(f"  {name:>5} {getattr(camera0, name):>12.6g} "
                     f"{getattr(result.camera, name):>12.6g} "
                     f"{'fixed' if sigma is None else format(sigma, '.3g'):>10}")
    for label, r in (("before", result.before), ("after", result.after)):
        lines.append(f"  residuals {label:<6} RMS {r['rms_px']:.3f} px {r['rms_arcsec']:.2f}\""
                     f", max {r['max_px']:.3f} px {r['max_arcsec']:.2f}\" ({r['n']} stars)")
    for f in result.frames:
        if "pairs" in f:
            lines.append(f"  {f['name']}: {f['status']}, {f['inliers']} of {f['pairs']} "
                         f"pairs ({f['solver_pairs']} from the solver), RA {f['ra_deg']:.4f} "
                         f"Dec {f['dec_deg']:+.4f} roll {f['roll_deg']:+.4f} deg")
        else:
            lines.append(f"  {f['name']}: {f['status']}")
    lines.append(f"wrote {out}")
    return "\n".join(lines)
