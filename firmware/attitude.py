"""Wahba-problem attitude solvers for the MCU: QUEST, Davenport's q-method, ESOQ2 and TRIAD.

``b`` are body (camera-frame) unit vectors, ``r`` the matching reference (ICRS) unit vectors
and ``w`` positive weights (``None``: all equal); vectors are normalised and weights rescaled
to ``sum(w) = 1`` on entry.  Every solver returns our quaternion ``q = [x, y, z, w]`` (scalar
last, ``w >= 0``) with ``quaternion.rotate(q, r_i) ~ b_i`` (``docs/conventions.md``); inside,
Shuster's formulation is followed literally and the result conjugated.  With ``refine=True``
(default) :func:`quest` and :func:`esoq2` match :func:`q_method`'s accuracy even for close
stars.  Input errors (bad lengths, NaN/inf, zero vectors, non-positive weights, fewer than two
pairs, unobservable roll) raise ``ValueError`` naming the element.  Pure Python, ``math`` only
(CPython and MicroPython).  Formulation and accuracy: ``docs/centroids_and_tracking.md``.
"""

import math

from . import geometry as G
from . import quaternion as Q
from .emit import native

MIN_SEPARATION = 1e-6
"""Smallest accepted ``sin`` of the largest angle between body (or reference) vectors."""

NEWTON_TOLERANCE = max(1e-14, 16.0 * G.EPS)
"""QUEST/ESOQ2 Newton-Raphson stops once a step is below this (``lambda_0 = sum w = 1``), or
as soon as the steps stop shrinking (the rounding floor)."""

NEWTON_MAX_ITERATIONS = 100
"""Cap on Newton-Raphson steps (quadratic convergence normally needs 1 to 5)."""

QUEST_GAMMA_MIN = 0.25
"""QUEST keeps the unrotated frame while ``gamma >= QUEST_GAMMA_MIN psi'(lambda)``, i.e.
``q4^2 >= 1/4`` (rotation angle up to 120 deg); otherwise it uses sequential rotations."""

REFINE_STEP_RAD = 5e-5
""":func:`refine` stops after a step smaller than this (rad, 10 arcsec): Gauss-Newton leaves
about the step times the step and the residuals, at most 5.5e-8 rad (0.011 arcsec) against
the q-method on 200 random skies with residuals up to 1e-3 rad (1e-4 would leave 5.5e-7);
a tracking fit from a prior a few arcseconds off and a weighted refit of an unweighted fit
then take one step."""

REFINE_MAX_ITERATIONS = 5
"""Most Gauss-Newton steps of :func:`refine` (from 0.3 deg off it takes three)."""

JACOBI_MAX_SWEEPS = 60
"""Cap on cyclic Jacobi sweeps in the q-method (a 4x4 converges in about 5)."""

_AXIS_QUATERNIONS = ([1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0])


# ---------------------------------------------------------------------------------------------
# Input validation
# ---------------------------------------------------------------------------------------------

def _length(seq, label):
    try:
        return len(seq)
    except TypeError:
        raise ValueError("%s must be a sequence, got %r" % (label, seq)) from None


def _unit(v, name, i=None):
    """``v`` (named ``name``, or ``name[i]``) normalised, as a list of floats; the name is
    formatted only for an error (this runs for every vector of every fit)."""
    try:
        k = len(v)
        x, y, z = float(v[0]), float(v[1]), float(v[2])
    except (TypeError, ValueError, IndexError):
        k = None
    if k != 3:
        label = name if i is None else "%s[%d]" % (name, i)
        try:
            k = len(v)
        except TypeError:
            raise ValueError("%s must be a sequence, got %r" % (label, v)) from None
        if k != 3:
            raise ValueError("%s must have 3 components, got %d" % (label, k))
        raise ValueError("%s must hold numbers, got %r" % (label, v))
    n = math.sqrt(x * x + y * y + z * z)
    if not G.finite(n) or n == 0.0:
        label = name if i is None else "%s[%d]" % (name, i)
        if n == 0.0:
            raise ValueError("%s is a zero vector" % label)
        raise ValueError("%s is not finite: %r" % (label, [x, y, z]))
    return [x / n, y / n, z / n]


