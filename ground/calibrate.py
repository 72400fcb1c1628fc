"""Lens calibration from stars (``lodestar calibrate``): focal lengths, principal point and
Brown-Conrady distortion of :class:`lodestar.firmware.camera.Camera` fitted to solved sky
frames.

Each frame is solved with the current camera (:func:`lodestar.ground.imagesolve.solve_image`,
the flight firmware); its matched stars, plus every other detected record within the match
radius of a catalogue star predicted from that solution, give pairs *pixel centroid <->
catalogue unit vector (ICRS)*.  One joint nonlinear least squares
(``scipy.optimize.least_squares``) then fits the free camera parameters and one attitude per
frame to the pixel residuals; pairs further than :data:`REJECT_SIGMA` robust sigmas from the
fit are dropped and the fit repeated until the set is stable.  Solve -> fit runs ``rounds``
times, so a far-off starting camera (no distortion, the nominal FOV) improves before the
final pairs are chosen.  Parameter 1-sigma come from the Jacobian at the solution, scaled by
the residuals (``s^2 (J^T J)^-1``).  Units: pixels of the whole image (``docs/conventions.md``),
residual angles in arcseconds.  Method and results: ``docs/calibration.md``.
"""

import hashlib
import math

import numpy as np
from scipy.optimize import least_squares
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from lodestar.firmware import status as S
from lodestar.firmware.camera import Camera
from lodestar.ground import imagesolve, onboard
from lodestar.ground.database import default_catalogue
from lodestar.sim.attitude import to_radec_roll

INTRINSICS = ("fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2")
"""Camera parameters a calibration can fit, in the order of the parameter vector."""
DEFAULT_FREE = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2")
"""Fitted by default; ``k3`` only on request (it trades off against ``k2`` over a frame)."""
COARSE = ("fx", "fy", "k1")
"""Parameters of the rounds before the last: the scale and the leading radial term, what a
start without distortion misses most."""
REJECT_SIGMA = 4.0
"""Pairs whose residual exceeds this many robust per-axis sigmas are outliers (a Gaussian
pair does so with probability ``exp(-8) = 3e-4``)."""
MIN_SIGMA_PX = 0.05
"""Floor of the robust sigma for the rejection, px (a perfect fit rejects nothing)."""
MAX_REJECT_ROUNDS = 8
"""Fit -> reject repetitions at most per round."""
MIN_FRAME_PAIRS = 3
"""A frame with fewer pairs fixes no attitude and is not used."""
PAIRS_PER_PARAMETER = 1.5
"""At least this many pairs (two residuals each) per fitted parameter, attitudes included."""
MAX_ROUNDS = 10
"""Most solve -> fit rounds (``--rounds``): each one solves every frame again (about a
second per frame), and a far-off start settles in two or three."""
SETTLED_SIGMA = 0.01
"""A coarse round whose parameters moved less than this many of their 1-sigma since the
previous coarse round has converged: the next round is the last (the convergence stop)."""
ARCSEC = math.degrees(1.0) * 3600.0


class FramePairs:
    """The pairs of one frame: ``xy`` ``(N, 2)`` pixel centroids (whole image), ``v``
    ``(N, 3)`` catalogue ICRS unit vectors, ``hip`` ``(N,)``, ``q`` the attitude found
    (scalar last), ``n_solver`` pairs the solver matched (the first ones), ``status``."""

    def __init__(self, name, xy, v, hip, q, n_solver, status="OK"):
        self.name = name
        self.xy = np.asarray(xy, dtype=np.float64).reshape(-1, 2)
        self.v = np.asarray(v, dtype=np.float64).reshape(-1, 3)
        self.hip = np.asarray(hip, dtype=np.int64)
        self.q = np.asarray(q, dtype=np.float64)
        self.n_solver = n_solver
        self.status = status


class CalibrationError(ValueError):
    """Calibration impossible (frames that do not solve, too few stars); the message is
    one line naming the frames."""


# --------------------------------------------------------------------------------------
# Model
# --------------------------------------------------------------------------------------

