"""Blind field-of-view search of the ground solve: scale-invariant star quads (Astrometry.net's
geometric hash, Lang et al. 2010) over a multiscale quad index find the focal length of a
frame whose FOV is unknown or approximate; the flight firmware then identifies and verifies
at that scale (:func:`lodestar.ground.solve.solve_unknown_fov`).

Units: pixels as ``lodestar.contract`` (a centred pinhole with square pixels, ``f`` in px),
angles in radians inside, FOVs in degrees at the interface.  The index is built once from the
whole Hipparcos and cached beside the star databases (:mod:`lodestar.ground.cache`); the
levels, the hash, the candidate budget and the measurements are in ``docs/solve_centroids.md``
(Unknown FOV)."""

import hashlib
import io
import math
from itertools import combinations

import numpy as np

from lodestar.ground.database import default_catalogue, select_density

FOV_RANGE_DEG = (8.0, 30.0)
"""Horizontal FOVs the blind search is documented (and tested) for, deg."""
LEVEL_RATIO = math.sqrt(2.0)
"""Ratio of consecutive index levels' FOVs: a frame is within ``LEVEL_RATIO ** 0.5`` of one."""
LEVELS_DEG = tuple(8.0 * LEVEL_RATIO ** k for k in range(0, 5))
"""Horizontal FOV of each index level (4:3 fields), deg: 8 .. 32."""
LEVEL_ASPECT = 4.0 / 3.0
STARS_PER_FIELD = 20
"""Stars of a level's uniform selection per field of the level's size."""
NEIGHBOURS = 5
"""A quad is a star with 3 of its ``NEIGHBOURS`` nearest level stars."""
QUAD_RADIUS = 0.3
"""Those neighbours lie within this fraction of the level's horizontal FOV."""
IMAGE_STARS = 40
"""Brightest image stars a level's quads are built from (:func:`image_quads`)."""
IMAGE_NEIGHBOURS = 8
"""Image neighbours a quad's other three stars are chosen from (56 quads per star)."""
ALL_SUBSETS = 8
"""Every 4-subset of this many brightest image stars is hashed as well (70 quads)."""
VERIFY_STARS = 30
"""Brightest image stars a candidate is verified against."""
CODE_TOL = 0.015
"""Largest Euclidean distance of two hash codes of one quad (about 1 px on a 100 px quad,
with the projection's residual)."""
MAX_CANDIDATES = 400
"""Most candidate quads verified in one search: the search's work budget."""
MIN_MATCHES = 10
"""Image stars a candidate must match to hand its scale to the firmware."""
MAX_FALSE_PROB = 1e-9
"""Largest chance that the matches of an accepted candidate are coincidences."""
INDEX_SCHEMA = 4


class FovEstimate:
    """A blind search's outcome: ``f_px`` (focal length, px; None when nothing was found),
    ``fov_deg`` (horizontal), ``n_matches`` (image stars the verification matched),
    ``candidates`` (quads verified), ``level_deg`` (the index level that matched)."""

    def __init__(self, f_px=None, fov_deg=None, n_matches=0, candidates=0, level_deg=None):
        self.f_px = f_px
        self.fov_deg = fov_deg
        self.n_matches = n_matches
        self.candidates = candidates
        self.level_deg = level_deg


def reach_deg():
    """``(lo, hi)`` horizontal FOVs (deg) the index's levels can serve at all: half a level
    step beyond the finest and the widest."""
    span = math.sqrt(LEVEL_RATIO)
    return LEVELS_DEG[0] / span, LEVELS_DEG[-1] * span


def fov_of_f(width, f_px):
    """Horizontal FOV (deg) of a centred pinhole ``width`` px wide with focal length ``f_px``."""
    return math.degrees(2 * math.atan(width / 2 / f_px))


def f_of_fov(width, fov_deg):
    """Focal length (px) of a centred pinhole ``width`` px wide with horizontal FOV ``fov_deg``."""
    return width / 2 / math.tan(math.radians(fov_deg) / 2)


# --------------------------------------------------------------------------------------
# The hash
# --------------------------------------------------------------------------------------