@native
def _check_spread(vs, name):
    """``ValueError`` unless two of the unit vectors ``vs`` are neither parallel nor opposite."""
    ax, ay, az = vs[0]
    enough = MIN_SEPARATION * MIN_SEPARATION
    best = 0.0
    for i in range(1, len(vs)):
        bx, by, bz = vs[i]
        cx = ay * bz - az * by
        cy = az * bx - ax * bz
        cz = ax * by - ay * bx
        s = cx * cx + cy * cy + cz * cz
        if s > best:
            best = s
            if best >= enough:
                return                  # two such vectors suffice
    best = math.sqrt(best)
    if best < MIN_SEPARATION:
        raise ValueError("all %s vectors are parallel or opposite (largest sin of separation "
                         "%.3g < %.3g): the rotation about them is unobservable"
                         % (name, best, MIN_SEPARATION))


_FLOAT = float


def _positive(values, name, n):
    """``values`` as a list of positive finite floats, else ``ValueError`` naming the entry
    (a float is taken as it is: ``float()`` and ``finite()`` would cost a call each)."""
    m = _length(values, name)
    if m != n:
        raise ValueError("%s must have one entry per vector pair (%d), got %d" % (name, n, m))
    out = []
    for i in range(n):
        a = values[i]
        if a.__class__ is not _FLOAT:
            try:
                a = float(a)
            except (TypeError, ValueError):
                raise ValueError("%s[%d] must be a number, got %r" % (name, i, a)) from None
        if not a - a == 0 or not a > 0.0:
            raise ValueError("%s[%d] = %r must be positive and finite" % (name, i, a))
        out.append(a)
    return out


@native
def _prepare(b, r, w, wname="w", min_pairs=2, shared=False):
    """Validated ``(unit b, unit r, weights)`` as lists of floats (weights not rescaled);
    ``r`` None: not checked, and None is returned for it.  ``shared``: a unit tuple of ``b``
    is taken as it is (not normalised again: where its last bits do not matter)."""
    n = _length(b, "b")
    m = n if r is None else _length(r, "r")
    if m != n:
        raise ValueError("b and r must have the same number of vectors, got %d and %d" % (n, m))
    if n < min_pairs:
        raise ValueError("need at least %d vector pairs, got %d" % (min_pairs, n))
    bs = [b[i] if shared and G.is_unit_tuple(b[i]) else _unit(b[i], "b", i)
          for i in range(n)]
    rs = None if r is None else [_unit(r[i], "r", i) for i in range(n)]
    if w is None:
        ws = [1.0] * n
    else:
        ws = _positive(w, wname, n)
    if min_pairs >= 2:
        _check_spread(bs, "body (b)")
        if rs is not None:
            _check_spread(rs, "reference (r)")
    return bs, rs, ws


@native
def _unit_weights(ws):
    total = 0.0
    for a in ws:
        total += a
    if not G.finite(total):
        raise ValueError("sum of weights is not finite")
    return [a / total for a in ws]


# ---------------------------------------------------------------------------------------------
# Shuster's quantities (B is a flat list of 9: B[3*i + j] = sum a b_i r_j)
# ---------------------------------------------------------------------------------------------

@native
def _profile(bs, rs, ws):
    B = [0.0] * 9
    for k in range(len(bs)):
        bv, rv, a = bs[k], rs[k], ws[k]
        for i in range(3):
            ab = a * bv[i]
            B[3 * i] += ab * rv[0]
            B[3 * i + 1] += ab * rv[1]
            B[3 * i + 2] += ab * rv[2]
    return B


def _flip(B, axis):
    """``B R_axis``: the profile matrix after turning the reference frame 180 deg about axis."""
    out = list(B)
    for j in range(3):
        if j != axis:
            out[j] = -out[j]
            out[3 + j] = -out[3 + j]
            out[6 + j] = -out[6 + j]
    return out


