"""Synthetic centroid scenes for star-identification tests and benchmarks (numpy).

:func:`centroid_scene` projects the catalogue through a sim :class:`Camera` at an attitude,
keeps the stars that land in the frame, drops some, adds Gaussian centroid noise and false
stars, orders everything by (jittered) brightness and returns camera-frame unit vectors, the
form the flight identification takes (``lodestar.firmware.starid.identify``).  Truth: the HIP
number of each observed star (0 for a false star) and the attitude.
"""

import numpy as np
from scipy.spatial.transform import Rotation

from lodestar.sim.catalogue import load


class Scene:
    """``vectors`` (N, 3) camera-frame unit vectors brightest first; ``hip`` (N,) truth HIP
    of the brightest component (0 = false star); ``components`` (list of N tuples) every HIP
    blended into the observed star; ``pixels`` (N, 2) noisy ``(x, y)``; ``q`` the true
    attitude."""

    def __init__(self, vectors, hip, pixels, q, components=None):
        self.vectors = vectors
        self.hip = hip
        self.pixels = pixels
        self.q = q
        self.components = components if components is not None else [
            (int(h),) if h else () for h in hip]

    def __len__(self):
        return len(self.hip)


def _blend(px, hips, mags, blend_px):
    """Merge stars closer than ``blend_px`` (brightest first) into flux-weighted blobs."""
    order = np.argsort(mags, kind="stable")
    blobs = []        # [sum_flux, sum_fx, sum_fy, [hips]]
    for i in order:
        f = 10 ** (-0.4 * mags[i])
        for blob in blobs:
            cx, cy = blob[1] / blob[0], blob[2] / blob[0]
            if (px[i, 0] - cx) ** 2 + (px[i, 1] - cy) ** 2 < blend_px ** 2:
                blob[0] += f
                blob[1] += f * px[i, 0]
                blob[2] += f * px[i, 1]
                blob[3].append(int(hips[i]))
                break
        else:
            blobs.append([f, f * px[i, 0], f * px[i, 1], [int(hips[i])]])
    out_px = np.array([[b[1] / b[0], b[2] / b[0]] for b in blobs]).reshape(-1, 2)
    out_mag = np.array([-2.5 * np.log10(b[0]) for b in blobs])
    return out_px, np.array([b[3][0] for b in blobs], dtype=np.int64), out_mag, \
        [tuple(b[3]) for b in blobs]


def centroid_scene(camera, q, rng, catalogue=None, mag_limit=6.0, noise_px=0.3, n_false=0,
                   drop_fraction=0.0, mag_jitter=0.2, max_stars=None, false_mag=(1.0, 6.0),
                   window=None, blend_px=2.0):
    """A :class:`Scene` at attitude ``q`` (``lodestar.sim`` convention).

    Stars with ``V <= mag_limit`` inside the frame (or ``window = (x0, y0, x1, y1)``,
    half-open pixel box) are observed; stars closer than ``blend_px`` merge into one
    flux-weighted centroid (as the detector sees them; truth ``hip`` = the brightest
    component, ``components`` = all); each observed star is then dropped with probability
    ``drop_fraction``; positions get Gaussian noise of ``noise_px`` per axis; ``n_false``
    false stars fall uniformly in the frame with magnitudes uniform in ``false_mag``; order
    is by magnitude plus Gaussian ``mag_jitter``; the list is cut to ``max_stars``.
    """
    if catalogue is None:
        catalogue = load()
    sel = catalogue.vmag <= mag_limit
    hip = np.asarray(catalogue.hip[sel], dtype=np.int64)
    vmag = np.asarray(catalogue.vmag[sel], dtype=np.float64)
    v_cam = Rotation.from_quat(q).apply(catalogue.unit_vectors()[sel])
    x, y, ok = camera.project(v_cam)
    x0, y0, x1, y1 = (-0.5, -0.5, camera.width - 0.5, camera.height - 0.5) if window is None \
        else window
    inside = ok & (x >= x0) & (x < x1) & (y >= y0) & (y < y1)
    px = np.stack([x[inside], y[inside]], axis=1)
    px, hips, mags, comps = _blend(px, hip[inside], vmag[inside], blend_px)
    keep = rng.random(len(hips)) >= drop_fraction
    px, hips, mags = px[keep], hips[keep], mags[keep]
    comps = [c for c, k in zip(comps, keep) if k]
    px = px + rng.normal(0.0, noise_px, px.shape)
    if n_false:
        fx = rng.uniform(x0, x1, n_false)
        fy = rng.uniform(y0, y1, n_false)
        px = np.concatenate([px, np.stack([fx, fy], axis=1)])
        hips = np.concatenate([hips, np.zeros(n_false, dtype=np.int64)])
        mags = np.concatenate([mags, rng.uniform(false_mag[0], false_mag[1], n_false)])
        comps = comps + [()] * n_false
    order = np.argsort(mags + rng.normal(0.0, mag_jitter, len(mags)), kind="stable")
    if max_stars is not None:
        order = order[:max_stars]
    px, hips = px[order], hips[order]
    vectors = camera.unproject(px[:, 0], px[:, 1]) if len(px) else np.zeros((0, 3))
    return Scene(vectors, hips, px, np.asarray(q, dtype=float), [comps[i] for i in order])


def attitude_error_deg(q_est, q_true):
    """Rotation angle (deg) between two attitudes."""
    r = Rotation.from_quat(q_est) * Rotation.from_quat(q_true).inv()
    return float(np.degrees(r.magnitude()))
