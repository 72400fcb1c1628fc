"""The lens of a frame solved as a pinhole, fitted from its own matched stars (issue 33: a
strongly distorted lens solves right, blind and with ``--fov``).

After a first identification through a centred pinhole, the focal length ``f`` and the
radial ``k1`` (``fy`` apart from ``fx`` and ``k2`` when the stars support them) are fitted with the
attitude to the matched stars' pixel residuals by least squares
(:func:`lodestar.ground.calibrate.fit_camera`, one frame, principal point at the centre);
the firmware then identifies and verifies again through the fitted lens (:func:`refine`,
the ``refine`` of :func:`lodestar.ground.imagesolve.solve_image`).  A lens is used only when
the stars determine it: at least :data:`MIN_STARS`, and the 1-sigma of its correction within
:data:`MAX_SIGMA_PX` at the farthest matched star and :data:`MAX_CORNER_SIGMA_PX` at the
frame's corner; else the pinhole (and the firmware's radial check's honest ``IMPRECISE``)
stays.  The lens fit's own uncertainty enters the
attitude's: the attitude's 1-sigma with the lens free over that with the lens held
(:attr:`LensFit.inflation`) scales the firmware's.  Units: pixels of the detector's frame,
``k1``/``k2`` of normalised radius (``docs/conventions.md``).  Method and figures:
``docs/image_solving.md`` (Unknown lens)."""

import math
import time

import numpy as np
from scipy.spatial.transform import Rotation

from lodestar.firmware import pipeline
from lodestar.firmware import status as S
from lodestar.firmware.camera import Camera
from lodestar.firmware.settings import DEFAULT_MAX_ERROR_ARCSEC
from lodestar.ground import calibrate, imagesolve, solve
from lodestar.ground.database import default_catalogue

MIN_STARS = 8
"""Fewest matched stars a lens is fitted from (2 residuals each, 5 or 6 unknowns)."""
K2_STARS = 20
"""Fewest matched stars ``k2`` is fitted from as well."""
ASPECT_STARS = 10
"""Fewest matched stars ``fy`` is fitted from apart from ``fx``."""
SIGNIFICANCE = 3.0
"""A fitted ``fy / fx - 1`` or ``k2`` within this many of its 1-sigma of 0 is dropped."""
MAX_SIGMA_PX = 1.0
"""Largest 1-sigma (px) of the fitted distortion's correction at the farthest matched star
(``f r^3 sigma_k1``) for the lens to be used."""
MIN_SIGMA_PX = 0.2
"""Floor of the fit's robust residual sigma, px: a matched star is dropped from the lens fit
beyond 4 of these (0.8 px; a few stars' tight fit must not reject a star for centroid
noise)."""
MAX_CORNER_SIGMA_PX = 10.0
"""Largest 1-sigma (px) of the fitted correction extrapolated to the frame's corner (4 of
the firmware's default match tolerances: the next round's identification through it still
finds stars towards the corners): stars near the centre alone do not fix the lens."""
ROUNDS = 3
"""Most fit -> identify rounds: each round's corrected directions match more stars towards
the corners, and the next fit reaches further."""
K1_GRID = (-0.15, -0.3, -0.45, 0.15)
"""Radial ``k1`` tried, in this order, when a frame does not identify through the pinhole
with :data:`MIN_STARS` (a strong lens moves the corners beyond the match tolerance): the
first that does is fitted from; each costs one firmware identification within the ground
work budget."""