def _parts(B):
    """``(S, sigma, z)`` with ``S`` as ``[S00, S11, S22, S01, S02, S12]``."""
    S = [2.0 * B[0], 2.0 * B[4], 2.0 * B[8], B[1] + B[3], B[2] + B[6], B[5] + B[7]]
    sigma = B[0] + B[4] + B[8]
    z = [B[5] - B[7], B[6] - B[2], B[1] - B[3]]
    return S, sigma, z


def _sym_mul(S, v):
    s00, s11, s22, s01, s02, s12 = S
    return [s00 * v[0] + s01 * v[1] + s02 * v[2],
            s01 * v[0] + s11 * v[1] + s12 * v[2],
            s02 * v[0] + s12 * v[1] + s22 * v[2]]


def _adj_trace_det(S):
    s00, s11, s22, s01, s02, s12 = S
    c00 = s11 * s22 - s12 * s12
    c11 = s00 * s22 - s02 * s02
    c22 = s00 * s11 - s01 * s01
    det = s00 * c00 + s01 * (s12 * s02 - s01 * s22) + s02 * (s01 * s12 - s11 * s02)
    return c00 + c11 + c22, det


def _coefficients(B):
    """QUEST's ``(a, b, c, d, sigma)``: ``psi(l) = (l^2 - a)(l^2 - b) - c (l - sigma) - d``.

    ``a = sigma^2 - tr adj S``, ``b = sigma^2 + z.z``, ``c = det S + z.S z``,
    ``d = z.S^2 z`` (Shuster; Lohmann's digest section 2.8 with its typos corrected), so
    ``psi(l) = det(l I - K) = l^4 - (a + b) l^2 - c l + (a b + c sigma - d)``.
    """
    S, sigma, z = _parts(B)
    kappa, delta = _adj_trace_det(S)
    Sz = _sym_mul(S, z)
    s2 = sigma * sigma
    return (s2 - kappa, s2 + G.dot(z, z), delta + G.dot(z, Sz), G.dot(Sz, Sz),
            sigma)


@native
def _lambda_max(B, lam0):
    """``(lambda_max, psi'(lambda_max))``: Newton-Raphson on ``psi`` from ``lam0 = sum a``.

    ``psi`` has four real roots and ``lam0 >= lambda_max``, so the iteration decreases
    monotonically onto ``lambda_max`` (``psi`` is increasing and convex to its right).
    """
    a, b, c, d, sigma = _coefficients(B)
    lam = lam0
    previous = None
    for _ in range(NEWTON_MAX_ITERATIONS):
        l2 = lam * lam
        psi = (l2 - a) * (l2 - b) - c * (lam - sigma) - d
        dpsi = 2.0 * lam * (2.0 * l2 - a - b) - c
        if not dpsi > 0.0:
            if psi == 0.0:
                return lam, dpsi
            raise ValueError("QUEST: psi'(lambda) = %r <= 0 at lambda = %r; the largest "
                             "eigenvalue is not isolated (degenerate geometry)" % (dpsi, lam))
        step = psi / dpsi
        # In exact arithmetic the steps are positive and shrinking; a step that is tiny, or
        # no smaller than the previous one, is rounding noise: we are at the root.
        converged = abs(step) <= NEWTON_TOLERANCE * lam0 or (
            previous is not None and abs(step) >= previous)
        if not (converged and step < 0.0):
            lam -= step
        if converged:
            l2 = lam * lam
            return lam, 2.0 * lam * (2.0 * l2 - a - b) - c
        previous = abs(step)
    raise ValueError("QUEST: Newton-Raphson did not converge in %d steps (last lambda %r)"
                     % (NEWTON_MAX_ITERATIONS, lam))


