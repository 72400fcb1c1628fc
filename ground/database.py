"""Ground-side builder of the star-identification database image (numpy): the Hipparcos
catalogue (:mod:`lodestar.sim.catalogue`), a camera field of view and a limiting magnitude
become one binary image (``bytes``) that the flight reader
:class:`lodestar.firmware.database.Database` validates and reads by offset.  The layout's
values are :mod:`lodestar.contract.stardb`; the format and the selection rules are specified
in ``docs/stardb.md``."""

import math
import struct
import zlib
from itertools import combinations
from typing import NamedTuple

import numpy as np

from lodestar.contract import stardb
from lodestar.contract.stardb import METHODS
from lodestar.firmware import database, kvector
from lodestar.firmware.starid import hashing, triangle
from lodestar.sim.catalogue import CatalogueError, load, load_deep

BLEND_MAG_DIFF = 2.0
"""Of two stars closer than ``blend_radius``, the brighter stays a pattern star only if it
is at least this many magnitudes brighter; the fainter never does."""


# --------------------------------------------------------------------------------------
# Field of view
# --------------------------------------------------------------------------------------

MIN_ASPECT, MAX_ASPECT = 0.01, 100.0
"""Aspect ratios (width / height) a database is built for: any real sensor, and no field so
thin that it holds no pattern."""


def fov_from_horizontal(fov_h_deg, aspect=None, fov_v_deg=None):
    """``(h, v, diag)`` in degrees of a pinhole camera with horizontal FOV ``fov_h_deg`` and
    either a vertical FOV or an ``aspect`` ratio (width / height, in the image plane)."""
    if not (isinstance(fov_h_deg, (int, float)) and 0 < fov_h_deg < 180):
        raise ValueError(f"the horizontal FOV must be in (0, 180) degrees, got {fov_h_deg!r}")
    th = math.tan(math.radians(fov_h_deg) / 2)
    if fov_v_deg is None:
        if aspect is None:
            raise ValueError("give aspect or fov_v_deg with fov_h_deg")
        if not (isinstance(aspect, (int, float)) and MIN_ASPECT <= aspect <= MAX_ASPECT):
            raise ValueError(f"the aspect (width / height) must be in {MIN_ASPECT:g} .. "
                             f"{MAX_ASPECT:g}, got {aspect!r}")
        fov_v_deg = math.degrees(2 * math.atan(th / aspect))
    tv = math.tan(math.radians(fov_v_deg) / 2)
    return float(fov_h_deg), float(fov_v_deg), math.degrees(2 * math.atan(math.hypot(th, tv)))


def check_fov(fov_h_deg, what="the horizontal FOV"):
    """Raise ``ValueError`` naming ``what`` unless ``fov_h_deg`` (deg) is a number within
    :data:`lodestar.contract.stardb.FOV_RANGE_DEG`, the fields a database serves."""
    lo, hi = stardb.FOV_RANGE_DEG
    if isinstance(fov_h_deg, bool) or not isinstance(fov_h_deg, (int, float)) or \
            not lo <= fov_h_deg <= hi:
        shown = f"{fov_h_deg:.4g} deg" if isinstance(fov_h_deg, (int, float)) else \
            repr(fov_h_deg)
        raise ValueError(f"{what} {shown} is outside the {lo:g} .. {hi:g} deg a star "
                         f"database serves")


def _check_per_fov(stars_per_fov):
    if not (isinstance(stars_per_fov, (int, float)) and 1 <= stars_per_fov <= 1000):
        raise ValueError(f"stars per field must be in 1..1000, got {stars_per_fov!r}")


def check_density(stars_per_fov, fov_h_deg, fov_v_deg):
    """Raise ``ValueError`` at once when ``stars_per_fov`` stars in every field of
    ``fov_h_deg`` x ``fov_v_deg`` (deg) add up to more stars over the sky than a database
    holds (:data:`lodestar.contract.stardb.MAX_STARS`) even at the
    :data:`DENSITY_REACHED` share :func:`select_density` settles for, naming the narrowest
    field of that aspect that fits; the selection would take seconds to find out (4.8 deg
    at 4:3: 70,459 stars)."""
    _check_per_fov(stars_per_fov)

    def need(h):
        v = math.degrees(2 * math.atan(math.tan(math.radians(h) / 2) * ratio))
        return DENSITY_REACHED * stars_per_fov * 4 * math.pi / field_solid_angle(h, v)

    ratio = math.tan(math.radians(fov_v_deg) / 2) / math.tan(math.radians(fov_h_deg) / 2)
    if need(fov_h_deg) <= stardb.MAX_STARS:
        return
    lo, hi = fov_h_deg, 179.0
    for _ in range(60):                     # bisection: need() falls as the field widens
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if need(mid) > stardb.MAX_STARS else (lo, mid)
    raise ValueError(f"a {fov_h_deg:.4g} x {fov_v_deg:.4g} deg field with {stars_per_fov:g} "
                     f"stars per field needs at least {need(fov_h_deg):,.0f} stars over the sky; "
                     f"a database holds {stardb.MAX_STARS}: fields of this aspect from "
                     f"{hi:.2f} deg, or give a magnitude limit (--mag, max_mag)")