class LensFit:
    """A fitted lens: ``camera`` (firmware, of the detector's frame), ``free`` (its fitted
    parameters), ``k1``, ``sigma_k1``, ``k2`` and ``sigma_k2`` (None when not fitted),
    ``f_px`` (``fx``), ``sigma_f_px``, ``aspect`` (``fy / fx``), ``sigma_aspect`` (0 when
    ``fy = fx`` was imposed), ``n_stars``, ``n_rejected``, ``scale_px`` (per-axis RMS
    residual), ``spread_px`` (1-sigma of the correction at the farthest star),
    ``inflation`` ``(cross, roll)`` (>= 1: the attitude's 1-sigma with the lens, and the
    tangential terms, free over that with them held)."""

    def as_dict(self):
        """The fit for the solve's JSON report."""
        return {"k1": self.k1, "sigma_k1": self.sigma_k1, "k2": self.k2,
                "sigma_k2": self.sigma_k2, "f_px": self.f_px, "sigma_f_px": self.sigma_f_px,
                "aspect": self.aspect, "sigma_aspect": self.sigma_aspect,
                "n_stars": self.n_stars, "n_rejected": self.n_rejected,
                "rms_px": self.scale_px, "sigma_at_edge_px": self.spread_px,
                "sigma_inflation": list(self.inflation)}


def pinhole(width, height, f_px, k1=0.0, k2=0.0):
    """The centred camera of focal length ``f_px`` with radial ``k1``, ``k2``.  Raises
    ``ValueError`` when that lens cannot be inverted over the frame."""
    return Camera(width, height, f_px, f_px, (width - 1) / 2, (height - 1) / 2, k1=k1, k2=k2)


def _inflation(fit, n_free, v):
    """``(cross, roll)``: the attitude's 1-sigma with the lens free over that with it held,
    from the fit's Jacobian (rotation vector applied in the camera frame: x, y across the
    boresight, z about it) with the columns of the tangential ``p1``, ``p2`` added (free too:
    a decentring the fit leaves out must not hide in the attitude).  ``v``: the inliers'
    catalogue unit vectors."""
    fx, fy = fit.params[0], fit.params[1]
    c = Rotation.from_quat(fit.q[0]).apply(v)
    x, y = c[:, 0] / c[:, 2], c[:, 1] / c[:, 2]
    r2 = x * x + y * y
    tangential = np.empty((2 * len(v), 2))
    tangential[0::2] = np.column_stack([fx * 2 * x * y, fx * (r2 + 2 * x * x)])
    tangential[1::2] = np.column_stack([fy * (r2 + 2 * y * y), fy * 2 * x * y])
    jac = np.hstack([fit.jac[:, :n_free], tangential, fit.jac[:, n_free:]])
    full = np.linalg.pinv(jac.T @ jac)[-3:, -3:]
    held = np.linalg.pinv(jac[:, -3:].T @ jac[:, -3:])
    ratio = np.sqrt(np.maximum(np.diag(full), 0.0) / np.maximum(np.diag(held), 1e-300))
    return max(1.0, float(max(ratio[0], ratio[1]))), max(1.0, float(ratio[2]))


def fit_lens(xy, v, q, camera):
    """The :class:`LensFit` of matched pixels ``xy`` ``(n, 2)`` (the detector's frame) of
    catalogue unit vectors ``v`` ``(n, 3)`` at a first attitude ``q`` (scalar last) seen
    through ``camera`` (its size and focal length the start), or None when the stars do not
    determine it (:func:`_fit`).  ``f`` and ``k1`` first; from :data:`ASPECT_STARS` stars
    ``fy`` apart from ``fx`` (pixels that are not square), and from :data:`K2_STARS` ``k2``,
    each kept when it is significant (beyond :data:`SIGNIFICANCE` of its 1-sigma).  The
    lens's tangential ``p1``, ``p2`` are not fitted (they trade off against the attitude
    across the boresight), but the attitude's inflation counts them free (:func:`_inflation`):
    an undetermined decentring widens the sigma instead of shifting the attitude unseen."""
    xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
    if len(xy) < MIN_STARS:
        return None
    frame = calibrate.FramePairs("frame", xy, v, np.zeros(len(xy), dtype=np.int64), q,
                                 len(xy))
    start = pinhole(camera.width, camera.height, math.sqrt(camera.fx * camera.fy))
    best = _fit(frame, start, ("fx", "k1"))
    if best is None:
        return None
    if len(xy) >= ASPECT_STARS:
        fit = _fit(frame, start, ("fx", "fy", "k1"))
        if fit is not None and abs(fit.aspect - 1.0) > SIGNIFICANCE * fit.sigma_aspect:
            best = fit
    if len(xy) >= K2_STARS:
        fit = _fit(frame, start, best.free + ("k2",))
        if fit is not None and abs(fit.k2) > SIGNIFICANCE * fit.sigma_k2:
            best = fit
    return best


