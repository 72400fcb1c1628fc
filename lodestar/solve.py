"""Ground-side plate solving of a centroid list, in the style of tetra3's
``solve_from_centroids``: the flight identification, QUEST and covariance behind one call.

    from lodestar.solve import solve_centroids
    result = solve_centroids([(x, y, flux), ...], width=2592, height=1944, fov_deg=20.2)
    if result.status == "OK":
        print(result.ra_deg, result.dec_deg, result.roll_deg, result.sigma_cross_arcsec)

Inputs and conventions
----------------------
* ``centroids``: a sequence (or numpy array) of ``(x, y)`` or ``(x, y, flux)`` in pixels,
  ``lodestar.contract`` convention: ``x`` the column, ``y`` the row, the centre of pixel
  ``(x, y)`` at the integer point, so the frame spans ``[-0.5, width - 0.5) x
  [-0.5, height - 0.5)``.  With fluxes the stars are used brightest first (and weighted by
  ``sqrt(flux)``); without, in the order given (put the brightest first).
* ``fov_deg``: horizontal field of view in degrees, edge to edge across ``width`` pixels, of a
  centred pinhole camera with square pixels: ``fx = fy = (width / 2) / tan(fov_deg / 2)``,
  principal point ``((width - 1) / 2, (height - 1) / 2)``.  ``distortion``: optional dict of
  Brown-Conrady coefficients ``k1 k2 k3 p1 p2`` (Bouguet's model of
  :mod:`lodestar.firmware.camera`, applied on top of that pinhole) and optionally ``cx``,
  ``cy``; the database is then built for the FOV through the distorted model.
* Camera frame and attitude as ``lodestar.sim``: ``+z`` boresight, ``+x`` along ``x``,
  ``+y`` along ``y``; ``q = [x, y, z, w]`` (scalar last) with ``v_cam = A(q) v_icrs``;
  ``ra_deg``, ``dec_deg``, ``roll_deg`` are :func:`lodestar.sim.attitude.to_radec_roll` of
  ``q`` (roll 0: celestial north along ``-y``).

Database cache
--------------
The star database (:func:`lodestar.ground.database.build_database`) depends on the FOV
(horizontal and vertical, through the camera model, rounded to 1e-4 deg), ``max_mag``,
``method``, the database format version and the catalogue file; a SHA-256 of those names the
file ``lodestar-<method>-<hash16>.lsdb`` in ``cache_dir`` (default: ``$LODESTAR_CACHE_DIR``,
else ``$XDG_CACHE_HOME/lodestar``, else ``~/.cache/lodestar``).  A missing or corrupt file
is (re)built and written atomically; databases are also kept in memory for the process.

Result
------
A :class:`SolveResult` (attribute or ``result["name"]`` access, :meth:`SolveResult.as_dict`):
``status`` (a :mod:`lodestar.firmware.status` name), ``reason``, ``ra_deg``, ``dec_deg``,
``roll_deg``, ``q``, ``matches`` (``{centroid index: HIP}``, indices into the input list),
``sigma_cross_arcsec``, ``sigma_roll_arcsec`` (Shuster covariance, per axis; the centroid
noise is estimated from the fit residuals unless ``centroid_sigma_px`` is given),
``patterns_tried``, ``probability``, ``n_centroids``, ``n_used``, ``n_duplicates``,
``n_outside``,
``centroid_sigma_px``, ``fov_deg`` (the ``(horizontal, vertical)`` FOV of the model),
``database`` (the file, or None) and ``solve_ms`` (identification and fit, wall clock).
Angles and ``q`` are None unless ``status == "OK"``.

Statuses (the function never raises for bad input):

=================  ===========================================================================
``OK``             identified and verified; the attitude is that of the matched stars
``TOO_FEW_STARS``  fewer than 4 distinct centroids inside the frame (an empty list, one,
                   two or three stars, all but a few duplicates or outside the frame)
``NO_MATCH``       no catalogue pattern verified (also when the search budget runs out,
                   unless the identification reports its own status for that)
``AMBIGUOUS``      two different attitudes verified equally well
``BAD_INPUT``      malformed input, with ``reason``: not a list of 2- or 3-tuples of numbers,
                   NaN or inf, width/height not an int in
                   1..4096, FOV not a number in [1, 90] deg, bad ``max_mag``, unknown
                   ``method`` or distortion key, a distortion not invertible over the frame,
                   or a database that cannot be built for these parameters (no star pairs)
``DATABASE_...``   a database problem (cache file unusable and rebuilding failed)
=================  ===========================================================================

Centroids outside the frame ``[-0.5, width - 0.5) x [-0.5, height - 0.5)`` are ignored
(``n_outside``, noted in ``reason``): a detector cannot report them, so they are corrupt or
belong to another frame size.  Duplicates (centroids closer than ``duplicate_px``, default
0.5 px) are merged: the first (brightest) is kept and ``n_duplicates`` counts the others
(among the centroids examined until ``max_stars`` distinct ones are found).
"""