def project(params, v_cam):
    """Pixels ``(N, 2)`` of camera-frame directions ``v_cam`` ``(N, 3)``, ``Z > 0``, under
    ``params`` in :data:`INTRINSICS` order: the model of
    :meth:`lodestar.firmware.camera.Camera.vector_to_pixel`, vectorised (the tests hold the
    two together)."""
    fx, fy, cx, cy, k1, k2, k3, p1, p2 = params
    x = v_cam[:, 0] / v_cam[:, 2]
    y = v_cam[:, 1] / v_cam[:, 2]
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return np.column_stack((cx + fx * xd, cy + fy * yd))


def camera_params(camera):
    """A firmware camera's :data:`INTRINSICS` as a float array."""
    return np.array([getattr(camera, name) for name in INTRINSICS], dtype=np.float64)


def camera_from_params(width, height, params):
    """The firmware :class:`Camera` of ``params`` (:data:`INTRINSICS`; the inverse of
    :func:`camera_params`).  Raises ``ValueError`` when the distortion is not invertible over
    the frame."""
    return Camera(width, height, **dict(zip(INTRINSICS, (float(p) for p in params))))


# --------------------------------------------------------------------------------------
# Pairs from one frame
# --------------------------------------------------------------------------------------

def _records_xy(image, det):
    """Centroids ``(N, 2)`` of the detected records that do not touch the frame's edge (a
    star cut by the edge has its centroid pulled inwards, where the distortion is
    largest), in whole-image pixels."""
    h, w = image.frame.shape
    xy = [image.to_original(b.sx / b.s0, b.sy / b.s0) for b in det.blobs
          if b.s0 > 0 and b.xmin > 0 and b.ymin > 0 and b.xmax < w - 1 and b.ymax < h - 1]
    return np.asarray(xy, dtype=np.float64).reshape(-1, 2)


def match_records(xy, camera, q, catalogue, radius_px):
    """``(record index, catalogue index)`` pairs: each record whose nearest predicted
    catalogue star (``catalogue`` projected at attitude ``q`` through the firmware
    ``camera``) lies within ``radius_px`` while the second nearest lies beyond
    ``2 radius_px``, one record per star.  Stars beyond the camera's fold radius are never
    predicted (the distortion polynomial would bring them back into the frame)."""
    if len(xy) == 0:
        return []
    v_cam = Rotation.from_quat(q).apply(catalogue.unit_vectors())
    with np.errstate(divide="ignore", invalid="ignore"):
        radius = np.hypot(v_cam[:, 0], v_cam[:, 1]) / v_cam[:, 2]
    ahead = np.flatnonzero((v_cam[:, 2] > 0) & (radius < camera.fold_radius()))
    if len(ahead) == 0:
        return []
    width, height = camera.width, camera.height
    pix = project(camera_params(camera), v_cam[ahead])
    keep = ((pix[:, 0] > -radius_px - 0.5) & (pix[:, 0] < width - 0.5 + radius_px) &
            (pix[:, 1] > -radius_px - 0.5) & (pix[:, 1] < height - 0.5 + radius_px))
    ahead, pix = ahead[keep], pix[keep]
    if len(ahead) == 0:
        return []
    k = min(2, len(ahead))
    dist, idx = cKDTree(pix).query(xy, k=k)
    dist = dist.reshape(len(xy), k)
    idx = idx.reshape(len(xy), k)
    best = {}
    for i in range(len(xy)):
        if dist[i, 0] > radius_px or (k == 2 and dist[i, 1] <= 2.0 * radius_px):
            continue
        star = int(ahead[idx[i, 0]])
        if star in best:
            best[star] = None                 # two records claim one star: neither
        else:
            best[star] = i
    return [(i, star) for star, i in best.items() if i is not None]


