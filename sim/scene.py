"""One simulated frame with its truth: catalogue -> attitude and rates -> camera -> pixels.

``simulate`` selects the catalogue stars around the boresight, moves them in the camera
frame at the body rates during the exposure (each rolling-shutter row at its own time),
projects them through the distorted camera model, renders them (``render``), adds the
extra objects (false stars, planets, cosmic rays) and runs the sensor chain (``sensor``).
Conventions are those of ``lodestar.sim`` (scalar-last quaternion ``v_cam = R(q) v_in``,
body rates in the camera frame).  Everything is deterministic for a given ``seed``.
"""

from dataclasses import dataclass, field

import numpy as np
from scipy.spatial.transform import Rotation

from lodestar import contract as C
from lodestar.firmware.aberration import SPEED_OF_LIGHT_KM_S
from lodestar.golden import DetectorConfig

from . import attitude, catalogue, photometry, render, sensor

SKY_E_PER_PX_S = 5.0
"""Default sky background (e⁻/px/s): zodiacal light and diffuse starlight, order of magnitude."""

CATALOGUE_LIMIT = 8.0
"""Faintest catalogue magnitude rendered by default (the catalogue's completeness)."""


@dataclass
class Extras:
    """Objects beyond the catalogue stars.

    ``false_stars``: count of point sources at random inertial directions in the field,
    magnitudes uniform in ``false_star_mag``; ``planets``: ``(name, ra_deg, dec_deg, vmag)``
    bright sources; ``cosmic_rays``: count of sharp streaks (``render.add_cosmic_rays``).
    """

    false_stars: int = 0
    false_star_mag: tuple = (3.0, 6.0)
    planets: tuple = ()
    cosmic_rays: int = 0


@dataclass
class SimFrame:
    """A simulated frame: ``frame`` (uint16, [y, x]) and ``truth`` (JSON-ready dict)."""

    frame: np.ndarray
    truth: dict = field(default_factory=dict)


def _check_vector(name, value):
    v = np.asarray(value, dtype=np.float64)
    if v.shape != (3,) or not np.all(np.isfinite(v)):
        raise ValueError(f"{name} must be 3 finite numbers, got {value!r}")
    return v


def apparent(v_inertial, velocity_km_s):
    """Apparent unit directions (N, 3) of the geometric ICRS unit directions ``v_inertial``
    seen by an observer moving at ``velocity_km_s`` (ICRS, km/s): the exact (special
    relativistic) aberration ``p = (u / gamma + beta + (u . beta) beta / (1 + 1 / gamma)) /
    (1 + u . beta)``, ``beta = v / c`` (``docs/apparent_directions.md``)."""
    u = np.asarray(v_inertial, dtype=np.float64)
    b = _check_vector("velocity_km_s", velocity_km_s) / SPEED_OF_LIGHT_KM_S
    if not np.dot(b, b) < 1.0:
        raise ValueError(f"velocity_km_s must be slower than light, got {velocity_km_s!r}")
    inv_gamma = np.sqrt(1.0 - np.dot(b, b))
    ub = u @ b
    p = (u * inv_gamma + b + np.outer(ub, b) / (1.0 + inv_gamma)) / (1.0 + ub)[:, None]
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _sources_in_view(cam, q, omega, span_s, cat):
    """Catalogue subset that may fall on the detector during ``span_s`` seconds."""
    ra, dec, _ = attitude.to_radec_roll(q)
    sweep = np.degrees(np.linalg.norm(omega)) * span_s
    return cat.cone(float(ra), float(dec), cam.boresight_radius_deg() + sweep + 1.0)


def _track_function(cam, q, omega, v_inertial):
    """``positions(t)`` for ``render.render_stars``: (N, T, 2) pixel tracks.

    A fixed inertial direction moves in the camera frame as ``v(t) = exp(-[omega x] t) v(0)``.
    Directions behind the camera or beyond the model's valid radius are placed far outside the
    frame so the renderer skips them.
    """
    v0 = Rotation.from_quat(q).apply(v_inertial)
    far = -1e6

    def positions(times):
        mats = Rotation.from_rotvec(-np.outer(times, omega)).as_matrix()    # (T, 3, 3)
        v = np.einsum("tij,nj->nti", mats, v0)
        x, y, _ = cam.project(v)
        ok = np.isfinite(x) & np.isfinite(y) & (v[..., 2] > 0) & \
            (np.hypot(v[..., 0], v[..., 1]) / np.maximum(v[..., 2], 1e-12) < cam.fold_radius())
        return np.stack([np.where(ok, x, far), np.where(ok, y, far)], axis=-1)

    return positions