def _plane(v):
    """Gnomonic coordinates ``(n, 4, 2)`` of quads of unit vectors ``v`` ``(n, 4, 3)`` about
    their mean direction, in a right-handed tangent basis (a rotation of the sky turns the
    plane, it never mirrors it)."""
    m = v.sum(axis=1)
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    d = v[:, 1] - v[:, 0]
    e1 = d - (d * m).sum(axis=1, keepdims=True) * m
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(m, e1)
    w = np.einsum("nkc,nc->nk", v, m)
    return np.stack([np.einsum("nkc,nc->nk", v, e1) / w,
                     np.einsum("nkc,nc->nk", v, e2) / w], axis=-1)


_PAIRS = np.array(list(combinations(range(4), 2)))
_OTHERS = np.array([[k for k in range(4) if k not in p] for p in _PAIRS])


def quad_codes(points, canonical=True):
    """Hash codes of quads of plane points ``(n, 4, 2)``: ``(codes, labels)``.

    ``A``, ``B`` is the most distant pair; the others' coordinates ``z = (p - A)(1 + i) /
    (B - A)`` (``A = 0``, ``B = 1 + i``) are ``(x_C, y_C, x_D, y_D)``: invariant under
    translation, rotation and scale.  ``canonical``: one code per quad, ``A``/``B`` ordered
    so that ``x_C + x_D <= 1`` and ``C``/``D`` so that ``x_C <= x_D`` (``codes (n, 4)``,
    ``labels (n, 4)`` the quad's point order A, B, C, D); else all four labellings
    (``(n, 4, 4)`` each), so that a quad near a canonical boundary is found either way."""
    z = points[..., 0] + 1j * points[..., 1]
    n = len(z)
    d = np.abs(z[:, _PAIRS[:, 0]] - z[:, _PAIRS[:, 1]])
    best = np.argmax(d, axis=1)
    a_i, b_i = _PAIRS[best, 0], _PAIRS[best, 1]
    c_i, d_i = _OTHERS[best, 0], _OTHERS[best, 1]
    rows = np.arange(n)
    labellings = [(a_i, b_i, c_i, d_i), (b_i, a_i, c_i, d_i), (a_i, b_i, d_i, c_i),
                  (b_i, a_i, d_i, c_i)]
    codes, labels = [], []
    for a, b, c, dd in labellings:
        za, zb = z[rows, a], z[rows, b]
        scale = (1 + 1j) / (zb - za)
        zc, zd = (z[rows, c] - za) * scale, (z[rows, dd] - za) * scale
        codes.append(np.stack([zc.real, zc.imag, zd.real, zd.imag], axis=1))
        labels.append(np.stack([a, b, c, dd], axis=1))
    codes, labels = np.stack(codes, axis=1), np.stack(labels, axis=1)
    if not canonical:
        return codes, labels
    k = np.where(codes[:, 0, 0] + codes[:, 0, 2] > 1, 1, 0)
    k = k + 2 * (codes[rows, k, 0] > codes[rows, k, 2])
    return codes[rows, k], labels[rows, k]


# --------------------------------------------------------------------------------------
# The index
# --------------------------------------------------------------------------------------

class Level:
    """One scale of the index: ``fov_deg``; ``separation`` (rad), ``vectors`` ``(n, 3)`` and
    its uniform star selection; ``quads`` ``(m, 4)`` rows of ``vectors``
    (labelled A, B, C, D) and their canonical ``codes`` ``(m, 4)``; ``code_tree`` and
    ``star_tree`` (cKDTrees)."""

    def __init__(self, fov_deg, separation, vectors, quads, codes):
        from scipy.spatial import cKDTree
        self.fov_deg = fov_deg
        self.separation = separation
        self.vectors = vectors
        self.quads = quads
        self.codes = codes
        self.code_tree = cKDTree(codes)
        self.star_tree = cKDTree(vectors)