def _fit(frame, start, free):
    """The :class:`LensFit` of ``free`` (``fx``, ``fy`` or with ``fy = fx``, ``k1`` and maybe
    ``k2``) from the pairs of ``frame`` starting at ``start``, or None: too few stars agree
    with one lens, it folds over the frame, or the 1-sigma of its correction exceeds
    :data:`MAX_SIGMA_PX` at the farthest star or :data:`MAX_CORNER_SIGMA_PX` at the frame's
    corner."""
    try:
        fit = calibrate.fit_camera([frame], start, free=free, one_focal="fy" not in free,
                                   min_sigma_px=MIN_SIGMA_PX)
    except ValueError:              # too few agree with one lens, or it folds over the frame
        return None
    sigma = fit.sigma
    inlier = frame.xy[fit.inlier]
    f = float(fit.params[0])
    def spread(r):
        """1-sigma (px) of the fitted lens's correction at normalised radius ``r``."""
        return f * r ** 3 * math.hypot(sigma["k1"], sigma.get("k2", 0.0) * r ** 2)

    r_max = float(np.max(np.hypot(inlier[:, 0] - start.cx, inlier[:, 1] - start.cy))) / f
    r_corner = math.hypot(start.cx + 0.5, start.cy + 0.5) / f
    if not (spread(r_max) <= MAX_SIGMA_PX and spread(r_corner) <= MAX_CORNER_SIGMA_PX and
            len(inlier) >= MIN_STARS):
        return None
    out = LensFit()
    out.free = free
    out.camera = fit.camera
    out.f_px, out.sigma_f_px = f, sigma["fx"]
    out.aspect, out.sigma_aspect = float(fit.params[1]) / f, 0.0
    if "fy" in free:                # sigma of fy / fx from the covariance of fx, fy
        grad = np.array([-fit.params[1] / f ** 2, 1.0 / f])
        out.sigma_aspect = float(math.sqrt(max(grad @ fit.cov[:2, :2] @ grad, 0.0)))
    out.k1, out.sigma_k1 = float(fit.params[4]), sigma["k1"]
    out.k2 = float(fit.params[5]) if "k2" in free else None
    out.sigma_k2 = sigma["k2"] if "k2" in free else None
    out.n_stars, out.n_rejected = int(len(inlier)), fit.n_rejected
    out.scale_px = fit.scale_px
    out.spread_px = spread(r_max)
    out.inflation = _inflation(fit, len(free), frame.v[fit.inlier])
    return out


# --------------------------------------------------------------------------------------
# The solve through the fitted lens
# --------------------------------------------------------------------------------------

def _identified(res):
    """The firmware named its stars: ``OK``, or ``IMPRECISE`` (only the attitude loose)."""
    return res is not None and (res.ok or res.status == S.IMPRECISE)


