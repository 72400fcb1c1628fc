"""Benchmark of the simulator's image formation (``render_stars`` and ``expose``).

Run: ``.venv/bin/python benchmarks/bench_sim_render.py [--repeat N] [--json]``.

A 2592 x 1944 frame (MT9P031) with 100 stars at random positions and directions, sigma
1.5 px, t_e = 0.1 s, rendered with straight tracks of 0, 13, 25 and 63 px (rest, and about
1, 2 and 5 deg/s cross-axis at f = 16 mm, 2.2 um pixels), with a global shutter and with the
MT9P031's 43.9 us rolling shutter.  Prints seconds per frame for ``render_stars`` and,
separately, for ``expose`` (shot, dark with DSNU and hot pixels, read noise, 12-bit ADC),
the fastest of ``--repeat`` runs.  Goals: rest well under 1 s, 63 px under ~1.5 s.
"""

import argparse
import json
import time

import numpy as np

from lodestar.sim.render import render_stars
from lodestar.sim.sensor import SensorDefects, expose

HEIGHT, WIDTH, N_STARS, SIGMA, EXPOSURE, ROW_TIME = 1944, 2592, 100, 1.5, 0.1, 43.9e-6
TRACKS_PX = {"rest": 0.0, "1 deg/s": 13.0, "2 deg/s": 25.0, "5 deg/s": 63.0}


def best_of(fn, repeat):
    """Fastest of ``repeat`` runs: ``(seconds, last result)``."""
    best, result = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        result = fn()
        best = min(best, time.perf_counter() - t0)
    return best, result


def star_field(track_px, seed=1):
    """``(positions, electrons)`` of straight tracks ``track_px`` long over the exposure."""
    rng = np.random.default_rng(seed)
    starts = np.column_stack([rng.uniform(0, WIDTH, N_STARS), rng.uniform(0, HEIGHT, N_STARS)])
    angle = rng.uniform(0, 2 * np.pi, N_STARS)
    velocity = track_px / EXPOSURE * np.column_stack([np.cos(angle), np.sin(angle)])
    electrons = np.exp(rng.uniform(np.log(200.0), np.log(2e5), N_STARS))

    def positions(t):
        return starts[:, None, :] + velocity[:, None, :] * np.asarray(t)[None, :, None]
    return positions, electrons


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    defects = SensorDefects.generate(HEIGHT, WIDTH, seed=1)
    rows = {}
    image = None
    for label, track in TRACKS_PX.items():
        positions, electrons = star_field(track)
        for shutter, row_time in (("global", 0.0), ("rolling", ROW_TIME)):
            seconds, (image, _) = best_of(lambda: render_stars(
                HEIGHT, WIDTH, positions, electrons, SIGMA, EXPOSURE, row_time), args.repeat)
            rows[f"render {label} ({track:.0f} px), {shutter} shutter"] = seconds
    rng = np.random.default_rng(2)
    rows["expose (12-bit, defects)"], _ = best_of(lambda: expose(
        image, rng, EXPOSURE, sky_e_per_px_s=50.0, dark_current_e_per_s=25.0, read_noise_e=3.5,
        gain_adu_per_e=7.0, adc_offset_adu=40.0, pixel_bits=12, defects=defects), args.repeat)
    if args.json:
        print(json.dumps(rows, indent=2))
        return
    for name, seconds in rows.items():
        print(f"{name:<45s} {seconds:7.3f} s/frame")


if __name__ == "__main__":
    main()
