"""The body rate a frame shows, and the attitude at one instant: no gyro needed.

A rolling shutter sees row ``y`` at ``t = exposure / 2 + y * row_time`` after the start of
row 0's exposure (a centroid is its star's mean position over the exposure), and a turning
camera shows each star where it was at its row's instant: the rate shears the matched stars
against their catalogue directions (a rate across the boresight as a scale or skew along the
columns, a roll as a rotation growing down the rows).  :func:`rate_fit` fits the attitude at
a reference instant and the rate together to the matched pairs (six unknowns, least
squares), so the attitude's covariance includes what the rate's uncertainty does to it.
:func:`smear_bound_px` reads the stars' own streaks (their second moments) for the frames
with too few stars to fit a rate: how long a smear they allow.  Rates in rad/s in the camera
frame, angles in rad, times in s (``docs/conventions.md``); ``docs/firmware.md`` (Epoch and
rate) tells how the pipeline uses them.  Pure Python for CPython and MicroPython, accurate in
single precision (the rate's unknowns are scaled by the stars' time spread).
"""

import math

from . import centroids
from . import geometry as G
from . import quaternion as Q
from .emit import native

MIN_RATE_STARS = 6
"""Fewest matched stars :func:`rate_fit` fits a rate to: six unknowns, and at least
``2n - 8 >= 4`` residual degrees of freedom for the noise it scales the covariance by."""
MIN_RADIAL_STARS = 8
"""Fewest matched stars :func:`radial_fit` fits a radial displacement to."""
RADIAL_CHI2 = 30.0
"""Largest ``chi^2`` of the radial displacement's two coefficients (about 5 sigma) before a
solution's residuals are said to show an unmodelled radial pattern."""
RATE_ITERATIONS = 3
"""Gauss-Newton rounds of :func:`rate_fit` (each turns the stars back by the rate so far):
the model is linear in the attitude and the rate to ``(rate * dt)^2``, 1e-5 rad at 10 deg/s
over a frame."""
RATE_CHI2 = ((6, 71.1), (8, 47.5), (10, 37.7), (12, 32.4), (16, 27.0), (20, 24.3),
             (30, 21.2), (40, 19.8), (60, 18.5), (120, 17.3))
"""``(degrees of freedom, limit)``: the largest ``chi^2`` of the frame's rate against a given
one before the given rate can be called contradicted, ``3 F(3, d)`` at 1e-3 (the noise is
estimated from ``d = 2n - 8`` residual degrees of freedom of ``n`` stars, so a chi-square of
3 degrees of freedom would understate the tail: 16.3 at infinite ``d``); a ``d`` between two
rows takes the lower row's.  A false alarm costs a frame (``RATE_CONTRADICTED``), a missed
wrong rate an attitude off by the rate error times the time to the epoch; the streaks must
agree too (``firmware.md``, Epoch and rate)."""
STREAK_RATE_CHI2 = 16.3
"""The limit instead when most matched stars' streaks side with the frame's rate
(:func:`streak_votes` at least half of them): a chi-square of 3 degrees of freedom at 1e-3,
the streaks being evidence the noise estimate does not enter (a gyro reading zero while
the stars trail 10 px: a 7-star frame at 1 deg/s has chi^2 30)."""
MIN_CHECK_STARS = 7
"""Fewest matched stars whose shear may contradict a given rate: 6 residual degrees of
freedom for the noise the rate's covariance is scaled by."""
STILL_ELONGATION_PX2 = 1.0
"""Median excess second moment ``sigma_major^2 - sigma_minor^2`` (px^2) of a still frame's
stars: noise and pixelisation make a round star look a little elongated (estcube2 at rest,
``docs/firmware.md``).  A smear ``L`` adds ``L^2 / 12``."""
ROUND_EXCESS_PX2 = 3.0 * STILL_ELONGATION_PX2
"""Largest excess second moment (px^2) of a star that looks round (three times the still
frame's median: a smear up to 6 px hides in the noise and the PSF)."""


@native
def _factor(n, a):
    """Overwrite the symmetric positive-definite ``n x n`` flat row-major ``a`` by its
    Cholesky factor (lower triangle); False when it is not positive definite."""
    for j in range(n):
        jn = j * n
        d = a[jn + j]
        for k in range(j):
            d -= a[jn + k] * a[jn + k]
        if not d > 0:
            return False
        d = math.sqrt(d)
        a[jn + j] = d
        for i in range(j + 1, n):
            i_n = i * n
            s = a[i_n + j]
            for k in range(j):
                s -= a[i_n + k] * a[jn + k]
            a[i_n + j] = s / d
    return True


