"""One Monte-Carlo trial of a campaign: simulator -> golden detector -> FPGA packet ->
flight firmware, checked against the truth.  Runs in worker processes (local or Dask), so
everything here is a plain function of its arguments and the results are JSON-ready.

A task is ``(study, preset, level, trial)``, keyed ``study/preset/level/trial``; its seed
depends on the trial index, not on the level, so every level sees the same attitudes and
noise (common random numbers).  :func:`verdict` judges one solve.  Seeds, camera settings and
the verdict's fields: ``docs/campaigns.md``.  Units: rates in deg/s in tasks and results,
rad/s towards the firmware; errors and sigmas in arcsec; magnitudes Johnson V.
"""

import dataclasses
import hashlib
import math

import numpy as np

from lodestar.contract.stardb import METHODS
from lodestar.firmware import centroids
from lodestar.firmware import status as S
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings
from lodestar.firmware.starid.search import DEFAULT_MAX_WORK
from lodestar.firmware.tracking import propagate
from lodestar.golden import detect_frame
from lodestar.ground import onboard
from lodestar.ground.onboard import detector_config
from lodestar.ground.solve import DEFAULT_DENSITY
from lodestar.ground.truth import attitude_error_arcsec, judge, match_rows
from lodestar.sim import attitude, catalogue, presets, scene

STUDIES = ("rate", "falsestars", "limiting", "accuracy", "fov")

RATES_DEG_S = (0.0, 0.5, 1.0, 1.5, 2.0, 3.0, 5.0)
"""Rates of the ``rate`` study (issue 7), deg/s."""
LIMITING_RATES_DEG_S = (0.0, 0.5, 1.0, 2.0, 3.0, 5.0, 10.0)
"""Rates of the ``limiting`` study, deg/s (Schumann's smear table reaches 10 deg/s and more)."""
FALSE_STARS = (0, 1, 2, 5, 10, 20)
"""False-star counts of the ``falsestars`` study (point sources at random directions,
V uniform in 3..6: ``lodestar.sim.scene.Extras``)."""
NOISE_PX = (0.0, 0.25, 0.5, 1.0, 1.5, 2.0, 3.0)
"""Extra Gaussian centroid noise of the ``falsestars`` study, px per axis."""
STAR_CAPS = (4, 5, 6, 8, 10, 12, 16, 24, 32)
"""Brightest records kept per frame in the ``accuracy`` study."""
AXES = ("cross", "random", "roll")
"""Rate axis: uniform in the camera's x-y plane (cross-boresight slew, the case of
Dzamba's Table 4.1 and the worst for smear), uniform on the sphere, or the boresight
(Schumann's spin)."""

RENDER_MAG_LIMIT = 7.0
"""Faintest catalogue star rendered in the ``rate``, ``falsestars`` and ``accuracy``
frames.  Fainter stars cannot be detected (a V = 7 star's brightest pixel gets about 40 % of
estcube2's 5-sigma threshold at rest; lohmann sees to V ~ 5), and rendering the catalogue to
V = 8 takes about three times as long at 2 deg/s.  The ``limiting`` study renders the whole
catalogue (``lodestar.sim.scene.CATALOGUE_LIMIT``) to measure detection near the limit."""

FOVS_DEG = (5.0, 8.0, 12.0, 20.0, 30.0, 40.0)
"""Horizontal fields of the ``fov`` study (issue 15), deg."""
FOV_FALSE_STARS = 3
"""False stars in every ``fov`` frame (``lodestar.sim.scene.Extras``: V uniform in 3..6)."""

LIMITING_BIN_MAG = 0.25
"""Magnitude bin of the ``limiting`` study's detection histograms."""
LIMITING_MAG_RANGE = (-2.0, 8.5)
"""Magnitudes binned by the ``limiting`` study (the catalogue stops at V = 8)."""
LIMITING_MATCH_PX = 3.0
"""A star counts as detected when a record's centroid lies this close to its true centroid
(the mean position over the exposure)."""
LIMITING_EDGE_PX = 10.0
"""Stars closer than this to the frame edge are left out of the ``limiting`` histograms."""

def task_key(task):
    """``study/preset/level/trial`` of a task tuple."""
    return "/".join(str(part) for part in task)


def trial_seed(seed, study, preset, trial):
    """The trial's seed (``docs/campaigns.md``): a non-negative int below 2**63."""
    digest = hashlib.sha256(f"{seed}/{study}/{preset}/{trial}".encode()).digest()
    return int.from_bytes(digest[:8], "little") >> 1



