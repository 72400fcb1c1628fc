"""Statistical analyses of detection on simulated frames (run them; report the tables).

``limiting``  Dzamba 2013 Eq 5.7 with the 1/4 restored, against simulated frames: the
              magnitude at which the golden detector finds half the stars (design 1 of
              Table 5.2: D = 12 mm, F# 1.2, 2.2 um pixels, 3.5 e- read noise, eta 0.5,
              t_e = 0.1 s), at rest and at 1 deg/s cross-axis.
``centroid``  golden-detector centroid error (sx/s0, sy/s0 against the exact truth) versus
              magnitude and rate for both presets: the U-shaped curve (noise-limited faint
              stars, saturation-limited bright ones).

    .venv/bin/python benchmarks/analysis_detection.py limiting
    .venv/bin/python benchmarks/analysis_detection.py centroid
"""

import argparse
import dataclasses

import numpy as np

from lodestar.golden import detect_frame
from lodestar.sim import photometry, presets, render, scene, sensor

GRID = 12          # stars per side of the test pattern
SPACING = 48       # px between stars


def star_grid(cam, vmag, rate_deg_s, rng, exposure_s=None, sigma_px=None):
    """Frame with GRID x GRID stars of magnitude ``vmag`` moving along +x at the rate.

    Returns ``(frame, truth_xy (N, 2), detector config)``.
    """
    exposure = exposure_s or cam.exposure_s
    sigma = sigma_px or cam.psf_sigma_px
    size = GRID * SPACING
    cam = dataclasses.replace(cam, width=size, height=size, cx=(size - 1) / 2,
                              cy=(size - 1) / 2)
    speed = cam.fx_px * np.radians(rate_deg_s)                         # px/s
    base = np.stack(np.meshgrid(np.arange(GRID), np.arange(GRID)), -1).reshape(-1, 2)
    start = (base + 0.5) * SPACING + rng.uniform(-0.5, 0.5, base.shape) - [speed * exposure / 2, 0]
    electrons = np.full(len(start), photometry.photo_electrons(vmag, cam.aperture_mm, exposure,
                                                                cam.qe))

    def positions(t):
        return start[:, None, :] + np.stack([speed * t, 0 * t], -1)[None, :, :]

    image, truth = render.render_stars(size, size, positions, electrons, sigma, exposure)
    frame = sensor.expose(image, rng, exposure, scene.SKY_E_PER_PX_S, cam.dark_current_e_per_s,
                          cam.read_noise_e, cam.gain_adu_per_e, cam.adc_offset_adu,
                          cam.pixel_bits)
    return frame, truth.centroid, scene.detector_config(cam, exposure, min_pixels=3)


def match(blobs, truth, radius=2.0):
    """``(found fraction, errors px, saturated flags)`` of blobs matched to truth points."""
    errors, saturated, found = [], [], np.zeros(len(truth), bool)
    for b in blobs:
        c = np.array([b.sx / b.s0, b.sy / b.s0])
        d = np.hypot(*(truth - c).T)
        i = int(d.argmin())
        if d[i] < radius and not found[i]:
            found[i] = True
            errors.append(d[i])
            saturated.append(b.nsat > 0)
    return found.mean(), np.array(errors), np.array(saturated, bool)


def limiting(args):
    cam = dataclasses.replace(presets.load_preset("estcube2"), aperture_mm=12.0,
                              focal_length_mm=14.4, fx_px=14.4e3 / 2.2, fy_px=14.4e3 / 2.2)
    rng = np.random.default_rng(args.seed)
    print("Dzamba design 1: D 12 mm, f 14.4 mm (F# 1.2), 2.2 um, 3.5 e-, eta 0.5, t_e 0.1 s;"
          " PSF sigma 2 px (radius 5 px)")
    for rate in (0.0, 1.0):
        formula = photometry.limiting_magnitude(12.0, 1.2, 2.2, 3.5, 0.5, 0.1, rate, 5.0, 10.0)
        mags = np.arange(4.0, 7.01, 0.25)
        fractions = []
        for m in mags:
            frame, truth, cfg = star_grid(cam, m, rate, rng, 0.1, 2.0)
            fractions.append(match(detect_frame(frame, cfg).blobs, truth)[0])
        fractions = np.array(fractions)
        m50 = float(np.interp(0.5, fractions[::-1], mags[::-1]))
        row = " ".join(f"{m:.2f}:{f:.2f}" for m, f in zip(mags, fractions))
        print(f"{rate:.0f} deg/s  Eq 5.7 (1/4 restored, SNR 10): m_t = {formula:.2f}; "
              f"simulated 50 % detection (T = B + 5 sigma): {m50:.2f}\n    {row}")


def centroid(args):
    rng = np.random.default_rng(args.seed)
    for name in ("estcube2", "lohmann"):
        cam = presets.load_preset(name)
        mags = np.arange(-1.0, 7.01, 0.5) if name == "estcube2" else np.arange(-2.0, 4.01, 0.5)
        print(f"\n{name}: RMS centroid error (px) of matched stars / detected fraction; "
              f"* = some saturated")
        print("  V     " + "".join(f"{r:>16g} deg/s" for r in args.rates))
        for m in mags:
            cells = []
            for rate in args.rates:
                frame, truth, cfg = star_grid(cam, m, rate, rng)
                found, err, sat = match(detect_frame(frame, cfg).blobs, truth)
                rms = float(np.sqrt(np.mean(err ** 2))) if len(err) else float("nan")
                cells.append(f"{rms:9.3f}{'*' if sat.any() else ' '} /{found:4.2f}")
            print(f"  {m:4.1f} " + "".join(f"{c:>22}" for c in cells))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("analysis", choices=("limiting", "centroid"))
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rates", type=float, nargs="+", default=[0.0, 0.5, 1.0, 2.0])
    args = parser.parse_args()
    {"limiting": limiting, "centroid": centroid}[args.analysis](args)


if __name__ == "__main__":
    main()
