"""``lodestar solve IMAGE``: detect, identify and solve a real sky image (PNG, TIFF or FITS)
with the golden detector and the flight firmware (:mod:`lodestar.ground.imagesolve`)."""

import json
import math
import sys

from lodestar import contract as C
from lodestar.firmware import starid
from lodestar.ground import lensfit
from lodestar.ground.camerafile import read_camera_file
from lodestar.ground.files import check_output, write_atomic
from lodestar.ground.imagesolve import (
    DEFAULT_KSIGMA,
    DEFAULT_MIN_PIXELS,
    fits_date_obs,
    format_report,
    fov_band,
    frame_timing,
    image_camera,
    read_image,
    solve_image,
    write_annotated,
)
from lodestar.ground.solve import DEFAULT_DENSITY, camera_fov_deg, observer_velocity_km_s
from lodestar.ground.wcs import header_bytes, wcs_header
from lodestar.sim.presets import PRESETS

WCS_SUFFIXES = (".wcs", ".fits", ".fit")


def add_parser(sub):
    """Register ``solve`` on an argparse subparsers object."""

    p = sub.add_parser("solve", help="detect, identify and solve a sky image (PNG/TIFF/FITS)",
                       description="Detect, identify and solve a real sky image with the "
                                   "golden detector (local threshold mode) and the flight "
                                   "firmware.  See docs/image_solving.md for the rules.")
    p.add_argument("image", help="PNG, TIFF or FITS file")
    cam = p.add_argument_group("camera (one of)")
    cam.add_argument("--preset", choices=PRESETS, default=None,
                     help="camera preset (the image must have its size)")
    cam.add_argument("--fov", type=float, metavar="DEG",
                     help="horizontal field of view edge to edge, degrees (without "
                          "--distortion the focal length and radial distortion are fitted to "
                          "the matched stars)")
    cam.add_argument("--fov-error", type=float, metavar="DEG",
                     help="search the FOV within --fov +- this (deg); without --fov, --preset "
                          "and an image not of the default preset's size the FOV is searched "
                          "over 8 .. 30 deg")
    cam.add_argument("--distortion", nargs=5, type=float, metavar=("K1", "K2", "K3", "P1", "P2"),
                     help="Brown-Conrady coefficients (with --fov)")
    cam.add_argument("--camera", metavar="FILE",
                     help="camera file (lodestar calibrate; docs/calibration.md)")
    data = p.add_argument_group("data")
    data.add_argument("--bits", type=int, choices=C.PIXEL_BITS, default=None,
                      help="significant bits of 16-bit data (default: detected)")
    data.add_argument("--bin", type=int, default=1, metavar="N",
                      help="average N x N pixel blocks first (for frames larger than "
                           f"{C.MAX_WIDTH}x{C.MAX_HEIGHT})")
    det = p.add_argument_group("detection and identification")
    det.add_argument("--ksigma", type=float, default=DEFAULT_KSIGMA,
                     help="local threshold offset in noise sigmas")
    det.add_argument("--min-pixels", type=int, default=DEFAULT_MIN_PIXELS)
    det.add_argument("--mag", type=float, default=None,
                     help="every catalogue star to this V in the database (default: about "
                          f"{DEFAULT_DENSITY['verification_stars_per_fov']} stars per field, "
                          "as deep as the field needs)")
    det.add_argument("--tolerance", type=float, default=None, metavar="PX",
                     help="match tolerance, px (default max(2.5, FOV/1000))")
    app = p.add_argument_group("apparent directions (docs/apparent_directions.md)")
    app.add_argument("--time", metavar="ISO",
                     help="observation time, UTC (default: a FITS image's DATE-OBS): the "
                          "Earth's velocity corrects the stellar aberration")
    app.add_argument("--velocity", nargs=3, type=float, metavar=("VX", "VY", "VZ"),
                     help="observer velocity, km/s, ICRS: added to the Earth's with --time "
                          "(a satellite's), else the whole velocity")
    mot = p.add_argument_group("motion (docs/image_solving.md, Motion)")
    mot.add_argument("--rate", nargs=3, type=float, metavar=("WX", "WY", "WZ"),
                     help="body rate, deg/s, camera frame (a gyro's): the attitude then "
                          "holds at the start of row 0's exposure; without it the rate is "
                          "fitted from the frame and the attitude holds at the reported "
                          "t_epoch_s")
    mot.add_argument("--exposure", type=float, metavar="S",
                     help="exposure, s (default: a preset's; else unknown)")
    mot.add_argument("--row-time", type=float, metavar="S",
                     help="rolling-shutter line time, s (default: a preset's; else 0, one "
                          "instant for every row)")
    p.add_argument("--annotate", metavar="FILE.png", help="write an annotated picture")
    p.add_argument("--wcs", metavar="FILE.wcs",
                   help="write the solution's FITS WCS header (TAN, SIP with a distortion; "
                        ".wcs, .fits or .fit)")
    p.add_argument("--force", action="store_true",
                   help="replace an existing --annotate or --wcs file")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=run)