@native
def _substitute(n, a, h):
    """``x`` with ``L L^T x = h`` for the Cholesky factor ``L`` of :func:`_factor` in ``a``."""
    x = _forward(n, a, h)
    for i in range(n - 1, -1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= a[k * n + i] * x[k]
        x[i] = s / a[i * n + i]
    return x


@native
def _forward(n, a, h):
    """``y`` with ``L y = h`` for the Cholesky factor ``L`` of :func:`_factor` in ``a``."""
    y = list(h)
    for i in range(n):
        s = y[i]
        i_n = i * n
        for k in range(i):
            s -= a[i_n + k] * y[k]
        y[i] = s / a[i_n + i]
    return y


@native
def _back(n, a, y, first):
    """Unknowns ``first..n-1`` of ``x`` with ``L^T x = y`` (``L`` as :func:`_forward`'s):
    the last ones need none of the others."""
    x = list(y)
    for i in range(n - 1, first - 1, -1):
        s = x[i]
        for k in range(i + 1, n):
            s -= a[k * n + i] * x[k]
        x[i] = s / a[i * n + i]
    return x[first:]


def _solve(n, a, h):
    """``x`` with ``a x = h`` for a symmetric positive-definite ``n x n`` ``a`` (a flat row-major
    list, overwritten by its Cholesky factor), or None when it is not positive definite."""
    if not _factor(n, a):
        return None
    return _substitute(n, a, h)


@native
def _columns(c, ax, ay, az, x, rate, radial, rho2):
    """The model's derivatives at catalogue direction ``a`` (camera frame) for a star seen
    ``x`` (scaled) after the reference, written into the flat list ``c`` (3 per unknown):
    three 3-vectors for the attitude's small rotation (``e_j x a``), three for the rate when
    ``rate`` (``-x e_j x a``), two for a radial displacement when ``radial`` (``g`` and
    ``|g|^2 / rho2 g``, ``g = a_z a - z`` pointing away from the boresight, of length the
    sine of the star's angle from it; ``a = (ax, ay, az)``).  No allocation: :func:`_normal`
    calls it per star."""
    c[0] = 0.0
    c[1] = -az
    c[2] = ay
    c[3] = az
    c[4] = 0.0
    c[5] = -ax
    c[6] = -ay
    c[7] = ax
    c[8] = 0.0
    j = 9
    if rate:
        for k in range(9):
            c[j + k] = -x * c[k]
        j = 18
    if radial:
        gx = az * ax
        gy = az * ay
        gz = az * az - 1.0
        k = (gx * gx + gy * gy + gz * gz) / rho2
        c[j] = gx
        c[j + 1] = gy
        c[j + 2] = gz
        c[j + 3] = k * gx
        c[j + 4] = k * gy
        c[j + 5] = k * gz


@native
def _normal(b, r, dts, w, q, omega, tau, rate, radial, rho2):
    """The normal equations of the linearised model at attitude ``q`` and rate ``omega``:
    ``(N, h, chi2)`` with ``N`` ``m x m`` (flat; ``m`` the unknowns of :func:`_columns`),
    ``h`` and ``chi2 = sum w_i |e_i|^2`` of the residuals ``e_i = R(omega dt_i) b_i - A(q)
    r_i`` (the star turned back to the reference instant).  The rate's unknowns are the rate
    times ``tau``.  One pass over the stars, no allocation per star."""
    m = Q.matrix(q)
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = m
    speed = G.norm(omega)
    turn = speed > 0
    ux = uy = uz = 0.0
    if turn:
        ux = omega[0] / speed
        uy = omega[1] / speed
        uz = omega[2] / speed
    size = 3 + (3 if rate else 0) + (2 if radial else 0)
    nn = [0.0] * (size * size)
    h = [0.0] * size
    c = [0.0] * (3 * size)
    chi2 = 0.0
    for i in range(len(b)):
        ri = r[i]
        r0, r1, r2 = ri[0], ri[1], ri[2]
        a0 = m0 * r0 + m1 * r1 + m2 * r2
        a1 = m3 * r0 + m4 * r1 + m5 * r2
        a2 = m6 * r0 + m7 * r1 + m8 * r2
        bi = b[i]
        vx, vy, vz = bi[0], bi[1], bi[2]
        if turn:
            angle = speed * dts[i]
            co = math.cos(angle)
            si = math.sin(angle)
            k = (ux * vx + uy * vy + uz * vz) * (1.0 - co)
            vx, vy, vz = (vx * co + (uy * vz - uz * vy) * si + ux * k,
                          vy * co + (uz * vx - ux * vz) * si + uy * k,
                          vz * co + (ux * vy - uy * vx) * si + uz * k)
        e0 = vx - a0
        e1 = vy - a1
        e2 = vz - a2
        wi = w[i]
        chi2 += wi * (e0 * e0 + e1 * e1 + e2 * e2)
        _columns(c, a0, a1, a2, dts[i] / tau if rate else 0.0, rate, radial, rho2)
        for j in range(size):
            j3 = 3 * j
            c0 = wi * c[j3]
            c1 = wi * c[j3 + 1]
            c2 = wi * c[j3 + 2]
            h[j] += c0 * e0 + c1 * e1 + c2 * e2
            row = j * size
            for kk in range(j, size):
                k3 = 3 * kk
                nn[row + kk] += c0 * c[k3] + c1 * c[k3 + 1] + c2 * c[k3 + 2]
    for j in range(size):
        for kk in range(j):
            nn[j * size + kk] = nn[kk * size + j]
    return nn, h, chi2


@native
def _normal_rate(b, r, dts, w, q, tau):
    """:func:`_normal` of the rate check's form (attitude and rate, no radial terms, the
    stars not turned: ``omega`` zero), from its structure: an attitude column ``j`` is
    ``e_j x a`` and the rate's ``-x`` times it, so the blocks of ``N`` are ``sum w M``, ``-sum
    w x M`` and ``sum w x^2 M`` with ``M = |a|^2 I - a a^T``, and ``h`` is ``sum w (a x e)``
    and ``-sum w x (a x e)``.  About a quarter of :func:`_normal`'s operations per star, in
    18 running sums; the same values to rounding (the check's verdict only reads them)."""
    m0, m1, m2, m3, m4, m5, m6, m7, m8 = Q.matrix(q)
    s00 = s01 = s02 = s11 = s12 = s22 = 0.0          # sum w M
    t00 = t01 = t02 = t11 = t12 = t22 = 0.0          # sum w x M
    u00 = u01 = u02 = u11 = u12 = u22 = 0.0          # sum w x^2 M
    h0 = h1 = h2 = g0 = g1 = g2 = chi2 = 0.0
    for i in range(len(b)):
        ri = r[i]
        r0, r1, r2 = ri[0], ri[1], ri[2]
        ax = m0 * r0 + m1 * r1 + m2 * r2
        ay = m3 * r0 + m4 * r1 + m5 * r2
        az = m6 * r0 + m7 * r1 + m8 * r2
        bi = b[i]
        e0 = bi[0] - ax
        e1 = bi[1] - ay
        e2 = bi[2] - az
        wi = w[i]
        chi2 += wi * (e0 * e0 + e1 * e1 + e2 * e2)
        wx = wi * (dts[i] / tau)
        wxx = wx * (dts[i] / tau)
        xx, yy, zz = ax * ax, ay * ay, az * az
        k00, k11, k22 = yy + zz, xx + zz, xx + yy
        k01, k02, k12 = -ax * ay, -ax * az, -ay * az
        s00 += wi * k00
        s01 += wi * k01
        s02 += wi * k02
        s11 += wi * k11
        s12 += wi * k12
        s22 += wi * k22
        t00 += wx * k00
        t01 += wx * k01
        t02 += wx * k02
        t11 += wx * k11
        t12 += wx * k12
        t22 += wx * k22
        u00 += wxx * k00
        u01 += wxx * k01
        u02 += wxx * k02
        u11 += wxx * k11
        u12 += wxx * k12
        u22 += wxx * k22
        c0 = ay * e2 - az * e1
        c1 = az * e0 - ax * e2
        c2 = ax * e1 - ay * e0
        h0 += wi * c0
        h1 += wi * c1
        h2 += wi * c2
        g0 += wx * c0
        g1 += wx * c1
        g2 += wx * c2
    nn = [s00, s01, s02, -t00, -t01, -t02,
          s01, s11, s12, -t01, -t11, -t12,
          s02, s12, s22, -t02, -t12, -t22,
          -t00, -t01, -t02, u00, u01, u02,
          -t01, -t11, -t12, u01, u11, u12,
          -t02, -t12, -t22, u02, u12, u22]
    return nn, [h0, h1, h2, -g0, -g1, -g2], chi2


def _inverse(n, nn, h):
    """The inverse of an ``n x n`` symmetric positive-definite flat ``nn`` (its columns) and
    ``nn^-1 h``, from one Cholesky factorisation: ``(columns, x)``, or None."""
    a = list(nn)
    if not _factor(n, a):
        return None
    cols = []
    for j in range(n):
        e = [0.0] * n
        e[j] = 1.0
        cols.append(_substitute(n, a, e))
    return cols, _substitute(n, a, h)


@native
def rate_fit(b, r, dts, w, q, min_sigma_rad=0.0, sigma_rad=None, rounds=RATE_ITERATIONS):
    """The attitude at the reference instant and the rate, fitted to matched pairs.

    ``b``: camera-frame unit vectors, each seen ``dts[i]`` s after the reference instant (a
    star's mean instant less the reference; already turned to the reference by a rate
    ``omega0``, if any, so that this fits what remains); ``r``: their catalogue unit vectors;
    ``w``: relative weights (``sigma_i = s / sqrt(w_i)``); ``q``: an attitude near the fit.
    Returns ``(q, omega, P, P_omega, s)``: the attitude at the reference instant, the rate
    (rad/s, camera frame, on top of ``omega0``), the attitude's 3x3 covariance (rad^2, as
    :func:`lodestar.firmware.attitude.covariance`, with the rate's uncertainty in it), the
    rate's (rad^2/s^2) and the per-axis noise ``s`` (rad) of a unit-weight star, estimated from
    the residuals over ``2n - 8`` degrees of freedom (six unknowns; the Student-t correction of
    ``docs/firmware.md``), at least ``min_sigma_rad``; ``sigma_rad``: that noise known (the
    configured ``centroid_sigma_px``), not estimated; ``rounds``: Gauss-Newton rounds before
    the last linearisation (0: one linear solve at ``q`` and no rate).  None with fewer than
    :data:`MIN_RATE_STARS` pairs, without a spread of instants, or when degenerate."""
    if len(b) < MIN_RATE_STARS:
        return None
    out = fit(b, r, dts, w, q, True, False, min_sigma_rad, sigma_rad, rounds)
    return None if out is None else out[:5]


def radial_fit(b, r, dts, w, q, rate, min_sigma_rad=0.0, sigma_rad=None,
               rounds=RATE_ITERATIONS):
    """:func:`rate_fit` (``rate`` True; else the attitude alone) with a radial displacement
    ``(c1 + c3 rho^2 / rho_m^2) g`` of every star as well (``g`` of :func:`_columns`; ``rho_m``
    the stars' RMS angle from the boresight): a lens distortion or focal length the camera
    model lacks.  Returns ``(q, omega, P, P_omega, s, c, P_c)`` (``omega``, ``P_omega`` None
    without ``rate``; ``c = (c1, c3)`` and its covariance), or None with fewer than
    :data:`MIN_RADIAL_STARS` pairs or when degenerate.  ``rounds`` as :func:`rate_fit`
    (:func:`check` gives the verdict alone)."""
    if len(b) < MIN_RADIAL_STARS:
        return None
    return fit(b, r, dts, w, q, rate, True, min_sigma_rad, sigma_rad, rounds)


@native
def check(b, r, dts, w, q, rate, radial, min_sigma_rad=0.0, sigma_rad=None):
    """A verdict of one linear solve at ``q`` (the arguments as :func:`fit`'s, the stars
    not turned): the attitude with the rate (``rate``) and, with ``radial``, the radial
    coefficients; the last unknowns, the radial coefficients with ``radial`` else the rate
    (rad/s: what remains of a given rate the stars were turned by), ``x``, and their
    chi-square against zero, ``x^T P_x^-1 x`` (None for a zero noise): ``(x, chi2)``;
    None with fewer stars than
    :func:`rate_fit` (:func:`radial_fit`) takes, without a spread of instants or when
    degenerate.  The same values as :func:`fit`'s with ``rounds`` 0, to rounding, from
    the Cholesky factor ``L`` of ``N`` alone: with ``y = L^-1 h``, ``x = L_x^-T y_x``
    (``L_x`` the last unknowns' block), ``P_x = s^2 (L_x L_x^T)^-1``, so the chi-square is
    ``|y_x|^2 / s^2``, and the residual is ``sum w |e|^2 - |y|^2``: no inverse, a
    quarter of the operations per star for the rate (:func:`_normal_rate`)."""
    n = len(b)
    if n < (MIN_RADIAL_STARS if radial else MIN_RATE_STARS):
        return None
    tau, rho2 = _scales(b, dts, w)
    if (rate and not tau > 0) or (radial and not rho2 > 0):
        return None
    size = 3 + (3 if rate else 0) + (2 if radial else 0)
    if rate and not radial:
        nn, h, chi2 = _normal_rate(b, r, dts, w, q, tau)
    else:
        nn, h, chi2 = _normal(b, r, dts, w, q, (0.0, 0.0, 0.0), tau, rate, radial, rho2)
    if not _factor(size, nn):
        return None
    y = _forward(size, nn, h)
    last = 2 if radial else 3
    head = size - last
    chi2_x = 0.0
    for j in range(size):
        chi2 -= y[j] * y[j]
        if j >= head:
            chi2_x += y[j] * y[j]
    s2 = _noise2(chi2, n, size, min_sigma_rad, sigma_rad)
    x = _back(size, nn, y, head)
    if not radial:
        x = [v / tau for v in x]
    return x, (chi2_x / s2 if s2 > 0 else None)


@native
def _scales(b, dts, w):
    """``(tau, rho2)``: the stars' weighted RMS instant (s; the rate's unknowns are the rate
    times it) and mean squared sine of their angle from the boresight."""
    total = spread = rho2 = 0.0
    for i in range(len(b)):
        total += w[i]
        spread += w[i] * dts[i] * dts[i]
        z = b[i][2]
        rho2 += 1.0 - z * z
    return (math.sqrt(spread / total) if total > 0 else 0.0), rho2 / len(b)


def _noise2(chi2, n, size, min_sigma_rad, sigma_rad):
    """The per-axis noise variance of a unit-weight star (rad^2): the residual ``chi2`` over
    ``2n - size - 2`` degrees of freedom (``docs/firmware.md``), or ``sigma_rad`` squared,
    at least ``min_sigma_rad`` squared."""
    s2 = chi2 / max(2 * n - size - 2, 1) if sigma_rad is None else sigma_rad * sigma_rad
    return s2 if s2 >= min_sigma_rad * min_sigma_rad else min_sigma_rad * min_sigma_rad


@native
def fit(b, r, dts, w, q, rate, radial, min_sigma_rad=0.0, sigma_rad=None,
        rounds=RATE_ITERATIONS):
    """The Gauss-Newton fit behind :func:`rate_fit` and :func:`radial_fit` (their arguments;
    ``rate``, ``radial``: which unknowns besides the attitude; ``rounds``: Gauss-Newton
    rounds before the last linearisation, whose solution is then applied too)."""
    n = len(b)
    tau, rho2 = _scales(b, dts, w)
    if (rate and not tau > 0) or (radial and not rho2 > 0):
        return None
    size = 3 + (3 if rate else 0) + (2 if radial else 0)
    omega = (0.0, 0.0, 0.0)
    for k in range(rounds + 1):
        nn, h, chi2 = _normal(b, r, dts, w, q, omega, tau, rate, radial, rho2)
        if k == rounds:
            break
        u = _solve(size, list(nn), h)
        if u is None:
            return None
        q = Q.normalise(Q.multiply(Q.from_rotation_vector((u[0], u[1], u[2])), q))
        if rate:
            omega = (omega[0] + u[3] / tau, omega[1] + u[4] / tau, omega[2] + u[5] / tau)
    # the covariance, and what the last linearisation still takes out
    out = _inverse(size, nn, h)
    if out is None:
        return None
    cols, d = out
    for j in range(size):
        chi2 -= h[j] * d[j]
    if rounds == 0:         # the one linear solve is the fit: apply it
        q = Q.normalise(Q.multiply(Q.from_rotation_vector((d[0], d[1], d[2])), q))
        if rate:
            omega = (d[3] / tau, d[4] / tau, d[5] / tau)
    s2 = _noise2(chi2, n, size, min_sigma_rad, sigma_rad)
    p = [[s2 * cols[j][i] for j in range(3)] for i in range(3)]
    p_omega = c = p_c = None
    if rate:
        t2 = tau * tau
        p_omega = [[s2 * cols[3 + j][3 + i] / t2 for j in range(3)] for i in range(3)]
    if radial:
        c = (d[size - 2], d[size - 1])
        p_c = [[s2 * cols[size - 2 + j][size - 2 + i] for j in range(2)] for i in range(2)]
    return q, omega if rate else None, p, p_omega, math.sqrt(s2), c, p_c


def rate_chi2_limit(n):
    """The :data:`RATE_CHI2` limit for a rate fitted to ``n`` stars (None below
    :data:`MIN_CHECK_STARS`)."""
    if n < MIN_CHECK_STARS:
        return None
    d = 2 * n - 8
    limit = None
    for dof, value in RATE_CHI2:
        if dof > d:
            break
        limit = value
    return limit


def chi2_rate(v, p):
    """``v^T P^-1 v`` of a difference ``v`` (a rate, or the radial coefficients) with
    covariance ``p`` (``len(v)`` square), or None when ``p`` is singular."""
    n = len(v)
    x = _solve(n, [p[i][j] for i in range(n) for j in range(n)], v)
    if x is None:
        return None
    total = 0.0
    for i in range(n):
        total += v[i] * x[i]
    return total


def smear_bound_px(moments):
    """The longest smear (px) the stars' second moments allow, from the median excess
    ``sigma_major^2 - sigma_minor^2`` over the still frame's (:data:`STILL_ELONGATION_PX2`):
    ``sqrt(12 (excess + STILL_ELONGATION_PX2))``, so a still frame bounds its smear by about
    3.5 px.  ``moments``: ``(sigma_major, sigma_minor, ...)`` per star; None without any."""
    excess = []
    for m in moments:
        excess.append(m[0] * m[0] - m[1] * m[1])
    if not excess:
        return None
    median = _median(excess)
    if median < 0:
        median = 0.0
    return math.sqrt(12.0 * (median + STILL_ELONGATION_PX2))


def _median(values):
    v = sorted(values)
    k = len(v)
    return v[k // 2] if k % 2 else 0.5 * (v[k // 2 - 1] + v[k // 2])


def smear_vector(v, omega, scale):
    """The pixel displacement ``(dx, dy)`` over the exposure of a star at camera-frame unit
    vector ``v`` under the rate ``omega`` (rad/s): ``dv/dt = -omega x v`` through a pinhole
    of ``scale`` = focal length (px) times exposure (s)."""
    x, y, z = v
    wx, wy, wz = omega
    dx = wz * y - wy * z
    dy = wx * z - wz * x
    dz = wy * x - wx * y
    k = scale / (z * z)
    return k * (dx * z - x * dz), k * (dy * z - y * dz)


def visible(stars, d, scale):
    """Whether a rate difference ``d`` (rad/s) moves the median of ``stars`` (``(v,
    moments)`` pairs: camera-frame unit vector and ``(sigma_major, sigma_minor,
    orientation)``) by more than their median ``sigma_minor`` (the PSF's second moment, px)
    over the exposure (``scale`` of :func:`smear_vector`): a difference the streaks could
    show."""
    moved = []
    width = []
    for v, m in stars:
        u = smear_vector(v, d, scale)
        moved.append(math.sqrt(u[0] * u[0] + u[1] * u[1]))
        width.append(m[1])
    return _median(moved) > _median(width)


def explains(m, u):
    """Whether the smear ``u`` (px over the exposure) explains a star's second moments ``m``
    (``(sigma_major, sigma_minor, orientation)``): a smear whose excess ``|u|^2 / 12`` is
    within :data:`ROUND_EXCESS_PX2` a star that looks round (its excess ``sigma_major^2 -
    sigma_minor^2`` within it too), a longer one a streak along it within a factor 2 of its
    length (:func:`lodestar.firmware.centroids.smear_consistent`: thresholding shortens a
    faint streak)."""
    if (u[0] * u[0] + u[1] * u[1]) / 12.0 <= ROUND_EXCESS_PX2:
        return m[0] * m[0] - m[1] * m[1] <= ROUND_EXCESS_PX2
    return centroids.smear_consistent(m[0], m[1], m[2], u)


def streak_votes(stars, gyro, frame, scale):
    """How many of ``stars`` (as :func:`visible`) have a streak (second moments) the rate
    ``frame`` explains and ``gyro`` does not (:func:`explains`), less how many the reverse:
    negative when the streaks side with the gyro.  A sign error ties (a streak has no
    sense)."""
    votes = 0
    for v, m in stars:
        g = explains(m, smear_vector(v, gyro, scale))
        if explains(m, smear_vector(v, frame, scale)) != g:
            votes += -1 if g else 1
    return votes
