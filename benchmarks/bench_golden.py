"""Benchmark of the golden models (run: ``.venv/bin/python benchmarks/bench_golden.py``).

* Vectorized model on a 2592 x 1944 12-bit star frame with noise (~100 stars), ms per frame,
  for each threshold mode, against the baseline measured in the same run: a bare
  ``scipy.ndimage.label`` of the thresholded frame plus ``numpy.bincount`` sums of the same
  seven features (float, so neither exact nor saturating, and unordered).  Goal <= 200 ms.
* Streaming model throughput in pixels/s on a 752 x 480 10-bit frame (MT9V022): a star frame
  (it visits only lit pixels and those below a blob) and a frame 59 % lit (its worst case).
"""

import argparse
import json
import time

import numpy as np
from scipy import ndimage

from lodestar.golden import DetectorConfig, detect_frame, streaming, vectorized
from lodestar.golden.frame import check_frame
from lodestar.golden.starfield import star_frame

CROSS = np.array([[0, 1, 0], [1, 1, 1], [0, 1, 0]], dtype=bool)


def best_of(fn, repeat):
    """Fastest of ``repeat`` runs, in seconds (the least disturbed by the machine)."""
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def baseline(frame, threshold, background):
    """Bare label + bincount sums: the floor any whole-frame detector builds on."""
    lit = frame > threshold
    labels, count = ndimage.label(lit, structure=CROSS)
    ys, xs = np.nonzero(labels)
    lab = labels[ys, xs]
    w = np.maximum(frame[ys, xs].astype(np.float64) - background, 0)
    return [np.bincount(lab, weights=v, minlength=count + 1)
            for v in (np.ones_like(w), w, w * xs, w * ys, w * xs * xs, w * ys * ys, w * xs * ys)]


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=7)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()

    frame, _ = star_frame(2592, 1944, 12, n_stars=100, seed=1)
    rows = {}
    t_base = best_of(lambda: baseline(frame, 120, 40), args.repeat)
    rows["baseline label+bincount"] = t_base
    configs = {
        "vectorized fixed (ST-16)": DetectorConfig(2592, 1944, 12, threshold=120, background=40,
                                                   min_pixels=6, min_sum=1000),
        "vectorized global 5 sigma": DetectorConfig(2592, 1944, 12, threshold_mode="global",
                                                    ksigma=5.0, min_pixels=6, min_sum=1000),
        "vectorized local 128": DetectorConfig(2592, 1944, 12, threshold_mode="local",
                                               local_offset=40, min_pixels=6, min_sum=1000),
    }
    checked = check_frame(frame, configs["vectorized fixed (ST-16)"])
    stats = vectorized.frame_stats(checked)
    for name, cfg in configs.items():
        rows[name] = best_of(lambda: vectorized.detect(check_frame(frame, cfg), cfg, stats),
                             args.repeat)
    n_blobs = len(detect_frame(frame, configs["vectorized fixed (ST-16)"]).blobs)

    small, _ = star_frame(752, 480, 10, n_stars=30, seed=2, background=30)
    scfg = DetectorConfig(752, 480, 10, threshold=60, background=30, min_pixels=4)
    t_stream = best_of(lambda: streaming.detect(check_frame(small, scfg), scfg, None), 3)
    t_svec = best_of(lambda: vectorized.detect(check_frame(small, scfg), scfg, None), 3)
    # worst case for the streaming model: half the pixels lit at the percolation threshold
    rng = np.random.default_rng(3)
    dense = np.where(rng.random((480, 752)) < 0.5927, 500, 0).astype(np.uint16)
    t_dense = best_of(lambda: streaming.detect(check_frame(dense, scfg), scfg, None), 1)

    report = {
        "frame": "2592x1944x12, 100 stars", "records": n_blobs,
        "ms": {k: round(v * 1e3, 2) for k, v in rows.items()},
        "ratio_to_baseline": {k: round(v / t_base, 2) for k, v in rows.items()},
        "streaming_752x480_pixels_per_s": round(752 * 480 / t_stream),
        "streaming_752x480_ms": round(t_stream * 1e3, 1),
        "vectorized_752x480_ms": round(t_svec * 1e3, 2),
        "streaming_752x480_dense_pixels_per_s": round(752 * 480 / t_dense),
    }
    if args.json:
        print(json.dumps(report, indent=1))
        return
    print(f"2592x1944x12 star frame, {n_blobs} records (fixed mode); best of {args.repeat}")
    for name, t in rows.items():
        print(f"  {name:<28} {t * 1e3:8.1f} ms   x{t / t_base:5.2f} baseline")
    print(f"streaming model, 752x480x10: {t_stream * 1e3:.0f} ms/frame = "
          f"{752 * 480 / t_stream / 1e6:.2f} Mpixel/s (vectorized: {t_svec * 1e3:.1f} ms); "
          f"59 % lit random frame: {752 * 480 / t_dense / 1e6:.2f} Mpixel/s")


if __name__ == "__main__":
    main()