def frame_pairs(name, image, camera, mag=None, tolerance_px=None, ksigma=None,
                min_pixels=None, radius_px=None, q_fallback=None):
    """Solve ``image`` (a :class:`lodestar.ground.imagesolve.SkyImage`) with the firmware
    ``camera`` of the whole image and return its :class:`FramePairs`, or ``(status,
    reason)`` when it does not solve.  ``radius_px``: radius of the extra matches (default
    the solve's match tolerance).  ``q_fallback``: attitude used when the solve fails (a
    previous round's fit), so a frame is never lost to a better camera."""
    ksigma = imagesolve.DEFAULT_KSIGMA if ksigma is None else ksigma
    min_pixels = imagesolve.DEFAULT_MIN_PIXELS if min_pixels is None else min_pixels
    binned, _ = imagesolve.image_camera(image, camera=camera)
    report, det, res, _ = imagesolve.solve_image(image, binned, mag, tolerance_px, ksigma,
                                                 min_pixels)
    # an IMPRECISE solve named its stars right: only its attitude is loose, as an
    # uncalibrated lens makes it, and the fit below is what tightens it
    identified = res is not None and (res.ok or res.status == S.IMPRECISE)
    if identified:
        q = np.asarray(res.q, dtype=np.float64)
    elif q_fallback is not None:
        q = np.asarray(q_fallback, dtype=np.float64)
    else:
        return report["status"], report["reason"]
    cat = default_catalogue(mag).brighter_than(report["mag_limit"] + 1e-6)
    xy_all = _records_xy(image, det)
    xy, hips = [], []
    for _index, x, y, hip in (res.matches if identified else ()):
        xy.append(image.to_original(x, y))
        hips.append(hip)
    n_solver = len(xy)
    if radius_px is None:
        radius_px = (tolerance_px if tolerance_px is not None else
                     onboard.default_tolerance_px(binned)) * image.bin
    taken = set(hips)
    for i, star in match_records(xy_all, camera, q, cat, radius_px):
        hip = int(cat.hip[star])
        if hip in taken or any(math.hypot(xy_all[i, 0] - x, xy_all[i, 1] - y) < 1.0
                               for x, y in xy[:n_solver]):
            continue
        taken.add(hip)
        xy.append(tuple(xy_all[i]))
        hips.append(hip)
    full = default_catalogue(mag)
    v = full.unit_vectors()[[full.by_hip(h) for h in hips]] if hips else np.zeros((0, 3))
    return FramePairs(name, xy, v, hips, q, n_solver,
                      report["status"] if identified else
                      f"{report['status']} (previous attitude)")


# --------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------

class Fit:
    """A fitted camera: ``camera`` (firmware), ``params`` (:data:`INTRINSICS`), ``sigma``
    (free parameter -> 1-sigma), ``free``, ``cov`` (covariance of the fitted parameters
    named by ``cov_names``, :data:`INTRINSICS` order, no ``fy`` with ``one_focal``),
    ``frames`` (those used), ``q`` per frame, ``inlier`` mask per pair, ``residual_px``
    ``(N, 2)``, ``n_pairs``, ``n_rejected``, ``scale_px`` (per-axis RMS residual of the
    inliers, the ``s`` of the covariance), ``jac`` (the inliers' Jacobian at the solution:
    the fitted parameters, then each frame's rotation vector, applied in the camera
    frame)."""


def _stack(frames):
    xy = np.concatenate([f.xy for f in frames])
    v = np.concatenate([f.v for f in frames])
    which = np.concatenate([np.full(len(f.xy), k) for k, f in enumerate(frames)])
    return xy, v, which