MAX_RATE_DEG_S = 360.0
"""Largest ``--rate`` component, deg/s."""


def _motion(args, image, what):
    """``(omega rad/s or None, exposure_s, row_time_s)`` of ``--rate``, ``--exposure`` and
    ``--row-time`` (:func:`lodestar.ground.imagesolve.frame_timing`); ``ValueError`` naming
    the option for a value out of range."""
    if args.rate is not None and not all(math.isfinite(w) and abs(w) <= MAX_RATE_DEG_S
                                         for w in args.rate):
        raise ValueError(f"--rate must be three numbers of at most {MAX_RATE_DEG_S:g} deg/s, "
                         f"got {args.rate}")
    if args.exposure is not None and not (math.isfinite(args.exposure) and
                                          0 < args.exposure <= 1000):
        raise ValueError(f"--exposure must be in (0, 1000] s, got {args.exposure}")
    if args.row_time is not None and not (math.isfinite(args.row_time) and
                                          0 <= args.row_time <= 1):
        raise ValueError(f"--row-time must be in [0, 1] s, got {args.row_time}")
    exposure, row_time = frame_timing(image, what, args.exposure, args.row_time)
    omega = None if args.rate is None else [math.radians(w) for w in args.rate]
    return omega, exposure, row_time


def run(args):
    """The ``solve`` command: 0 when solved, 1 when not (reason on stderr), 2 for bad input
    or an annotated picture or WCS file that cannot be written (after the solution is
    printed).  No WCS file is written for a frame that is not solved."""
    if args.annotate:
        check_output(args.annotate, (".png",), inputs=[args.image], what="--annotate",
                     force=args.force)
    if args.wcs:
        check_output(args.wcs, WCS_SUFFIXES, inputs=[args.image], what="--wcs",
                     force=args.force)
    given = read_camera_file(args.camera) if args.camera else None
    image = read_image(args.image, args.bits, args.bin)
    for note in image.notes:
        print(f"lodestar solve: note: {note}", file=sys.stderr)
    camera, what = image_camera(image, args.preset, args.fov, args.distortion, camera=given,
                                fov_error=args.fov_error)
    if given is not None:
        what = f"camera file {args.camera}" + (f", binned {image.bin}x{image.bin}"
                                               if image.bin > 1 else "")
    band = None
    if camera is None:
        band = fov_band(args.fov, args.fov_error)
        # the widest field searched: its tolerance limit is the tightest in pixels
        width = image.frame.shape[1]
        fov_h, f_px = math.radians(band[1]), width / 2 / math.tan(math.radians(band[1]) / 2)
    else:
        fov_h, f_px = math.radians(camera_fov_deg(camera)[0]), math.sqrt(camera.fx * camera.fy)
    widest = starid.max_tolerance_rad(fov_h) * f_px  # px
    obstime = args.time if args.time is not None else fits_date_obs(args.image)
    velocity = observer_velocity_km_s(obstime, args.velocity)
    if args.tolerance is not None and not (math.isfinite(args.tolerance) and
                                           0 < args.tolerance <= widest):
        raise ValueError(f"--tolerance must be a number of pixels in (0, {widest:.0f}] (5 % "
                         f"of the field), got {args.tolerance}")
    motion = _motion(args, image, what)
    # a lens not told (a searched FOV, or --fov alone) is fitted to the matched stars
    unknown = camera is None or (args.fov is not None and args.distortion is None)
    refine = lensfit.refine if unknown else None
    report, det, res, camera = solve_image(image, camera, args.mag, args.tolerance,
                                           args.ksigma, args.min_pixels, log=sys.stderr,
                                           fov_band=band, velocity_km_s=velocity,
                                           motion=motion, refine=refine)
    report["time"] = obstime
    report["camera"] = what
    failure = None
    if args.annotate:
        try:
            write_annotated(args.annotate, image, camera, det, res, report, args.mag)
            report["annotated"] = args.annotate
        except OSError as exc:
            failure = f"--annotate {args.annotate}: {exc}"
            report["annotated"] = None
    if args.wcs and res.ok:
        try:
            header, residual = wcs_header(res.q, camera, image.frame.shape[1],
                                          image.frame.shape[0], image.bin)
            write_atomic(args.wcs, header_bytes(header))
            report["wcs"] = {"file": args.wcs, "sip_residual_px": residual}
        except (OSError, ValueError) as exc:
            failure = f"--wcs {args.wcs}: {exc}"
            report["wcs"] = None
    if args.json:
        print(json.dumps(report, indent=1))
    else:
        print(format_report(args.image, report, what))
    if failure is not None:
        print(f"lodestar solve: error: {failure}", file=sys.stderr)
        return 2
    if report["status"] != "OK":
        print(f"lodestar solve: {args.image} not solved: {report['status']}: "
              f"{report['reason']}", file=sys.stderr)
        if report["status"] == "MIRRORED":
            print("lodestar solve: the image is a mirror image of the sky: flip it left-right "
                  "(or top-bottom) and solve it again", file=sys.stderr)
        return 1
    return 0