def build_level(catalogue, fov_deg):
    """``(separation, vectors, quads, codes)`` of the level of horizontal FOV ``fov_deg``: the
    uniform selection of :data:`STARS_PER_FIELD` per 4:3 field, brightest first
    (:func:`lodestar.ground.database.select_density`), and every quad of a star with 3 of
    its :data:`NEIGHBOURS` nearest within :data:`QUAD_RADIUS` of the FOV."""
    from scipy.spatial import cKDTree
    fov_v = math.degrees(2 * math.atan(math.tan(math.radians(fov_deg) / 2) / LEVEL_ASPECT))
    allv = catalogue.unit_vectors()
    mask, separation = select_density(allv, np.asarray(catalogue.vmag, dtype=np.float64),
                                STARS_PER_FIELD, fov_deg, fov_v)
    vectors = allv[mask]
    n = len(vectors)
    chord = 2 * math.sin(math.radians(QUAD_RADIUS * fov_deg) / 2)
    _dist, idx = cKDTree(vectors).query(vectors, k=NEIGHBOURS + 1, distance_upper_bound=chord)
    quads = []
    for trio in combinations(range(1, NEIGHBOURS + 1), 3):
        q = np.column_stack([idx[:, 0]] + [idx[:, t] for t in trio])
        quads.append(q[np.all(q < n, axis=1)])
    quads = np.unique(np.sort(np.concatenate(quads), axis=1), axis=0)
    codes, labels = quad_codes(_plane(vectors[quads]))
    quads = np.take_along_axis(quads, labels, axis=1)
    return np.array(separation), vectors, quads.astype(np.int32), codes.astype(np.float64)


def _index_key():
    from lodestar.ground import cache
    parts = [f"schema={INDEX_SCHEMA}", f"levels={LEVELS_DEG}", f"aspect={LEVEL_ASPECT}",
             f"stars={STARS_PER_FIELD}", f"neighbours={NEIGHBOURS}", f"radius={QUAD_RADIUS}",
             f"catalogue={cache._catalogue_hash()}", cache._deep_tag(None)]
    return hashlib.sha256("|".join(parts).encode()).hexdigest()


_INDEX = {}


def load_index(cache_dir=None, log=None):
    """The multiscale quad index (a list of :class:`Level`, finest first): from memory, the
    cache file ``lodestar-quads-<hash16>.npz`` (:func:`lodestar.ground.cache.default_cache_dir`
    unless ``cache_dir``), or built from the whole Hipparcos (15 to 40 s) and written
    atomically; ``log``: a text stream told when it is built (None: silent).  Raises
    ``ValueError`` when the deep catalogue is not installed."""
    from pathlib import Path

    from lodestar.ground import cache
    from lodestar.ground.files import write_atomic
    key = _index_key()
    directory = Path(cache_dir) if cache_dir is not None else cache.default_cache_dir()
    target = directory / f"lodestar-quads-{key[:16]}.npz"
    if str(target) in _INDEX:
        return _INDEX[str(target)]
    arrays = None
    try:
        with np.load(target) as data:
            arrays = {name: data[name] for name in data.files}
        if str(arrays["key"]) != key:
            arrays = None
    except Exception:              # missing, unreadable or another build's: rebuild
        arrays = None
    if arrays is None:
        if log is not None:
            print("lodestar: building the multiscale quad index of the FOV search (first run "
                  "only) ...", file=log, flush=True)
        catalogue = default_catalogue(None)
        arrays = {"key": np.array(key)}
        for k, fov in enumerate(LEVELS_DEG):
            for name, value in zip(("separation", "vectors", "quads", "codes"),
                                   build_level(catalogue, fov)):
                arrays[f"{name}{k}"] = value
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        try:
            write_atomic(target, buf.getvalue(), folders=True)
            where = f"cached in {target}"
        except OSError:            # read-only cache: keep the index in memory only
            where = "not cached (cache directory not writable)"
        if log is not None:
            print(f"lodestar: built the quad index; {where}", file=log, flush=True)
    levels = [Level(fov, float(arrays[f"separation{k}"]), arrays[f"vectors{k}"],
                    arrays[f"quads{k}"], arrays[f"codes{k}"])
              for k, fov in enumerate(LEVELS_DEG)]
    _INDEX.clear()
    _INDEX[str(target)] = levels
    return levels


# --------------------------------------------------------------------------------------
# The search
# --------------------------------------------------------------------------------------