@native
def _quest_column(B, lam):
    """Shuster's ``(x, gamma)`` for ``lambda``: ``x = [alpha I + (lambda - sigma) S + S^2] z``,
    ``gamma = alpha (lambda + sigma) - det S``, ``alpha = lambda^2 - sigma^2 + tr adj S``.

    ``[x; gamma]`` is the last column of ``adj(lambda I - K) = psi'(lambda) qbar qbar^T``,
    i.e. ``psi' q4 qbar``; so ``|gamma| = psi' q4^2``, small near 180 deg rotations.
    """
    S, sigma, z = _parts(B)
    kappa, delta = _adj_trace_det(S)
    alpha = lam * lam - sigma * sigma + kappa
    gamma = alpha * (lam + sigma) - delta
    Sz = _sym_mul(S, z)
    SSz = _sym_mul(S, Sz)
    ls = lam - sigma
    x = [alpha * z[i] + ls * Sz[i] + SSz[i] for i in range(3)]
    return x, gamma


def _ours(vec, scalar, axis):
    """Our quaternion from Shuster's ``[vec; scalar]`` solved in the frame turned about axis."""
    n = math.sqrt(vec[0] * vec[0] + vec[1] * vec[1] + vec[2] * vec[2] + scalar * scalar)
    if not (n > 0.0 and G.finite(n)):
        raise ValueError("degenerate attitude solution (quaternion norm %r)" % n)
    q = [-vec[0] / n, -vec[1] / n, -vec[2] / n, scalar / n]    # conjugate: Shuster -> ours
    if axis >= 0:
        q = Q.multiply(q, _AXIS_QUATERNIONS[axis])           # A = A' R_axis
    return Q.canonical(q)


# ---------------------------------------------------------------------------------------------
# Public helpers
# ---------------------------------------------------------------------------------------------

def profile_matrix(b, r, w=None):
    """Attitude profile matrix ``B = sum w_i b_i r_i^T`` (3 row lists; weights as given,
    ``None``: all 1)."""
    bs, rs, ws = _prepare(b, r, w, min_pairs=1)
    B = _profile(bs, rs, ws)
    return [B[0:3], B[3:6], B[6:9]]


def davenport_k(b, r, w=None):
    """Davenport's ``K = [[S - sigma I, z], [z^T, sigma]]`` (4 row lists; weights as given).

    Its top eigenvector is Shuster's quaternion (the conjugate of ours).
    """
    bs, rs, ws = _prepare(b, r, w, min_pairs=1)
    S, sigma, z = _parts(_profile(bs, rs, ws))
    s00, s11, s22, s01, s02, s12 = S
    return [[s00 - sigma, s01, s02, z[0]],
            [s01, s11 - sigma, s12, z[1]],
            [s02, s12, s22 - sigma, z[2]],
            [z[0], z[1], z[2], sigma]]


def quest_polynomial(b, r, w=None):
    """Coefficients ``[1, 0, -(a + b), -c, a b + c sigma - d]`` of ``det(lambda I - K)``
    (highest power first, as ``numpy.poly``) from QUEST's ``a, b, c, d`` (weights as given)."""
    bs, rs, ws = _prepare(b, r, w, min_pairs=1)
    a, bb, c, d, sigma = _coefficients(_profile(bs, rs, ws))
    return [1.0, 0.0, -(a + bb), -c, a * bb + c * sigma - d]


def loss(q, b, r, w=None):
    """Wahba's loss ``1/2 sum w_i |b_i - A(q) r_i|^2`` (weights as given, ``None``: all 1;
    vectors normalised).

    ``q`` is our quaternion (normalised implicitly); a single pair is allowed here.
    """
    bs, rs, ws = _prepare(b, r, w, min_pairs=1)
    A = Q.to_matrix(q)
    total = 0.0
    for k in range(len(bs)):
        bv, rv = bs[k], rs[k]
        e = 0.0
        for i in range(3):
            row = A[i]
            d = bv[i] - (row[0] * rv[0] + row[1] * rv[1] + row[2] * rv[2])
            e += d * d
        total += ws[k] * e
    return 0.5 * total


# ---------------------------------------------------------------------------------------------
# Solvers
# ---------------------------------------------------------------------------------------------