def resolve_fov(camera=None, fov_h_deg=None, aspect=None, fov_v_deg=None):
    """FOV ``(h, v, diag)`` in degrees from a :class:`lodestar.sim.camera.Camera` or numbers."""
    if camera is not None:
        if fov_h_deg is not None:
            raise ValueError("give either camera or fov_h_deg, not both")
        return tuple(float(a) for a in camera.fov_deg())
    if fov_h_deg is None:
        raise ValueError("give camera or fov_h_deg")
    return fov_from_horizontal(fov_h_deg, aspect, fov_v_deg)


# --------------------------------------------------------------------------------------
# Building blocks
# --------------------------------------------------------------------------------------

def select_pattern_stars(vectors, vmag, radius_rad, per_region, blend_radius_rad=0.0):
    """Boolean mask of pattern stars (brightest first, at most ``per_region`` kept within
    ``radius_rad`` of each kept star at the time it is kept; blends excluded)."""
    n = len(vectors)
    order = np.lexsort((np.arange(n), vmag))
    blended = blended_stars(vectors, vmag, blend_radius_rad)
    kept = np.zeros((n, 3))
    n_kept = 0
    mask = np.zeros(n, dtype=bool)
    cos_r = math.cos(radius_rad)
    for i in order:
        if blended[i]:
            continue
        if n_kept and np.count_nonzero(kept[:n_kept] @ vectors[i] >= cos_r) >= per_region:
            continue
        kept[n_kept] = vectors[i]
        n_kept += 1
        mask[i] = True
    return mask


RSA_DENSITY = 0.65
"""Stars per square of the separation that brightest-first thinning with a minimum
separation leaves where the catalogue is deep enough: random sequential adsorption of
discs jams at 54.7 % coverage (Feder 1980), 0.547 * 4 / pi = 0.697."""


def field_solid_angle(fov_h_deg, fov_v_deg):
    """Solid angle (sr) of a pinhole camera's rectangular field."""
    a, b = math.radians(fov_h_deg) / 2, math.radians(fov_v_deg) / 2
    return 4 * math.asin(math.sin(a) * math.sin(b))


def separation_for_density(stars_per_fov, fov_h_deg, fov_v_deg, per_region=1):
    """Separation (rad) for which :func:`select_uniform` with ``per_region`` leaves about
    ``stars_per_fov`` stars in every field of this size (:data:`RSA_DENSITY`; a disc
    holding ``per_region`` stars instead of one is ``sqrt(per_region)`` times wider)."""
    _check_per_fov(stars_per_fov)
    return math.sqrt(RSA_DENSITY * per_region * field_solid_angle(fov_h_deg, fov_v_deg)
                     / stars_per_fov)


def select_uniform(vectors, vmag, separation_rad, eligible=None, per_region=1):
    """Boolean mask of a uniform selection, brightest first (ties by index): a star is kept
    while fewer than ``per_region`` kept stars lie closer than ``separation_rad``, so dense
    regions stop at bright stars and sparse ones reach as deep as the catalogue goes (with
    ``per_region`` > 1 a bright close pair survives: what a brightest-first pattern search
    sees).  ``eligible``: a mask of the candidates (default all).  A grid of cubes one
    chord wide finds the neighbours."""
    n = len(vectors)
    mask = np.zeros(n, dtype=bool)
    order = np.lexsort((np.arange(n), vmag))
    if eligible is not None:
        order = order[eligible[order]]
    from scipy.spatial import cKDTree
    chord = 2 * math.sin(separation_rad / 2)
    chord2 = chord * chord
    cells = np.floor(vectors / chord).astype(np.int64).tolist()
    rows = vectors.tolist()
    grid = {}
    near = [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in (-1, 0, 1)]
    for start in range(0, len(order), SELECT_CHUNK):
        chunk = order[start:start + SELECT_CHUNK]
        if mask.any():
            # already full where per_region kept stars lie within a hair less than the
            # separation: rejected whatever this chunk adds (the kept set only grows)
            full = cKDTree(vectors[mask]).query_ball_point(
                vectors[chunk], chord * (1 - 1e-9), return_length=True) >= per_region
            chunk = chunk[~full]
        _select_sequential(chunk.tolist(), rows, cells, grid, near, chord2, per_region, mask)
    return mask


def _select_sequential(indices, rows, cells, grid, near, chord2, per_region, mask):
    """The rule of :func:`select_uniform` star by star over ``indices`` (brightest first),
    the kept stars filed in ``grid`` by cube cell."""
    for i in indices:
        x, y, z = rows[i]
        cx, cy, cz = cells[i]
        room = per_region
        for a, b, c in near:
            for u, v, w in grid.get((cx + a, cy + b, cz + c), ()):
                if (x - u) ** 2 + (y - v) ** 2 + (z - w) ** 2 < chord2:
                    room -= 1
                    if not room:
                        break
            if not room:
                break
        if room:
            mask[i] = True
            grid.setdefault((cx, cy, cz), []).append((x, y, z))


SELECT_CHUNK = 2048
"""Stars :func:`select_uniform` screens at once against the stars kept before them."""

