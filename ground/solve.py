"""Ground-side star-field solve from centroids (tetra3 style) with the flight firmware, over a
star database built and cached for the field of view (:mod:`lodestar.ground.cache`).
Inputs, outputs and statuses: ``docs/solve_centroids.md``."""

import math
import time

import numpy as np

from lodestar import contract as C
from lodestar.contract import stardb
from lodestar.firmware import status as S
from lodestar.firmware.aberration import MAX_SPEED_KM_S
from lodestar.firmware.camera import Camera
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings
from lodestar.ground import fovsearch
from lodestar.ground.cache import load_database
from lodestar.ground.database import check_fov, default_catalogue
from lodestar.sim.attitude import to_radec_roll

MIN_STARS = 4
MAG_RANGE = (-2.0, 18.0)
"""``max_mag`` (V) a database is built to: ``(lo, hi]``, within what a star record's
magnitude code stores (-2 .. 18.47, ``docs/stardb.md``)."""
DEFAULT_DUPLICATE_PX = 0.5
GROUND_MAX_WORK = 1_500_000
"""Work budget of one ground identification (units of
:data:`lodestar.firmware.starid.search.DEFAULT_MAX_WORK`): a frame that cannot be solved
ends within about 0.25 s of CPython here (``docs/solve_centroids.md``, Failures fast)."""
DB_FOV_STEP = 1.01
"""A blind solve's databases are built for FOVs on a grid of this ratio (the camera keeps
the fitted FOV; the firmware accepts a database within 2 %), so solves share them."""
ARCSEC_PER_RAD = 180 * 3600 / math.pi
DEFAULT_DENSITY = {"verification_stars_per_fov": 30, "pattern_stars_per_fov": 10}
"""Stars per field of the ground databases (:func:`lodestar.ground.database.build_database`)
when no ``max_mag`` is given: depth follows the field, from V ~5 at 40 deg to the whole
Hipparcos at 5 deg (``docs/stardb.md``)."""


class SolveResult:
    """Outcome of :func:`solve_centroids` (fields in ``docs/solve_centroids.md``): ``status``
    is a firmware status code (:mod:`lodestar.firmware.status`), ``status_name`` its name, as
    in the firmware's ``Result``."""

    FIELDS = ("status", "status_name", "reason", "ra_deg", "dec_deg", "roll_deg", "q",
              "matches", "sigma_cross_arcsec", "sigma_roll_arcsec", "patterns_tried",
              "probability", "n_centroids", "n_used", "n_duplicates", "n_outside",
              "centroid_sigma_px", "fov_deg", "pixel_scale_arcsec", "fov_search",
              "database", "solve_ms")

    def __init__(self, status, reason="", **fields):
        self.status = status
        self.reason = reason
        self.ra_deg = self.dec_deg = self.roll_deg = self.q = None
        self.matches = {}
        self.sigma_cross_arcsec = self.sigma_roll_arcsec = None
        self.patterns_tried = 0
        self.probability = 1.0
        self.n_centroids = self.n_used = self.n_duplicates = self.n_outside = 0
        self.centroid_sigma_px = None
        self.fov_deg = None
        self.pixel_scale_arcsec = None
        self.fov_search = None
        self.database = None
        self.solve_ms = 0.0
        for name, value in fields.items():
            if name not in self.FIELDS or name == "status_name":
                raise TypeError(f"unknown field {name!r}")
            setattr(self, name, value)

    @property
    def ok(self):
        return self.status == S.OK

    @property
    def status_name(self):
        return S.name(self.status)

    def __getitem__(self, name):
        if name not in self.FIELDS:
            raise KeyError(name)
        return getattr(self, name)

    def keys(self):
        return self.FIELDS

    def as_dict(self):
        return {name: getattr(self, name) for name in self.FIELDS}

    def __repr__(self):
        if not self.ok:
            return f"SolveResult({self.status_name}, reason={self.reason!r})"
        return (f"SolveResult(OK, ra={self.ra_deg:.5f}, dec={self.dec_deg:.5f}, "
                f"roll={self.roll_deg:.4f} deg, matches={len(self.matches)}, "
                f"sigma_cross={self.sigma_cross_arcsec:.2f}\", "
                f"sigma_roll={self.sigma_roll_arcsec:.2f}\")")


