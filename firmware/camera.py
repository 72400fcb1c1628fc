"""Camera model of the MCU: pixel <-> camera-frame unit vector, pinhole + Brown-Conrady.

:class:`Camera` (``pixel_to_vector``, ``vector_to_pixel``, ``smear_px``) is the model of
``lodestar.sim.camera.Camera`` (the tests hold the two together to 1e-6 rad): Bouguet's
distortion ``k1, k2, k3, p1, p2``, focal lengths and principal point in pixels, frames and
pixel centres as in ``docs/conventions.md``.  The inverse is a Newton iteration accepted only
if it reproduces the pixel inside :meth:`Camera.fold_radius`.  Invalid camera parameters raise
``ValueError`` at construction (configuration time); pixel and vector calls never raise on
numbers: they return None (``last_status`` then says why, a ``lodestar.firmware.status``
code).  Formulas: ``docs/centroids_and_tracking.md`` (Camera model).  Pure Python for CPython
and MicroPython, single- or double-precision floats.
"""

import math

from lodestar.contract import detection
from lodestar.firmware import status as S
from lodestar.firmware.geometry import EPS, finite, is_number, norm

from .emit import native

_INF = float("inf")

NEWTON_MAX_ITER = 50
NEWTON_STEP_PX = 1e-11
"""Newton stops when a step is below this many pixels (or the float resolution)."""
NEWTON_RESIDUAL_PX = 1e-9
"""A converged point reproduces its pixel to this many pixels (or the float resolution)."""
BORDER_SAMPLES = 65
"""Points per frame edge checked for invertibility at construction (as ``lodestar.sim``)."""

_PARAMS = ("width", "height", "fx", "fy", "cx", "cy", "k1", "k2", "k3", "p1", "p2")
_ALIASES = {"fx_px": "fx", "fy_px": "fy"}


def _number(name, value):
    if not is_number(value):
        raise ValueError("{} must be a finite number, got {!r}".format(name, value))
    return float(value)


def _smallest_positive_root(c0, c1, c2, c3):
    """Smallest ``s > 0`` with ``c0 + c1 s + c2 s^2 + c3 s^3 = 0`` given ``c0 > 0``, else None.

    The derivative's roots split ``s > 0`` into monotone pieces; the first piece whose end
    is not positive holds the root, found by bisection.
    """
    def p(s):
        return c0 + s * (c1 + s * (c2 + s * c3))

    # critical points: c1 + 2 c2 s + 3 c3 s^2 = 0
    crit = []
    a, b, c = 3.0 * c3, 2.0 * c2, c1
    if a != 0:
        disc = b * b - 4 * a * c
        if disc >= 0:
            r = math.sqrt(disc)
            crit = [(-b - r) / (2 * a), (-b + r) / (2 * a)]
    elif b != 0:
        crit = [-c / b]
    ends = sorted(s for s in crit if s > 0)
    lo = 0.0
    for hi in ends:
        if p(hi) <= 0:
            break
        lo = hi
    else:
        # last piece [lo, inf): a root exists iff p eventually goes negative
        lead = c3 if c3 != 0 else (c2 if c2 != 0 else c1)
        if lead >= 0:
            return None
        hi = max(lo, 1.0)
        while p(hi) > 0:
            hi *= 2.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        if mid <= lo or mid >= hi:
            break
        if p(mid) > 0:
            lo = mid
        else:
            hi = mid
    return hi