DENSITY_PER_REGION = 6
"""Stars a density selection keeps within its separation (:func:`select_uniform`): 6, as
the ``pattern_per_region`` rule, keeps the bright close pairs a brightest-first search
meets; 1 (a minimum separation, tetra3's rule) cost Pyramid 5-15 % of the estcube2
frames at the same size (``docs/stardb.md``)."""

DENSITY_REACHED = 0.97
"""Share of the stars per field at which :func:`select_density` stops refining: it keeps
at least this share of ``stars_per_fov / field share`` stars where the catalogue is deep
enough (0.977 to 0.988 of it at 4.2 to 5 deg, measured)."""

DENSITY_ITERATIONS = 4
"""Separation refinements of :func:`select_density` (each one a :func:`select_uniform`)."""


def select_density(vectors, vmag, stars_per_fov, fov_h_deg, fov_v_deg, eligible=None,
                   per_region=1):
    """``(mask, separation_rad)``: :func:`select_uniform` (``per_region`` stars within the
    separation) with the separation that leaves
    ``stars_per_fov`` stars per field on average over the sky (the kept count times the
    field's share of the sphere).  Where the catalogue thins out the selection stays below
    jamming, so the separation is shrunk by the shortfall's square root and the selection
    redone, :data:`DENSITY_ITERATIONS` times at most, until 97 % of the target is met."""
    field_share = field_solid_angle(fov_h_deg, fov_v_deg) / (4 * math.pi)
    separation = separation_for_density(stars_per_fov, fov_h_deg, fov_v_deg, per_region)
    for _ in range(DENSITY_ITERATIONS):
        mask = select_uniform(vectors, vmag, separation, eligible, per_region)
        per_fov = np.count_nonzero(mask) * field_share
        if per_fov >= DENSITY_REACHED * stars_per_fov:
            break
        separation *= math.sqrt(per_fov / stars_per_fov)
    return mask, separation


def blended_stars(vectors, vmag, blend_radius_rad):
    """Boolean mask of the stars that merge with a neighbour closer than
    ``blend_radius_rad``: both of a pair, except the brighter one when it is at least
    :data:`BLEND_MAG_DIFF` brighter."""
    blended = np.zeros(len(vectors), dtype=bool)
    if blend_radius_rad > 0:
        from scipy.spatial import cKDTree
        tree = cKDTree(vectors)
        chord = 2 * math.sin(blend_radius_rad / 2)
        for a, b in tree.query_pairs(chord):
            if abs(float(vmag[a]) - float(vmag[b])) < BLEND_MAG_DIFF:
                blended[a] = blended[b] = True
            elif vmag[a] > vmag[b]:
                blended[a] = True
            else:
                blended[b] = True
    return blended


def cell_radius(n):
    """Largest angle (rad) between a cell centre and its corners on the ``n x n`` cube."""
    worst = 0.0
    for c in range(database.n_cells(n)):
        centre = np.array(database.cell_centre(c, n))
        face, rest = divmod(c, n * n)
        iu, iv = divmod(rest, n)
        a, s = face >> 1, (-1.0 if face & 1 else 1.0)
        for du in (0, 1):
            for dv in (0, 1):
                u = (iu + du) * 2.0 / n - 1.0
                v = (iv + dv) * 2.0 / n - 1.0
                corner = np.zeros(3)
                corner[a], corner[(a + 1) % 3], corner[(a + 2) % 3] = s, u, v
                corner /= np.linalg.norm(corner)
                worst = max(worst, math.atan2(np.linalg.norm(np.cross(centre, corner)),
                                              float(centre @ corner)))
    return worst


def pair_table(vectors, min_angle, max_angle, key_step):
    """Sorted ``(keys, a, b)`` arrays of all pairs of ``vectors`` (float64 copies of the
    stored float32 vectors) with ``min_angle <= angle <= max_angle`` (rad)."""
    from scipy.spatial import cKDTree
    tree = cKDTree(vectors)
    pairs = np.array(sorted(tree.query_pairs(2 * math.sin(max_angle / 2) * (1 + 1e-9))),
                     dtype=np.int64).reshape(-1, 2)
    a, b = pairs[:, 0], pairs[:, 1]
    va, vb = vectors[a], vectors[b]
    angle = np.arctan2(np.linalg.norm(np.cross(va, vb), axis=1), np.sum(va * vb, axis=1))
    keep = (angle >= min_angle) & (angle <= max_angle)
    a, b, angle = a[keep], b[keep], angle[keep]
    keys = np.rint(angle / key_step).astype(np.int64)
    if keys.size and keys.max() > 0xFFFF:
        raise AssertionError("pair key overflow")
    order = np.lexsort((b, a, keys))
    return keys[order], a[order], b[order]


def kvector_numpy(keys, n_bins, margin=0.5):
    """The k-vector of sorted integer ``keys`` with float32 line parameters: ``(m, q,
    table)``, equal to :func:`lodestar.firmware.kvector.build` with the same ``(m, q)``."""
    m, q = kvector.line(float(keys[0]), float(keys[-1]), n_bins, margin)
    m, q = float(np.float32(m)), float(np.float32(q))
    z = q + m * np.arange(n_bins + 1, dtype=np.float64)
    table = np.searchsorted(keys, z, side="right").astype(np.int64)
    table[-1] = len(keys)
    return m, q, table


