"""Lens calibration from stars on simulated ``lohmann`` frames: how close the fitted camera
comes to the preset's, and whether the reported 1-sigma describe the scatter.

Each trial renders ``--frames`` frames of the ``lohmann`` preset (752 x 480, k1 = -0.37:
about 14 px of barrel distortion at the edge) at random attitudes with the flight exposure
(``lodestar.ground.onboard.SETTINGS``), then runs :func:`lodestar.ground.calibrate.calibrate`
from a distortion-free pinhole with the nominal horizontal FOV, as ``lodestar calibrate
--fov`` does.  Per free parameter: the median reported 1-sigma and the deviation from the
truth in units of the reported 1-sigma (``z``): mean, standard deviation (1 when the 1-sigma
are right), largest ``|z|`` and the share within 3; the joint chi-square of the deviation
under the fit's covariance (8 degrees of freedom: median 7.3, 99 % quantile 20.1);
residuals before and after (RMS, px and arcsec); wall time per calibration.

    .venv/bin/python benchmarks/bench_calibrate.py --trials 20 --frames 6
"""

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from lodestar.ground import calibrate, imagesolve

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from tests.ground import lohmann_frames  # noqa: E402  (the tests' frames and start camera)


def trial(folder, n_frames, seed):
    paths = lohmann_frames.write_frames(folder, n=n_frames, seed=seed)
    images = [(p.name, imagesolve.read_image(p)) for p in paths]
    t0 = time.perf_counter()
    result = calibrate.calibrate(images, lohmann_frames.start_camera(),
                           ksigma=lohmann_frames.KSIGMA, skip_unsolved=True)
    seconds = time.perf_counter() - t0
    truth = calibrate.camera_params(lohmann_frames.truth_camera())
    names = result.fit.cov_names
    delta = np.array([result.fit.params[calibrate.INTRINSICS.index(n)] -
                      truth[calibrate.INTRINSICS.index(n)] for n in names])
    z = {n: d / result.sigma[n] for n, d in zip(names, delta)}
    chi2 = float(delta @ np.linalg.solve(result.fit.cov, delta))
    solved = sum(f["status"] == "OK" for f in result.frames)
    return z, chi2, result, seconds, solved


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--frames", type=int, default=6)
    p.add_argument("--seed", type=int, default=1000)
    args = p.parse_args(argv)
    zs, chi2s, rows, sigmas = [], [], [], []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(args.trials):
            try:
                z, chi2, res, sec, solved = trial(Path(tmp), args.frames, args.seed + k)
            except calibrate.CalibrationError as exc:
                print(f"trial {k}: {exc}", flush=True)
                continue
            zs.append(z)
            sigmas.append(res.sigma)
            chi2s.append(chi2)
            rows.append((res.before["rms_px"], res.after["rms_px"], res.before["rms_arcsec"],
                         res.after["rms_arcsec"], res.fit.n_pairs, res.fit.n_rejected, sec,
                         solved))
            print(f"trial {k}: chi2 {chi2:6.1f}, " + " ".join(
                f"{n} {v:+.2f}" for n, v in z.items()) + f"; {sec:.1f} s", flush=True)
    names = list(zs[0])
    z = np.array([[t[n] for n in names] for t in zs])
    print(f"\n{len(zs)} of {args.trials} trials calibrated, {args.frames} frames each\n")
    print("| parameter | median 1-sigma | mean z | std z | max abs z | within 3 sigma |")
    print("|---|---|---|---|---|---|")
    for j, n in enumerate(names):
        col = z[:, j]
        print(f"| {n} | {np.median([s[n] for s in sigmas]):.3g} | {col.mean():+.2f} | "
              f"{col.std(ddof=1):.2f} | {np.abs(col).max():.2f} | "
              f"{np.mean(np.abs(col) < 3):.0%} |")
    chi2s = np.array(chi2s)
    rows = np.array(rows)
    print(f"\njoint chi-square ({len(names)} dof): median {np.median(chi2s):.1f}, "
          f"max {chi2s.max():.1f}, above the 99 % quantile: {np.mean(chi2s > 20.09):.0%}")
    print(f"residual RMS before {np.median(rows[:, 0]):.2f} px ({np.median(rows[:, 2]):.0f}\"),"
          f" after {np.median(rows[:, 1]):.3f} px ({np.median(rows[:, 3]):.1f}\") (medians)")
    print(f"pairs per calibration {np.median(rows[:, 4]):.0f} (median), rejected "
          f"{np.median(rows[:, 5]):.0f}; frames solved in the last round "
          f"{rows[:, 7].sum():.0f} of {len(rows) * args.frames}; time per calibration "
          f"p50 {np.median(rows[:, 6]):.1f} s, max {rows[:, 6].max():.1f} s")


if __name__ == "__main__":
    main()
