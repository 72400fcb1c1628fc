"""Co-simulation speed: build time and pixels per second of the Verilated detector.

    .venv/bin/python benchmarks/bench_cosim.py [--sizes 752x480x10 2592x1944x12] [--frames N]

For each geometry: the Verilator build (once; cached builds are reused, so the first run
reports the real build time), then ``--frames`` simulated star frames through
``lodestar.cosim.runner.run_frames``, checked against the golden model.  Reports build seconds,
run seconds (stimulus, simulation, output parsing) and pixels per second of the run, with
the golden model's own speed on the same frames for comparison.
"""

import argparse
import tempfile
import time

import numpy as np

from lodestar.cosim.runner import Build, run_frames
from lodestar.golden import Detector
from lodestar.sim.presets import load_preset
from lodestar.sim.scene import detector_config, simulate


def frames_for(width, height, bits, n):
    preset = "lohmann" if bits == 10 else "estcube2"
    cam = load_preset(preset)
    cfg = detector_config(cam)
    frames = []
    for seed in range(n):
        q = np.array([0.1 * seed, 0.2, 0.3, 0.9])
        sim = simulate(cam, q / np.linalg.norm(q), seed=seed)
        frames.append(sim.frame[:height, :width].copy())
    return frames, cfg.replace(width=width, height=height)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", nargs="+", default=["752x480x10", "2592x1944x12"])
    ap.add_argument("--frames", type=int, default=2)
    args = ap.parse_args()
    root = tempfile.mkdtemp(prefix="bench-cosim-")
    print(f"{'frame':>14} {'build s':>8} {'run s':>7} {'Mpx/s':>6} {'golden Mpx/s':>12} exact")
    for size in args.sizes:
        w, h, bits = (int(v) for v in size.split("x"))
        frames, cfg = frames_for(w, h, bits, args.frames)
        t0 = time.perf_counter()
        Build(w, h, bits, root=root).ensure()
        t_build = time.perf_counter() - t0
        t0 = time.perf_counter()
        got = run_frames(frames, cfg, build_root=root)
        t_run = time.perf_counter() - t0
        golden = Detector(cfg)
        t0 = time.perf_counter()
        want = [golden.process(f) for f in frames]
        t_golden = time.perf_counter() - t0
        px = w * h * len(frames)
        print(f"{size:>14} {t_build:>8.1f} {t_run:>7.1f} {px / t_run / 1e6:>6.2f} "
              f"{px / t_golden / 1e6:>12.2f} {got == want}")


if __name__ == "__main__":
    main()