TRACK_POINTS = 5
"""Points of a source's visible track in the truth (``track``)."""
TRACK_SAMPLES = 129
"""Times sampled over the frame's span to find each source's visible track."""


def visible_tracks(positions, indices, height, exposure_s, row_time_s):
    """Visible tracks of the sources ``indices`` of ``positions`` (``_track_function``):
    a list of ``TRACK_POINTS`` ``[x, y]`` points each (px), evenly spaced in time from the
    first to the last instant the source is seen: at time ``t`` (s from the start of row 0's
    exposure) a source at row ``y`` is seen when ``y row_time_s <= t <= y row_time_s +
    exposure_s`` (rolling shutter; ``row_time_s = 0`` is a global shutter).  A source
    never seen on a sampled instant (it only grazes the frame) gets an empty list."""
    if len(indices) == 0:
        return []
    span = (height - 1) * row_time_s + exposure_s
    times = np.linspace(0.0, span, TRACK_SAMPLES)
    tracks = positions(times)[indices]                      # (N, T, 2)
    row = np.clip(np.rint(tracks[..., 1]), 0, height - 1)
    start = row * row_time_s
    seen = (start <= times + 1e-12) & (times <= start + exposure_s + 1e-12) & \
        (tracks[..., 1] > -0.5) & (tracks[..., 1] < height - 0.5)
    out = []
    for i in range(len(indices)):
        t_seen = times[seen[i]]
        if len(t_seen) == 0:
            out.append([])
            continue
        pts = positions(np.linspace(t_seen[0], t_seen[-1], TRACK_POINTS))[indices[i]]
        out.append([[float(x), float(y)] for x, y in pts])
    return out


def _random_directions_in_view(cam, q, rng, count):
    """Inertial unit vectors of ``count`` random pixels of the frame (at t = 0)."""
    x = rng.uniform(-0.5, cam.width - 0.5, count)
    y = rng.uniform(-0.5, cam.height - 0.5, count)
    return Rotation.from_quat(q).inv().apply(cam.unproject(x, y))