def fit_camera(frames, camera0, free=DEFAULT_FREE, one_focal=False,
               reject_sigma=REJECT_SIGMA, min_sigma_px=MIN_SIGMA_PX):
    """Fit the ``free`` parameters of ``camera0`` (firmware camera, whole image) and one
    attitude per frame to ``frames`` (:class:`FramePairs`); ``one_focal``: ``fy = fx``;
    ``min_sigma_px``: the floor of the rejection's robust sigma.
    Returns a :class:`Fit`; raises :class:`CalibrationError` when there are too few pairs
    and ``ValueError`` when the fitted distortion cannot be inverted over the frame."""
    free = tuple(name for name in INTRINSICS if name in free)
    if one_focal:
        free = tuple(name for name in free if name != "fy")
    base = camera_params(camera0)
    if one_focal:
        base[0] = base[1] = math.sqrt(base[0] * base[1])
    free_idx = [INTRINSICS.index(name) for name in free]
    frames = [f for f in frames if len(f.xy) >= MIN_FRAME_PAIRS]
    xy, v, which = _stack(frames) if frames else (np.zeros((0, 2)), None, None)
    n_params = len(free) + 3 * len(frames)
    if not frames or len(xy) < PAIRS_PER_PARAMETER * n_params:
        raise CalibrationError(
            f"too few matched stars: {len(xy)} pairs in {len(frames)} frames with at least "
            f"{MIN_FRAME_PAIRS}, {math.ceil(PAIRS_PER_PARAMETER * max(n_params, 1))} needed "
            f"for {len(free)} camera parameters and {len(frames)} attitudes (add frames, fix "
            f"parameters or lower --ksigma)")
    r0 = np.stack([Rotation.from_quat(f.q).as_matrix() for f in frames])

    def unpack(theta):
        p = base.copy()
        p[free_idx] = theta[:len(free)]
        if one_focal:
            p[1] = p[0]
        rot = Rotation.from_rotvec(theta[len(free):].reshape(-1, 3)).as_matrix() @ r0
        return p, rot

    def residuals(theta, mask):
        p, rot = unpack(theta)
        v_cam = np.einsum("nij,nj->ni", rot[which[mask]], v[mask])
        return (project(p, v_cam) - xy[mask]).ravel()

    theta = np.concatenate([base[free_idx], np.zeros(3 * len(frames))])
    mask = np.ones(len(xy), dtype=bool)
    for attempt in range(MAX_REJECT_ROUNDS):
        robust = attempt == 0
        sol = least_squares(residuals, theta, args=(mask,), x_scale="jac", method="trf",
                            loss="soft_l1" if robust else "linear", f_scale=1.0)
        theta = sol.x
        everyone = residuals(theta, np.ones(len(xy), dtype=bool)).reshape(-1, 2)
        sigma = max(1.4826 * float(np.median(np.abs(everyone[mask]))), min_sigma_px)
        new_mask = np.hypot(everyone[:, 0], everyone[:, 1]) <= reject_sigma * sigma
        if not robust and np.array_equal(new_mask, mask):
            break
        if np.count_nonzero(new_mask) < PAIRS_PER_PARAMETER * n_params:
            raise CalibrationError(
                f"too few matched stars agree with one camera: {np.count_nonzero(new_mask)} "
                f"of {len(xy)} pairs within {reject_sigma:g} sigma ({sigma:.2f} px)")
        mask = new_mask
    else:                                   # no stable set: the last one, fitted
        sol = least_squares(residuals, theta, args=(mask,), x_scale="jac", method="trf")
        theta = sol.x
        everyone = residuals(theta, np.ones(len(xy), dtype=bool)).reshape(-1, 2)
    p, rot = unpack(theta)
    jac = sol.jac
    dof = max(int(2 * np.count_nonzero(mask)) - len(theta), 1)
    scale2 = float(np.sum(sol.fun ** 2)) / dof
    cov = scale2 * np.linalg.pinv(jac.T @ jac)
    fit = Fit()
    fit.free = free + (("fy",) if one_focal and "fx" in free else ())
    fit.params = p
    fit.cov = cov[:len(free), :len(free)]
    fit.cov_names = free
    fit.sigma = {name: math.sqrt(max(cov[i, i], 0.0)) for i, name in enumerate(free)}
    if one_focal and "fx" in fit.sigma:
        fit.sigma["fy"] = fit.sigma["fx"]
    fit.camera = camera_from_params(camera0.width, camera0.height, p)
    fit.q = [Rotation.from_matrix(m).as_quat() for m in rot]
    fit.frames = frames
    fit.inlier = mask
    fit.residual_px = everyone
    fit.n_pairs = len(xy)
    fit.n_rejected = int(len(xy) - np.count_nonzero(mask))
    fit.scale_px = math.sqrt(scale2)
    fit.jac = jac
    return fit


