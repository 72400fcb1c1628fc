"""``lodestar db build``: build the star-identification database image of a camera;
``lodestar db info``: validate and describe one; ``lodestar db quads``: build (or read) the
multiscale quad index of the ground's FOV search and describe it."""

import math

from lodestar.contract import stardb
from lodestar.firmware.database import DatabaseError
from lodestar.ground.camerafile import read_camera_file
from lodestar.ground.database import build_database, check_fov, describe
from lodestar.ground.files import check_output, write_atomic
from lodestar.ground.onboard import DEFAULT_MAX_MAG, FLIGHT_DENSITY
from lodestar.ground.solve import camera_fov_deg
from lodestar.sim.presets import DEFAULT_PRESET, PRESETS, load_preset


def add_parser(sub):
    p = sub.add_parser("db", help="build or describe a star-identification database",
                       description="Star-identification database images for the firmware.")
    dsub = p.add_subparsers(dest="db_command", required=True)
    b = dsub.add_parser("build", help="build a database image for a camera")
    src = b.add_mutually_exclusive_group()
    src.add_argument("--preset", choices=PRESETS, default=None,
                     help=f"camera preset (default {DEFAULT_PRESET})")
    src.add_argument("--fov", type=float, metavar="DEG", help="horizontal field of view")
    src.add_argument("--camera", metavar="FILE",
                     help="camera file (lodestar calibrate): its field of view")
    b.add_argument("--aspect", type=float, default=4 / 3,
                   help="width/height with --fov (default 4/3)")
    b.add_argument("--mag", type=_magnitude, default=None,
                   help="limiting V magnitude (default 6, with --density none; 'none': the "
                        "whole catalogue)")
    depth = b.add_mutually_exclusive_group()
    depth.add_argument("--density", nargs=2, type=float, metavar=("V", "P"),
                       help="about V stars (star table) and P pattern stars per field, as "
                            "deep as each region needs, instead of every star to --mag")
    depth.add_argument("--flight", action="store_true",
                       help="the flight database: V <= 6 at the flight density "
                            "(lodestar.ground.onboard.FLIGHT_DENSITY, docs/stardb.md)")
    b.add_argument("--method", nargs="+", default=["pyramid"],
                   choices=stardb.METHODS,
                   help="identification method(s) the image serves (default: pyramid)")
    b.add_argument("-o", "--out", required=True, help="output file")
    b.add_argument("--force", action="store_true", help="replace an existing --out file")
    p.set_defaults(func=run)
    i = dsub.add_parser("info", help="validate and describe a database image")
    i.add_argument("file")
    dsub.add_parser("quads", help="build (or read) the quad index of the FOV search, in the "
                                  "cache directory (docs/solve_centroids.md, Unknown FOV)")


def _print_db(info):
    for key in ("n_stars", "n_pattern_stars", "n_pairs", "mag_limit", "epoch"):
        if key in info:
            print(f"{key:>16}: {info[key]}")
    for key in ("fov_h", "fov_v"):
        print(f"{key:>16}: {info[key] * 57.29577951308232:.3f} deg")
    for name, length in info["section_bytes"].items():
        print(f"{name:>16}: {length} B")
    print(f"{'total':>16}: {info['total_bytes']} B = {info['total_bytes'] / 1024:.1f} KiB")


def _magnitude(text):
    """``--mag``: a finite number, or ``"none"``."""
    if text.lower() == "none":
        return "none"
    value = float(text)
    if not math.isfinite(value):
        raise ValueError(f"--mag must be a finite magnitude or none, got {text}")
    return value


def _run_db_build(args):
    check_output(args.out, None, inputs=[args.camera] if args.camera else (), what="-o",
                 force=args.force)
    mag = None if args.mag == "none" else args.mag
    if args.flight:
        if args.mag is not None:
            raise ValueError("--flight has its own magnitude limit (V <= 6): drop --mag")
        depth = dict(FLIGHT_DENSITY, mag_limit=DEFAULT_MAX_MAG)
    elif args.density is not None:
        depth = {"verification_stars_per_fov": args.density[0],
                 "pattern_stars_per_fov": args.density[1], "mag_limit": mag}
    elif args.mag == "none":
        raise ValueError("--mag none needs --density (the whole catalogue in every field)")
    else:
        depth = {"mag_limit": 6.0 if mag is None else mag}
    if args.camera is not None:
        fov_h, fov_v = camera_fov_deg(read_camera_file(args.camera))
        image = build_database(fov_h_deg=fov_h, fov_v_deg=fov_v, methods=tuple(args.method),
                               **depth)
    elif args.fov is not None:
        check_fov(args.fov, "--fov")
        image = build_database(fov_h_deg=args.fov, aspect=args.aspect,
                               methods=tuple(args.method), **depth)
    else:
        image = build_database(camera=load_preset(args.preset or DEFAULT_PRESET),
                               methods=tuple(args.method), **depth)
    write_atomic(args.out, image)
    print(f"wrote {args.out}")
    _print_db(describe(image))
    return 0


def _run_db_info(args):

    with open(args.file, "rb") as fh:
        image = fh.read()
    try:
        info = describe(image)
    except DatabaseError as exc:
        raise ValueError(f"{args.file}: {exc}") from None
    _print_db(info)
    return 0


def _run_db_quads(_args):
    import sys

    from lodestar.ground import fovsearch
    levels = fovsearch.load_index(log=sys.stderr)
    lo, hi = fovsearch.FOV_RANGE_DEG
    print(f"quad index of the FOV search: {lo:g} .. {hi:g} deg documented, "
          f"{fovsearch.reach_deg()[0]:.1f} .. {fovsearch.reach_deg()[1]:.1f} deg reached")
    for lv in levels:
        print(f"  level {lv.fov_deg:6.2f} deg: {len(lv.vectors):6d} stars, {len(lv.quads):7d} "
              f"quads, separation {math.degrees(lv.separation):.3f} deg")
    return 0


def run(args):
    """The ``db`` command: ``build``, ``info`` or ``quads``."""
    return {"build": _run_db_build, "info": _run_db_info,
            "quads": _run_db_quads}[args.db_command](args)
