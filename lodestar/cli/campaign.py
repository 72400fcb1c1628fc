"""``lodestar campaign STUDY``: a Monte-Carlo campaign (simulator, golden detector, FPGA
packet, firmware, checked against the truth) and its tables and plots
(:mod:`lodestar.ground.campaign`)."""

import os
import signal
import sys
import time

from lodestar.ground.campaign import trials
from lodestar.ground.campaign.runner import (
    DEFAULT_TRIALS,
    JOURNAL,
    QUICK,
    format_table,
    make_config,
    run_campaign,
)
from lodestar.ground.onboard import DEFAULT_SETTINGS, SETTINGS
from lodestar.sim.presets import PRESETS


def add_parser(sub):
    """Register ``campaign`` on an argparse subparsers object."""

    p = sub.add_parser("campaign", help="Monte-Carlo studies: rate, false stars, limiting "
                                        "magnitude, accuracy, field of view",
                       description="Run a Monte-Carlo campaign (simulator, golden detector, "
                                   "firmware) and write its table (JSON, CSV) and plot.")
    p.add_argument("name", choices=trials.STUDIES)
    p.add_argument("--out", help="output folder (default out/campaign-NAME)")
    p.add_argument("--trials", type=int, help="trials per level (defaults: " + ", ".join(
        f"{k} {v}" for k, v in DEFAULT_TRIALS.items()) + f"; --quick {QUICK['trials']})")
    p.add_argument("--quick", action="store_true",
                   help="a small campaign for smoke tests (few trials and levels)")
    p.add_argument("--seed", type=int, default=0, help="campaign seed (default 0)")
    p.add_argument("--presets", nargs="+", default=list(PRESETS), choices=PRESETS)
    p.add_argument("--rates", nargs="+", type=float, metavar="DEG_S",
                   help="rates of the rate and limiting studies, deg/s")
    p.add_argument("--axis", choices=trials.AXES, default="cross",
                   help="rate axis: cross-boresight (default), random, roll")
    p.add_argument("--no-gyro", action="store_true",
                   help="rate study: solve without the rate (the firmware fits it from the "
                        "frame; each solution judged at the instant it reports)")
    p.add_argument("--method", choices=trials.METHODS, default="pyramid",
                   help="identification method of the rate, accuracy and fov studies")
    p.add_argument("--settings", choices=tuple(SETTINGS), default=DEFAULT_SETTINGS,
                   help="camera settings (lodestar.ground.onboard): tuned (3-sigma threshold; "
                        "lohmann at 0.2 s, 3 pixels) or each preset as is")
    p.add_argument("--workers", type=int, default=os.cpu_count() or 1,
                   help="local worker processes (default: the CPU count)")
    p.add_argument("--dask", metavar="ADDRESS",
                   help="run on the Dask scheduler at ADDRESS (tcp://HOST:8786) instead; "
                        "start it with dask scheduler and dask worker (docs/campaigns.md)")
    p.add_argument("--resume", action="store_true",
                   help="continue the campaign journaled in --out")
    p.add_argument("--max-tasks", type=int, metavar="N",
                   help="run at most N pending tasks, then stop (continue with --resume)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _interrupt(signum, frame):
    raise KeyboardInterrupt


def run(args):
    """The ``campaign`` command: run, print the table and the files written."""
    config = make_config(args.name, args.presets, args.seed, args.rates, args.axis,
                         args.method, args.settings, args.quick, gyro=not args.no_gyro)
    n_trials = args.trials if args.trials is not None else \
        QUICK["trials"] if args.quick else DEFAULT_TRIALS[args.name]
    out = args.out or os.path.join("out", f"campaign-{args.name}")
    t0 = time.perf_counter()
    signal.signal(signal.SIGTERM, _interrupt)     # SIGTERM stops a campaign as Ctrl-C does
    try:
        rows, paths = run_campaign(config, n_trials, out, args.workers, args.dask, args.resume,
                                   args.max_tasks, progress=not args.no_progress)
    except KeyboardInterrupt:
        print(f"lodestar campaign: interrupted; the finished tasks are in "
              f"{os.path.join(out, JOURNAL)}: run again with --resume", file=sys.stderr)
        return 130
    if rows is None:
        return 0
    print(format_table(args.name, rows))
    print(f"wrote {', '.join(paths)} ({time.perf_counter() - t0:.0f} s)")
    return 0