def residual_stats(fit, camera=None):
    """Residuals of ``fit``'s inlier pairs under ``camera`` (default the fit's) with the
    attitudes refitted for that camera (the best that camera does): ``{"n", "rms_px",
    "max_px", "rms_arcsec", "max_arcsec"}`` (RMS and max of the 2-D pixel error and of the
    angle between each measured direction and its catalogue star)."""
    if camera is None:
        camera, qs = fit.camera, fit.q
    else:
        kept = [FramePairs(f.name, f.xy[m], f.v[m], f.hip[m], f.q, 0)
                for f, m in zip(fit.frames, _per_frame(fit))]
        qs = fit_camera(kept, camera, free=(), reject_sigma=math.inf).q
    err_px, err_as = [], []
    for f, m, q in zip(fit.frames, _per_frame(fit), qs):
        v_cam = Rotation.from_quat(q).apply(f.v[m])
        pix = project(camera_params(camera), v_cam)
        err_px.extend(np.hypot(*(pix - f.xy[m]).T))
        for (x, y), vc in zip(f.xy[m], v_cam):
            u = camera.pixel_to_vector(float(x), float(y))
            if u is None:
                err_as.append(math.inf)
                continue
            err_as.append(math.atan2(np.linalg.norm(np.cross(u, vc)), float(np.dot(u, vc)))
                          * ARCSEC)
    err_px, err_as = np.asarray(err_px), np.asarray(err_as)
    return {"n": int(len(err_px)),
            "rms_px": float(np.sqrt(np.mean(err_px ** 2))), "max_px": float(err_px.max()),
            "rms_arcsec": float(np.sqrt(np.mean(err_as ** 2))),
            "max_arcsec": float(err_as.max())}


def _per_frame(fit):
    """The inlier mask of each frame's pairs."""
    out, start = [], 0
    for f in fit.frames:
        out.append(fit.inlier[start:start + len(f.xy)])
        start += len(f.xy)
    return out


# --------------------------------------------------------------------------------------
# Solve -> fit
# --------------------------------------------------------------------------------------

def _refuse_duplicates(images):
    """Raise :class:`CalibrationError` when two of ``images`` (``[(name, SkyImage)]``) hold
    the same pixels (the same file twice, a link or a copy): the fit would count its stars
    as independent twice over."""
    seen = {}
    for name, image in images:
        frame = np.ascontiguousarray(image.frame)
        key = (frame.shape, str(frame.dtype), hashlib.sha256(frame.tobytes()).hexdigest())
        if key in seen:
            raise CalibrationError(f"{name} is the same frame as {seen[key]}: give each frame "
                                   f"once (a frame counted twice halves every 1-sigma)")
        seen[key] = name


def _settled(fit, before):
    """True when coarse ``fit`` moved none of its parameters by :data:`SETTLED_SIGMA` of
    its 1-sigma since the coarse fit ``before`` (None: not yet two fits)."""
    if fit is None or before is None or fit.cov_names != before.cov_names:
        return False
    for name in fit.cov_names:
        i = INTRINSICS.index(name)
        if not abs(fit.params[i] - before.params[i]) <= SETTLED_SIGMA * fit.sigma[name]:
            return False
    return True


class Calibration:
    """Result of :func:`calibrate`: ``camera`` (firmware, whole image), ``sigma``, ``fit``
    (the last :class:`Fit`), ``before`` / ``after`` (:func:`residual_stats` of the starting
    and the fitted camera on the final pairs), ``frames`` (per frame: name, status, pairs,
    solver pairs, inliers, RA/Dec/roll of the fitted attitude), ``rounds``."""

    def as_dict(self):
        """JSON-ready summary (the camera file's ``calibration`` block)."""
        return {"frames": self.frames, "rounds": self.rounds, "free": list(self.fit.free),
                "pairs": self.fit.n_pairs, "rejected": self.fit.n_rejected,
                "reject_sigma": REJECT_SIGMA, "residual_scale_px": self.fit.scale_px,
                "residuals": {"before": self.before, "after": self.after}}