def pixel_vectors(xy, width, height, f_px):
    """Unit vectors ``(n, 3)`` of pixels ``xy`` ``(n, 2)`` through the centred pinhole."""
    v = np.column_stack([xy[:, 0] - (width - 1) / 2, xy[:, 1] - (height - 1) / 2,
                         np.full(len(xy), float(f_px))])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def fit_rotation(cam, ref, weights=None):
    """Rotation ``R`` (3x3) minimising ``sum w |cam - R ref|^2`` (Kabsch, proper)."""
    w = np.ones(len(cam)) if weights is None else weights
    u, _s, vt = np.linalg.svd((cam * w[:, None]).T @ ref)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def fit_focal(xy, ref, width, height, f_px, max_iterations=50):
    """Least-squares ``(f_px, R)`` of pixels ``xy`` of catalogue unit vectors ``ref``:
    alternately the attitude (Kabsch) at ``f`` and the ``f`` minimising the pixel residuals
    ``|(x - cx, y - cy) - f (X/Z, Y/Z)|^2`` at that attitude (linear in ``f``), until ``f``
    moves by less than 1e-12 of itself (the alternation converges linearly)."""
    u = np.column_stack([xy[:, 0] - (width - 1) / 2, xy[:, 1] - (height - 1) / 2])
    for _ in range(max_iterations):
        rot = fit_rotation(pixel_vectors(xy, width, height, f_px), ref)
        p = ref @ rot.T
        t = p[:, :2] / p[:, 2:3]
        f_new = float((u * t).sum() / (t * t).sum())
        done = abs(f_new / f_px - 1) < 1e-12
        f_px = f_new
        if done:
            break
    return f_px, fit_rotation(pixel_vectors(xy, width, height, f_px), ref)


def _binomial_tail(n, k, p):
    """P(X >= k) of X ~ Binomial(n, p)."""
    if k <= 0:
        return 1.0
    return float(sum(math.comb(n, i) * p ** i * (1 - p) ** (n - i) for i in range(k, n + 1)))


def _verify(xy, width, height, f_px, rot, level, tolerance_px):
    """``(n_matches, false_prob, f_px)`` of a candidate: the level's stars in the
    frame matched to the image stars (nearest within a radius narrowed from 1.5 % of the width
    to ``3 * tolerance_px`` over three least-squares refits of ``f`` and the attitude)."""
    diag = math.hypot(width, height) / 2
    cos_r = math.cos(math.atan(diag / f_px) * 1.05)
    radius = max(3 * tolerance_px, 0.015 * width)
    for step in range(3):
        boresight = rot[2]
        near = level.star_tree.query_ball_point(boresight, 2 * math.sqrt(max(0.0, 2 - 2 * cos_r)))
        ref = level.vectors[near]
        p = ref @ rot.T
        front = p[:, 2] > 0
        px = f_px * p[front, 0] / p[front, 2] + (width - 1) / 2
        py = f_px * p[front, 1] / p[front, 2] + (height - 1) / 2
        inside = (px >= -0.5) & (px < width - 0.5) & (py >= -0.5) & (py < height - 0.5)
        rows = np.asarray(near)[front][inside]
        cat_xy = np.column_stack([px[inside], py[inside]])
        n_cat = len(cat_xy)
        if n_cat < MIN_MATCHES:
            return 0, 1.0, f_px
        d = np.hypot(xy[:, None, 0] - cat_xy[None, :, 0], xy[:, None, 1] - cat_xy[None, :, 1])
        nearest = np.argmin(d, axis=1)
        ok = d[np.arange(len(xy)), nearest] <= radius
        # one catalogue star per image star and vice versa
        taken, pairs = set(), []
        for i in np.flatnonzero(ok):
            if nearest[i] not in taken:
                taken.add(nearest[i])
                pairs.append((int(i), int(rows[nearest[i]])))
        if len(pairs) < MIN_MATCHES:
            return len(pairs), 1.0, f_px
        img = np.array([i for i, _r in pairs])
        f_px, rot = fit_focal(xy[img], level.vectors[[r for _i, r in pairs]], width, height,
                              f_px)
        if step < 2:
            radius = max(3 * tolerance_px, radius / 2.5)
    prob = _binomial_tail(len(xy), len(pairs), min(1.0, n_cat * math.pi * radius ** 2 /
                                                    (width * height)))
    return len(pairs), prob, f_px