# --------------------------------------------------------------------------------------
# Camera and database
# --------------------------------------------------------------------------------------

DISTORTION_KEYS = ("k1", "k2", "k3", "p1", "p2", "cx", "cy")


def make_camera(width, height, fov_deg, distortion=None):
    """The firmware camera of a centred pinhole of horizontal FOV ``fov_deg`` (deg) with
    square pixels, plus the Brown-Conrady ``distortion`` (a dict of :data:`DISTORTION_KEYS`);
    raises ``ValueError``."""
    f = (width / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    kwargs = {}
    for key, value in (distortion or {}).items():
        if key not in DISTORTION_KEYS:
            raise ValueError(f"unknown distortion key {key!r} (known: {DISTORTION_KEYS})")
        if not _is_number(value):
            raise ValueError(f"distortion {key} must be a finite number, got {value!r}")
        kwargs[key] = float(value)
    return Camera(width, height, f, f, **kwargs)


def camera_fov_deg(cam):
    """``(horizontal, vertical)`` FOV in degrees through the camera model (edges along the
    middle row and column, as ``lodestar.sim.camera.Camera.fov_deg``)."""
    w, h = cam.width, cam.height
    xm, ym = (w - 1) / 2, (h - 1) / 2

    def angle(a, b):
        return math.degrees(2 * math.asin(min(1.0, 0.5 * math.dist(a, b))))

    return (angle(cam.pixel_to_vector(-0.5, ym), cam.pixel_to_vector(w - 0.5, ym)),
            angle(cam.pixel_to_vector(xm, -0.5), cam.pixel_to_vector(xm, h - 0.5)))


# --------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------

def _is_int(value):
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_number(value):
    """A finite int or float (numpy's too), not a bool; an int no float holds is not."""
    if not isinstance(value, (int, float, np.integer, np.floating)) or \
            isinstance(value, (bool, np.bool_)):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:                 # 10**400
        return False


def _centroid_array(centroids):
    """``(N, 2 or 3)`` float array, or a reason string."""
    try:
        arr = np.asarray(centroids, dtype=np.float64)
    except (TypeError, ValueError, OverflowError):
        return "centroids must be a sequence of (x, y) or (x, y, flux) numbers"
    if arr.size == 0:
        return np.zeros((0, 2))
    if arr.ndim != 2 or arr.shape[1] not in (2, 3):
        return f"centroids must have shape (N, 2) or (N, 3), got {arr.shape}"
    if not np.all(np.isfinite(arr)):
        bad = int(np.flatnonzero(~np.all(np.isfinite(arr), axis=1))[0])
        return f"centroid {bad} is not finite: {arr[bad].tolist()}"
    return arr


# --------------------------------------------------------------------------------------
# The solver
# --------------------------------------------------------------------------------------

def observer_velocity_km_s(obstime=None, velocity_km_s=None):
    """The observer's barycentric velocity for the aberration correction, km/s, ICRS
    (``docs/apparent_directions.md``): the Earth's at ``obstime`` (an ISO string in UTC, e.g.
    a FITS ``DATE-OBS``, or an ``astropy.time.Time``; astropy's built-in ephemeris) plus
    ``velocity_km_s`` (3 numbers: a satellite's geocentric velocity; without ``obstime`` the
    whole barycentric velocity).  None when neither is given; ``ValueError`` for a time
    astropy cannot read, a velocity that is not 3 finite numbers or a total faster than
    the firmware accepts (:data:`lodestar.firmware.aberration.MAX_SPEED_KM_S`)."""
    if obstime is None and velocity_km_s is None:
        return None
    total = np.zeros(3)
    if obstime is not None:
        from astropy import units as u
        from astropy.coordinates import get_body_barycentric_posvel
        from astropy.time import Time
        try:
            t = obstime if isinstance(obstime, Time) else Time(obstime, scale="utc")
            vel = get_body_barycentric_posvel("earth", t)[1]
        except Exception as exc:          # astropy's messages run over several lines
            raise ValueError(f"observation time {obstime!r}: {' '.join(str(exc).split())}") \
                from None
        total += vel.xyz.to_value(u.km / u.s)
    if velocity_km_s is not None:
        v = np.asarray(velocity_km_s, dtype=np.float64) if _is_vector(velocity_km_s) else None
        if v is None or v.shape != (3,) or not np.all(np.isfinite(v)):
            raise ValueError(f"velocity must be 3 finite numbers (km/s), got {velocity_km_s!r}")
        total += v
    if not np.linalg.norm(total) <= MAX_SPEED_KM_S:
        raise ValueError(f"observer speed {np.linalg.norm(total):.1f} km/s is beyond "
                         f"{MAX_SPEED_KM_S:g} km/s")
    return [float(x) for x in total]


def _is_vector(value):
    try:
        return len(value) == 3 and all(_is_number(x) for x in value)
    except TypeError:
        return False


def solve_centroids(centroids, width, height, fov_deg=None, method="pyramid", max_mag=None,
                    distortion=None, cache_dir=None, tolerance_px=None, max_stars=32,
                    budget=2000, centroid_sigma_px=None, duplicate_px=DEFAULT_DUPLICATE_PX,
                    fov_error_deg=None, max_work=GROUND_MAX_WORK, obstime=None,
                    velocity_km_s=None):
    """Identify the stars of ``centroids`` and return a :class:`SolveResult`; never raises
    for bad input (``docs/solve_centroids.md``).

    ``width``, ``height``: frame size, px.  ``fov_deg``: horizontal FOV, deg; None: unknown,
    searched over :data:`lodestar.ground.fovsearch.FOV_RANGE_DEG`; with ``fov_error_deg``
    (deg): searched over ``fov_deg +- fov_error_deg`` (a pinhole; the result's ``fov_deg``
    and ``pixel_scale_arcsec`` are then fitted, ``fov_search`` says how).  ``method``:
    the lost-in-space method (``"pyramid"``, ``"triangle"`` or ``"hashing"``, as far as
    :mod:`lodestar.ground.database` builds and :mod:`lodestar.firmware.starid` serves it).
    ``max_mag``: faintest catalogue star of the database (None: the stars per field of
    :data:`DEFAULT_DENSITY` decide, from the whole Hipparcos; a number: every star to that
    magnitude, the database of earlier versions).  ``distortion``: Brown-Conrady
    dict (known FOV only).  ``cache_dir``: database cache.
    ``tolerance_px``: match tolerance (default ``max(2 px, fov/1000)``).  ``max_stars``:
    brightest centroids used.  ``budget``: pattern budget.  ``centroid_sigma_px``: fixed
    centroid noise for the covariance (default: estimated from the residuals).
    ``duplicate_px``: centroids closer than this are one star.  ``max_work``: work budget
    of one identification (:data:`GROUND_MAX_WORK`).  ``obstime``, ``velocity_km_s``: the
    observation time and/or observer velocity for the aberration correction
    (:func:`observer_velocity_km_s`; neither: none).
    """
    n_in = len(centroids) if hasattr(centroids, "__len__") else 0
    band, reason = _fov_band(width, height, fov_deg, fov_error_deg, distortion)
    if reason is None:
        reason = _option_error(max_mag, method, distortion, tolerance_px, max_stars, budget,
                               max_work, duplicate_px)
    if reason is None:
        try:
            velocity = observer_velocity_km_s(obstime, velocity_km_s)
        except ValueError as exc:
            reason = str(exc)
    if reason is not None:
        return SolveResult(S.BAD_INPUT, reason, n_centroids=n_in)
    cam = fov = None
    if band is None:
        try:
            cam = make_camera(int(width), int(height), float(fov_deg), distortion)
            fov = camera_fov_deg(cam)
            check_fov(fov[0], "the distorted camera's horizontal FOV")
        except (ValueError, TypeError) as exc:
            return SolveResult(S.BAD_INPUT, f"camera: {exc}", n_centroids=n_in)

    arr = _centroid_array(centroids)
    if isinstance(arr, str):
        return SolveResult(S.BAD_INPUT, arr, n_centroids=n_in, fov_deg=fov)
    # a blind solve's quad search looks at more stars than the identification uses
    wanted = max_stars if band is None else max(max_stars, fovsearch.IMAGE_STARS)
    searched, n_dup, n_outside = _distinct(arr, width, height, wanted, max_stars, duplicate_px)
    kept = searched[:max_stars]
    info = dict(n_centroids=len(arr), n_used=len(kept), n_duplicates=n_dup,
                n_outside=n_outside, fov_deg=fov)
    note = f"{n_outside} centroids outside the {width}x{height} frame ignored" \
        if n_outside else ""
    if len(kept) < MIN_STARS:
        return SolveResult(S.TOO_FEW_STARS, f"{len(kept)} distinct centroids in the frame, "
                           f"at least {MIN_STARS} needed" + ("; " + note if note else ""),
                           **info)
    frame = _Frame(arr, kept, searched, width, height, note, info,
                   dict(method=method, max_mag=max_mag, cache_dir=cache_dir,
                        tolerance_px=tolerance_px, max_stars=max_stars, budget=budget,
                        centroid_sigma_px=centroid_sigma_px, max_work=max_work,
                        velocity_km_s=velocity))
    if band is None:
        return _firmware_solve(frame, cam)
    return _blind_solve(frame, band)


def _fov_band(width, height, fov_deg, fov_error_deg, distortion):
    """``(band, reason)``: the FOV band (deg) to search, None for a known FOV; ``reason``
    says what is wrong with the frame size or the FOV arguments (None: nothing)."""
    for name, value in (("width", width), ("height", height)):
        limit = C.MAX_WIDTH if name == "width" else C.MAX_HEIGHT
        if not _is_int(value) or not 1 <= value <= limit:
            return None, f"{name} must be an int in 1..{limit}, got {value!r}"
    if fov_deg is not None:
        lo, hi = stardb.FOV_RANGE_DEG
        if not _is_number(fov_deg) or not lo <= fov_deg <= hi:
            return None, f"fov_deg must be a number in [{lo:g}, {hi:g}], got {fov_deg!r}"
    if fov_error_deg is not None:
        if fov_deg is None:
            return None, "fov_error_deg needs fov_deg"
        if not _is_number(fov_error_deg) or not 0 < fov_error_deg < fov_deg:
            return None, f"fov_error_deg must be a number in (0, fov_deg), got {fov_error_deg!r}"
        band = (fov_deg - fov_error_deg, fov_deg + fov_error_deg)
    elif fov_deg is None:
        band = fovsearch.FOV_RANGE_DEG
    else:
        return None, None
    reach = fovsearch.reach_deg()
    if band[1] < reach[0] or band[0] > reach[1]:
        return None, (f"FOV band {band[0]:g} .. {band[1]:g} deg: the blind search reaches "
                      f"{reach[0]:.1f} .. {reach[1]:.1f} deg")
    if distortion:
        return None, "distortion needs a known FOV (fov_deg without fov_error_deg)"
    return (max(band[0], reach[0]), min(band[1], reach[1])), None


def _option_error(max_mag, method, distortion, tolerance_px, max_stars, budget, max_work,
                  duplicate_px):
    """What is wrong with the database and identification options, or None."""
    if max_mag is not None and (not _is_number(max_mag) or
                                not MAG_RANGE[0] < max_mag <= MAG_RANGE[1]):
        return f"max_mag must be a finite magnitude in ({MAG_RANGE[0]:g}, {MAG_RANGE[1]:g}], " \
            f"got {max_mag!r}"
    if method not in stardb.METHOD_NAMES:
        return f"unknown method {method!r} (known: {sorted(stardb.METHOD_NAMES)})"
    if distortion is not None and not isinstance(distortion, dict):
        return "distortion must be a dict of k1, k2, k3, p1, p2 (and cx, cy)"
    if tolerance_px is not None and not (_is_number(tolerance_px) and tolerance_px > 0):
        return f"tolerance_px must be a positive number, got {tolerance_px!r}"
    if not _is_int(max_stars) or max_stars < MIN_STARS:
        return f"max_stars must be an int >= {MIN_STARS}"
    if not _is_int(budget) or budget < 1:
        return "budget must be a positive int"
    if not _is_int(max_work) or max_work < 1:
        return "max_work must be a positive int"
    if not _is_number(duplicate_px) or duplicate_px < 0:
        return f"duplicate_px must be a number >= 0, got {duplicate_px!r}"
    return None


def _distinct(arr, width, height, wanted, max_stars, duplicate_px):
    """``(indices, n_duplicates, n_outside)``: up to ``wanted`` rows of ``arr`` inside the
    frame, brightest first (input order without fluxes), none closer than
    ``duplicate_px`` to one before it; duplicates are counted among the first
    ``max_stars`` distinct ones."""
    xs, ys = arr[:, 0], arr[:, 1]
    inside = (xs >= -0.5) & (xs < width - 0.5) & (ys >= -0.5) & (ys < height - 0.5)
    n_outside = int(len(arr) - np.count_nonzero(inside))
    if arr.shape[1] == 3:
        order = np.argsort(-arr[:, 2], kind="stable")
    else:
        order = np.arange(len(arr))
    kept = []
    n_dup = 0
    for i in order:
        if not inside[i]:
            continue
        if len(kept) == wanted:
            break
        if all(math.hypot(xs[i] - xs[j], ys[i] - ys[j]) >= duplicate_px for j in kept):
            kept.append(int(i))
        elif len(kept) < max_stars:
            n_dup += 1
    return kept, n_dup, n_outside


class _Frame:
    """The checked centroids of one solve: ``arr`` (the input rows), ``kept`` (indices,
    brightest first), ``searched`` (as many for the quad search), the frame size, the
    outside-frame ``note``, the result ``info`` and the firmware ``options``."""

    def __init__(self, arr, kept, searched, width, height, note, info, options):
        self.arr = arr
        self.kept = kept
        self.searched = searched
        self.width = width
        self.height = height
        self.note = note
        self.info = info
        self.options = options


def _firmware_solve(frame, cam, database_fov_deg=None):
    """The flight identification of ``frame`` through the firmware ``cam``, over the
    database of the camera's FOV (or of horizontal FOV ``database_fov_deg`` with the
    camera's aspect)."""
    info = dict(frame.info)
    opt = frame.options
    fov = camera_fov_deg(cam)
    info["fov_deg"] = fov
    info["pixel_scale_arcsec"] = ARCSEC_PER_RAD / math.sqrt(cam.fx * cam.fy)
    arr, kept = frame.arr, frame.kept
    vectors = [cam.pixel_to_vector(float(arr[i, 0]), float(arr[i, 1])) for i in kept]
    if any(v is None for v in vectors):
        return SolveResult(S.BAD_INPUT, "a centroid is outside the camera model", **info)
    flux_list = [float(arr[i, 2]) for i in kept] if arr.shape[1] == 3 else None
    db_fov = fov
    if database_fov_deg is not None:
        db_fov = camera_fov_deg(make_camera(frame.width, frame.height, database_fov_deg))
    max_mag = opt["max_mag"]
    method = opt["method"]
    try:
        db, path = load_database(db_fov[0], db_fov[1],
                                 None if max_mag is None else float(max_mag),
                                 method, opt["cache_dir"],
                                 density=DEFAULT_DENSITY if max_mag is None else None)
    except ValueError as exc:
        return SolveResult(S.BAD_INPUT, f"database: {exc}", **info)
    except Exception as exc:              # the builder's output failed the reader
        return SolveResult(S.DATABASE_CORRUPT, f"database: {exc!r}", **info)
    info["database"] = None if path is None else str(path)
    tolerance_px = opt["tolerance_px"]
    if tolerance_px is None:
        tolerance_px = max(2.0, math.radians(fov[0]) / 1000.0 * cam.fx)
    tracker = StarTracker(db, cam, Settings(method=method, max_stars=opt["max_stars"],
                          tolerance_px=float(tolerance_px), budget=int(opt["budget"]),
                          centroid_sigma_px=opt["centroid_sigma_px"],
                          max_work=int(opt["max_work"])))
    if tracker.status != S.OK:
        return SolveResult(tracker.status, tracker.reason, **info)
    t0 = time.perf_counter()
    res = tracker.solve_vectors(vectors, fluxes=flux_list, velocity_km_s=opt["velocity_km_s"])
    info["solve_ms"] = (time.perf_counter() - t0) * 1e3
    info["patterns_tried"] = res.patterns_tried
    info["probability"] = res.probability
    reason = "; ".join(r for r in (frame.note, res.reason) if r)
    if res.status == S.IMPRECISE:       # named right, its attitude too loose to be one
        return SolveResult(res.status, reason,
                           matches={kept[o]: int(hip) for o, _x, _y, hip in res.matches},
                           sigma_cross_arcsec=res.sigma_cross_arcsec,
                           sigma_roll_arcsec=res.sigma_roll_arcsec, **info)
    if res.status != S.OK:
        return SolveResult(res.status, reason, **info)
    q = [float(v) for v in res.q]
    ra, dec, roll = to_radec_roll(np.asarray(q))
    return SolveResult(S.OK, reason, ra_deg=float(ra), dec_deg=float(dec),
                       roll_deg=float(roll), q=q,
                       matches={kept[o]: int(hip) for o, _x, _y, hip in res.matches},
                       sigma_cross_arcsec=res.sigma_cross_arcsec,
                       sigma_roll_arcsec=res.sigma_roll_arcsec,
                       centroid_sigma_px=res.centroid_sigma_px, **info)


def database_fov(fov_h_deg):
    """The horizontal FOV (deg) a blind solve's database is built for: ``fov_h_deg`` rounded
    to the grid of ratio :data:`DB_FOV_STEP` (within half a step, 0.5 %)."""
    step = math.log(DB_FOV_STEP)
    return round(math.exp(round(math.log(fov_h_deg) / step) * step), 4)


def refit_focal(xy, hips, width, height, f_px):
    """Least-squares focal length (px) of a centred pinhole from matched pixels ``xy``
    ``(n, 2)`` and their Hipparcos numbers (:func:`lodestar.ground.fovsearch.fit_focal`,
    catalogue directions of the whole Hipparcos)."""
    cat = default_catalogue(None)
    rows = [cat.by_hip(h) for h in hips]
    return fovsearch.fit_focal(np.asarray(xy, dtype=np.float64), cat.unit_vectors()[rows],
                               width, height, f_px)[0]


def _blind_solve(frame, band):
    """Unknown or approximate FOV (``band``, deg): the quad search of
    :mod:`lodestar.ground.fovsearch` finds the focal length, the firmware identifies at it,
    the focal length is fitted to the matched stars by least squares and the firmware
    verifies again at the fitted scale (``docs/solve_centroids.md``, Unknown FOV)."""
    arr = frame.arr
    opt = frame.options
    t0 = time.perf_counter()
    try:
        est = fovsearch.search_fov(arr[frame.searched, :2], frame.width, frame.height, band,
                                   opt["tolerance_px"] or 2.0, opt["cache_dir"])
    except ValueError as exc:              # no deep catalogue for the index
        return SolveResult(S.BAD_INPUT, f"FOV search: {exc}", **frame.info)
    search = {"range_deg": [float(band[0]), float(band[1])], "candidates": est.candidates,
              "estimate_deg": est.fov_deg, "level_deg": est.level_deg,
              "quad_matches": est.n_matches,
              "ms": (time.perf_counter() - t0) * 1e3}
    if est.f_px is None:
        return SolveResult(S.NO_MATCH, f"no field of view in {band[0]:g} .. {band[1]:g} deg "
                           f"verified ({est.candidates} candidate quads)",
                           fov_search=search, solve_ms=search["ms"], **frame.info)
    f_px = est.f_px
    res = None
    for attempt in range(2):               # the estimate, then the fitted scale
        fov_h = fovsearch.fov_of_f(frame.width, f_px)
        res = _firmware_solve(frame, make_camera(frame.width, frame.height, fov_h),
                              database_fov(fov_h))
        res.fov_search = search
        res.solve_ms += search["ms"]
        search["fitted_deg"] = fov_h if attempt else None
        if attempt or not (res.ok or res.status == S.IMPRECISE):   # IMPRECISE: named right
            break
        idx = sorted(res.matches)
        f_new = refit_focal(arr[idx, :2], [res.matches[i] for i in idx], frame.width,
                            frame.height, f_px)
        if abs(f_new / f_px - 1) < 1e-6:
            search["fitted_deg"] = fov_h
            break
        f_px = f_new
    return res
