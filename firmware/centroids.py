"""Star centroids and shapes from blob records, with a quality filter.

:func:`extract` turns blob records (``contract.BlobRecord``) into stars: centroid
``(sx / s0, sy / s0)`` in pixels (``docs/conventions.md``), exact central second moments
(px^2, from the integer numerators: no cancellation in single precision), ``sigma_major`` and
``sigma_minor`` (px), ``elongation`` and ``orientation`` (rad); failing records are counted
per reason of :data:`REASONS`.  With an ``expected_smear_px`` (a known body rate) elongated
tracks pass the cosmic-ray test, pieces of a broken track are joined into one star and each
star carries its ``unseen`` half-track (px).  Stars come brightest first (ties in record
order).  Filter order, smear and joining rules: ``docs/centroids_and_tracking.md``.  Pure
Python for CPython and MicroPython: no numpy, typing, dataclasses or itertools.
"""

import math

from lodestar import contract as C
from lodestar.firmware.emit import native
from lodestar.firmware.geometry import finite
from lodestar.firmware.packet import WideRecord

DEFAULT_MAX_STARS = 32
"""Stars kept per frame: enough for identification and attitude, few enough for the MCU."""
DEFAULT_MIN_PIXELS = 3
"""Blobs of fewer pixels are hot-pixel-like (a star's PSF lights a few pixels at least)."""
DEFAULT_MIN_SIGMA_PX = 0.3
"""Second-moment sigma below which a blob is sharper than any optics of the presets: the
Lohmann lens' PSF sigma is 0.6 px, ESTCube-2's 2 px (thresholding narrows a blob, so the
limit sits well below the sharpest PSF)."""
DEFAULT_MAX_ELONGATION = 3.0
"""sigma_major / sigma_minor above which a blob is a track (cosmic ray) unless the expected
smear explains it.  A star at rest is round (about 1); ESTCube-2 (PSF sigma 2 px) reaches 3
only for smears longer than about 20 px."""
DEFAULT_SMEAR_ANGLE_TOL = 0.35
"""Largest angle (radians, about 20 degrees) between a blob's major axis and the expected
smear direction for the smear to explain the elongation."""
DEFAULT_SMEAR_LENGTH_RATIO = 2.0
"""The measured smear length may differ from the expected one by this factor either way
(thresholding shortens a track by the PSF wings at its ends)."""
DEFAULT_JOIN_ACROSS_PX = 1.0
"""Pieces of one broken track are joined when their centroids lie within this many pixels
plus their two ``sigma_minor`` of one line along the smear (rolling-shutter shear and
centroid noise included)."""

JOINED_UNSEEN_SHARE = 0.1
"""Least ``unseen`` half-track of a star joined from pieces, as a share of its expected
smear: where the threshold cuts each piece's ends is noise, so the middle of a broken track's
extent is uncertain by more than its missing length says (estcube2 at 30 and 45 deg/s roll,
275 joined tracks: along-track errors up to 14 px with 1-3 px unseen, 41 beyond 5 sigma;
with this floor none, RMS 0.86 sigma)."""

REASONS = ("empty", "saturated", "inconsistent", "hot_pixel", "cosmic_ray", "fragment",
           "excess")
"""Rejection reasons, the keys of the ``rejected`` dict, in the order the tests apply."""

_INF = float("inf")
_PRUNE_SLACK = 8
"""Stars beyond ``max_stars`` that :func:`extract` holds before it drops the faintest (a
sort of ``max_stars + _PRUNE_SLACK`` stars every ``_PRUNE_SLACK`` accepted blobs)."""


