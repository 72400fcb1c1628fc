"""Benchmark of ``lodestar.sim.scene.simulate`` on full frames of the default camera.

Goal (issue): a 2592 x 1944 frame with ~100 stars renders in under 2 s.  Real catalogue
fields hold more: the table reports the sources each frame carries.

    .venv/bin/python benchmarks/bench_simulate.py
"""

import time

import numpy as np

from lodestar.sim import attitude, presets, scene, sensor


def main():
    cam = presets.load_preset("estcube2")
    defects = sensor.SensorDefects.generate(cam.height, cam.width, seed=1)
    cases = [("sparse, V<=6.5", (192.86, 27.13, 0.0), 6.5),
             ("Orion, V<=8", (83.8, -5.4, 10.0), 8.0)]
    print("estcube2 2592x1944x12, rolling shutter, with sensor defects; best of 3")
    for label, pointing, mag in cases:
        q = attitude.from_radec_roll(*pointing)
        for rate in (0.0, 1.0, 2.0, 5.0):
            omega = (rate * 0.8, rate * 0.6, 0.0)
            best, n = np.inf, 0
            for seed in range(3):
                t0 = time.perf_counter()
                sim = scene.simulate(cam, q, omega, seed=seed, mag_limit=mag, defects=defects)
                best = min(best, time.perf_counter() - t0)
                n = len(sim.truth["sources"])
            print(f"  {label:<16} {rate:3.0f} deg/s  {n:4d} sources  {best:5.2f} s/frame")


if __name__ == "__main__":
    main()
