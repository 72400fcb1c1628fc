"""Co-simulation speed: build time and pixels per second of the Verilated detector, against
a baseline commit measured side by side in the same run.

    .venv/bin/python benchmarks/bench_cosim.py [--sizes 752x480x10 2592x1944x12] [--frames N]
        [--baseline REF | --no-baseline]

For each geometry, and for this tree and the ``--baseline`` commit (default: the last commit
before issue 18's fast playback, checked out with ``git worktree add`` into a temporary
folder): a fresh Verilator build in an empty cache, then ``--frames`` simulated star frames
through ``lodestar.cosim.runner.run_frames``, checked against the golden model.  Each
measurement runs in its own process (``--worker``), so the baseline imports its own
``lodestar``.  Reports build and run seconds (run: stimulus, simulation, output parsing),
their CPU seconds (this process and its children: comparable on a loaded machine, where
wall time is not) and pixels per second of the run, wall and CPU.
"""

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

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


def _cpu():
    own = resource.getrusage(resource.RUSAGE_SELF)
    kids = resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def worker(frames_path, out_path):
    """Build and run the frames of ``frames_path`` with the ``lodestar`` on ``sys.path``;
    write the timings and whether the results match the golden model as JSON."""

    from lodestar.cosim.runner import Build, run_frames
    from lodestar.golden import Detector, DetectorConfig

    data = np.load(frames_path)
    frames = list(data["frames"])
    cfg = DetectorConfig(**json.loads(str(data["config"])))
    root = tempfile.mkdtemp(prefix="bench-cosim-")
    try:
        t0, c0 = time.perf_counter(), _cpu()
        Build(cfg.width, cfg.height, cfg.pixel_bits, cfg.label_capacity, cfg.record_capacity,
              root=root).ensure()
        t1, c1 = time.perf_counter(), _cpu()
        got = run_frames(frames, cfg, build_root=root)
        t2, c2 = time.perf_counter(), _cpu()
    finally:
        shutil.rmtree(root, ignore_errors=True)
    golden = Detector(cfg)
    exact = got == [golden.process(f) for f in frames]
    Path(out_path).write_text(json.dumps({"build": t1 - t0, "build_cpu": c1 - c0,
                                          "run": t2 - t1, "run_cpu": c2 - c1,
                                          "exact": exact}))


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


def measure(frames_path, pythonpath=None):
    env = dict(os.environ)
    if pythonpath:
        env["PYTHONPATH"] = str(pythonpath)
    with tempfile.NamedTemporaryFile(suffix=".json") as out:
        subprocess.run([sys.executable, __file__, "--worker", str(frames_path), out.name],
                       env=env, check=True, stdout=subprocess.DEVNULL,
                       stderr=subprocess.DEVNULL)
        return json.loads(Path(out.name).read_text())


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["752x480x10", "2592x1944x12"])
    ap.add_argument("--frames", type=int, default=2)
    ap.add_argument("--baseline", default=BASELINE, help="git commit to compare with")
    ap.add_argument("--no-baseline", action="store_true")
    ap.add_argument("--worker", nargs=2, metavar=("FRAMES", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        worker(*args.worker)
        return
    tmp = Path(tempfile.mkdtemp(prefix="bench-cosim-"))
    trees = [("this tree", None)]
    try:
        if not args.no_baseline:
            base = tmp / "baseline"
            subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", str(base),
                            args.baseline], check=True, capture_output=True)
            trees.append((f"baseline {args.baseline}", shim_for(base, tmp / "shim")))
        print(f"{'frame':>14} {'code':>17} {'build s':>8} {'cpu s':>6} {'run s':>6} "
              f"{'cpu s':>6} {'Mpx/s':>6} {'cpu Mpx/s':>9} exact")
        for size in args.sizes:
            w, h, bits = (int(v) for v in size.split("x"))
            frames, cfg = frames_for(w, h, bits, args.frames)
            path = tmp / f"{size}.npz"
            fields = {k: getattr(cfg, k) for k in cfg.__dataclass_fields__}
            np.savez(path, frames=np.stack(frames), config=json.dumps(fields))
            px = w * h * len(frames)
            for name, pythonpath in trees:
                r = measure(path, pythonpath)
                print(f"{size:>14} {name:>17} {r['build']:>8.1f} {r['build_cpu']:>6.1f} "
                      f"{r['run']:>6.1f} {r['run_cpu']:>6.1f} {px / r['run'] / 1e6:>6.2f} "
                      f"{px / r['run_cpu'] / 1e6:>9.2f} {r['exact']}", flush=True)
    finally:
        if not args.no_baseline:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force",
                            str(tmp / "baseline")], capture_output=True)
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