def rate_vector(rng, rate_deg_s, axis):
    """Body rate (deg/s, camera frame) of magnitude ``rate_deg_s`` about an axis drawn from
    ``rng`` as :data:`AXES` says."""
    if axis == "cross":
        phi = rng.uniform(0.0, 2.0 * math.pi)
        direction = np.array([math.cos(phi), math.sin(phi), 0.0])
    elif axis == "random":
        direction = rng.standard_normal(3)
        direction /= np.linalg.norm(direction)
    elif axis == "roll":
        direction = np.array([0.0, 0.0, 1.0 if rng.uniform() < 0.5 else -1.0])
    else:
        raise ValueError(f"unknown rate axis {axis!r} (known: {', '.join(AXES)})")
    return direction * rate_deg_s


class Frame:
    """One simulated and detected frame: ``cam`` (the preset), ``q`` (truth), ``omega_deg_s``,
    ``truth`` (the simulator's), ``image`` (its ADU, for the ground's own solve), ``det``
    (``DetectionResult``) and ``fw_cam``.  The catalogue
    is rendered to ``mag_limit`` (V), with ``false_stars`` extra point sources; ``cam``
    replaces the preset's camera (a sim ``Camera``), ``cat`` the shipped catalogue."""

    def __init__(self, preset, settings, seed, rate_deg_s=0.0, axis="cross",
                 false_stars=0, mag_limit=RENDER_MAG_LIMIT, cam=None, cat=None):

        self.cam = presets.load_preset(preset) if cam is None else cam
        rng = np.random.default_rng(seed)
        self.q = attitude.random_attitude(rng)
        self.omega_deg_s = rate_vector(rng, rate_deg_s, axis)
        sim = scene.simulate(self.cam, self.q, self.omega_deg_s, settings["exposure_s"], seed,
                             extras=scene.Extras(false_stars=false_stars),
                             mag_limit=mag_limit, cat=cat)
        self.truth = sim.truth
        self.image = sim.frame
        self.det = detect_frame(sim.frame, detector_config(self.cam, settings))
        self.fw_cam = onboard.firmware_camera(self.cam)

    @property
    def omega_rad_s(self):
        return [math.radians(w) for w in self.omega_deg_s]

    def database(self, method):
        return onboard.star_database(self.fw_cam, method=method)[0]

    def solve(self, method="pyramid", det=None, gyro=1.0, track=None):
        """The firmware on this frame's packet (or on ``det``): :func:`verdict`.  ``gyro``:
        the rate given, as a multiple of the true rate (a wrong gyro: -1, 2); None: none
        (the firmware fits it from the frame).  ``track``: ``(dt_s, seed)`` to track as the
        flight loop does, from a prior :func:`tracking_prior`; None: lost in space."""
        det = self.det if det is None else det
        omega = None if gyro is None else [gyro * w for w in self.omega_rad_s]
        prior = dt = None
        if track is not None:
            dt = track[0]
            prior = tracking_prior(self, dt, np.random.default_rng(track[1]))
        _data, res, _timings = onboard.process(
            det, self.fw_cam, self.database(method), omega=omega,
            exposure_s=self.truth["exposure_s"], row_time_s=self.truth["row_time_s"],
            method=method, prior=prior, dt=dt)
        return verdict(res, det.blobs, self)


TRACK_PRIOR_ERROR_ARCSEC = (30.0, 200.0)
"""1-sigma error (cross per axis, roll; arcsec) of :func:`tracking_prior`: about the reported
1 sigma of a solution at 30 deg/s about the boresight (``docs/campaigns.md``)."""


def tracking_prior(frame, dt_s, rng):
    """The flight loop's prior for ``frame``: the true attitude ``dt_s`` s before the frame's
    epoch, turned by a random error of :data:`TRACK_PRIOR_ERROR_ARCSEC` (Gaussian, per axis,
    camera frame), as the previous frame's solution would be; the firmware propagates it
    over ``dt_s`` with the gyro."""
    sigma = np.radians(np.array(TRACK_PRIOR_ERROR_ARCSEC)[[0, 0, 1]] / 3600.0)
    error = sigma * rng.standard_normal(3)
    return propagate(list(truth_at(frame, -dt_s)), list(-error), 1.0)


def truth_at(frame, t_s):
    """The true attitude of ``frame`` ``t_s`` s after the start of row 0's exposure (the
    simulator's instant; None: that instant), turned by its constant rate."""
    if not t_s:
        return frame.q
    return propagate(list(frame.q), frame.omega_rad_s, t_s)


