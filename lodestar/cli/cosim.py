"""``lodestar cosim FRAME...``: run frames through the Verilated gateware, print the blob
table and diff it against the golden model (:mod:`lodestar.cosim`)."""

import json
import sys
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar.cosim import runner
from lodestar.golden import Detector, DetectorConfig
from lodestar.sim.goldenset import load_frame_doc
from lodestar.sim.imageio import load_frame
from lodestar.sim.presets import PRESETS, load_preset
from lodestar.sim.scene import detector_config


def _load(path, cfg_override):
    """``(frame, DetectorConfig)`` of a golden-set JSON, a PNG or a .npy frame."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file")
    if path.suffix == ".json":

        frame, doc, cfg = load_frame_doc(path)
        return frame, cfg_override or cfg
    if path.suffix == ".npy":
        frame = np.load(path)
    else:

        frame = load_frame(path)
    if cfg_override is None:
        raise ValueError(f"{path}: a PNG or .npy frame needs --preset or --config")
    return frame, cfg_override


def _config_from_args(args):
    if args.config:
        try:
            fields = json.loads(Path(args.config).read_text())
            return DetectorConfig.from_fields(fields)
        except (OSError, ValueError) as exc:
            raise ValueError(f"--config {args.config}: {exc}") from None
    if args.preset:
        return detector_config(load_preset(args.preset))
    return None


def add_parser(sub):
    """Register ``cosim`` on an argparse subparsers object."""

    p = sub.add_parser(
        "cosim", help="run frames through the Verilated gateware and diff with the golden model",
        description="Co-simulate the detection gateware (Verilator) on FRAME files, print the "
                    "blob table and diff it against the golden model; exit 1 on any mismatch. "
                    "A FRAME is a golden-set JSON (its PNG and config beside it), or a PNG or "
                    ".npy frame with --preset or --config.  Frames sharing a geometry run as "
                    "one sequence, back to back.")
    p.add_argument("frames", nargs="+", metavar="FRAME")
    src = p.add_mutually_exclusive_group()
    src.add_argument("--preset", choices=PRESETS, help="the camera's detector registers")
    src.add_argument("--config", metavar="FILE", help="JSON of DetectorConfig fields")
    p.add_argument("--json", action="store_true", help="print JSON instead of tables")
    p.add_argument("--gate-level", action="store_true",
                   help="simulate the Yosys gate-level netlist of the detector instead of its "
                        "RTL (catches simulation/synthesis mismatches; docs/cosim.md)")
    p.set_defaults(func=run)


def run(args):


    def log(msg):
        print(msg, file=sys.stderr)

    try:
        override = _config_from_args(args)
        loaded = [(name, *_load(name, override)) for name in args.frames]
        cfg = loaded[0][2]
        for name, _frame, c in loaded:
            if (c.width, c.height, c.pixel_bits) != (cfg.width, cfg.height, cfg.pixel_bits):
                raise ValueError(f"{name}: geometry {c.width}x{c.height}x{c.pixel_bits} differs "
                                 f"from the first frame's; run them separately")
        results = runner.run_frames([f for _, f, _ in loaded], cfg,
                                    cfgs=[c for _, _, c in loaded], log=log,
                                    gate_level=args.gate_level)
    except ValueError as exc:
        print(f"lodestar cosim: error: {exc}", file=sys.stderr)
        return 2
    golden = Detector(cfg)
    report, bad = [], 0
    for (name, frame, c), got in zip(loaded, results):
        golden.configure(c)
        want = golden.process(frame)
        diffs = [k for k, v in got.header().items() if want.header()[k] != v]
        if got.blobs != want.blobs:
            diffs.append("records")
        bad += bool(diffs)
        report.append({"frame": name, "records": len(got.blobs), "n_blobs": got.n_blobs,
                       "flags": got.flags, "threshold": got.threshold,
                       "match": not diffs, "differences": diffs,
                       "blobs": [dict(zip(C.RECORD_NAMES, b.as_tuple())) for b in got.blobs]})
    if args.json:
        print(json.dumps(report, indent=1))
        return 1 if bad else 0
    for r in report:
        print(f"{r['frame']}: {r['records']} records of {r['n_blobs']} blobs, T={r['threshold']}, "
              f"flags={r['flags']}: " + ("bit-exact with the golden model" if r["match"]
                                         else "MISMATCH in " + ", ".join(r["differences"])))
        print(f"  {'#':>4} {'n':>6} {'s0':>10} {'x':>9} {'y':>9} {'peak':>5} "
              f"{'bbox x0-x1,y0-y1':>22}")
        for i, b in enumerate(r["blobs"]):
            cx = b["sx"] / b["s0"] if b["s0"] else float("nan")
            cy = b["sy"] / b["s0"] if b["s0"] else float("nan")
            box = f"{b['xmin']}-{b['xmax']},{b['ymin']}-{b['ymax']}"
            print(f"  {i:>4} {b['n']:>6} {b['s0']:>10} {cx:>9.3f} {cy:>9.3f} {b['peak']:>5} "
                  f"{box:>22}")
    print(f"{len(report) - bad} of {len(report)} frames bit-exact", file=sys.stderr)
    return 1 if bad else 0