class Star(object):
    """One accepted blob.

    ``x``, ``y`` centroid (px), ``flux`` = s0 (weight sum, ADU above background),
    ``sigma_major``, ``sigma_minor`` (px), ``elongation``, ``orientation`` (rad, major axis
    from +x towards +y), ``n`` pixels, ``nsat`` saturated pixels, ``peak`` pixel value and
    ``index`` of the record in the packet; ``parts``: the record indices of a star joined
    from the pieces of a broken track (``index`` is the brightest), else None; ``unseen``:
    how far (px) the star's mean position may lie from the centroid along the expected
    smear, the half of the track the detector did not see (``docs/centroids_and_tracking.md``; 0
    without a smear).

    The values are one tuple read through properties (``unseen`` alone is an attribute):
    MicroPython then allocates a star in a few blocks of fixed size instead of growing a
    13-entry attribute table, whose discarded tables fragment a small heap.
    """

    __slots__ = ("_v", "unseen")

    @native
    def __init__(self, x, y, flux, sigma_major, sigma_minor, elongation, orientation,
                 n, nsat, peak, index, parts=None):
        self._v = (x, y, flux, sigma_major, sigma_minor, elongation, orientation, n, nsat,
                   peak, index, parts)
        self.unseen = 0.0

    x = property(lambda self: self._v[0])
    y = property(lambda self: self._v[1])
    flux = property(lambda self: self._v[2])
    sigma_major = property(lambda self: self._v[3])
    sigma_minor = property(lambda self: self._v[4])
    elongation = property(lambda self: self._v[5])
    orientation = property(lambda self: self._v[6])
    n = property(lambda self: self._v[7])
    nsat = property(lambda self: self._v[8])
    peak = property(lambda self: self._v[9])
    index = property(lambda self: self._v[10])
    parts = property(lambda self: self._v[11])

    def as_tuple(self):
        """``(x, y, flux, sigma_major, sigma_minor, elongation, orientation, n, nsat, peak,
        index)``."""
        return self._v[:11]

    def __repr__(self):
        return ("Star(x={:.3f}, y={:.3f}, flux={}, sigma_major={:.3f}, sigma_minor={:.3f}, "
                "elongation={:.3f}, orientation={:.3f}, n={}, nsat={}, peak={}, index={})"
                ).format(*self.as_tuple())


_INT = type(0)
"""Exactly int (a bool is not), tested as ``v.__class__ is _INT``: ``type(v)`` is a call,
about 3 ticks on the MCU, six per record."""


@native
def moments(rec):
    """``(x, y, cxx, cyy, cxy, det)`` of a record, or None when it has no valid centroid.

    ``det = cxx*cyy - cxy^2``.  Integer records are computed from exact integer numerators;
    float records (another source, or tests) with the float formulas; a
    ``packet.WideRecord`` (the flight decoder's) from its limbs (:func:`_limb_moments`) when
    its moments allow.  None when ``s0`` is not a positive finite number, a moment is not
    finite, the centroid lies outside the bounding box, or the moment matrix is not positive
    semi-definite.
    """
    if rec.__class__ is _WIDE_RECORD:
        m = _limb_moments(rec.s0, rec.limbs)
        if m is not None:
            x, y = m[0], m[1]
            if rec.xmin <= x <= rec.xmax and rec.ymin <= y <= rec.ymax:
                return m
            return None
    s0, sx, sy = rec.s0, rec.sx, rec.sy
    sxx, syy, sxy = rec.sxx, rec.syy, rec.sxy
    if not (s0 - s0 == 0 and s0 > 0):       # finite(s0), inline: this runs for every record
        return None
    if s0.__class__ is _INT and sx.__class__ is _INT and sy.__class__ is _INT and \
            sxx.__class__ is _INT and syy.__class__ is _INT and sxy.__class__ is _INT:
        nxx = s0 * sxx - sx * sx          # s0^2 cxx, exact
        nyy = s0 * syy - sy * sy
        nxy = s0 * sxy - sx * sy
        d = nxx * nyy - nxy * nxy       # s0^4 det
        if nxx < 0 or nyy < 0 or d < 0:
            return None
        q, r = divmod(sx, s0)
        x = q + r / s0
        q, r = divmod(sy, s0)
        y = q + r / s0
        s02 = s0 * s0
        cxx = nxx / s02
        cyy = nyy / s02
        cxy = nxy / s02
        # det = (nxx nyy - nxy^2) / s0^4; dividing by s0^2 in integers first (quotient and
        # remainder) keeps every float below 2**128 (single-precision MCU floats)
        q, r = divmod(d, s02)
        det = (q + r / s02) / s02
    else:
        for v in (sx, sy, sxx, syy, sxy):
            if not finite(v):
                return None
        x = sx / s0
        y = sy / s0
        cxx = sxx / s0 - x * x
        cyy = syy / s0 - y * y
        cxy = sxy / s0 - x * y
        # float rounding: tolerate tiny negative values, clamp them
        tol = 1e-9 * (abs(sxx / s0) + abs(syy / s0) + 1.0)
        if cxx < -tol or cyy < -tol:
            return None
        cxx = max(cxx, 0.0)
        cyy = max(cyy, 0.0)
        det = cxx * cyy - cxy * cxy
        if det < -tol * (cxx + cyy + 1.0):
            return None
        det = max(det, 0.0)
        for v in (x, y, cxx, cyy, cxy, det):    # overflow of huge or tiny values
            if not finite(v):
                return None
    if not (rec.xmin <= x <= rec.xmax and rec.ymin <= y <= rec.ymax):
        return None
    return x, y, cxx, cyy, cxy, det