def _rayleigh(B, vec, scalar):
    """``qbar^T K qbar / |qbar|^2`` for Shuster's ``qbar = [vec; scalar]`` and ``K`` of ``B``."""
    S, sigma, z = _parts(B)
    Sv = _sym_mul(S, vec)
    vv = G.dot(vec, vec)
    num = (G.dot(vec, Sv) - sigma * vv + 2.0 * scalar * G.dot(z, vec)
           + sigma * scalar * scalar)
    return num / (vv + scalar * scalar)


@native
def quest(b, r, w=None, refine=True):
    """Shuster's QUEST; returns our quaternion ``[x, y, z, w]`` (``rotate(q, r_i) ~ b_i``).

    ``lambda_max`` by Newton-Raphson on QUEST's quartic from ``lambda_0 = 1`` (until a step is
    below :data:`NEWTON_TOLERANCE`), Shuster's ``[x; gamma]`` from it, and the method of
    sequential rotations when ``gamma < QUEST_GAMMA_MIN psi'`` (``q4^2 < 1/4``: the reference
    frame is turned 180 deg about the axis giving the largest ``|gamma|``, undone afterwards).
    ``refine`` (default, not in Shuster's paper): one Rayleigh-quotient update of ``lambda``
    and a second solve, which brings the error from ``eps / gap^2`` to the q-method's
    ``eps / gap``; ``refine=False`` gives textbook QUEST.  The steps and the accuracy
    argument: ``docs/centroids_and_tracking.md`` (Attitude solvers).
    """
    bs, rs, ws = _prepare(b, r, w)
    B = _profile(bs, rs, _unit_weights(ws))
    lam, dpsi = _lambda_max(B, 1.0)
    x, gamma = _quest_column(B, lam)
    axis = -1
    if not gamma >= QUEST_GAMMA_MIN * dpsi:
        best = -1.0
        for k in range(3):
            xk, gk = _quest_column(_flip(B, k), lam)
            if abs(gk) > best:
                best, axis, x, gamma = abs(gk), k, xk, gk
        B = _flip(B, axis)
    if refine:
        x, gamma = _quest_column(B, _rayleigh(B, x, gamma))
    return _ours(x, gamma, axis)


@native
def refine(q, b, r, w=None, max_iterations=REFINE_MAX_ITERATIONS):
    """Wahba's least-squares attitude near ``q`` (our quaternion, within a few degrees) by
    Gauss-Newton on the small rotation ``phi`` with ``A = exp([phi x]) A(q)``: each step
    solves ``sum a_i (I - p_i p_i^T) phi = sum a_i p_i x (b_i - p_i)``, ``p_i = A(q) r_i``,
    and turns ``q`` by ``phi``, until a step is below :data:`REFINE_STEP_RAD`.

    Why, rather than QUEST: every quantity is a residual or a sum of squares of the
    vectors' components across the boresight, so single precision keeps its relative
    accuracy (an eigenvalue solver loses ``eps / gap``: arcseconds of roll in a narrow field
    in float32), and a start from the prior or the last fit costs one step, without
    QUEST's sequential rotations.  ``b``, ``r``: unit 3-sequences (not normalised: a norm
    error moves ``p_i`` along itself, which the step ignores); ``w``: positive weights
    (None: all 1).  Raises ``ValueError`` for fewer than two pairs, mismatched lengths, an
    unobservable rotation (all vectors parallel) or no convergence."""
    n = _length(b, "b")
    if _length(r, "r") != n or (w is not None and _length(w, "w") != n):
        raise ValueError("b, r and w must have one entry per vector pair")
    if n < 2:
        raise ValueError("need at least 2 vector pairs, got %d" % n)
    q = Q.normalise(q)
    enough = REFINE_STEP_RAD * REFINE_STEP_RAD
    for _ in range(max_iterations):
        m0, m1, m2, m3, m4, m5, m6, m7, m8 = Q.matrix(q)
        sxx = syy = szz = sxy = sxz = syz = gx = gy = gz = 0.0
        for k in range(n):
            rv = r[k]
            r0, r1, r2 = rv[0], rv[1], rv[2]
            px = m0 * r0 + m1 * r1 + m2 * r2
            py = m3 * r0 + m4 * r1 + m5 * r2
            pz = m6 * r0 + m7 * r1 + m8 * r2
            bv = b[k]
            ex, ey, ez = bv[0] - px, bv[1] - py, bv[2] - pz
            a = 1.0 if w is None else w[k]
            ax, ay, az = a * px, a * py, a * pz
            gx += ay * ez - az * ey
            gy += az * ex - ax * ez
            gz += ax * ey - ay * ex
            sxx += ax * px
            syy += ay * py
            szz += az * pz
            sxy += ax * py
            sxz += ax * pz
            syz += ay * pz
        # M = sum a (|p|^2 I - p p^T), its diagonal as sums of the other two squares
        # (1 - pz^2 would cancel for stars near the boresight)
        mxx, myy, mzz = syy + szz, sxx + szz, sxx + syy
        c00 = myy * mzz - syz * syz
        c11 = mxx * mzz - sxz * sxz
        c22 = mxx * myy - sxy * sxy
        c01 = sxy * mzz + sxz * syz
        c02 = sxy * syz + myy * sxz
        c12 = mxx * syz + sxy * sxz
        det = mxx * c00 - sxy * c01 - sxz * c02
        scale = mxx + myy + mzz
        if not det > scale * scale * scale * (MIN_SEPARATION * MIN_SEPARATION):
            raise ValueError("refine: the rotation is unobservable (all vectors parallel, "
                             "or not finite)")
        px = (c00 * gx + c01 * gy + c02 * gz) / det
        py = (c01 * gx + c11 * gy + c12 * gz) / det
        pz = (c02 * gx + c12 * gy + c22 * gz) / det
        q = Q.multiply(Q.from_rotation_vector((px, py, pz)), q)
        if px * px + py * py + pz * pz <= enough:
            return Q.canonical(q)
    raise ValueError("refine: no convergence in %d steps (start more than a few degrees "
                     "off?)" % max_iterations)