class Camera(object):
    """Pinhole + Brown-Conrady (Bouguet) camera from plain numbers (model:
    ``docs/centroids_and_tracking.md``).

    ``width``, ``height`` in pixels; ``fx``, ``fy`` focal lengths in pixels; ``cx``, ``cy``
    principal point (default: the geometric centre ``((W-1)/2, (H-1)/2)``); ``k1 k2 k3``
    radial and ``p1 p2`` tangential coefficients.  Raises ``ValueError`` naming the parameter
    for an invalid value, or when the distortion is not invertible over the frame.
    """

    def __init__(self, width, height, fx, fy, cx=None, cy=None, k1=0.0, k2=0.0, k3=0.0,
                 p1=0.0, p2=0.0):
        for name, value, limit in (("width", width, detection.MAX_WIDTH),
                                   ("height", height, detection.MAX_HEIGHT)):
            if isinstance(value, bool) or not isinstance(value, int) or not \
                    1 <= value <= limit:
                raise ValueError("{} must be an int in 1..{}, got {!r}".format(
                    name, limit, value))
        self.width = width
        self.height = height
        self.fx = _number("fx", fx)
        self.fy = _number("fy", fy)
        if self.fx <= 0 or self.fy <= 0:
            raise ValueError("fx and fy must be > 0, got {} and {}".format(fx, fy))
        self.cx = (width - 1) / 2 if cx is None else _number("cx", cx)
        self.cy = (height - 1) / 2 if cy is None else _number("cy", cy)
        self.k1 = _number("k1", k1)
        self.k2 = _number("k2", k2)
        self.k3 = _number("k3", k3)
        self.p1 = _number("p1", p1)
        self.p2 = _number("p2", p2)
        self.last_status = S.OK
        self._pinhole = not (self.k1 or self.k2 or self.k3 or self.p1 or self.p2)
        self._smear_key = None          # (wx, wy, wz, exposure_s) of _smear
        self._smear = None              # smear_function of the last smear_px call's rate
        s = _smallest_positive_root(1.0, 3 * self.k1, 5 * self.k2, 7 * self.k3)
        self._fold = _INF if s is None else math.sqrt(s)
        # float-resolution floors of the Newton tolerances (pixels)
        scale = max(self.fx, self.fy)
        self._step_px = max(NEWTON_STEP_PX, 4 * EPS * scale)
        self._residual_px = max(NEWTON_RESIDUAL_PX, 64 * EPS * scale)
        self._check_border()

    @classmethod
    def from_dict(cls, params):
        """A camera from a dict: the constructor's names, or the ``lodestar.sim`` preset
        names (``fx_px``, ``fy_px``); other keys are ignored, so a preset's whole ``camera``
        block can be passed."""
        kwargs = {}
        for key in params:
            name = _ALIASES.get(key, key)
            if name in _PARAMS:
                if name in kwargs:
                    raise ValueError("{} given twice".format(name))
                kwargs[name] = params[key]
        for name in ("width", "height", "fx", "fy"):
            if name not in kwargs:
                raise ValueError("camera parameter {} is missing".format(name))
        return cls(**kwargs)

    def as_dict(self):
        """The constructor's parameters as a dict (``from_dict(cam.as_dict())`` is ``cam``)."""
        out = {}
        for name in _PARAMS:
            out[name] = getattr(self, name)
        return out

    def __repr__(self):
        return "Camera({})".format(", ".join(
            "{}={!r}".format(name, getattr(self, name)) for name in _PARAMS))

    # ---- distortion ---------------------------------------------------------------------

    def fold_radius(self):
        """Normalised radius where ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` stops increasing
        (``inf`` if it never does)."""
        return self._fold

    def distort(self, x, y):
        """Distorted normalised coordinates ``(xd, yd)`` of ``(x, y) = (X/Z, Y/Z)``."""
        r2 = x * x + y * y
        radial = 1.0 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        xd = x * radial + 2.0 * self.p1 * x * y + self.p2 * (r2 + 2.0 * x * x)
        yd = y * radial + self.p1 * (r2 + 2.0 * y * y) + 2.0 * self.p2 * x * y
        return xd, yd

    def _distort_jacobian(self, x, y):
        """``(xd, yd, dxd/dx, dxd/dy (= dyd/dx), dyd/dy)``."""
        k1, k2, k3, p1, p2 = self.k1, self.k2, self.k3, self.p1, self.p2
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        dradial = k1 + r2 * (2.0 * k2 + 3.0 * k3 * r2)        # d radial / d r^2
        xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
        yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
        jxx = radial + 2.0 * x * x * dradial + 2.0 * p1 * y + 6.0 * p2 * x
        jxy = 2.0 * x * y * dradial + 2.0 * p1 * x + 2.0 * p2 * y
        jyy = radial + 2.0 * y * y * dradial + 6.0 * p1 * y + 2.0 * p2 * x
        return xd, yd, jxx, jxy, jyy

    def undistort(self, xd, yd):
        """Normalised ``(x, y)`` whose distortion is ``(xd, yd)``, or None (``last_status``
        is ``CAMERA_NOT_CONVERGED`` or ``BAD_INPUT``)."""
        if not (finite(xd) and finite(yd)):
            self.last_status = S.BAD_INPUT
            return None
        if self._pinhole:               # no distortion: Newton would stop at (xd, yd)
            self.last_status = S.OK
            return xd, yd
        fx, fy = self.fx, self.fy
        x, y = xd, yd
        for _ in range(NEWTON_MAX_ITER):
            ex_d, ey_d, jxx, jxy, jyy = self._distort_jacobian(x, y)
            ex = ex_d - xd
            ey = ey_d - yd
            det = jxx * jyy - jxy * jxy
            if not det > 0:              # also catches NaN
                break
            dx = (jyy * ex - jxy * ey) / det
            dy = (jxx * ey - jxy * ex) / det
            x -= dx
            y -= dy
            if not (abs(dx) * fx > self._step_px or abs(dy) * fy > self._step_px):
                break                   # converged, or NaN (caught below)
        ex_d, ey_d, jxx, jxy, jyy = self._distort_jacobian(x, y)
        residual = max(abs(ex_d - xd) * fx, abs(ey_d - yd) * fy)
        if not (residual <= self._residual_px and jxx * jyy - jxy * jxy > 0
                and math.sqrt(x * x + y * y) < self._fold):
            self.last_status = S.CAMERA_NOT_CONVERGED
            return None
        self.last_status = S.OK
        return x, y

    # ---- pixel <-> vector ---------------------------------------------------------------

    @native
    def pixel_to_vector(self, x, y):
        """Unit vector ``(X, Y, Z)`` (camera frame) of pixel ``(x, y)``, or None when the
        undistortion fails (``last_status`` says why)."""
        if not (is_number(x) and is_number(y)):
            self.last_status = S.BAD_INPUT
            return None
        xn = (x - self.cx) / self.fx
        yn = (y - self.cy) / self.fy
        if self._pinhole:               # undistort would return (xn, yn) itself
            self.last_status = S.OK
        else:
            xy = self.undistort(xn, yn)
            if xy is None:
                return None
            xn, yn = xy
        norm = math.sqrt(xn * xn + yn * yn + 1.0)
        return xn / norm, yn / norm, 1.0 / norm

    def vector_to_pixel(self, v):
        """Pixel ``(x, y)`` of camera-frame direction ``v`` (any length), or None when it is
        behind the camera (``Z <= 0``) or beyond the fold radius (``CAMERA_OUT_OF_VIEW``), or
        not three finite numbers (``BAD_INPUT``).  The pixel may lie outside the frame:
        see :meth:`in_frame`."""
        try:
            X, Y, Z = v[0], v[1], v[2]
        except (TypeError, IndexError, KeyError):
            self.last_status = S.BAD_INPUT
            return None
        if not (is_number(X) and is_number(Y) and is_number(Z)):
            self.last_status = S.BAD_INPUT
            return None
        return self._project(X, Y, Z)

    @native
    def _project(self, X, Y, Z):
        """:meth:`vector_to_pixel` of finite numbers."""
        if not Z > 0:
            self.last_status = S.CAMERA_OUT_OF_VIEW
            return None
        xn = X / Z
        yn = Y / Z
        if not math.sqrt(xn * xn + yn * yn) < self._fold:
            self.last_status = S.CAMERA_OUT_OF_VIEW
            return None
        xd, yd = self.distort(xn, yn) if not self._pinhole else (xn, yn)
        self.last_status = S.OK
        return self.cx + self.fx * xd, self.cy + self.fy * yd

    def in_frame(self, x, y):
        """True iff pixel ``(x, y)`` lies in the frame ``[-0.5, W-0.5) x [-0.5, H-0.5)``."""
        return -0.5 <= x < self.width - 0.5 and -0.5 <= y < self.height - 0.5

    def smear_px(self, x, y, omega, exposure_s):
        """Expected smear ``(dx, dy)`` in pixels of a star centred at ``(x, y)``.

        ``omega``: the camera's angular velocity ``(wx, wy, wz)`` in the camera frame, rad/s;
        a fixed star moves as ``dv/dt = -omega x v`` (``lodestar.sim`` convention).  The
        track runs from the direction at ``-exposure_s/2`` to ``+exposure_s/2`` about the
        centroid's, rotated exactly (Rodrigues).  None (and ``last_status``) for non-numbers,
        or when the pixel or either end leaves the model.
        """
        try:
            key = (omega[0], omega[1], omega[2], exposure_s)
        except (TypeError, IndexError, KeyError):
            key = None
        if key != self._smear_key:      # the turn is the frame's: computed once per rate
            self._smear = self.smear_function(omega, exposure_s)
            self._smear_key = key
        if self._smear is None or not (is_number(x) and is_number(y)):
            self.last_status = S.BAD_INPUT
            return None
        return self._smear(x, y)

    def smear_function(self, omega, exposure_s):
        """``smear(x, y)``: :meth:`smear_px` at ``omega`` and ``exposure_s`` for a pixel whose
        coordinates are numbers, the turn computed once (a frame's stars share it, and the
        flight pipeline calls it without checking each star's arguments again); None when
        ``omega`` is not three numbers or ``exposure_s`` not a number."""
        try:
            wx, wy, wz = omega[0], omega[1], omega[2]
        except (TypeError, IndexError, KeyError):
            return None
        if not (is_number(wx) and is_number(wy) and is_number(wz) and is_number(exposure_s)):
            return None
        rate = norm((wx, wy, wz))
        turn = rate > 0
        if turn:
            half = 0.5 * rate * exposure_s
            ax, ay, az = wx / rate, wy / rate, wz / rate
            c, s = math.cos(half), math.sin(half)
        pinhole = self._pinhole
        cx, cy, fx, fy = self.cx, self.cy, self.fx, self.fy

        @native
        def smear(x, y):
            if pinhole:
                # a homogeneous direction: the turn is linear and the projection divides by Z
                vx, vy, vz = (x - cx) / fx, (y - cy) / fy, 1.0
            else:
                v = self.pixel_to_vector(x, y)
                if v is None:
                    return None
                vx, vy, vz = v
            if not turn:
                return 0.0, 0.0
            # v turned by +half (earlier: rotated back) and -half about the axis (Rodrigues,
            # as geometry.rotate_about)
            k = (ax * vx + ay * vy + az * vz) * (1.0 - c)
            kx, ky, kz = ax * k, ay * k, az * k
            px, py, pz = vx * c, vy * c, vz * c
            tx = (ay * vz - az * vy) * s
            ty = (az * vx - ax * vz) * s
            tz = (ax * vy - ay * vx) * s
            sx, sy, sz = px + tx + kx, py + ty + ky, pz + tz + kz
            ex, ey, ez = px - tx + kx, py - ty + ky, pz - tz + kz
            if pinhole:                 # _project without its checks (no fold radius)
                if not (sz > 0 and ez > 0):
                    self.last_status = S.CAMERA_OUT_OF_VIEW
                    return None
                self.last_status = S.OK
                return fx * (ex / ez - sx / sz), fy * (ey / ez - sy / sz)
            start = self._project(sx, sy, sz)
            end = self._project(ex, ey, ez)
            if start is None or end is None:
                return None
            return end[0] - start[0], end[1] - start[1]
        return smear

    @native
    def pixel_tangent(self, x, y, ex, ey):
        """``(ux, uy, uz, rad_per_px)``: the camera-frame unit tangent of the direction of
        pixel ``(x, y)`` as the pixel moves along the unit ``(ex, ey)``, and how many radians
        one pixel of that move turns it; None when the model does not invert the pixel.  A
        pinhole's is the derivative of ``p / |p|``, ``p = ((x - cx) / fx, (y - cy) / fy, 1)``;
        with distortion, the difference over one pixel."""
        if self._pinhole:
            xn = (x - self.cx) / self.fx
            yn = (y - self.cy) / self.fy
            dx = ex / self.fx
            dy = ey / self.fy
            r2 = xn * xn + yn * yn + 1.0
            a = (xn * dx + yn * dy) / r2
            tx, ty, tz = dx - xn * a, dy - yn * a, -a        # |p| times the derivative
            r = math.sqrt(r2)
        else:
            v0 = self.pixel_to_vector(x, y)
            v1 = self.pixel_to_vector(x + ex, y + ey)
            if v0 is None or v1 is None:
                return None
            tx, ty, tz = v1[0] - v0[0], v1[1] - v0[1], v1[2] - v0[2]
            r = 1.0
        t = math.sqrt(tx * tx + ty * ty + tz * tz)
        if not t > 0:
            return None
        return tx / t, ty / t, tz / t, t / r

    # ---- construction check ---------------------------------------------------------------

    def _check_border(self):
        """Every sampled point of the frame's outer edge must undistort (as lodestar.sim)."""
        w, h = self.width, self.height
        n = BORDER_SAMPLES
        for i in range(n):
            t = i / (n - 1)
            xs = -0.5 + t * w
            ys = -0.5 + t * h
            for px, py in ((xs, -0.5), (xs, h - 0.5), (-0.5, ys), (w - 0.5, ys)):
                if self.pixel_to_vector(px, py) is None:
                    raise ValueError(
                        "distortion k1={}, k2={}, k3={}, p1={}, p2={} is not invertible "
                        "over the frame (pixel ({}, {}))".format(
                            self.k1, self.k2, self.k3, self.p1, self.p2, px, py))
        self.last_status = S.OK
