"""``lodestar detect``: the golden detector on the built-in synthetic star frame (or a
``.npy`` frame), sent through the FPGA->MCU packet codec; prints the blob table with
centroids."""

import json
import time

import numpy as np

from lodestar import contract as C
from lodestar.golden import Detector, DetectorConfig
from lodestar.golden.starfield import star_frame
from lodestar.ground import codec

DEFAULT_WIDTH, DEFAULT_HEIGHT, DEFAULT_BITS = 2592, 1944, 12  # MT9P031 (estcube2 camera)


def add_parser(sub):
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
    p.set_defaults(func=run)


def _load_frame(args):
    """``(frame, stars)``: the ``--frame`` array (stars None) or the built-in star frame."""
    if args.frame:
        try:
            frame = np.load(args.frame, allow_pickle=False)
        except ValueError:
            frame = None
        if not isinstance(frame, np.ndarray):      # an .npz archive, pickled or other data
            raise ValueError(f"--frame {args.frame}: not a .npy array file (numpy.save of "
                             f"one 2-D array)")
        if frame.ndim != 2 or frame.dtype.kind not in "ui":
            raise ValueError(f"--frame {args.frame}: expected a 2-D unsigned integer frame, "
                             f"got {frame.dtype} of shape {frame.shape}")
        return frame, None
    for name, value, lo, hi in (("--width", args.width, 1, C.MAX_WIDTH),
                                ("--height", args.height, 1, C.MAX_HEIGHT),
                                ("--stars", args.stars, 0, 100000)):
        if not lo <= value <= hi:
            raise ValueError(f"{name} must be in {lo}..{hi}, got {value}")
    return star_frame(args.width, args.height, args.pixel_bits, n_stars=args.stars,
                      seed=args.seed)


def _nearest(stars, x, y):
    if not stars:
        return None
    return min(((s.x - x) ** 2 + (s.y - y) ** 2) ** 0.5 for s in stars)


def run(args):

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
    data = codec.encode(result)
    decoded = codec.decode(data)
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