def _f32(x):
    return float(np.float32(x))


def _step_for(max_value, n_keys=0xFFFF):
    """float32 key step such that ``max_value / step`` rounds to at most ``n_keys``."""
    step = _f32(max_value / n_keys) if max_value > 0 else _f32(1e-30)
    while step * n_keys < max_value:
        step = float(np.nextafter(np.float32(step), np.float32(np.inf)))
    return step


def regional_groups(vectors, vmag, candidates, regions_per_face, radius, per_region, size,
                    max_diameter, min_diameter=0.0):
    """Groups of ``size`` stars spread evenly over the sky: for every cell of the
    ``regions_per_face`` gnomonic cube (:func:`lodestar.firmware.database.cell_centre`), the
    ``per_region`` brightest ``candidates`` (a boolean mask) within ``radius`` (rad) of the
    cell centre (ties by index), and every ``size``-subset of them whose largest pairwise
    angle lies in ``[min_diameter, max_diameter]``.  Returns a sorted ``(n, size)`` int array
    of unique ascending index tuples (into ``vectors``, float64 copies of the stored
    float32 vectors)."""

    from scipy.spatial import cKDTree
    idx = np.flatnonzero(candidates)
    if len(idx) < size:
        return np.zeros((0, size), dtype=np.int64)
    tree = cKDTree(vectors[idx])
    chord = 2 * math.sin(radius / 2)
    cos_max, cos_min = math.cos(max_diameter), math.cos(min_diameter)
    found = set()
    for c in range(database.n_cells(regions_per_face)):
        near = idx[tree.query_ball_point(np.array(database.cell_centre(c, regions_per_face)),
                                         chord)]
        near = near[np.lexsort((near, vmag[near]))][:per_region]
        if len(near) < size:
            continue
        near = np.sort(near)
        dots = vectors[near] @ vectors[near].T
        for comb in combinations(range(len(near)), size):
            sub = dots[np.ix_(comb, comb)][np.triu_indices(size, 1)]
            if sub.min() >= cos_max and sub.min() <= cos_min:
                found.add(tuple(int(near[k]) for k in comb))
    return np.array(sorted(found), dtype=np.int64).reshape(-1, size)


def triangle_table(v32, groups, key_bits=16):
    """Triangle records of the star triples ``groups`` (``(n, 3)`` indices into the float32
    vectors ``v32``): ``(records, area_step, moment_step)`` with ``records`` a structured
    array (area key, moment key, s0, s1, s2) sorted by ``(area key, moment key, s0, s1,
    s2)``; ``s0, s1, s2`` are opposite the shortest, middle and longest side (firmware
    :func:`lodestar.firmware.starid.triangle.canonical_order`), area and moment computed by the
    firmware's own :func:`~lodestar.firmware.starid.triangle.area_moment` on the stored vectors."""
    vec = v32.astype(np.float64).tolist()
    n = len(groups)
    area = np.zeros(n)
    moment = np.zeros(n)
    verts = np.zeros((n, 3), dtype=np.int64)
    for r, (i, j, k) in enumerate(groups.tolist()):
        tri = (i, j, k)
        order, _ = triangle.canonical_order(vec[i], vec[j], vec[k])
        verts[r] = [tri[order[0]], tri[order[1]], tri[order[2]]]
        area[r], moment[r] = triangle.area_moment(vec[i], vec[j], vec[k])
    n_keys = (1 << key_bits) - 1
    area_step, moment_step = _step_for(area.max(), n_keys), _step_for(moment.max(), n_keys)
    records = np.zeros(n, dtype=[("area", "<u2"), ("moment", "<u2"), ("s0", "<u2"),
                                 ("s1", "<u2"), ("s2", "<u2")])
    records["area"] = np.minimum(np.rint(area / area_step), n_keys)
    records["moment"] = np.minimum(np.rint(moment / moment_step), n_keys)
    records["s0"], records["s1"], records["s2"] = verts[:, 0], verts[:, 1], verts[:, 2]
    records = records[np.lexsort((records["s2"], records["s1"], records["s0"],
                                  records["moment"], records["area"]))]
    return records, area_step, moment_step


class _HashGrid:
    """The bucket grid of a hash section (the attributes the firmware's
    :func:`lodestar.firmware.starid.hashing.bucket_code` reads from a database)."""

    def __init__(self, coord_lo, coord_bucket, coord_buckets, flags, dist_bucket,
                 dist_buckets):
        self.hash_coord_lo = coord_lo
        self.hash_coord_bucket = coord_bucket
        self.hash_coord_buckets = coord_buckets
        self.hash_flags = flags
        self.hash_dist_bucket = dist_bucket
        self.hash_dist_buckets = dist_buckets