def verdict(res, records, frame):
    """The outcome of a firmware ``Result`` on ``frame``, judged at the instant it holds for
    (``t_epoch_s``); ``records`` are the records its ``matches`` index.  An ``IMPRECISE``
    result (an attitude whose error bound exceeds ``max_error_arcsec``) is not solved, but
    its attitude's error and sigmas are kept under ``loose`` (the availability and the
    wrong solutions another limit would give follow from them exactly)."""
    out = {"status": res.status_name, "solved": bool(res.ok), "wrong": False,
           "imprecise": False,
           "wrong_matches": 0, "n_matches": 0, "n_records": len(records),
           "error_arcsec": None, "sigma_arcsec": None}
    if res.status == S.IMPRECISE and res.q is not None:
        error = attitude_error_arcsec(res.q, truth_at(frame, res.t_epoch_s))
        out["loose"] = {"error_arcsec": [error["x"], error["y"], error["roll"]],
                        "sigma_arcsec": [res.sigma_cross_arcsec, res.sigma_roll_arcsec]}
    if not res.ok:
        return out
    out["t_epoch_s"] = res.t_epoch_s
    error = attitude_error_arcsec(res.q, truth_at(frame, res.t_epoch_s))
    rows = match_rows(res.matches, records, frame.truth["sources"])
    out["n_matches"] = len(rows)
    out["wrong_matches"] = sum(not r["right"] for r in rows)
    out["wrong"], out["imprecise"] = judge(error, res.sigma_cross_arcsec,
                                           res.sigma_roll_arcsec, out["wrong_matches"])
    out["status"] = "WRONG" if out["wrong"] else "OK"
    out["error_arcsec"] = [error["x"], error["y"], error["roll"]]
    out["sigma_arcsec"] = [res.sigma_cross_arcsec, res.sigma_roll_arcsec]
    return out


# ---- the studies' trials ---------------------------------------------------------------

def rate_trial(preset, level, seed, config):
    """``rate``: one frame at ``level`` deg/s, solved with the campaign's method."""
    frame = Frame(preset, config["camera"], seed, float(level), config["axis"])
    return frame.solve(config["method"], gyro=1.0 if config.get("gyro", True) else None)


def falsestars_trial(preset, level, seed, config):
    """``falsestars``: at rest.  ``false=N``: a frame with N false stars, solved by every
    method.  ``noise``: one frame, its firmware centroids displaced by Gaussian noise of each
    :data:`NOISE_PX` (the same unit draws scaled, for every method), solved from the
    directions.  Returns ``{method: verdict}`` or ``{method: {noise: verdict}}``."""
    if level.startswith("false="):
        frame = Frame(preset, config["camera"], seed, false_stars=int(level[6:]))
        return {method: frame.solve(method) for method in METHODS}
    if level != "noise":
        raise ValueError(f"unknown falsestars level {level!r}")

    frame = Frame(preset, config["camera"], seed)
    stars, _rejected = centroids.extract(frame.det.blobs)
    unit = np.random.default_rng(seed).standard_normal((len(stars), 2))
    out = {}
    for method in METHODS:
        # the ground budget, as every other trial (onboard.process): the study is of noise
        tracker = StarTracker(frame.database(method), frame.fw_cam, Settings(
            method=method, tolerance_px=onboard.default_tolerance_px(frame.fw_cam),
            max_work=DEFAULT_MAX_WORK))
        out[method] = {}
        for sigma in NOISE_PX:
            vectors, used = [], []
            for i, star in enumerate(stars):
                v = frame.fw_cam.pixel_to_vector(star.x + sigma * unit[i, 0],
                                                 star.y + sigma * unit[i, 1])
                if v is not None:
                    vectors.append(v)
                    used.append(i)
            res = tracker.solve_vectors(vectors, fluxes=[stars[i].flux for i in used])
            if res.ok:
                res.matches = [(stars[used[o]].index, stars[used[o]].x, stars[used[o]].y, hip)
                               for o, _x, _y, hip in res.matches]
            out[method][f"{sigma:g}"] = verdict(res, frame.det.blobs, frame)
    return out


