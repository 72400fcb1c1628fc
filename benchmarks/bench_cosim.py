"""Co-simulation speed: build time and pixels per second of the Verilated detector, against
a baseline commit measured side by side in the same run.

    .venv/bin/python benchmarks/bench_cosim.py [--sizes 752x480x10 2592x1944x12] [--frames N]
        [--repeat N] [--baseline REF... | --no-baseline]

For each geometry, and for this tree and each ``--baseline`` commit (default: the last
commit before issue 18's fast playback, checked out with ``git worktree add`` into a
temporary folder): a fresh Verilator build in an empty cache (the build ``run_frames``
uses), then ``--repeat`` runs of ``--frames`` simulated star frames through
``lodestar.cosim.runner.run_frames``, checked against the golden model.  Each tree is
measured in its own process (``--worker``), so a baseline imports its own ``lodestar``.
Reports build seconds, wall and CPU (this process and its children: comparable on a
loaded machine, where wall time is not), and the median over the runs of run seconds (run:
stimulus, simulation, output parsing), wall and CPU, of the simulator's CPU seconds (the
child process) and of pixels per second, wall and CPU.
"""

import argparse
import inspect
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from statistics import median

import numpy as np
import tomllib

REPO = Path(__file__).resolve().parent.parent
BASELINE = "1118c7c"
"""main before issue 18: a 64-bit stimulus word read per clock, -O2, an edge-awaiting player."""


def frames_for(width, height, bits, n):
    from lodestar.sim.presets import load_preset
    from lodestar.sim.scene import detector_config, simulate

    cam = load_preset("lohmann" if bits == 10 else "estcube2")
    cfg = detector_config(cam)
    frames = []
    for seed in range(n):
        q = np.array([0.1 * seed, 0.2, 0.3, 0.9])
        sim = simulate(cam, q / np.linalg.norm(q), seed=seed)
        frames.append(sim.frame[:height, :width].copy())
    return frames, cfg.replace(width=width, height=height)


def _times():
    """``(wall, CPU of this process, CPU of its children)`` in seconds."""
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return (time.perf_counter(), own.ru_utime + own.ru_stime, kids.ru_utime + kids.ru_stime)


def worker(frames_path, out_path, repeat):
    """Build and run (``repeat`` times) the frames of ``frames_path`` with the ``lodestar``
    on ``sys.path``; write the timings and whether the results match the golden model as
    JSON.  The build is the one ``run_frames`` uses (``native`` where the tree has it)."""

    from lodestar.cosim.runner import Build, run_frames
    from lodestar.golden import Detector, DetectorConfig

    data = np.load(frames_path)
    frames = list(data["frames"])
    cfg = DetectorConfig(**json.loads(str(data["config"])))
    native = {"native": True} if "native" in inspect.signature(Build).parameters else {}
    root = tempfile.mkdtemp(prefix="bench-cosim-")
    runs = []
    try:
        a = _times()
        Build(cfg.width, cfg.height, cfg.pixel_bits, cfg.label_capacity, cfg.record_capacity,
              root=root, **native).ensure()
        b = _times()
        build = {"build": b[0] - a[0], "build_cpu": b[1] + b[2] - a[1] - a[2]}
        for _ in range(repeat):
            a = _times()
            got = run_frames(frames, cfg, build_root=root)
            b = _times()
            runs.append({"run": b[0] - a[0], "run_cpu": b[1] + b[2] - a[1] - a[2],
                         "sim_cpu": b[2] - a[2]})
    finally:
        shutil.rmtree(root, ignore_errors=True)
    golden = Detector(cfg)
    exact = got == [golden.process(f) for f in frames]
    out = {k: median(r[k] for r in runs) for k in runs[0]}
    Path(out_path).write_text(json.dumps({**build, **out, "exact": exact}))


def shim_for(tree, folder):
    """A folder that imports ``lodestar`` from the checkout ``tree`` (its pyproject's package
    folders, as the editable install of this tree maps them)."""
    conf = tomllib.loads((tree / "pyproject.toml").read_text())["tool"]["setuptools"]
    dirs = conf["package-dir"]
    pkg = folder / "lodestar"
    pkg.mkdir(parents=True)
    for item in (tree / dirs.get("lodestar", "lodestar")).iterdir():
        (pkg / item.name).symlink_to(item)
    for name, path in dirs.items():
        parts = name.split(".")
        if len(parts) == 2 and not (pkg / parts[1]).exists():
            (pkg / parts[1]).symlink_to(tree / path)
    return folder


def measure(frames_path, repeat, pythonpath=None):
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = str(pythonpath)
    with tempfile.NamedTemporaryFile(suffix=".json") as out:
        subprocess.run([sys.executable, __file__, "--worker", str(frames_path), out.name,
                        str(repeat)],
                       env=env, check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
        return json.loads(Path(out.name).read_text())


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", nargs="+", default=["752x480x10", "2592x1944x12"])
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=3, help="runs per build (median)")
    ap.add_argument("--baseline", nargs="+", default=[BASELINE],
                    help="git commits to compare with")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--worker", nargs=3, metavar=("FRAMES", "OUT", "REPEAT"),
                    help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(*args.worker[:2], int(args.worker[2]))
        return
    tmp = Path(tempfile.mkdtemp(prefix="bench-cosim-"))
    trees = [("this tree", None)]
    bases = [] if args.no_baseline else args.baseline
    try:
        for i, ref in enumerate(bases):
            base = tmp / f"baseline{i}"
            subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(base),
                            ref], check=True, capture_output=True)
            trees.append((f"baseline {ref}", shim_for(base, tmp / f"shim{i}")))
        print(f"{'frame':>14} {'code':>17} {'build s':>8} {'cpu s':>6} {'run s':>6} "
              f"{'cpu s':>6} {'sim cpu':>7} {'Mpx/s':>6} {'cpu Mpx/s':>9} exact")
        for size in args.sizes:
            w, h, bits = (int(v) for v in size.split("x"))
            frames, cfg = frames_for(w, h, bits, args.frames)
            path = tmp / f"{size}.npz"
            fields = {k: getattr(cfg, k) for k in cfg.__dataclass_fields__}
            np.savez(path, frames=np.stack(frames), config=json.dumps(fields))
            px = w * h * len(frames)
            for name, pythonpath in trees:
                r = measure(path, args.repeat, pythonpath)
                print(f"{size:>14} {name:>17} {r['build']:>8.1f} {r['build_cpu']:>6.1f} "
                      f"{r['run']:>6.1f} {r['run_cpu']:>6.1f} {r['sim_cpu']:>7.1f} "
                      f"{px / r['run'] / 1e6:>6.2f} {px / r['run_cpu'] / 1e6:>9.2f} "
                      f"{r['exact']}", flush=True)
    finally:
        for i in range(len(bases)):
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                            str(tmp / f"baseline{i}")], capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