def hash_table(v32, groups, grid):
    """Hash records of the star groups ``groups`` (``(n, g)`` indices into ``v32``): a
    structured array (code, then the g stars in canonical order A, B, C(, D)) sorted by
    ``(code, stars)``, hashed by the firmware's own
    :func:`lodestar.firmware.starid.hashing.group_hash` and
    :func:`~lodestar.firmware.starid.hashing.bucket_code`."""
    vec = v32.astype(np.float64).tolist()
    n, g = groups.shape
    names = ("a", "b", "c", "d")[:g]
    records = np.zeros(n, dtype=[("code", "<u4")] + [(name, "<u2") for name in names])
    for r, grp in enumerate(groups.tolist()):
        order, h, d = hashing.group_hash([vec[s] for s in grp])
        records[r]["code"] = hashing.bucket_code(h, d, grid)
        for name, o in zip(names, order):
            records[r][name] = grp[o]
    keys = [records[name] for name in reversed(names)] + [records["code"]]
    return records[np.lexsort(keys)]


def _kvector_tail(records, keys, per_bin):
    """``(bytes, kv_bins, kv_m, kv_q)``: ``records`` + zero padding to 4 bytes + the k-vector
    of their sorted integer ``keys``."""
    kv_bins = max(1, len(keys) // per_bin)
    kv_m, kv_q, kv_table = kvector_numpy(keys.astype(np.int64), kv_bins)
    body = records.tobytes()
    body += b"\0" * ((-len(body)) % stardb.SECTION_ALIGN)
    return body + kv_table.astype("<u4").tobytes(), kv_bins, kv_m, kv_q


class Sky(NamedTuple):
    """The ordered star table a method's section builder reads (indices are its rows)."""

    v32: np.ndarray         # (n, 3) float32 unit vectors as stored
    v64: np.ndarray         # the same as float64
    vmag: np.ndarray        # V magnitudes
    pattern: np.ndarray     # bool: pattern stars (pairs, triangles)
    unblended: np.ndarray   # bool: stars without a close neighbour (hash groups)
    fov_v: float            # vertical FOV, deg
    fov_d: float            # diagonal FOV, deg
    min_pair: float         # pair angle range, rad
    max_pair: float


# --------------------------------------------------------------------------------------
# The builder
# --------------------------------------------------------------------------------------

def default_catalogue(mag_limit):
    """The catalogue a build with ``mag_limit`` (None: no limit) reads: the shipped one when
    the limit is within its depth, else the whole Hipparcos (ValueError with the install
    command when the optional package is missing)."""
    shipped = load()
    if mag_limit is not None and mag_limit <= float(shipped.vmag.max()):
        return shipped
    try:
        return load_deep()
    except CatalogueError as exc:
        raise ValueError(f"V <= {mag_limit}: deeper than the shipped catalogue "
                         f"(V <= {float(shipped.vmag.max()):.2f}); {exc}") from None


def build_database(catalogue=None, camera=None, *, fov_h_deg=None, aspect=None,
                   fov_v_deg=None, mag_limit=6.0, method=None, methods=None,
                   max_pair_angle_deg=None, min_pair_angle_deg=0.0, pattern_radius_deg=None,
                   pattern_per_region=6, blend_radius_deg=0.02, cells_per_face=8,
                   options=None, verification_stars_per_fov=None, pattern_stars_per_fov=None,
                   density_per_region=None, max_pair_fraction=1.0):
    """Build a database image (``bytes``; layout in the module docstring).

    ``catalogue``: a :class:`lodestar.sim.catalogue.Catalogue` (default: the shipped one
    when ``mag_limit`` is within its depth, else the whole Hipparcos of
    :func:`lodestar.sim.catalogue.load_deep`).
    FOV: ``camera`` (a sim ``Camera``; its ``fov_deg()`` is used) **or** ``fov_h_deg`` with
    ``aspect`` (width/height) or ``fov_v_deg``.  ``mag_limit``: stars with ``V <= mag_limit``
    (None: the whole catalogue).  Depth by density: ``verification_stars_per_fov`` keeps
    in the star table a uniform selection of about that many stars per field
    (:func:`select_uniform`, brightest first) instead of every star; ``pattern_stars_per_fov``
    picks the pattern stars the same way from the unblended stars of the table instead of
    the ``pattern_per_region`` rule; ``density_per_region``: stars allowed within the
    selection's separation (default :data:`DENSITY_PER_REGION`).
    ``methods``: the identification methods the image serves, any of :data:`METHODS`
    (all of them give one image with every section; default ``("pyramid",)``); ``method``:
    a single name, the same as ``methods=(method,)``.
    ``max_pair_angle_deg`` defaults to ``max_pair_fraction`` (default 1) of the FOV
    diagonal, ``pattern_radius_deg`` to half the vertical FOV.  ``options``: ``{method name:
    {option: value}}`` overriding the defaults of the contract's
    :data:`~lodestar.contract.stardb.METHOD_TABLE` (``docs/stardb.md``, Builder options).
    """
    methods = _methods(method, methods)
    opts = _method_options(options)
    fov_h, fov_v, fov_d = resolve_fov(camera, fov_h_deg, aspect, fov_v_deg)
    check_fov(fov_h)
    if not 0 < fov_v < 180:
        raise ValueError("the vertical FOV must be in (0, 180) degrees")
    if verification_stars_per_fov is not None:
        check_density(verification_stars_per_fov, fov_h, fov_v)
    if catalogue is None:
        catalogue = default_catalogue(mag_limit)
    if not 0 < max_pair_fraction <= 1:
        raise ValueError(f"max_pair_fraction must be in (0, 1], got {max_pair_fraction!r}")
    max_pair = math.radians(fov_d * max_pair_fraction if max_pair_angle_deg is None
                            else max_pair_angle_deg)
    min_pair = math.radians(min_pair_angle_deg)
    pattern_radius = math.radians(fov_v / 2 if pattern_radius_deg is None
                                  else pattern_radius_deg)
    if not 0 <= min_pair < max_pair <= math.pi:
        raise ValueError("need 0 <= min_pair_angle < max_pair_angle <= 180 deg")
    if not 1 <= cells_per_face <= 64:
        raise ValueError("cells_per_face must be in 1..64")

    per_region = DENSITY_PER_REGION if density_per_region is None else int(density_per_region)
    if per_region < 1:
        raise ValueError(f"density_per_region must be >= 1, got {density_per_region!r}")
    sel = _table_rows(catalogue, mag_limit, verification_stars_per_fov, fov_h, fov_v,
                      per_region)
    vectors64 = catalogue.unit_vectors()[sel]
    vmag = np.asarray(catalogue.vmag[sel], dtype=np.float64)
    hip = np.asarray(catalogue.hip[sel], dtype=np.int64)
    if hip.max() >= 1 << 17:
        raise ValueError("HIP number too large for the 17-bit field")
    mag_code = np.rint((vmag + stardb.MAG_OFFSET) * stardb.MAG_SCALE).astype(np.int64)
    if mag_code.min() < 0 or mag_code.max() > 0x7FF:
        raise ValueError("magnitude out of the storable range [-2, 18.47]")

    unblended = ~blended_stars(vectors64, vmag, math.radians(blend_radius_deg))
    if pattern_stars_per_fov is None:
        pattern = select_pattern_stars(vectors64, vmag, pattern_radius, pattern_per_region,
                                       math.radians(blend_radius_deg))
    else:
        pattern, pattern_radius = select_density(vectors64, vmag, pattern_stars_per_fov,
                                                 fov_h, fov_v, unblended, per_region)
        pattern_per_region = int(round(pattern_stars_per_fov))

    # order the star table by (cell, magnitude, HIP) of the stored float32 vectors
    v32 = vectors64.astype(np.float32)
    cells = np.array([database.cell_of(float(x), float(y), float(z), cells_per_face)
                      for x, y, z in v32], dtype=np.int64)
    order = np.lexsort((hip, vmag, cells))
    v32, vmag, hip, mag_code, pattern, unblended, cells = (
        arr[order] for arr in (v32, vmag, hip, mag_code, pattern, unblended, cells))
    sky = Sky(v32, v32.astype(np.float64), vmag, pattern, unblended, fov_v, fov_d, min_pair,
              max_pair)
    sections, flags, values = _method_sections(sky, methods, opts)
    cell_start = np.searchsorted(cells, np.arange(database.n_cells(cells_per_face) + 1),
                                 side="left")
    sections[stardb.SEC_CELLS] = cell_start.astype("<u2").tobytes()
    sections[stardb.SEC_STARS] = _star_section(v32, hip, mag_code, flags)
    values.update({
        "star_record_size": stardb.STAR_SIZE,
        "fov_h": math.radians(fov_h), "fov_v": math.radians(fov_v),
        "fov_diag": math.radians(fov_d),
        "mag_limit": float(vmag.max()) if mag_limit is None else mag_limit,
        "epoch": catalogue.epoch,
        "n_stars": len(order), "cells_per_face": cells_per_face,
        "pattern_per_region": pattern_per_region,
        "cell_radius": cell_radius(cells_per_face) + 1e-5, "pattern_radius": pattern_radius,
    })
    return _image(sections, values)


def _table_rows(catalogue, mag_limit, stars_per_fov, fov_h, fov_v, per_region):
    """The catalogue rows of the star table: ``V <= mag_limit``, thinned to about
    ``stars_per_fov`` per field when given (:func:`select_density`)."""
    sel = np.flatnonzero(catalogue.vmag <= (np.inf if mag_limit is None else mag_limit))
    if stars_per_fov is not None:
        sel = sel[select_density(catalogue.unit_vectors()[sel], catalogue.vmag[sel],
                                 stars_per_fov, fov_h, fov_v, per_region=per_region)[0]]
    if not 4 <= len(sel) <= stardb.MAX_STARS:
        raise ValueError(f"{len(sel)} stars with V <= {mag_limit}: a database holds 4.."
                         f"{stardb.MAX_STARS}")
    return sel


def _methods(method, methods):
    """The method names of :func:`build_database`'s ``method`` / ``methods``, checked."""
    if method is not None and methods is not None:
        raise ValueError("give method or methods, not both")
    if methods is None:
        methods = ("pyramid",) if method is None else (method,)
    if isinstance(methods, str):
        methods = (methods,)
    methods = tuple(methods)
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        raise NotImplementedError(f"methods {unknown or methods!r}: only {METHODS} can be "
                                  "built")
    return methods


def _method_options(given):
    """``{method name: {option: value}}``: the table's defaults, overridden by ``given``
    (ValueError for an unknown method or option)."""
    given = dict(given or {})
    out = {}
    for name, _, _, _, defaults in stardb.METHOD_TABLE:
        out[name] = dict(defaults)
        for key, value in given.pop(name, {}).items():
            if key not in out[name]:
                raise ValueError(f"options[{name!r}]: unknown option {key!r} "
                                 f"(known: {sorted(out[name])})")
            out[name][key] = value
    if given:
        raise ValueError(f"options for unknown methods {sorted(given)} (known: {METHODS})")
    return out


def _method_sections(sky, methods, opts):
    """``(sections, star flags, header values)`` of the ``methods``, each built by its
    :data:`SECTION_BUILDERS` entry in the order of the contract's table."""
    sections = {}
    flags = np.zeros(len(sky.v32), dtype=np.int64)
    values = {"methods": 0, "n_pattern_stars": 0, "n_pairs": 0, "pair_min_angle": 0.0,
              "pair_max_angle": 0.0, "key_step": 0.0, "kv_bins": 0, "kv_m": 0.0, "kv_q": 0.0}
    for name in METHODS:
        if name in methods:
            built, member_flags, header = SECTION_BUILDERS[name](sky, opts[name])
            sections.update(built)
            flags |= member_flags
            values.update(header)
            values["methods"] |= stardb.METHOD_NAMES[name]
    return sections, flags, values


def _star_section(v32, hip, mag_code, flags):
    """The star table's bytes (:data:`~lodestar.contract.stardb.STAR_FORMAT` records)."""
    word = (hip >> 16) | (mag_code << 1) | (flags << 12)
    stars = np.zeros(len(v32), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"),
                                      ("hip_lo", "<u2"), ("word", "<u2")])
    stars["x"], stars["y"], stars["z"] = v32[:, 0], v32[:, 1], v32[:, 2]
    stars["hip_lo"], stars["word"] = hip & 0xFFFF, word
    return stars.tobytes()