def limiting_trial(preset, level, seed, config):
    """``limiting``: one frame at ``level`` deg/s; per magnitude bin (:data:`LIMITING_BIN_MAG`
    from ``LIMITING_MAG_RANGE[0]``) the stars in the frame (at least
    :data:`LIMITING_EDGE_PX` from the edges) and those detected: ``{"total": [...],
    "found": [...]}``.  Stars are taken brightest first, each claiming the nearest unclaimed
    record centroid within :data:`LIMITING_MATCH_PX`."""

    frame = Frame(preset, config["camera"], seed, float(level), config["axis"],
                  mag_limit=scene.CATALOGUE_LIMIT)
    lo, hi = LIMITING_MAG_RANGE
    n_bins = int(round((hi - lo) / LIMITING_BIN_MAG))
    total = [0] * n_bins
    found = [0] * n_bins
    blobs = [b for b in frame.det.blobs if b.s0 > 0]
    centres = np.array([(b.sx / b.s0, b.sy / b.s0) for b in blobs]).reshape(-1, 2)
    free = np.ones(len(centres), dtype=bool)
    e = LIMITING_EDGE_PX
    stars = sorted((s for s in frame.truth["sources"] if s["kind"] == "star"
                    and e <= s["x"] <= frame.cam.width - 1 - e
                    and e <= s["y"] <= frame.cam.height - 1 - e), key=lambda s: s["vmag"])
    for s in stars:
        k = int((s["vmag"] - lo) // LIMITING_BIN_MAG)
        if not 0 <= k < n_bins:
            continue
        total[k] += 1
        if free.any():
            d = np.hypot(centres[:, 0] - s["x"], centres[:, 1] - s["y"])
            d[~free] = np.inf
            j = int(np.argmin(d))
            if d[j] <= LIMITING_MATCH_PX:
                free[j] = False
                found[k] += 1
    return {"total": total, "found": found}


def accuracy_trial(preset, level, seed, config):
    """``accuracy``: one frame at rest; for each cap of :data:`STAR_CAPS` the packet keeps
    the cap's brightest records (largest ``s0``, emission order kept):
    ``{str(cap): verdict}``."""
    frame = Frame(preset, config["camera"], seed)
    order = sorted(range(len(frame.det.blobs)), key=lambda i: (-frame.det.blobs[i].s0, i))
    out = {}
    for cap in STAR_CAPS:
        keep = sorted(order[:cap])
        det = frame.det.replace(blobs=[frame.det.blobs[i] for i in keep],
                                  n_filtered=frame.det.n_filtered + len(order) - len(keep))
        out[str(cap)] = frame.solve(config["method"], det)
    return out


def fov_camera(preset, fov_deg):
    """The ``fov`` study's camera: :func:`lodestar.sim.presets.pinhole` of ``preset`` with a
    horizontal FOV of ``fov_deg`` (a 5 deg lens of estcube2's f/1.2 is 65 mm, 54 mm across;
    a 40 deg one 7.8 mm, 6.5 mm across)."""
    return dataclasses.replace(presets.pinhole(preset, fov_deg),
                               name=f"{preset}-fov{fov_deg:g}")


def fov_render_limit(preset, cam):
    """Faintest star (V) rendered by the ``fov`` study for ``cam`` (from
    :func:`fov_camera`): :data:`RENDER_MAG_LIMIT` shifted by the aperture's light grasp
    over the preset's, ``5 log10(D / D_preset)`` (same sensor, same PSF in pixels, so the
    same detection threshold in electrons): V 10.0 at 5 deg, V 5.5 at 40 deg for estcube2."""
    return RENDER_MAG_LIMIT + 5 * math.log10(cam.aperture_mm /
                                             presets.load_preset(preset).aperture_mm)


def fov_database(fw_cam, method):
    """The ``fov`` study's star database for the firmware camera ``fw_cam``: the ground
    solve's default (:data:`lodestar.ground.solve.DEFAULT_DENSITY` stars per field, no
    magnitude limit, from the whole Hipparcos), built once and cached."""
    return onboard.star_database(fw_cam, max_mag=None, method=method,
                                     density=DEFAULT_DENSITY)[0]


def fov_trial(preset, level, seed, config):
    """``fov``: one frame at rest of :func:`fov_camera` at ``level`` deg (the whole
    Hipparcos rendered to :func:`fov_render_limit`, :data:`FOV_FALSE_STARS` false stars),
    solved by the flight pipeline over :func:`fov_database`: the :func:`verdict` with the
    solve's wall time ``solve_ms`` (CPython) and the database's ``db_stars``."""
    cam = fov_camera(preset, float(level))
    frame = Frame(preset, config["camera"], seed, false_stars=FOV_FALSE_STARS,
                  mag_limit=fov_render_limit(preset, cam), cam=cam, cat=catalogue.load_deep())
    db = fov_database(frame.fw_cam, config["method"])
    _data, res, timings = onboard.process(
        frame.det, frame.fw_cam, db, omega=frame.omega_rad_s,
        exposure_s=frame.truth["exposure_s"], row_time_s=frame.truth["row_time_s"],
        method=config["method"])
    return dict(verdict(res, frame.det.blobs, frame), solve_ms=timings["solve"],
                db_stars=db.n_stars)


TRIALS = {"rate": rate_trial, "falsestars": falsestars_trial, "limiting": limiting_trial,
          "accuracy": accuracy_trial, "fov": fov_trial}


def run_task(task, config):
    """Run one task ``(study, preset, level, trial)`` under the campaign ``config``
    (``seed``, ``camera`` = :func:`camera_settings` per preset, ``axis``, ``method``):
    ``(key, result)``."""
    study, preset, level, trial = task
    seed = trial_seed(config["seed"], study, preset, trial)
    settings = config["camera"][preset]
    return task_key(task), TRIALS[study](preset, level, seed, dict(config, camera=settings))