_WIDE_RECORD = WideRecord
_CLEAR = 0.01
"""Least ``det / (cxx cyy)`` and ``cxx / (1 + cxx)`` (the same for ``cyy``) of a moment
matrix :func:`_limb_moments` computes in floats: below, the float formulas' rounding (a few
units of the last place of ``cxx + 1``) could matter to the sign or the minor axis, and the
exact integer formulas decide (a single-row blob, a diagonal track of elongation above
about 20)."""


@native
def _limb_moments(s0, limbs):
    """``(x, y, cxx, cyy, cxy, det)`` of a record from ``s0`` and the 15-bit limbs of its
    wide moments (``packet.WideRecord``: ``sx, sy, sxx, syy, sxy``), in small ints only, or
    None when they do not allow it (then :func:`moments` computes from the integers).

    The centroid is ``c + r / s0`` with ``(c, r) = divmod(sx, s0)`` exactly as
    :func:`moments` computes it; the second moments about the integer point ``(cx, cy)``
    (``kxx = sxx - cx (sx + rx)``, ``kyy``, ``kxy = sxy - cy sx - cx ry``) are exact small
    ints (at most ``s0 (c + 1)``) and the central ones ``k / s0 - f f'`` with ``f = r / s0 <
    1``: a few units of the last place of ``c + 1`` against the exact numerators' one of
    ``c`` (:data:`_CLEAR`), and no long int (the exact numerators exceed a small int for every
    star brighter than ``s0`` = 2**15: two heap blocks each, about 670 bytes a record)."""
    if not s0 > 0 or limbs[0] or limbs[3]:
        return None                         # sx or sy not below 2**30
    sx = (limbs[1] << 15) | limbs[2]
    sy = (limbs[4] << 15) | limbs[5]
    cx = sx // s0
    rx = sx - cx * s0
    cy = sy // s0
    ry = sy - cy * s0
    kxx = _less(limbs, 6, cx, sx + rx, 0, 0)
    kyy = _less(limbs, 9, cy, sy + ry, 0, 0)
    kxy = _less(limbs, 12, cy, sx, cx, ry)
    if kxx is None or kyy is None or kxy is None:
        return None
    fx = rx / s0
    fy = ry / s0
    cxx = kxx / s0 - fx * fx
    cyy = kyy / s0 - fy * fy
    cxy = kxy / s0 - fx * fy
    det = cxx * cyy - cxy * cxy
    if not (cxx > _CLEAR * (1.0 + cxx) and cyy > _CLEAR * (1.0 + cyy) and
            det > _CLEAR * cxx * cyy):
        return None
    return cx + fx, cy + fy, cxx, cyy, cxy, det


@native
def _less(limbs, k, a, p, b, q):
    """``v - a p - b q`` for the wide moment ``v`` at ``limbs[k:k + 3]`` (``h 2**30 + m
    2**15 + l``), ``0 <= a, b < 2**15`` and ``0 <= p, q < 2**31``, when it is a small int
    (``-2**30 <= . < 2**30``), else None: limb by limb with borrows, every intermediate
    below ``2**30``."""
    p1 = p >> 15
    q1 = q >> 15
    low = limbs[k + 2] - a * (p & 0x7FFF) - b * (q & 0x7FFF)
    mid = limbs[k + 1] - a * p1 - b * q1 + (low >> 15)
    high = limbs[k] + (mid >> 15)
    value = ((mid & 0x7FFF) << 15) | (low & 0x7FFF)
    if high == 0:
        return value
    if high == -1:
        return value - 0x40000000
    return None