def refine(image, det, camera, res, found, ctx):
    """``(camera, res, db, db_path, LensFit or None)``: the solve ``res`` (``found``: its
    ``(db, db_path)``) through the pinhole ``camera`` redone through the lens fitted to its
    matched stars (:func:`fit_lens`), for at most :data:`ROUNDS` rounds (each round's
    corrected directions match more stars towards the corners) until the fit stands still.
    A frame the pinhole matches with fewer than :data:`MIN_STARS` (``NO_MATCH`` included) is
    tried through the radial ``k1`` of :data:`K1_GRID` first (those whose FOV the pinhole's
    database serves: no database is built for the grid); every solve uses the pinhole's
    database where it serves the camera.  A fit the stars do not determine, or a solve
    through it that names no stars, keeps the previous camera and solution (without any fit,
    the pinhole's, even when a grid lens identified).  The lens fit's
    uncertainty scales the attitude's 1-sigma (:func:`_lens_sigma`).  The ``refine`` of
    :func:`lodestar.ground.imagesolve.solve_image` (``ctx`` as it says)."""
    max_mag, tolerance_px, log, timings, velocity_km_s, motion = ctx
    db, db_path = found
    t = time.perf_counter()

    def attempt(cam, database=None):
        return imagesolve.solve_at(image, det, cam, max_mag, tolerance_px, log, timings,
                                   blind=True, velocity_km_s=velocity_km_s, motion=motion,
                                   database=database)[:3]

    def served(cam):
        """The pinhole's database, when it serves ``cam`` (the firmware's FOV rule)."""
        fov = math.radians(solve.camera_fov_deg(cam)[0])
        return (db, db_path) if abs(fov - db.fov_h) <= pipeline.FOV_TOLERANCE * db.fov_h \
            else None

    first = camera, res, db, db_path
    unmatched = res is not None and (res.status == S.NO_MATCH or _identified(res))
    if camera.k1 == 0.0 and unmatched and not (_identified(res) and
                                               len(res.matches) >= MIN_STARS):
        for k1 in K1_GRID:
            try:
                cam = pinhole(camera.width, camera.height, camera.fx, k1)
            except ValueError:                  # folds over the frame
                continue
            database = served(cam)
            if database is None:
                continue                        # another database: not worth its build
            db_k, path_k, res_k = attempt(cam, database)
            if _identified(res_k) and len(res_k.matches) >= MIN_STARS:
                camera, res, db, db_path = cam, res_k, db_k, path_k
                break
    lens = None
    cat = default_catalogue(None)
    for _round in range(ROUNDS + 1):
        if not _identified(res):
            break
        xy = [(x, y) for _i, x, y, _h in res.matches]
        v = cat.unit_vectors()[[cat.by_hip(h) for _i, _x, _y, h in res.matches]]
        fit = fit_lens(xy, v, res.q, camera)
        if fit is None:
            break
        if lens is not None and _same_lens(fit, camera):
            lens = fit
            break
        if _round == ROUNDS:
            break
        db_f, path_f, res_f = attempt(fit.camera, served(fit.camera))
        if not _identified(res_f):
            break
        camera, res, db, db_path, lens = fit.camera, res_f, db_f, path_f, fit
    timings["lens_fit"] = (time.perf_counter() - t) * 1e3
    if lens is None:                # a grid lens no fit confirmed is no better than none
        return first + (None,)
    _lens_sigma(res, lens)
    return camera, res, db, db_path, lens


def _same_lens(fit, camera):
    """A fit within a tenth of its 1-sigma of ``camera``'s focal length and ``k1``."""
    return (abs(fit.f_px - camera.fx) <= 0.1 * fit.sigma_f_px and
            abs(fit.k1 - camera.k1) <= 0.1 * fit.sigma_k1)


def _lens_sigma(res, lens):
    """Scale ``res``'s 1-sigma by the lens fit's :attr:`LensFit.inflation` and, when its
    bound then exceeds the default ``max_error_arcsec``, make an ``OK`` ``IMPRECISE`` (the
    firmware's rule, :func:`lodestar.firmware.pipeline.precise`), noted in ``reason``."""
    cross, roll = lens.inflation
    res.sigma_cross_arcsec *= cross
    res.sigma_roll_arcsec *= roll
    note = (f"lens fitted from {lens.n_stars} stars (k1 {lens.k1:+.4f} +- "
            f"{lens.sigma_k1:.4f}), sigma x{cross:.2f} across, x{roll:.2f} in roll")
    res.reason = note if not res.reason else res.reason + "; " + note
    if res.ok:
        pipeline.precise(res, DEFAULT_MAX_ERROR_ARCSEC)