def image_quads(v, radius, n_all=ALL_SUBSETS):
    """Quads ``(m, 4)`` of image star indices (``v`` unit vectors, brightest first): every
    star with 3 of its :data:`IMAGE_NEIGHBOURS` nearest image stars within ``radius`` (the
    image holds stars a level's uniform selection thinned out, and false ones, so a level
    quad's neighbours are among more image neighbours than the index takes), plus every
    4-subset of the ``n_all`` brightest stars; without repeats, in the order of their
    faintest star."""
    quads = set(combinations(range(min(n_all, len(v))), 4))
    cos_r = math.cos(radius)
    dots = v @ v.T
    for i in range(len(v)):
        near = [j for j in np.argsort(-dots[i]) if j != i and dots[i, j] >= cos_r]
        for trio in combinations(near[:IMAGE_NEIGHBOURS], 3):
            quads.add(tuple(sorted((i,) + tuple(int(t) for t in trio))))
    return np.array(sorted(quads, key=lambda q: (q[3], q)), dtype=np.int64).reshape(-1, 4)


def _verify_level(levels, width, f_px):
    """The level verifying a candidate of focal length ``f_px``: the one whose fields are
    ``LEVEL_RATIO`` times smaller than the candidate's (about 40 stars in its frame)."""
    target = math.log(fov_of_f(width, f_px) / LEVEL_RATIO)
    return min(levels, key=lambda lv: abs(math.log(lv.fov_deg) - target))


def search_fov(xy, width, height, fov_range_deg=FOV_RANGE_DEG, tolerance_px=2.0,
               cache_dir=None, max_candidates=MAX_CANDIDATES, log=None):
    """Blind search of the focal length of a centred pinhole ``width x height`` px whose
    horizontal FOV lies in ``fov_range_deg`` from pixels ``xy`` ``(n, 2)``, brightest
    first.  Returns a :class:`FovEstimate` (``f_px`` None when no candidate verified within
    ``max_candidates``).  ``cache_dir``, ``log``: of :func:`load_index`."""
    xy = np.asarray(xy, dtype=np.float64)[:, :2]
    lo, hi = fov_range_deg
    f_lo, f_hi = f_of_fov(width, hi), f_of_fov(width, lo)
    if len(xy) < 4:
        return FovEstimate()
    xy_img = xy[:IMAGE_STARS]
    verify_xy = xy[:VERIFY_STARS]
    levels = load_index(cache_dir, log)
    span = math.sqrt(LEVEL_RATIO)
    usable = [k for k, lv in enumerate(levels) if lo / span <= lv.fov_deg <= hi * span]
    tried = 0
    for k in usable:
        level = levels[k]
        f_guess = min(max(f_of_fov(width, level.fov_deg), f_lo), f_hi)
        v = pixel_vectors(xy_img, width, height, f_guess)
        subsets = image_quads(v, math.radians(QUAD_RADIUS * level.fov_deg))
        if not len(subsets):
            continue
        with np.errstate(divide="ignore", invalid="ignore"):
            codes, labels = quad_codes(_plane(v[subsets]), canonical=False)
        codes = np.where(np.isfinite(codes), codes, 1e9)   # coincident stars match nothing
        hits = level.code_tree.query_ball_point(codes.reshape(-1, 4), CODE_TOL)
        for flat, found in enumerate(hits):
            if not found:
                continue
            s, lab = divmod(flat, 4)
            img = subsets[s][labels[s, lab]]
            for row in found:
                cat = level.vectors[level.quads[row]]
                # scale: the image's angular size (at f_guess) over the sky's
                a_img = math.acos(min(1.0, float(v[img[0]] @ v[img[1]])))
                a_cat = math.acos(min(1.0, float(cat[0] @ cat[1])))
                f_est = f_guess * a_img / a_cat
                if not f_lo * 0.98 <= f_est <= f_hi * 1.02:
                    continue
                if tried == max_candidates:
                    return FovEstimate(candidates=tried)
                tried += 1
                rot = fit_rotation(pixel_vectors(xy[img], width, height, f_est), cat)
                n, prob, f_fit = _verify(verify_xy, width, height, f_est, rot,
                                         _verify_level(levels, width, f_est), tolerance_px)
                if n >= MIN_MATCHES and prob <= MAX_FALSE_PROB and f_lo * 0.98 <= f_fit <= \
                        f_hi * 1.02:
                    return FovEstimate(f_fit, fov_of_f(width, f_fit), n, tried,
                                       level.fov_deg)
    return FovEstimate(candidates=tried)