@native
def shape(cxx, cyy, cxy, det=None):
    """``(sigma_major, sigma_minor, elongation, orientation)`` of central second moments.

    ``det`` (``cxx*cyy - cxy^2``), when given exactly, makes the minor eigenvalue accurate
    for very elongated blobs (``l2 = det / l1``, no cancellation).
    """
    half_trace = 0.5 * (cxx + cyy)
    half_diff = 0.5 * (cxx - cyy)
    root = math.sqrt(half_diff * half_diff + cxy * cxy)
    l1 = half_trace + root
    if det is None:
        det = cxx * cyy - cxy * cxy
    l2 = det / l1 if l1 > 0 else 0.0
    if l2 < 0:
        l2 = 0.0
    sigma_major = math.sqrt(l1) if l1 > 0 else 0.0
    sigma_minor = math.sqrt(l2)
    if sigma_minor > 0:
        elongation = sigma_major / sigma_minor
    elif sigma_major > 0:
        elongation = _INF
    else:
        elongation = 1.0
    orientation = 0.5 * math.atan2(2.0 * cxy, cxx - cyy)
    return sigma_major, sigma_minor, elongation, orientation


@native
def smear_consistent(sigma_major, sigma_minor, orientation, smear,
                     angle_tol=DEFAULT_SMEAR_ANGLE_TOL, length_ratio=DEFAULT_SMEAR_LENGTH_RATIO,
                     partial=False):
    """True when a blob's elongation is explained by the expected smear ``(dx, dy)`` (px).

    The major axis must lie within ``angle_tol`` radians of the smear direction (either
    sense) and ``sqrt(12 (sigma_major^2 - sigma_minor^2))`` within a factor ``length_ratio``
    of the smear length; with ``partial`` any shorter length passes too (a piece of a track
    the threshold broke, or the part of a faint one it let through: :func:`extract` joins
    the pieces and the star's ``unseen`` half-track carries the rest).
    """
    if smear is None:
        return False
    dx, dy = smear[0], smear[1]
    if not (finite(dx) and finite(dy)):
        return False
    length = math.sqrt(dx * dx + dy * dy)
    if length <= 0:
        return False
    diff = orientation - math.atan2(dy, dx)
    diff = math.fmod(diff, math.pi)       # the axis has no sense: compare modulo pi
    if diff > 0.5 * math.pi:
        diff -= math.pi
    elif diff < -0.5 * math.pi:
        diff += math.pi
    if abs(diff) > angle_tol:
        return False
    excess = sigma_major * sigma_major - sigma_minor * sigma_minor
    measured = math.sqrt(12.0 * excess) if excess > 0 else 0.0
    return (partial or length / length_ratio <= measured) and measured <= length * length_ratio


@native
def unseen_px(sigma_major, sigma_minor, orientation, smear, share=0.0):
    """Half the expected track (px) a blob of this shape did not show: ``max(0, (L - l) /
    2)`` with ``L`` the length of the expected smear ``(dx, dy)`` (px) and ``l =
    sqrt(12 (c_uu - c_vv))`` the length measured along it (``docs/centroids_and_tracking.md``),
    at least ``share * L`` (:data:`JOINED_UNSEEN_SHARE` for a joined track); 0 without a
    smear."""
    if smear is None:
        return 0.0
    dx, dy = smear[0], smear[1]
    if not (dx - dx == 0 and dy - dy == 0):     # finite, inline (once per star)
        return 0.0
    length = math.sqrt(dx * dx + dy * dy)
    if not length > 0:
        return 0.0
    c = math.cos(orientation - math.atan2(dy, dx))
    c2 = c * c
    excess = (sigma_major * sigma_major - sigma_minor * sigma_minor) * (2.0 * c2 - 1.0)
    seen = math.sqrt(12.0 * excess) if excess > 0 else 0.0
    unseen = 0.5 * (length - seen) if seen < length else 0.0
    return unseen if unseen >= share * length else share * length


_TRACK, _PIECE, _RAY = 0, 1, 2


@native
def _elongated(sigma_major, sigma_minor, orientation, smear, joining, min_sigma_px,
               angle_tol, length_ratio):
    """What an elongated blob is (:func:`extract`): ``_TRACK`` when the expected ``smear``
    explains it (:func:`smear_consistent`), ``_PIECE`` when it lies along the smear but is
    shorter and, with tracks to join, is as wide across as a star (a piece of a broken or
    partly seen track, kept only if it joins another piece), else ``_RAY`` (a cosmic ray)."""
    if smear_consistent(sigma_major, sigma_minor, orientation, smear, angle_tol,
                        length_ratio):
        return _TRACK
    if joining and sigma_minor >= min_sigma_px and smear_consistent(
            sigma_major, sigma_minor, orientation, smear, angle_tol, length_ratio, True):
        return _PIECE
    return _RAY