def _pyramid_sections(sky, opt):
    """The pair table and its k-vector over the pattern stars' pairs (indices into the
    ordered star table), the pattern flags and the pair header values."""
    max_pair = sky.max_pair
    key_step = _f32(max_pair / 0xFFFF)
    if key_step * 0xFFFF < max_pair:
        key_step = float(np.nextafter(np.float32(key_step), np.float32(1)))
    pidx = np.flatnonzero(sky.pattern)
    keys, a, b = pair_table(sky.v64[pidx], sky.min_pair, max_pair, key_step)
    a, b = pidx[a], pidx[b]
    lo_, hi_ = np.minimum(a, b), np.maximum(a, b)
    order = np.lexsort((hi_, lo_, keys))
    keys, a, b = keys[order], lo_[order], hi_[order]
    n_pairs = len(keys)
    if n_pairs == 0:
        raise ValueError("no star pairs: FOV too small or magnitude limit too bright")
    kv_bins = max(1, n_pairs // opt["pairs_per_bin"])
    kv_m, kv_q, kv_table = kvector_numpy(keys, kv_bins)
    pairs = np.zeros(n_pairs, dtype=[("key", "<u2"), ("a", "<u2"), ("b", "<u2")])
    pairs["key"], pairs["a"], pairs["b"] = keys, a, b
    values = {"n_pattern_stars": int(sky.pattern.sum()), "n_pairs": n_pairs,
              "pair_min_angle": sky.min_pair, "pair_max_angle": max_pair,
              "key_step": key_step, "kv_bins": kv_bins, "kv_m": kv_m, "kv_q": kv_q}
    sections = {stardb.SEC_PAIRS: pairs.tobytes(),
                stardb.SEC_KVECTOR: kv_table.astype("<u4").tobytes()}
    return sections, np.where(sky.pattern, stardb.STAR_FLAG_PATTERN, 0), values


def _radians(value_deg, default_deg):
    return math.radians(default_deg if value_deg is None else value_deg)


def _triangle_section(sky, opt):
    """The triangle section, the flags of its stars and no header values."""
    radius = _radians(opt["region_radius_deg"], sky.fov_v / 2)
    max_side = _radians(opt["max_side_deg"], sky.fov_d)
    groups = regional_groups(sky.v64, sky.vmag, sky.pattern, opt["regions_per_face"], radius,
                             opt["stars_per_region"], 3, max_side)
    if len(groups) == 0:
        raise ValueError("no triangles: FOV too small or magnitude limit too bright")
    records, area_step, moment_step = triangle_table(sky.v32, groups)
    tail, kv_bins, kv_m, kv_q = _kvector_tail(records, records["area"], opt["per_bin"])
    header = struct.pack(stardb.TRI_HEADER_FORMAT, stardb.TRI_MAGIC, len(records), kv_bins,
                         area_step,
                         moment_step, max_side, kv_m, kv_q, opt["regions_per_face"],
                         opt["stars_per_region"], radius)
    return ({stardb.SEC_TRIANGLES: header + tail},
            _member_flags(len(sky.v32), groups, stardb.STAR_FLAG_TRIANGLE), {})


def _hash_section(sky, opt):
    """The geometric-hashing section, the flags of its stars and no header values."""
    g = int(opt["group_size"])
    if g not in stardb.HASH_GROUP_SIZES:
        raise ValueError(f"hash group size {g}: must be one of {stardb.HASH_GROUP_SIZES}")
    radius = _radians(opt["region_radius_deg"], sky.fov_v / 2)
    max_diam = _radians(opt["max_diameter_deg"], sky.fov_d)
    min_diam = _radians(opt["min_diameter_deg"], sky.fov_v / 4)
    flags_h = 0 if opt["normalized"] else stardb.HASH_FLAG_DISTANCE
    coord_lo, coord_bucket = _f32(opt["coord_lo"]), _f32(opt["coord_bucket"])
    coord_buckets = int(math.ceil(3.0 / coord_bucket))
    dist_bucket = _f32(math.radians(opt["dist_bucket_deg"]))
    dist_buckets = int(math.floor(max_diam / dist_bucket)) + 2
    if coord_buckets ** (2 * (g - 2)) * (dist_buckets if flags_h else 1) > stardb.HASH_MAX_CODE:
        raise ValueError("hash bucket grid too fine: codes would exceed 2**30")
    grid = _HashGrid(coord_lo, coord_bucket, coord_buckets, flags_h, dist_bucket, dist_buckets)
    groups = regional_groups(sky.v64, sky.vmag, sky.unblended, opt["regions_per_face"], radius,
                             opt["stars_per_region"], g, max_diam, min_diam)
    if len(groups) == 0:
        raise ValueError("no hash groups: FOV too small or magnitude limit too bright")
    records = hash_table(sky.v32, groups, grid)
    tail, kv_bins, kv_m, kv_q = _kvector_tail(records, records["code"], opt["per_bin"])
    header = struct.pack(stardb.HASH_HEADER_FORMAT, stardb.HASH_MAGIC, len(records), kv_bins, g,
                         flags_h,
                         coord_lo, coord_bucket, coord_buckets, dist_buckets, dist_bucket,
                         min_diam, max_diam, kv_m, kv_q, opt["regions_per_face"],
                         opt["stars_per_region"], radius)
    return ({stardb.SEC_HASH: header + tail},
            _member_flags(len(sky.v32), groups, stardb.STAR_FLAG_HASH), {})


SECTION_BUILDERS = {"pyramid": _pyramid_sections, "triangle": _triangle_section,
                    "hashing": _hash_section}
"""Method name -> its section builder ``(sky, options) -> (sections, star flags, header
values)``: one per name of the contract's :data:`~lodestar.contract.stardb.METHOD_TABLE`."""


def _member_flags(n_stars, groups, flag):
    """``flag`` on every star that belongs to one of ``groups``, else 0."""
    used = np.zeros(n_stars, dtype=bool)
    used[groups.ravel()] = True
    return np.where(used, flag, 0)


def _image(sections, values):
    """The image: header (``values`` by field, the directory, the CRCs) and the sections,
    each aligned to :data:`~lodestar.contract.stardb.SECTION_ALIGN`."""
    payload = bytearray()
    directory = [(0, 0)] * stardb.N_SECTIONS
    for sec in sorted(sections):
        while (stardb.HEADER_SIZE + len(payload)) % stardb.SECTION_ALIGN:
            payload.append(0)
        directory[sec] = (stardb.HEADER_SIZE + len(payload), len(sections[sec]))
        payload += sections[sec]
    while len(payload) % stardb.SECTION_ALIGN:
        payload.append(0)
    values = dict(values, magic=stardb.MAGIC, version=stardb.VERSION,
                  header_size=stardb.HEADER_SIZE,
                  image_size=stardb.HEADER_SIZE + len(payload),
                  payload_crc=zlib.crc32(payload) & 0xFFFFFFFF)
    header = bytearray(stardb.HEADER_SIZE)
    struct.pack_into(stardb.HEADER_FORMAT, header, 0,
                     *(values[name] for name in stardb.HEADER_FIELDS))
    for sec, (offset, length) in enumerate(directory):
        struct.pack_into("<II", header, stardb.DIRECTORY_OFFSET + 8 * sec, offset, length)
    struct.pack_into("<I", header, stardb.HEADER_CRC_OFFSET,
                     zlib.crc32(bytes(header[:stardb.HEADER_CRC_OFFSET])) & 0xFFFFFFFF)
    image = bytes(header) + bytes(payload)
    status, reason = database.check(image)
    # parameters the flight reader refuses: never hand such a file out
    if status != database.OK:
        raise ValueError(f"the database for these parameters would be unreadable in flight "
                         f"({reason})")
    return image


def describe(image):
    """Header values, section sizes (bytes) and total size of an image, as a dict."""
    db = database.Database(image)
    info = db.info()
    info["section_bytes"] = {stardb.SECTION_NAMES[i]: length
                             for i, (offset, length) in enumerate(db.sections) if length}
    info["total_bytes"] = len(image)
    return info