import hashlib
import math
import os
import tempfile
import time
from importlib import resources
from pathlib import Path

import numpy as np

from lodestar.firmware import database as fwdatabase
from lodestar.firmware import status as fwstatus
from lodestar.firmware.camera import Camera
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import Settings

CACHE_SCHEMA = 1
"""Bumped when the builder's output for the same parameters changes (invalidates caches)."""
MIN_FOV_DEG = 1.0
MAX_FOV_DEG = 90.0
MIN_STARS = 4
DEFAULT_DUPLICATE_PX = 0.5

MEMORY_CACHE_SIZE = 8
"""Databases kept in memory (the least recently built or read ones are dropped first)."""

_MEMORY = {}          # cache file path -> (Database, path or None)


class SolveResult:
    """Outcome of :func:`solve_centroids` (fields in the module docstring)."""

    FIELDS = ("status", "reason", "ra_deg", "dec_deg", "roll_deg", "q", "matches",
              "sigma_cross_arcsec", "sigma_roll_arcsec", "patterns_tried", "probability",
              "n_centroids", "n_used", "n_duplicates", "n_outside", "centroid_sigma_px",
              "fov_deg",
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
        self.database = None
        self.solve_ms = 0.0
        for name, value in fields.items():
            if name not in self.FIELDS:
                raise TypeError(f"unknown field {name!r}")
            setattr(self, name, value)

    @property
    def ok(self):
        return self.status == "OK"

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
            return f"SolveResult({self.status}, reason={self.reason!r})"
        return (f"SolveResult(OK, ra={self.ra_deg:.5f}, dec={self.dec_deg:.5f}, "
                f"roll={self.roll_deg:.4f} deg, matches={len(self.matches)}, "
                f"sigma_cross={self.sigma_cross_arcsec:.2f}\", "
                f"sigma_roll={self.sigma_roll_arcsec:.2f}\")")


# --------------------------------------------------------------------------------------
# Camera and database
# --------------------------------------------------------------------------------------

DISTORTION_KEYS = ("k1", "k2", "k3", "p1", "p2", "cx", "cy")


def make_camera(width, height, fov_deg, distortion=None):
    """The firmware camera of the module docstring (raises ``ValueError``)."""
    f = (width / 2.0) / math.tan(math.radians(fov_deg) / 2.0)
    kwargs = {}
    for key, value in (distortion or {}).items():
        if key not in DISTORTION_KEYS:
            raise ValueError(f"unknown distortion key {key!r} (known: {DISTORTION_KEYS})")
        if isinstance(value, bool) or not isinstance(value, (int, float, np.floating,
                                                              np.integer)):
            raise ValueError(f"distortion {key} must be a number, got {value!r}")
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


def default_cache_dir():
    """``$LODESTAR_CACHE_DIR``, else ``$XDG_CACHE_HOME/lodestar``, else
    ``~/.cache/lodestar``."""
    if os.environ.get("LODESTAR_CACHE_DIR"):
        return Path(os.environ["LODESTAR_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "lodestar"


_CATALOGUE_HASH = []


def _catalogue_hash():
    if not _CATALOGUE_HASH:
        from lodestar.sim import catalogue
        data = resources.files("lodestar.sim").joinpath("data/" + catalogue.DATA_FILE)
        _CATALOGUE_HASH.append(hashlib.sha256(data.read_bytes()).hexdigest())
    return _CATALOGUE_HASH[0]


def cache_key(fov_h_deg, fov_v_deg, max_mag, method):
    """The SHA-256 hex digest naming the database of these parameters."""
    text = "|".join([f"schema={CACHE_SCHEMA}", f"format={fwdatabase.VERSION}",
                     f"fov_h={fov_h_deg:.4f}", f"fov_v={fov_v_deg:.4f}",
                     f"mag={max_mag:.3f}", f"method={method}",
                     f"catalogue={_catalogue_hash()}"])
    return hashlib.sha256(text.encode()).hexdigest()


def write_atomic(target, data):
    """Write ``data`` to ``target`` (creating its folder) through a temporary file renamed
    into place, so readers never see a partial file.  Raises ``OSError``."""
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=target.name, suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(data)
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


def load_database(fov_h_deg, fov_v_deg, max_mag=6.0, method="pyramid", cache_dir=None):
    """``(Database, path)`` for the parameters: from memory, the cache file, or built (and
    written to ``cache_dir``; ``path`` is None when the cache cannot be written).  Raises
    ``ValueError`` when the database cannot be built for these parameters."""
    key = cache_key(fov_h_deg, fov_v_deg, max_mag, method)
    directory = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = directory / f"lodestar-{method}-{key[:16]}.lsdb"
    hit = _MEMORY.get(str(target))
    if hit is not None:
        return hit
    db = path = None
    try:
        db = fwdatabase.Database(target.read_bytes())
        path = target
    except Exception:            # missing, unreadable or corrupt: rebuild
        db = None
    if db is None:
        from lodestar.ground.database import build_database
        try:
            image = build_database(fov_h_deg=round(fov_h_deg, 4), fov_v_deg=round(fov_v_deg, 4),
                                   mag_limit=float(max_mag), method=method)
        except NotImplementedError as exc:
            raise ValueError(str(exc)) from None
        db = fwdatabase.Database(image)
        try:
            write_atomic(target, image)
            path = target
        except OSError:
            path = None            # read-only cache: keep the database in memory only
    _MEMORY[str(target)] = (db, path)
    while len(_MEMORY) > MEMORY_CACHE_SIZE:
        del _MEMORY[next(iter(_MEMORY))]
    return db, path


# --------------------------------------------------------------------------------------
# Input checks
# --------------------------------------------------------------------------------------

def _is_int(value):
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_number(value):
    return isinstance(value, (int, float, np.integer, np.floating)) and \
        not isinstance(value, (bool, np.bool_)) and math.isfinite(value)


def _centroid_array(centroids):
    """``(N, 2 or 3)`` float array, or a reason string."""
    try:
        arr = np.asarray(centroids, dtype=np.float64)
    except (TypeError, ValueError):
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

def solve_centroids(centroids, width, height, fov_deg, method="pyramid", max_mag=6.0,
                    distortion=None, cache_dir=None, tolerance_px=None, max_stars=32,
                    budget=2000, centroid_sigma_px=None, duplicate_px=DEFAULT_DUPLICATE_PX):
    """Identify the stars of ``centroids`` and return a :class:`SolveResult`; never raises
    for bad input (see the module docstring).

    ``width``, ``height``: frame size, px.  ``fov_deg``: horizontal FOV, deg.  ``method``:
    the lost-in-space method (``"pyramid"``, ``"triangle"`` or ``"hashing"``, as far as
    :mod:`lodestar.ground.database` builds and :mod:`lodestar.firmware.starid` serves it).
    ``max_mag``: faintest catalogue star of the database.  ``distortion``: Brown-Conrady
    dict.  ``cache_dir``: database cache.
    ``tolerance_px``: match tolerance (default ``max(2 px, fov/1000)``).  ``max_stars``:
    brightest centroids used.  ``budget``: pattern budget.  ``centroid_sigma_px``: fixed
    centroid noise for the covariance (default: estimated from the residuals).
    ``duplicate_px``: centroids closer than this are one star.
    """
    n_in = len(centroids) if hasattr(centroids, "__len__") else 0

    def bad(reason, status="BAD_INPUT", **fields):
        return SolveResult(status, reason, n_centroids=n_in, **fields)

    # ---- parameters -------------------------------------------------------------------
    for name, value in (("width", width), ("height", height)):
        if not _is_int(value) or not 1 <= value <= 4096:
            return bad(f"{name} must be an int in 1..4096, got {value!r}")
    if not _is_number(fov_deg) or not MIN_FOV_DEG <= fov_deg <= MAX_FOV_DEG:
        return bad(f"fov_deg must be a number in [{MIN_FOV_DEG}, {MAX_FOV_DEG}], "
                   f"got {fov_deg!r}")
    if not _is_number(max_mag) or not -2.0 < max_mag <= 18.0:
        return bad(f"max_mag must be a finite magnitude, got {max_mag!r}")
    if method not in fwdatabase.METHOD_NAMES:
        return bad(f"unknown method {method!r} (known: {sorted(fwdatabase.METHOD_NAMES)})")
    if distortion is not None and not isinstance(distortion, dict):
        return bad("distortion must be a dict of k1, k2, k3, p1, p2 (and cx, cy)")
    if tolerance_px is not None and not (_is_number(tolerance_px) and tolerance_px > 0):
        return bad(f"tolerance_px must be a positive number, got {tolerance_px!r}")
    if not _is_int(max_stars) or max_stars < MIN_STARS:
        return bad(f"max_stars must be an int >= {MIN_STARS}")
    if not _is_int(budget) or budget < 1:
        return bad("budget must be a positive int")
    if not _is_number(duplicate_px) or duplicate_px < 0:
        return bad(f"duplicate_px must be a number >= 0, got {duplicate_px!r}")
    try:
        cam = make_camera(int(width), int(height), float(fov_deg), distortion)
        fov = camera_fov_deg(cam)
    except (ValueError, TypeError) as exc:
        return bad(f"camera: {exc}")

    # ---- centroids --------------------------------------------------------------------
    arr = _centroid_array(centroids)
    if isinstance(arr, str):
        return bad(arr, fov_deg=fov)
    n_in = len(arr)
    xs, ys = arr[:, 0], arr[:, 1]
    inside = (xs >= -0.5) & (xs < width - 0.5) & (ys >= -0.5) & (ys < height - 0.5)
    n_outside = int(n_in - np.count_nonzero(inside))
    if arr.shape[1] == 3:
        order = np.argsort(-arr[:, 2], kind="stable")
        fluxes = arr[order, 2]
    else:
        order = np.arange(n_in)
        fluxes = None
    order = [i for i in order if inside[i]]
    kept = []                              # indices into the input, brightest first
    n_dup = 0
    for i in order:
        if len(kept) == max_stars:
            break
        if all(math.hypot(xs[i] - xs[j], ys[i] - ys[j]) >= duplicate_px for j in kept):
            kept.append(int(i))
        else:
            n_dup += 1
    info = dict(n_centroids=n_in, n_used=len(kept), n_duplicates=n_dup, n_outside=n_outside,
                fov_deg=fov)
    note = f"{n_outside} centroids outside the {width}x{height} frame ignored" \
        if n_outside else ""
    if len(kept) < MIN_STARS:
        return SolveResult("TOO_FEW_STARS", f"{len(kept)} distinct centroids in the frame, "
                           f"at least {MIN_STARS} needed" + ("; " + note if note else ""),
                           **info)
    vectors = [cam.pixel_to_vector(float(xs[i]), float(ys[i])) for i in kept]
    if any(v is None for v in vectors):
        return SolveResult("BAD_INPUT", "a centroid is outside the camera model", **info)
    flux_list = None
    if fluxes is not None:
        flux_list = [float(arr[i, 2]) for i in kept]

    # ---- database and tracker ---------------------------------------------------------
    try:
        db, path = load_database(fov[0], fov[1], float(max_mag), method, cache_dir)
    except ValueError as exc:
        return SolveResult("BAD_INPUT", f"database: {exc}", **info)
    except Exception as exc:              # the builder's output failed the reader
        return SolveResult("DATABASE_CORRUPT", f"database: {exc!r}", **info)
    info["database"] = None if path is None else str(path)
    if tolerance_px is None:
        tolerance_px = max(2.0, math.radians(fov[0]) / 1000.0 * cam.fx)
    tracker = StarTracker(db, cam, Settings(method=method, max_stars=max_stars,
                          tolerance_px=float(tolerance_px), budget=int(budget),
                          centroid_sigma_px=centroid_sigma_px))
    if tracker.status != fwstatus.OK:
        return SolveResult(fwstatus.name(tracker.status), tracker.reason, **info)
    t0 = time.perf_counter()
    res = tracker.solve_vectors(vectors, fluxes=flux_list)
    info["solve_ms"] = (time.perf_counter() - t0) * 1e3
    info["patterns_tried"] = res.patterns_tried
    info["probability"] = res.probability
    reason = "; ".join(r for r in (note, res.reason) if r)
    if res.status != fwstatus.OK:
        return SolveResult(fwstatus.name(res.status), reason, **info)
    from lodestar.sim.attitude import to_radec_roll
    q = [float(v) for v in res.q]
    ra, dec, roll = to_radec_roll(np.asarray(q))
    return SolveResult("OK", reason, ra_deg=float(ra), dec_deg=float(dec),
                       roll_deg=float(roll), q=q,
                       matches={kept[o]: int(hip) for o, _x, _y, hip in res.matches},
                       sigma_cross_arcsec=res.sigma_cross_arcsec,
                       sigma_roll_arcsec=res.sigma_roll_arcsec,
                       centroid_sigma_px=res.centroid_sigma_px, **info)
