"""Camera models: pinhole + Brown–Conrady distortion (:class:`Camera`) and Dzamba's inverse model.

Both models map between pixel coordinates and unit direction vectors in the **camera frame** of
``lodestar.sim`` (``+z`` boresight, ``+x`` along increasing column ``x``, ``+y`` along increasing
row ``y``; pixel centres at integer indices, as in ``lodestar.contract``).  The frame is the
half-open box ``[-0.5, W - 0.5) x [-0.5, H - 0.5)``.

:class:`Camera` carries the geometry (focal lengths in pixels, principal point, Bouguet
distortion) together with the optics and sensor numbers the image simulator needs (aperture,
quantum efficiency, noise, gain, shutter, exposure).  :class:`DzambaCamera` is the 8-parameter
inverse model of the ST-16 star tracker (Dzamba 2013, section 3.1.1), with the printed errata
fixed; see its docstring.
"""

import math
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from lodestar import contract as C

SHUTTERS = ("rolling", "global")
"""Shutter types: ``rolling`` (row ``r`` starts its exposure ``r * row_time_s`` after row 0) and
``global`` (all rows expose together)."""

FOCAL_LENGTH_TOLERANCE = 0.10
"""Largest relative difference allowed between ``fx_px * pixel_pitch`` (or ``fy``) and the
nominal ``focal_length_mm``: calibrated focal lengths differ from the nameplate by a few per
cent (Lohmann 8.63 mm vs 8.5 mm), a unit mistake by orders of magnitude."""

_NEWTON_MAX_ITER = 50
_NEWTON_STEP_PX = 1e-11      # stop when every Newton step is below this many pixels
_NEWTON_RESIDUAL_PX = 1e-9   # a converged point reproduces its pixel to this many pixels
_BORDER_SAMPLES = 65         # points per frame edge used to check invertibility and FOV


# --------------------------------------------------------------------------------------
# Validation helpers: every failure names the field
# --------------------------------------------------------------------------------------

def _require_int(name, value, lo, hi):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an int, got {value!r}")
    if not lo <= value <= hi:
        raise ValueError(f"{name}={value} is out of range {lo}..{hi}")


def _require_number(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} must be a number, got {value!r}")
    if not math.isfinite(value):
        raise ValueError(f"{name}={value} is not finite")


def _require_positive(name, value):
    _require_number(name, value)
    if value <= 0:
        raise ValueError(f"{name}={value} must be > 0")


def _require_non_negative(name, value):
    _require_number(name, value)
    if value < 0:
        raise ValueError(f"{name}={value} must be >= 0")


def _require_inside(name, value, size, axis):
    _require_number(name, value)
    if not -0.5 <= value < size - 0.5:
        raise ValueError(f"{name}={value} is outside the sensor ({axis} range "
                         f"[-0.5, {size - 0.5}))")