def calibrate(images, camera0, rounds=2, free=DEFAULT_FREE, one_focal=False, mag=None,
              tolerance_px=None, ksigma=None, min_pixels=None, skip_unsolved=False,
              log=None):
    """Calibrate from ``images`` (``[(name, SkyImage)]``, one camera) starting at firmware
    ``camera0`` (whole image): ``rounds`` times solve every frame with the current camera
    and fit (:func:`fit_camera`); the rounds before the last fit only the :data:`COARSE`
    parameters among ``free``, which a far-off start can determine from few stars, and once
    they have settled (:data:`SETTLED_SIGMA`) the next round is the last.  ``rounds`` is at
    most :data:`MAX_ROUNDS`.  A frame that solves in no round raises
    :class:`CalibrationError` naming it, unless ``skip_unsolved``; so does a frame given
    twice (the same pixels: counted twice it would halve every 1-sigma).  ``log``: a text
    stream for one progress line per round."""
    if isinstance(rounds, bool) or not isinstance(rounds, int) or \
            not 1 <= rounds <= MAX_ROUNDS:
        raise ValueError(f"--rounds must be an int in 1..{MAX_ROUNDS}, got {rounds!r}")
    _refuse_duplicates(images)
    camera, fit, previous, coarse_fit = camera0, None, {}, None
    rnd, final = 0, False
    while not final:
        final = rnd == rounds - 1 or _settled(fit, coarse_fit)
        coarse_fit = fit
        rnd += 1
        frames, failed = [], []
        for name, image in images:
            got = frame_pairs(name, image, camera, mag, tolerance_px, ksigma, min_pixels,
                              q_fallback=previous.get(name))
            if isinstance(got, tuple):
                failed.append(f"{name} ({got[0]}: {got[1]})")
            else:
                frames.append(got)
        coarse = tuple(name for name in free if name in COARSE)
        try:
            fit = fit_camera(frames, camera, free if final or not coarse else coarse,
                             one_focal)
        except CalibrationError as exc:
            if failed:
                raise CalibrationError(f"{exc}; not solved: {'; '.join(failed)}") from None
            raise
        previous.update((f.name, q) for f, q in zip(fit.frames, fit.q))
        camera = fit.camera
        if log is not None:
            print(f"lodestar calibrate: round {rnd}: {len(fit.frames)} frames, "
                  f"{fit.n_pairs} pairs ({fit.n_rejected} rejected), residual "
                  f"{fit.scale_px:.3f} px per axis; fitted {' '.join(fit.free)}",
                  file=log, flush=True)
    if failed and not skip_unsolved:
        raise CalibrationError(f"{len(failed)} of {len(images)} frames do not solve: "
                               f"{'; '.join(failed)} (drop them or give --skip-unsolved)")
    out = Calibration()
    out.camera, out.sigma, out.fit, out.rounds = fit.camera, fit.sigma, fit, rnd
    out.before = residual_stats(fit, camera0)
    out.after = residual_stats(fit)
    out.frames = []
    used = {f.name: (f, m, q) for f, m, q in zip(fit.frames, _per_frame(fit), fit.q)}
    for name, _image in images:
        if name not in used:
            out.frames.append({"name": name, "status": "not used"})
            continue
        f, m, q = used[name]
        ra, dec, roll = to_radec_roll(np.asarray(q))
        out.frames.append({"name": name, "status": f.status, "pairs": int(len(f.xy)),
                           "solver_pairs": int(f.n_solver), "inliers": int(np.sum(m)),
                           "ra_deg": float(ra), "dec_deg": float(dec),
                           "roll_deg": float(roll)})
    return out