def _root(parent, i):
    while parent[i] != i:
        parent[i] = parent[parent[i]]
        i = parent[i]
    return i


@native
def join_fragments(stars, central, smear, across_px=DEFAULT_JOIN_ACROSS_PX):
    """Join the pieces of broken smeared tracks (``docs/centroids_and_tracking.md``):
    returns the list of stars with each group of pieces replaced by one joined
    :class:`Star` (at the place of its first piece).  ``central``: per star, its central
    second moments ``(cxx, cyy, cxy)`` (px^2); ``smear``: the expected smear ``(dx, dy)`` or
    a function of ``(x, y)``.  Each star tests only the stars whose ``x`` lies within its
    reach (stars sorted by ``x`` once): a pair further apart in ``x`` than the track's
    length plus both widths fails the tests below."""
    n = len(stars)
    parent = list(range(n))
    joined = False
    vs = [star._v for star in stars]    # (x, y, flux, sigma_major, sigma_minor, ...): the
    widest = 0.0                        # pair loop reads tuples, not properties
    keys = []
    for i in range(n):
        if vs[i][4] > widest:
            widest = vs[i][4]
        keys.append((vs[i][0], i))
    keys.sort()
    rank = [0] * n                      # position of each star in x order
    for k in range(n):
        rank[keys[k][1]] = k
    smear_fn = smear if callable(smear) else None     # one test, not one per star
    sm = smear
    for i in range(n):
        a = vs[i]
        ax, ay = a[0], a[1]
        if smear_fn is not None:
            sm = smear_fn(ax, ay)
        if sm is None:
            continue
        dx, dy = sm[0], sm[1]
        length = math.sqrt(dx * dx + dy * dy) if dx - dx == 0 and dy - dy == 0 else 0.0
        if not length > 0:
            continue
        ux = dx / length
        uy = dy / length
        reach = length + 1.0
        across = across_px + a[4]
        # |ex| <= |e.u| + |e x u| <= reach + across + the other's sigma_minor
        lim = reach + across + widest
        for step in (1, -1):
            k = rank[i] + step
            while 0 <= k < n:
                xj, j = keys[k]
                k += step
                if xj - ax > lim or ax - xj > lim:
                    break
                if j <= i:
                    continue
                b = vs[j]
                ex = xj - ax
                ey = b[1] - ay
                if abs(ex * ux + ey * uy) > reach:
                    continue
                if abs(ex * uy - ey * ux) > across + b[4]:
                    continue
                ri = _root(parent, i)
                rj = _root(parent, j)
                if ri != rj:
                    parent[rj] = ri
                    joined = True
    vs = keys = rank = None
    if not joined:
        return stars
    groups = {}
    order = []
    for i in range(n):
        r = _root(parent, i)
        if r not in groups:
            groups[r] = []
            order.append(r)
        groups[r].append(i)
    out = []
    for r in order:
        members = groups[r]
        if len(members) == 1:
            out.append(stars[members[0]])
            continue
        out.append(_joined(stars, central, members, smear))
    return out


@native
def _joined(stars, central, members, smear):
    """One :class:`Star` with the moments of the union of ``members``' pieces (its flux the
    exact sum of integer ``s0``), its centroid moved along the smear to the middle of the
    pieces' extent (:func:`_mid_shift`)."""
    f = 0
    fx = 0.0
    fy = 0.0
    best = members[0]
    for i in members:
        s = stars[i]
        f += s.flux
        fx += s.flux * s.x
        fy += s.flux * s.y
        if _sort_key(s) < _sort_key(stars[best]):
            best = i
    x = fx / f
    y = fy / f
    cxx = cyy = cxy = 0.0
    n = nsat = peak = 0
    for i in members:
        s = stars[i]
        c = central[i]
        w = s.flux / f
        cxx += w * (c[0] + (s.x - x) * (s.x - x))
        cyy += w * (c[1] + (s.y - y) * (s.y - y))
        cxy += w * (c[2] + (s.x - x) * (s.y - y))
        n += s.n
        nsat += s.nsat
        if s.peak > peak:
            peak = s.peak
    sigma_major, sigma_minor, elongation, orientation = shape(cxx, cyy, cxy)
    u = smear(x, y) if callable(smear) else smear
    shift = _mid_shift(stars, central, members, x, y, u)
    parts = sorted(stars[i].index for i in members)
    if shift:
        x += shift * u[0]
        y += shift * u[1]
    return Star(x, y, f, sigma_major, sigma_minor, elongation, orientation, n, nsat, peak,
                stars[best].index, parts)