def _as_directions(v):
    """``v`` as a float array of shape ``(..., 3)``; NaN, inf or zero vectors raise."""
    v = np.asarray(v, dtype=float)
    if v.ndim == 0 or v.shape[-1] != 3:
        raise ValueError(f"direction vectors must have shape (..., 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise ValueError("direction vectors contain NaN or inf")
    if np.any(np.all(v == 0, axis=-1)):
        raise ValueError("direction vectors contain a zero vector")
    return v


def _as_pixels(x, y):
    """``x`` and ``y`` broadcast to float arrays of one shape; NaN or inf raise."""
    x, y = np.broadcast_arrays(np.asarray(x, dtype=float), np.asarray(y, dtype=float))
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise ValueError("pixel coordinates contain NaN or inf")
    return x, y


def _angle(a, b):
    """Angle in radians between the rows of ``a`` and ``b`` (accurate at small angles)."""
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def _in_frame(x, y, width, height):
    with np.errstate(invalid="ignore"):
        return (x >= -0.5) & (x < width - 0.5) & (y >= -0.5) & (y < height - 0.5)


def _border(width, height, n=_BORDER_SAMPLES):
    """Points along the frame's outer edge, including the four corners."""
    xs = np.linspace(-0.5, width - 0.5, n)
    ys = np.linspace(-0.5, height - 0.5, n)
    x = np.concatenate([xs, xs, np.full(n, -0.5), np.full(n, width - 0.5)])
    y = np.concatenate([np.full(n, -0.5), np.full(n, height - 0.5), ys, ys])
    return x, y


# --------------------------------------------------------------------------------------
# Pinhole + Brown–Conrady camera
# --------------------------------------------------------------------------------------

@dataclass(frozen=True, kw_only=True)
class Camera:
    """A star camera: pinhole + Brown–Conrady (Bouguet) geometry, optics and sensor model.

    Geometry (pixels).  A camera-frame direction ``(X, Y, Z)`` with ``Z > 0`` has normalised
    coordinates ``x = X/Z, y = Y/Z``, ``r^2 = x^2 + y^2``; Bouguet's distortion (the
    MATLAB Camera Calibration Toolbox model Lohmann 2017 used, L857-865) gives::

        x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) + 2 p1 x y + p2 (r^2 + 2 x^2)
        y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) + p1 (r^2 + 2 y^2) + 2 p2 x y

    and the pixel is ``(cx + fx_px x_d, cy + fy_px y_d)``.  Bouguet's camera frame (x right
    along columns, y down along rows, z forward) is ours, so calibrated coefficients apply
    unchanged.  ``cx``, ``cy`` default to the geometric centre ``((W-1)/2, (H-1)/2)``.

    Optics and sensor: ``focal_length_mm`` is the nominal (nameplate) focal length,
    ``aperture_mm`` the entrance-pupil diameter (``f_number`` is derived from the two),
    ``pixel_pitch_um`` the pixel size; ``qe`` the quantum efficiency in (0, 1]; ``read_noise_e``
    the read noise (electrons RMS); ``gain_adu_per_e`` the conversion gain (ADU per electron);
    ``full_well_e`` the pixel capacity (electrons); ``adc_offset_adu`` the black level added
    before quantisation (ADU); ``dark_current_e_per_s`` (electrons per pixel per second);
    ``shutter`` one of :data:`SHUTTERS` and ``row_time_s`` its line time (s, rolling shutter
    offset between consecutive rows); ``psf_sigma_px`` the default Gaussian defocus sigma
    (pixels); ``exposure_s`` the default exposure (s).  ``meta`` holds preset extras (board,
    FPGA, sources, reserved codes ...); it takes no part in comparisons.

    Every invalid value raises ``ValueError`` naming the field, including distortion that is
    not invertible over the frame.
    """

    width: int
    height: int
    pixel_bits: int
    pixel_pitch_um: float
    focal_length_mm: float
    aperture_mm: float
    fx_px: float
    fy_px: float
    qe: float
    read_noise_e: float
    gain_adu_per_e: float
    full_well_e: float
    adc_offset_adu: float
    dark_current_e_per_s: float
    shutter: str
    row_time_s: float
    psf_sigma_px: float
    exposure_s: float
    cx: float | None = None
    cy: float | None = None
    k1: float = 0.0
    k2: float = 0.0
    k3: float = 0.0
    p1: float = 0.0
    p2: float = 0.0
    name: str = "custom"
    meta: MappingProxyType = field(default_factory=dict, compare=False, repr=False)

    def __post_init__(self):
        _require_int("width", self.width, 1, C.MAX_WIDTH)
        _require_int("height", self.height, 1, C.MAX_HEIGHT)
        if self.cx is None:
            object.__setattr__(self, "cx", (self.width - 1) / 2)
        if self.cy is None:
            object.__setattr__(self, "cy", (self.height - 1) / 2)
        object.__setattr__(self, "meta", MappingProxyType(dict(self.meta)))
        if self.pixel_bits not in C.PIXEL_BITS:
            raise ValueError(f"pixel_bits={self.pixel_bits!r} is not one of {C.PIXEL_BITS}")
        for name in ("pixel_pitch_um", "focal_length_mm", "aperture_mm", "fx_px", "fy_px",
                     "gain_adu_per_e", "full_well_e", "psf_sigma_px", "exposure_s"):
            _require_positive(name, getattr(self, name))
        for name in ("read_noise_e", "adc_offset_adu", "dark_current_e_per_s", "row_time_s"):
            _require_non_negative(name, getattr(self, name))
        for name in ("k1", "k2", "k3", "p1", "p2"):
            _require_number(name, getattr(self, name))
        for name in ("fx_px", "fy_px"):
            f_mm = getattr(self, name) * self.pixel_pitch_um * 1e-3
            if abs(f_mm / self.focal_length_mm - 1) > FOCAL_LENGTH_TOLERANCE:
                raise ValueError(
                    f"{name}={getattr(self, name)} px x {self.pixel_pitch_um} um = {f_mm:.4g} mm "
                    f"disagrees with focal_length_mm={self.focal_length_mm} by more than "
                    f"{FOCAL_LENGTH_TOLERANCE:.0%}")
        _require_inside("cx", self.cx, self.width, "column")
        _require_inside("cy", self.cy, self.height, "row")
        _require_number("qe", self.qe)
        if not 0 < self.qe <= 1:
            raise ValueError(f"qe={self.qe} is outside (0, 1]")
        if self.adc_offset_adu >= self.full_scale_adu:
            raise ValueError(f"adc_offset_adu={self.adc_offset_adu} must be below the "
                             f"{self.pixel_bits}-bit full scale {self.full_scale_adu}")
        if self.shutter not in SHUTTERS:
            raise ValueError(f"shutter={self.shutter!r} is not one of {SHUTTERS}")
        if self.shutter == "rolling" and self.row_time_s <= 0:
            raise ValueError(f"row_time_s={self.row_time_s} must be > 0 for a rolling shutter")
        try:
            self.unproject(*_border(self.width, self.height))
        except ValueError as err:
            raise ValueError(
                f"distortion k1={self.k1}, k2={self.k2}, k3={self.k3}, p1={self.p1}, "
                f"p2={self.p2} is not invertible over the frame ({err})") from None

    # ---- derived numbers --------------------------------------------------------------

    @property
    def f_number(self):
        """Focal ratio ``focal_length_mm / aperture_mm``."""
        return self.focal_length_mm / self.aperture_mm

    @property
    def full_scale_adu(self):
        """Largest pixel value (saturation code) of the ADC."""
        return C.full_scale(self.pixel_bits)

    def plate_scale_arcsec(self):
        """Angular size of one pixel at the principal point, ``(along x, along y)``, arcsec."""
        to_arcsec = 180 / math.pi * 3600
        return (math.atan(1 / self.fx_px) * to_arcsec, math.atan(1 / self.fy_px) * to_arcsec)

    # ---- distortion on normalised coordinates -----------------------------------------

    def _distort_with_jacobian(self, x, y):
        """Distorted ``(xd, yd)`` and the symmetric Jacobian ``(dxd/dx, dxd/dy, dyd/dy)``."""
        r2 = x * x + y * y
        radial = 1 + r2 * (self.k1 + r2 * (self.k2 + r2 * self.k3))
        dradial = self.k1 + r2 * (2 * self.k2 + 3 * self.k3 * r2)  # d radial / d r^2
        xd = x * radial + 2 * self.p1 * x * y + self.p2 * (r2 + 2 * x * x)
        yd = y * radial + self.p1 * (r2 + 2 * y * y) + 2 * self.p2 * x * y
        jxx = radial + 2 * x * x * dradial + 2 * self.p1 * y + 6 * self.p2 * x
        jxy = 2 * x * y * dradial + 2 * self.p1 * x + 2 * self.p2 * y  # = dyd/dx
        jyy = radial + 2 * y * y * dradial + 6 * self.p1 * y + 2 * self.p2 * x
        return xd, yd, jxx, jxy, jyy

    def fold_radius(self):
        """Normalised radius where the radial map ``r (1 + k1 r^2 + k2 r^4 + k3 r^6)`` stops
        increasing (``inf`` if it never does).  Points beyond it are not imaged uniquely."""
        # d/dr [r (1 + k1 r^2 + k2 r^4 + k3 r^6)] = 1 + 3 k1 s + 5 k2 s^2 + 7 k3 s^3, s = r^2
        roots = np.roots(np.trim_zeros([7 * self.k3, 5 * self.k2, 3 * self.k1, 1.0], "f"))
        s = [r.real for r in roots if abs(r.imag) <= 1e-12 * abs(r) and r.real > 0]
        return math.sqrt(min(s)) if s else math.inf

    def distort_normalized(self, x, y):
        """Apply the distortion to normalised coordinates ``(X/Z, Y/Z)``; returns ``(xd, yd)``."""
        xd, yd, *_ = self._distort_with_jacobian(*_as_pixels(x, y))
        return xd, yd

    def undistort_normalized(self, xd, yd):
        """Invert :meth:`distort_normalized` by 2-D Newton iteration with the analytic Jacobian.

        Converges to ``1e-9`` px (measured in pixels through ``fx_px``, ``fy_px``).  Raises
        ``ValueError`` for points that do not converge or lie beyond :meth:`fold_radius`.
        """
        xd, yd = _as_pixels(xd, yd)
        x, y = xd.copy(), yd.copy()
        with np.errstate(all="ignore"):
            for _ in range(_NEWTON_MAX_ITER):
                fx, fy, jxx, jxy, jyy = self._distort_with_jacobian(x, y)
                ex, ey = fx - xd, fy - yd
                det = jxx * jyy - jxy * jxy
                dx = (jyy * ex - jxy * ey) / det
                dy = (jxx * ey - jxy * ex) / det
                x, y = x - dx, y - dy
                step = np.maximum(np.abs(dx) * self.fx_px, np.abs(dy) * self.fy_px)
                if not np.any(step > _NEWTON_STEP_PX):   # also stops on all-NaN
                    break
            fx, fy, jxx, jxy, jyy = self._distort_with_jacobian(x, y)
            residual = np.maximum(np.abs(fx - xd) * self.fx_px, np.abs(fy - yd) * self.fy_px)
            ok = (residual <= _NEWTON_RESIDUAL_PX) & (jxx * jyy - jxy * jxy > 0)
            ok &= np.hypot(x, y) < self.fold_radius()
        if not np.all(ok):
            i = np.flatnonzero(~ok.ravel())[0]
            raise ValueError(f"undistortion does not converge at normalised point "
                             f"({xd.ravel()[i]:.6g}, {yd.ravel()[i]:.6g})")
        return x, y

    # ---- projection -------------------------------------------------------------------

    def project(self, v_cam):
        """Camera-frame directions ``(..., 3)`` (any non-zero length) -> pixels ``(x, y, valid)``.

        ``valid`` is true where the direction is in front of the camera (``Z > 0``), inside the
        radius where the distortion is one-to-one, and lands inside the frame
        ``[-0.5, W - 0.5) x [-0.5, H - 0.5)``.  ``x`` and ``y`` are NaN behind the camera and
        otherwise computed even outside the frame.  NaN, inf or zero vectors raise ``ValueError``.
        """
        v = _as_directions(v_cam)
        X, Y, Z = v[..., 0], v[..., 1], v[..., 2]
        front = Z > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            xn = np.where(front, X / Z, np.nan)
            yn = np.where(front, Y / Z, np.nan)
            xd, yd, *_ = self._distort_with_jacobian(xn, yn)
            x = self.cx + self.fx_px * xd
            y = self.cy + self.fy_px * yd
            valid = front & (np.hypot(xn, yn) < self.fold_radius())
        return x, y, valid & _in_frame(x, y, self.width, self.height)

    def unproject(self, x, y):
        """Pixel coordinates (broadcast together) -> unit vectors ``(..., 3)`` in the camera frame.

        Inverts the distortion by Newton iteration (:meth:`undistort_normalized`); NaN pixels
        and pixels far outside the frame where it does not converge raise ``ValueError``.
        """
        x, y = _as_pixels(x, y)
        xn, yn = self.undistort_normalized((x - self.cx) / self.fx_px,
                                           (y - self.cy) / self.fy_px)
        v = np.stack([xn, yn, np.ones_like(xn)], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    # ---- field of view ----------------------------------------------------------------

    def fov_deg(self):
        """Full field of view ``(horizontal, vertical, diagonal)`` in degrees, through the model.

        Horizontal: angle between the outer edges of the left and right columns along the
        middle row ``(H-1)/2``; vertical: between the top and bottom edges along the middle
        column ``(W-1)/2``; diagonal: between the outer corners ``(-0.5, -0.5)`` and
        ``(W-0.5, H-0.5)``.
        """
        w, h = self.width, self.height
        xm, ym = (w - 1) / 2, (h - 1) / 2
        v = self.unproject([-0.5, w - 0.5, xm, xm, -0.5, w - 0.5],
                           [ym, ym, -0.5, h - 0.5, -0.5, h - 0.5])
        return tuple(float(np.degrees(_angle(v[i], v[i + 1]))) for i in (0, 2, 4))

    def boresight_radius_deg(self):
        """Half-angle in degrees of the smallest cone about ``+z`` containing the whole frame
        (the largest off-axis angle of the frame's border): the radius for catalogue cone
        queries.  Equals the half-diagonal for a centred principal point."""
        v = self.unproject(*_border(self.width, self.height))
        return float(np.degrees(np.max(_angle(v, np.array([0.0, 0.0, 1.0])))))


# --------------------------------------------------------------------------------------
# Dzamba's inverse camera model (ST-16)
# --------------------------------------------------------------------------------------

@dataclass(frozen=True, kw_only=True)
class DzambaCamera:
    """Dzamba (2013) inverse camera model of the ST-16 (Eqs 3.12-3.19, L1041-1078), errata fixed.

    Pixel and frame conventions (thesis Table 3.1, L1033-1039; Fig 3.3):

    * pixel frame P: ``m`` is the **row** index (our ``y``), ``n`` the **column** index (our
      ``x``), from pixel ``[0, 0]``; the centroid of Eq 2.1 is a weighted mean of indices, so
      pixel centres sit at integers as in ``lodestar.contract``.  ``m0``, ``n0`` is the
      principal point (row, column).
    * Dzamba's camera frame C: ``X_C`` = negative row direction, ``Y_C`` = column direction,
      ``Z_C`` = optical axis (virtual image plane, no inversion, Eq 3.2).  In our camera frame
      that is ``X_C = -y``, ``Y_C = +x``, ``Z_C = +z`` (right-handed, a 90 degree turn about the
      boresight), so a native vector ``a_C`` is ours as ``(a_Y, -a_X, a_Z)``.

    The 8 parameters (Table 3.2): ``f_m`` focal length (metres), ``j1`` (1/m^2) and ``j2``
    (1/m^4) inverse radial coefficients on the image-plane radius in metres, ``gamma1``,
    ``gamma2`` decentering/prism angles (radians; small-angle rotation, the thesis bounds them
    at +-0.175 rad, Table 3.5), ``m0``, ``n0`` (pixels) and ``c_s`` the column (Y) scale.
    ``pixel_pitch_m`` is gamma_p, ``width``, ``height`` the frame in pixels.

    Inverse model as implemented (pixel -> unit vector, the model's native direction):

    1. ``j_x = -gamma_p (m - m0)``, ``j_y = gamma_p (n - n0) / c_s``.  Erratum: printed Eq 3.14
       (L1055) has ``+gamma_p (m - m0)`` and ``* c_s``; the form here inverts the forward
       Eq 3.11 (L1019, ``m = m0 - j_x/gamma_p``, ``n = n0 + c_s j_y/gamma_p``) and keeps
       ``X_C = -row`` (the printed sign would mirror the image).
    2. ``j_z = gamma2 j_x - gamma1 j_y`` (third row of R_ID, Eqs 3.15-3.16).
    3. ``h = f / (f - j_z) * (j_x, j_y)``.  Erratum: printed Eq 3.17 (L1069) has the unknown
       ``h`` with swapped indices in the denominator (``h_y gamma2 - h_x gamma1 + f``); by
       analogy with Eq 3.10 the ray through ``j_I`` meets the image plane at ``f - j_z``.
       With ``gamma = -psi`` this exactly inverts the forward Eqs 3.9-3.10.
    4. ``g = (1 + j1 rho^2 + j2 rho^4) h``, ``rho = |h|`` (Eqs 3.12-3.13, explicit).
    5. ``a_C = (g_x, g_y, f)`` normalised (Eqs 3.18-3.19).

    The forward direction (:meth:`project`) inverts this numerically.  Typical Table 3.6 values
    cannot be used: ``j1 = -1.416e7`` makes ``1 + 3 j1 rho^2`` negative inside the frame, which
    the validation rejects (the printed unit or exponent is wrong; re-fit instead).
    """

    width: int
    height: int
    pixel_pitch_m: float
    f_m: float
    m0: float
    n0: float
    c_s: float = 1.0
    j1: float = 0.0
    j2: float = 0.0
    gamma1: float = 0.0
    gamma2: float = 0.0

    GAMMA_LIMIT = 0.175
    """Largest |gamma| (radians): the thesis' calibration bound (Table 3.5, L1200)."""

    def __post_init__(self):
        _require_int("width", self.width, 1, C.MAX_WIDTH)
        _require_int("height", self.height, 1, C.MAX_HEIGHT)
        for name in ("pixel_pitch_m", "f_m", "c_s"):
            _require_positive(name, getattr(self, name))
        for name in ("j1", "j2", "gamma1", "gamma2"):
            _require_number(name, getattr(self, name))
        for name in ("gamma1", "gamma2"):
            if abs(getattr(self, name)) > self.GAMMA_LIMIT:
                raise ValueError(f"{name}={getattr(self, name)} exceeds the small-angle "
                                 f"limit {self.GAMMA_LIMIT} rad")
        _require_inside("m0", self.m0, self.height, "row")
        _require_inside("n0", self.n0, self.width, "column")
        # the radial map rho -> rho (1 + j1 rho^2 + j2 rho^4) must increase over the frame:
        # 1 + 3 j1 s + 5 j2 s^2 > 0 for s = rho^2 in [0, s_max]
        x, y = _border(self.width, self.height)
        hx, hy = self._image_plane(x, y)
        s_max = float(np.max(hx * hx + hy * hy))
        candidates = [s_max]
        if self.j2 != 0 and 0 < -3 * self.j1 / (10 * self.j2) < s_max:
            candidates.append(-3 * self.j1 / (10 * self.j2))
        worst = min(1 + 3 * self.j1 * s + 5 * self.j2 * s * s for s in candidates)
        if worst <= 0:
            raise ValueError(f"j1={self.j1}, j2={self.j2} fold the radial map inside the "
                             f"frame (rho up to {math.sqrt(s_max):.4g} m)")

    def _image_plane(self, x, y):
        """Steps 1-3: pixel (column ``x`` = n, row ``y`` = m) -> image-plane ``h`` in metres."""
        jx = -self.pixel_pitch_m * (y - self.m0)
        jy = self.pixel_pitch_m * (x - self.n0) / self.c_s
        jz = self.gamma2 * jx - self.gamma1 * jy
        scale = self.f_m / (self.f_m - jz)
        return scale * jx, scale * jy

    def _tangent(self, x, y):
        """Pixel -> our tangent-plane coordinates ``(X/Z, Y/Z)`` (steps 1-4, frame mapping)."""
        hx, hy = self._image_plane(x, y)
        radial = 1 + (hx * hx + hy * hy) * (self.j1 + self.j2 * (hx * hx + hy * hy))
        gx, gy = radial * hx, radial * hy
        return gy / self.f_m, -gx / self.f_m

    def unproject_native(self, m, n):
        """Row ``m``, column ``n`` -> unit vectors ``(..., 3)`` in Dzamba's camera frame C."""
        m, n = _as_pixels(m, n)
        tx, ty = self._tangent(n, m)
        a = np.stack([-ty, tx, np.ones_like(tx)], axis=-1)   # (g_x, g_y, f) / f
        return a / np.linalg.norm(a, axis=-1, keepdims=True)

    def unproject(self, x, y):
        """Column ``x``, row ``y`` -> unit vectors ``(..., 3)`` in the ``lodestar.sim`` frame."""
        x, y = _as_pixels(x, y)
        tx, ty = self._tangent(x, y)
        v = np.stack([tx, ty, np.ones_like(tx)], axis=-1)
        return v / np.linalg.norm(v, axis=-1, keepdims=True)

    def project(self, v_cam):
        """Our camera-frame directions ``(..., 3)`` -> ``(x, y, valid)`` by Newton iteration.

        Solves :meth:`unproject` for the pixel with a central-difference Jacobian, to
        ``1e-9`` px.  ``valid``: in front (``Z > 0``), converged, and inside the frame.  ``x``
        and ``y`` are NaN where the direction is behind the camera or the iteration fails.
        """
        v = _as_directions(v_cam)
        front = v[..., 2] > 0
        with np.errstate(divide="ignore", invalid="ignore"):
            tx = np.where(front, v[..., 0] / v[..., 2], np.nan)
            ty = np.where(front, v[..., 1] / v[..., 2], np.nan)
            scale = self.f_m / self.pixel_pitch_m                      # pixels per radian
            x = self.n0 + self.c_s * scale * tx                        # pinhole start
            y = self.m0 + scale * ty
            h = 0.5                                                    # difference step, px
            for _ in range(_NEWTON_MAX_ITER):
                ex, ey = (t - s for t, s in zip(self._tangent(x, y), (tx, ty)))
                ax, ay = (a - b for a, b in zip(self._tangent(x + h, y), self._tangent(x - h, y)))
                bx, by = (a - b for a, b in zip(self._tangent(x, y + h), self._tangent(x, y - h)))
                jxx, jyx, jxy, jyy = ax / (2 * h), ay / (2 * h), bx / (2 * h), by / (2 * h)
                det = jxx * jyy - jxy * jyx
                dx = (jyy * ex - jxy * ey) / det
                dy = (jxx * ey - jyx * ex) / det
                x, y = x - dx, y - dy
                if not np.any(np.maximum(np.abs(dx), np.abs(dy)) > _NEWTON_STEP_PX):
                    break
            rx, ry = (t - s for t, s in zip(self._tangent(x, y), (tx, ty)))
            ok = np.maximum(np.abs(rx), np.abs(ry)) * scale <= _NEWTON_RESIDUAL_PX
        x = np.where(ok, x, np.nan)
        y = np.where(ok, y, np.nan)
        return x, y, ok & _in_frame(x, y, self.width, self.height)