def simulate(cam, q, omega_deg_s=(0.0, 0.0, 0.0), exposure_s=None, seed=0, *,
             mag_limit=CATALOGUE_LIMIT, psf_sigma_px=None, sky_e_per_px_s=SKY_E_PER_PX_S,
             defects=None, extras=None, cat=None, velocity_km_s=None):
    """Render one frame of camera ``cam`` at attitude ``q`` turning at ``omega_deg_s``.

    ``q``: scalar-last quaternion (inertial -> camera).  ``omega_deg_s``: body rates, deg/s,
    camera frame.  ``exposure_s``: s (default ``cam.exposure_s``).  ``seed``: frame noise and
    extras.  ``defects``: ``sensor.SensorDefects`` of the camera's sensor (fixed pattern),
    or None for an ideal sensor.  ``velocity_km_s``: the observer's velocity (ICRS, km/s):
    every source is drawn at its aberrated, apparent direction (:func:`apparent`; None:
    geometric directions, no aberration).  Returns a :class:`SimFrame`; its truth's ``sources`` give
    per rendered source ``kind``, ``hip``, ``name``, ``vmag``, ``electrons``,
    ``electrons_in_frame``, ``x``, ``y`` (the centroid of its smeared image, px) and
    ``track`` (:func:`visible_tracks`: where it was seen during the exposure).
    """
    q = np.asarray(q, dtype=np.float64)
    attitude.boresight(q)                         # validates q (NaN, norm, shape)
    omega = np.radians(_check_vector("omega_deg_s", omega_deg_s))
    exposure = cam.exposure_s if exposure_s is None else float(exposure_s)
    if not exposure > 0 or not np.isfinite(exposure):
        raise ValueError(f"exposure_s must be > 0, got {exposure_s!r}")
    sigma = cam.psf_sigma_px if psf_sigma_px is None else float(psf_sigma_px)
    extras = extras or Extras()
    rng = np.random.default_rng(seed)
    noise_rng, extra_rng = rng.spawn(2)
    row_time = cam.row_time_s if cam.shutter == "rolling" else 0.0
    span = exposure + (cam.height - 1) * row_time

    cat = (cat or catalogue.load()).brighter_than(mag_limit)
    stars = _sources_in_view(cam, q, omega, span, cat)
    kinds = ["star"] * len(stars)
    ids = [int(h) for h in stars.hip]
    names = [stars.name(h) for h in stars.hip]
    mags = [float(m) for m in stars.vmag]
    dirs = [stars.unit_vectors()]
    if extras.false_stars:
        dirs.append(_random_directions_in_view(cam, q, extra_rng, extras.false_stars))
        mags += list(extra_rng.uniform(*extras.false_star_mag, extras.false_stars))
        kinds += ["false_star"] * extras.false_stars
        ids += [None] * extras.false_stars
        names += [None] * extras.false_stars
    for name, ra, dec, vmag in extras.planets:
        dirs.append(catalogue.radec_to_vectors(np.array([ra]), np.array([dec])))
        mags.append(float(vmag))
        kinds.append("planet")
        ids.append(None)
        names.append(name)
    v_inertial = np.concatenate(dirs) if dirs else np.zeros((0, 3))
    if velocity_km_s is not None:
        v_inertial = apparent(v_inertial, velocity_km_s)

    electrons = photometry.photo_electrons(np.array(mags, dtype=np.float64), cam.aperture_mm,
                                           exposure, cam.qe)
    electrons = np.atleast_1d(np.asarray(electrons, dtype=np.float64))
    positions = _track_function(cam, q, omega, v_inertial)
    image_e, rtruth = render.render_stars(cam.height, cam.width, positions, electrons, sigma,
                                          exposure, row_time)
    rays = render.add_cosmic_rays(image_e, extra_rng, extras.cosmic_rays)
    frame = sensor.expose(image_e, noise_rng, exposure, sky_e_per_px_s, cam.dark_current_e_per_s,
                          cam.read_noise_e, cam.gain_adu_per_e, cam.adc_offset_adu,
                          cam.pixel_bits, defects=defects,
                          reserved_low_codes=cam.meta.get("reserved_low_codes") or None)

    sources = []
    shown = np.flatnonzero(rtruth.in_frame_fraction > 0)
    tracks = visible_tracks(positions, shown, cam.height, exposure, row_time)
    for i, track in zip(shown, tracks):
        sources.append({
            "kind": kinds[i], "hip": ids[i], "name": names[i], "vmag": round(mags[i], 4),
            "electrons": float(electrons[i]),
            "electrons_in_frame": float(rtruth.electrons_in_frame[i]),
            "x": float(rtruth.centroid[i, 0]), "y": float(rtruth.centroid[i, 1]),
            "track": track,
        })
    ra, dec, roll = attitude.to_radec_roll(q)
    truth = {
        "preset": cam.name, "width": cam.width, "height": cam.height,
        "pixel_bits": cam.pixel_bits,
        "quaternion_xyzw": [float(v) for v in q],
        "quaternion_convention": "scalar last; v_cam = Rotation.from_quat(q).apply(v_inertial)",
        "ra_deg": float(ra), "dec_deg": float(dec), "roll_deg": float(roll),
        "omega_deg_s": [float(v) for v in np.degrees(omega)],
        "exposure_s": exposure, "row_time_s": row_time, "psf_sigma_px": sigma,
        "seed": seed, "sky_e_per_px_s": sky_e_per_px_s, "mag_limit": mag_limit,
        "hot_pixels": [] if defects is None else defects.hot_pixels.tolist(),
        "sources": sources,
        "cosmic_rays": [{"start": list(r.start), "end": list(r.end), "electrons": r.electrons}
                        for r in rays],
    }
    if velocity_km_s is not None:
        truth["velocity_km_s"] = [float(v) for v in velocity_km_s]
    return SimFrame(frame, truth)


def detector_config(cam, exposure_s=None, **changes):
    """Fixed-mode detector registers suited to a camera and exposure (s, default the
    camera's): ``B`` at the mean dark level (offset, dark current and sky) and
    ``T = B + 5 sigma`` of the dark-frame noise (at least 1 ADU), ``min_pixels = 4``.

    ``changes`` override any ``DetectorConfig`` field.
    """

    t = cam.exposure_s if exposure_s is None else exposure_s
    dark_e = cam.dark_current_e_per_s * t + SKY_E_PER_PX_S * t
    background = int(round(cam.adc_offset_adu + cam.gain_adu_per_e * dark_e))
    sigma_adu = cam.gain_adu_per_e * float(np.sqrt(cam.read_noise_e ** 2 + dark_e))
    fs = C.full_scale(cam.pixel_bits)
    args = {"width": cam.width, "height": cam.height, "pixel_bits": cam.pixel_bits,
            "threshold_mode": "fixed", "background": min(background, fs),
            "threshold": min(background + max(int(np.ceil(5 * sigma_adu)), 1), fs),
            "min_pixels": 4}
    args.update(changes)
    return DetectorConfig(**args)