@native
def _mid_shift(stars, central, members, x, y, smear):
    """How far (in units of the smear ``(dx, dy)``) the middle of the pieces' extent along
    the smear lies from their flux-weighted centroid ``(x, y)``: each piece spans its
    centroid ``+- sqrt(3 c_uu)`` along the unit smear ``u`` (a uniform segment's half
    length).  A star moving uniformly lights its track evenly, so a gap the threshold cut
    out of it pulls the flux-weighted centroid towards the longer side, up to ``L/2`` (the
    first rule, measured at 30 deg/s roll: along-track errors up to 15 px against an unseen
    half-track of 3 px), and the extent's middle not; 0 without a smear."""
    if smear is None:
        return 0.0
    dx, dy = smear[0], smear[1]
    l2 = dx * dx + dy * dy if dx - dx == 0 and dy - dy == 0 else 0.0
    if not l2 > 0:
        return 0.0
    length = math.sqrt(l2)
    ux = dx / length
    uy = dy / length
    lo = hi = None
    for i in members:
        s = stars[i]
        c = central[i]
        p = (s.x - x) * ux + (s.y - y) * uy
        var = ux * ux * c[0] + 2.0 * ux * uy * c[2] + uy * uy * c[1]
        half = math.sqrt(3.0 * var) if var > 0 else 0.0
        if lo is None or p - half < lo:
            lo = p - half
        if hi is None or p + half > hi:
            hi = p + half
    return 0.5 * (lo + hi) / length


def _sort_key(star):
    v = star._v                         # (flux, index), without two property calls
    return (-v[2], v[10])


def _on_border(rec, border):
    return not (rec.xmin > 0 and rec.ymin > 0 and rec.xmax < border[0] - 1 and
                rec.ymax < border[1] - 1)