def _esoq2_solve(B, lam):
    """Shuster's ``([(lambda - sigma) e], z.e)`` (unnormalised) from ``M e = 0``."""
    S, sigma, z = _parts(B)
    t = lam - sigma
    u = lam + sigma
    s00, s11, s22, s01, s02, s12 = S
    m0 = [t * (s00 - u) + z[0] * z[0], t * s01 + z[0] * z[1], t * s02 + z[0] * z[2]]
    m1 = [m0[1], t * (s11 - u) + z[1] * z[1], t * s12 + z[1] * z[2]]
    m2 = [m0[2], m1[2], t * (s22 - u) + z[2] * z[2]]
    e = None
    best = -1.0
    for c in (G.cross(m1, m2), G.cross(m2, m0), G.cross(m0, m1)):
        n2 = c[0] * c[0] + c[1] * c[1] + c[2] * c[2]
        if n2 > best:
            best, e = n2, c
    if not (best > 0.0 and G.finite(best)):
        raise ValueError("ESOQ2: M has rank < 2 (degenerate geometry)")
    n = math.sqrt(best)
    e = [e[0] / n, e[1] / n, e[2] / n]
    return [t * e[0], t * e[1], t * e[2]], G.dot(z, e)


def esoq2(b, r, w=None, refine=True):
    """Mortari's ESOQ2; returns our quaternion ``[x, y, z, w]`` (``rotate(q, r_i) ~ b_i``).

    ``lambda_max`` from the same Newton-Raphson as :func:`quest`; the rotation axis ``e`` from
    ``M e = 0`` with ``M = (lambda - sigma)(S - (lambda + sigma) I) + z z^T`` (the largest
    cross product of its rows), ``qbar = [(lambda - sigma) e; z.e] / norm``.  ESOQ2 is singular
    at rotation angle **zero**, so the reference frame is always turned (0 or 180 deg about x,
    y or z) to minimise ``tr B'``, which keeps the solved rotation far from zero; the turn is
    undone afterwards.  ``refine`` (default): one Rayleigh-quotient update and a second solve,
    as in :func:`quest`.  Derivation: ``docs/centroids_and_tracking.md`` (Attitude solvers).
    """
    bs, rs, ws = _prepare(b, r, w)
    B = _profile(bs, rs, _unit_weights(ws))
    lam = _lambda_max(B, 1.0)[0]
    sigma0 = B[0] + B[4] + B[8]
    axis, best = -1, sigma0
    for k in range(3):
        s = 2.0 * B[4 * k] - sigma0
        if s < best:
            axis, best = k, s
    if axis >= 0:
        B = _flip(B, axis)
    vec, scalar = _esoq2_solve(B, lam)
    if refine:
        vec, scalar = _esoq2_solve(B, _rayleigh(B, vec, scalar))
    return _ours(vec, scalar, axis)


