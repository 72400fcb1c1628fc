"""``lodestar simulate``: render a star-field frame of a camera preset (16-bit PNG), its
truth (JSON) and a preview PNG with the stars marked."""

import json
import os

import numpy as np

from lodestar.golden import detect_frame
from lodestar.ground.files import check_output, write_atomic
from lodestar.ground.solve import observer_velocity_km_s
from lodestar.sim import attitude, imageio, presets, scene, sensor
from lodestar.sim.presets import DEFAULT_PRESET, PRESETS


def add_parser(sub):

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
    p.add_argument("--time", metavar="ISO",
                   help="observation time, UTC: stars drawn aberrated by the Earth's velocity")
    p.add_argument("--velocity", nargs=3, type=float, metavar=("VX", "VY", "VZ"),
                   help="observer velocity, km/s, ICRS (added to the Earth's with --time): "
                        "stars drawn aberrated (docs/apparent_directions.md)")
    p.add_argument("-o", "--out", default="frame", help="output prefix (default: frame)")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.set_defaults(func=run)


def run(args):
    """The ``simulate`` command: 0 when the frame, its truth and the preview are written;
    2 with one line for bad options or an output that may not be written."""
    if not os.path.basename(args.out):
        raise ValueError(f"-o {args.out!r} must name the files' prefix, e.g. -o out/frame")
    for suffix in (".png", ".json", "_preview.png"):
        check_output(args.out + suffix, None, what="-o", force=args.force)
    cam = presets.load_preset(args.preset)
    if args.quaternion:
        q = np.asarray(args.quaternion, dtype=np.float64)
    elif args.radec:
        q = attitude.from_radec_roll(*args.radec)
    else:
        q = attitude.random_attitude(np.random.default_rng(args.seed))
    defects = (sensor.SensorDefects.generate(cam.height, cam.width, seed=args.seed)
               if args.hot_pixels else None)
    velocity = observer_velocity_km_s(args.time, args.velocity)
    sim = scene.simulate(cam, q, args.rate, args.exposure, args.seed, defects=defects,
                         extras=scene.Extras(false_stars=args.false_stars,
                                             cosmic_rays=args.cosmic_rays),
                         velocity_km_s=velocity)
    cfg = scene.detector_config(cam, sim.truth["exposure_s"])
    found = detect_frame(sim.frame, cfg)
    marks = [(s["x"], s["y"], s["name"] or "") for s in sim.truth["sources"]
             if s["vmag"] < 6.5 or s["kind"] != "star"]
    write_atomic(f"{args.out}.png", imageio.frame_png(sim.frame))
    write_atomic(f"{args.out}.json", json.dumps(sim.truth, indent=1))
    write_atomic(f"{args.out}_preview.png", imageio.preview_png(sim.frame, marks))
    t = sim.truth
    print(f"{args.out}.png: {cam.name} {cam.width}x{cam.height}x{cam.pixel_bits}, "
          f"RA {t['ra_deg']:.3f} Dec {t['dec_deg']:.3f} roll {t['roll_deg']:.3f} deg, "
          f"rates {args.rate} deg/s, exposure {t['exposure_s']} s")
    print(f"{len(t['sources'])} sources on the detector, "
          f"{sum(s['vmag'] < 6 for s in t['sources'])} brighter than V 6; golden detector "
          f"(T={cfg.threshold}, B={cfg.background}): {len(found.blobs)} records")
    print(f"wrote {args.out}.png, {args.out}.json, {args.out}_preview.png")
    return 0