@native
def extract(records, max_stars=DEFAULT_MAX_STARS, min_pixels=DEFAULT_MIN_PIXELS,
            min_sigma_px=DEFAULT_MIN_SIGMA_PX, max_elongation=DEFAULT_MAX_ELONGATION,
            expected_smear_px=None, smear_angle_tol=DEFAULT_SMEAR_ANGLE_TOL,
            smear_length_ratio=DEFAULT_SMEAR_LENGTH_RATIO, join_across_px=DEFAULT_JOIN_ACROSS_PX,
            border=None):
    """Centroid, measure and filter blob records: ``(stars, rejected)``.

    ``records``: ``contract.BlobRecord`` (or any objects with the same attributes), any
    iterable.  ``stars``: at most ``max_stars`` :class:`Star`, brightest (largest s0) first,
    ties in record order; ``max_stars=None`` keeps all.  ``border``: ``(width, height)`` of
    the frame to reject stars any of whose records touch its edge (reason ``"border"``), or
    None.  ``rejected``: ``{reason: count}`` for every reason in ``REASONS`` (and
    ``"border"`` with a ``border``); ``len(stars) + sum(rejected.values())`` is the number of
    records.  The parameters and the order of the tests are described in
    ``docs/centroids_and_tracking.md``.  Memory: without an ``expected_smear_px`` at most
    ``max_stars + _PRUNE_SLACK`` stars are held at once.  Never raises on bad record
    values.
    """
    rejected = {}
    for reason in REASONS:
        rejected[reason] = 0
    if border is not None:
        rejected["border"] = 0
    smear_fn = expected_smear_px if callable(expected_smear_px) else None
    joining = expected_smear_px is not None
    stars = []
    central = [] if joining else None      # per star, for joining the pieces of tracks
    edge = {} if joining and border is not None else None     # indices of edge records
    pieces = {} if joining else None    # indices of records shorter than their track
    index = -1
    for rec in records:
        index += 1
        s0 = rec.s0
        if not (s0 - s0 == 0 and s0 > 0):   # finite(s0), inline
            rejected["empty"] += 1
            continue
        if rec.flags.__class__ is _INT and rec.flags & C.BLOB_MOMENTS_SATURATED:
            rejected["saturated"] += 1
            continue
        m = moments(rec)
        if m is None:
            rejected["inconsistent"] += 1
            continue
        x, y, cxx, cyy, cxy, det = m
        sigma_major, sigma_minor, elongation, orientation = shape(cxx, cyy, cxy, det)
        if rec.n < min_pixels or sigma_major < min_sigma_px:
            rejected["hot_pixel"] += 1
            continue
        if elongation > max_elongation:
            smear = smear_fn(x, y) if smear_fn is not None else expected_smear_px
            kind = _elongated(sigma_major, sigma_minor, orientation, smear, joining,
                              min_sigma_px, smear_angle_tol, smear_length_ratio)
            if kind == _RAY:
                rejected["cosmic_ray"] += 1
                continue
            if kind == _PIECE:
                pieces[index] = True    # shorter than its track: kept only when joined
        if sigma_minor < min_sigma_px:
            rejected["hot_pixel"] += 1
            continue
        if border is not None and not joining and _on_border(rec, border):
            rejected["border"] += 1
            continue
        stars.append(Star(x, y, s0, sigma_major, sigma_minor, elongation, orientation,
                          rec.n, rec.nsat, rec.peak, index))
        if joining:
            central.append((cxx, cyy, cxy))
            if edge is not None and _on_border(rec, border):
                edge[index] = True
        elif max_stars is not None and len(stars) >= max_stars + _PRUNE_SLACK:
            _keep_brightest(stars, max_stars, rejected)
    if joining and len(stars) > 1:
        n_before = len(stars)
        stars = join_fragments(stars, central, expected_smear_px, join_across_px)
        rejected["fragment"] = n_before - len(stars)
    central = None
    if pieces:
        stars = _joined_pieces(stars, pieces, rejected)
    if edge:
        # a joined star is on the border when any of its pieces is
        kept = []
        for star in stars:
            for i in (star.parts or (star.index,)):
                if i in edge:
                    break
            else:
                kept.append(star)
        rejected["border"] = len(stars) - len(kept)
        stars = kept
    if joining:
        for star in stars:
            v = star._v                 # (x, y, flux, sigma_major, sigma_minor, elongation,
            smear = smear_fn(v[0], v[1]) if smear_fn is not None else expected_smear_px
            star.unseen = unseen_px(v[3], v[4], v[6], smear,        # orientation, ...)
                                    JOINED_UNSEEN_SHARE if v[11] is not None else 0.0)
    if max_stars is not None:
        _keep_brightest(stars, max_stars, rejected)
    else:
        _brightest_first(stars)
    return stars, rejected


def _joined_pieces(stars, pieces, rejected):
    """``stars`` without the unjoined ``pieces`` (record indices of elongated blobs shorter
    than their expected track): a piece the joining found no other piece of the same track
    for is as likely a cosmic ray lying along the smear, and counts as ``"cosmic_ray"``."""
    kept = []
    for star in stars:
        if star.parts is not None or star.index not in pieces:
            kept.append(star)
    rejected["cosmic_ray"] += len(stars) - len(kept)
    return kept


@native
def _brightest_first(stars):
    """Sort ``stars`` in place by :func:`_sort_key`, computed once per star (MicroPython's
    ``sort(key=...)`` calls the key at every comparison)."""
    keyed = [None] * len(stars)
    for i in range(len(stars)):
        v = stars[i]._v                 # _sort_key(stars[i]) + (i,), inline: tuples of
        keyed[i] = (-v[2], v[10], i)    # numbers, no call to compare
    keyed.sort()
    old = stars[:]
    for i in range(len(keyed)):
        stars[i] = old[keyed[i][2]]


def _keep_brightest(stars, max_stars, rejected):
    """Sort ``stars`` brightest first and drop all but ``max_stars`` (as ``"excess"``)."""
    _brightest_first(stars)
    if len(stars) > max_stars:
        rejected["excess"] += len(stars) - max_stars
        del stars[max_stars:]