def _jacobi_top_eigenvector(K):
    """Eigenvector (list of 4) of the largest eigenvalue of a symmetric 4x4 (cyclic Jacobi)."""
    a = [list(row) for row in K]
    v = [[1.0, 0.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    scale = 0.0
    for i in range(4):
        for j in range(4):
            scale += a[i][j] * a[i][j]
    for _ in range(JACOBI_MAX_SWEEPS):
        off = 0.0
        for p in range(3):
            for q in range(p + 1, 4):
                off += a[p][q] * a[p][q]
        if off <= 1e-4 * G.EPS * G.EPS * scale:
            break
        for p in range(3):
            for q in range(p + 1, 4):
                apq = a[p][q]
                if apq == 0.0:
                    continue
                theta = (a[q][q] - a[p][p]) / (2.0 * apq)
                if abs(theta) > 1e15:      # 1 / (2 theta) to every digit; a float32 literal
                    t = 0.5 / theta
                else:
                    t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                    if theta < 0.0:
                        t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for k in range(4):
                    akp, akq = a[k][p], a[k][q]
                    a[k][p] = c * akp - s * akq
                    a[k][q] = s * akp + c * akq
                for k in range(4):
                    apk, aqk = a[p][k], a[q][k]
                    a[p][k] = c * apk - s * aqk
                    a[q][k] = s * apk + c * aqk
                a[p][q] = 0.0
                a[q][p] = 0.0
                for k in range(4):
                    vkp, vkq = v[k][p], v[k][q]
                    v[k][p] = c * vkp - s * vkq
                    v[k][q] = s * vkp + c * vkq
    best = 0
    for i in range(1, 4):
        if a[i][i] > a[best][best]:
            best = i
    return [v[0][best], v[1][best], v[2][best], v[3][best]]


def q_method(b, r, w=None):
    """Davenport's q-method (the reference solver); returns our quaternion ``[x, y, z, w]``.

    The eigenvector of the largest eigenvalue of ``K`` (weights rescaled to ``sum 1``) by a
    cyclic Jacobi eigen-solver, which is accurate for every rotation angle; it is Shuster's
    quaternion and is conjugated into ours.
    """
    bs, rs, ws = _prepare(b, r, w)
    S, sigma, z = _parts(_profile(bs, rs, _unit_weights(ws)))
    s00, s11, s22, s01, s02, s12 = S
    K = [[s00 - sigma, s01, s02, z[0]],
         [s01, s11 - sigma, s12, z[1]],
         [s02, s12, s22 - sigma, z[2]],
         [z[0], z[1], z[2], sigma]]
    qbar = _jacobi_top_eigenvector(K)
    return _ours(qbar[0:3], qbar[3], -1)


def _triad_frame(u, v, name):
    c = G.cross(u, v)
    n = G.norm(c)
    if n < MIN_SEPARATION:
        raise ValueError("TRIAD: the two %s vectors are parallel or opposite (sin of "
                         "separation %.3g < %.3g)" % (name, n, MIN_SEPARATION))
    t2 = [c[0] / n, c[1] / n, c[2] / n]
    return u, t2, G.cross(u, t2)


def triad(b1, b2, r1, r2):
    """TRIAD (Black 1964) with the first pair exact: ``rotate(q, r1) == b1`` to rounding.

    Triads ``t1 = v1``, ``t2 = unit(v1 x v2)``, ``t3 = t1 x t2`` in both frames give
    ``A = sum_k t_k^b (t_k^r)^T``; ``b2``/``r2`` only fix the roll about the first pair.
    Returns our quaternion ``[x, y, z, w]`` with ``w >= 0``.
    """
    bu1, bu2 = _unit(b1, "b1"), _unit(b2, "b2")
    ru1, ru2 = _unit(r1, "r1"), _unit(r2, "r2")
    tb = _triad_frame(bu1, bu2, "body")
    tr = _triad_frame(ru1, ru2, "reference")
    A = [[tb[0][i] * tr[0][j] + tb[1][i] * tr[1][j] + tb[2][i] * tr[2][j] for j in range(3)]
         for i in range(3)]
    return Q.from_matrix(A)


# ---------------------------------------------------------------------------------------------
# Covariance
# ---------------------------------------------------------------------------------------------

@native
def covariance(b, r, sigmas):
    """Shuster's QUEST measurement-model attitude covariance in the **body** frame, rad^2.

    ``P = (sum_i sigma_i^-2 (I - b_i b_i^T))^-1`` (3 row lists), where ``sigma_i`` (rad) is
    the per-axis standard deviation of the noise on ``b_i`` in each of the two directions
    perpendicular to it.  ``P`` is the covariance of the small rotation vector ``dtheta`` with
    ``A_est = exp([dtheta x]) A_true`` (rotation vector of ``A_est A_true^T``, camera axes)
    when the solver uses weights ``a_i`` proportional to ``sigma_i^-2``.  ``r`` is only
    validated (same count, finite, not all parallel; None: not checked): to first order the
    information depends on the body directions alone.
    """
    bs, rs, ss = _prepare(b, r, sigmas, wname="sigmas", shared=True)
    f00 = f11 = f22 = f01 = f02 = f12 = 0.0
    for k in range(len(bs)):
        g = 1.0 / ss[k]
        g *= g
        if not g - g == 0:              # finite(g), inline
            raise ValueError("sigmas[%d] = %r is too small" % (k, ss[k]))
        x, y, z = bs[k]
        f00 += g * (1.0 - x * x)
        f11 += g * (1.0 - y * y)
        f22 += g * (1.0 - z * z)
        f01 -= g * x * y
        f02 -= g * x * z
        f12 -= g * y * z
    c00 = f11 * f22 - f12 * f12
    c01 = f02 * f12 - f01 * f22
    c02 = f01 * f12 - f11 * f02
    c11 = f00 * f22 - f02 * f02
    c12 = f01 * f02 - f00 * f12
    c22 = f00 * f11 - f01 * f01
    det = f00 * c00 + f01 * c01 + f02 * c02
    if not (det > 0.0 and G.finite(det)):
        raise ValueError("covariance: information matrix is singular (det %r)" % det)
    return [[c00 / det, c01 / det, c02 / det],
            [c01 / det, c11 / det, c12 / det],
            [c02 / det, c12 / det, c22 / det]]


def sigmas_cross_roll(P):
    """``(sigma_cross_boresight, sigma_roll)`` in rad from a body-frame covariance ``P``.

    The boresight is camera ``+z``.  ``sigma_roll = sqrt(Pzz)`` (rotation about ``+z``);
    ``sigma_cross_boresight = sqrt((Pxx + Pyy) / 2)``, the RMS of the two cross-boresight
    axes (a per-axis figure, not their root-sum-square: multiply by ``sqrt(2)`` for the RSS
    total pointing error of the boresight).
    """
    if len(P) != 3:
        raise ValueError("P must be 3x3, got %d rows" % len(P))
    d = []
    for i in range(3):
        if len(P[i]) != 3:
            raise ValueError("P row %d must have 3 elements, got %d" % (i, len(P[i])))
        v = float(P[i][i])
        if not G.finite(v) or v < 0.0:
            raise ValueError("P[%d][%d] = %r must be finite and >= 0" % (i, i, v))
        d.append(v)
    return math.sqrt(0.5 * (d[0] + d[1])), math.sqrt(d[2])
