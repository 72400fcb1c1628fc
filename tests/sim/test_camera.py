"""Camera models: round trips, hand-checked projections, FOV, Dzamba errata, validation."""

import dataclasses
import math

import numpy as np
import pytest

from lodestar.sim.camera import Camera, DzambaCamera
from lodestar.sim.presets import PRESETS, load_preset

ARCSEC = math.pi / 180 / 3600


def frame_grid(cam, n=81):
    """Dense grid over the whole frame, outer corners and edges included."""
    xs = np.linspace(-0.5, cam.width - 0.5, n)
    ys = np.linspace(-0.5, cam.height - 0.5, n)
    return np.meshgrid(xs, ys)


def angle(a, b):
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


# ---- Brown–Conrady camera: round trips ------------------------------------------------

@pytest.mark.parametrize("name", PRESETS)
def test_pixel_round_trip_whole_frame(name):
    cam = load_preset(name)
    x, y = frame_grid(cam)
    v = cam.unproject(x, y)
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-15)
    px, py, valid = cam.project(v)
    assert np.max(np.hypot(px - x, py - y)) <= 1e-6
    assert valid[1:-1, 1:-1].all()   # exact edges are rounding-limited: see test_project_validity


@pytest.mark.parametrize("name", PRESETS)
def test_vector_round_trip(name):
    cam = load_preset(name)
    rng = np.random.default_rng(7)
    v = cam.unproject(rng.uniform(-0.5, cam.width - 0.5, 2000),
                      rng.uniform(-0.5, cam.height - 0.5, 2000))
    v = v * rng.uniform(0.1, 10, (2000, 1))          # project accepts any length
    x, y, valid = cam.project(v)
    assert valid.all()
    back = cam.unproject(x, y)
    assert np.max(angle(back, v)) <= 1e-12


@pytest.mark.parametrize("name", PRESETS)
def test_round_trip_random_distortion(name):
    base = load_preset(name)
    rng = np.random.default_rng(11)
    for _ in range(20):
        cam = dataclasses.replace(
            base, k1=rng.uniform(-0.4, 0.4), k2=rng.uniform(-0.3, 0.3),
            k3=rng.uniform(-0.1, 0.1), p1=rng.uniform(-5e-3, 5e-3), p2=rng.uniform(-5e-3, 5e-3),
            cx=base.cx + rng.uniform(-20, 20), cy=base.cy + rng.uniform(-20, 20))
        x, y = frame_grid(cam, 41)
        px, py, _ = cam.project(cam.unproject(x, y))
        assert np.max(np.hypot(px - x, py - y)) <= 1e-6


# ---- hand-checked geometry ------------------------------------------------------------

def test_pinhole_hand_values_estcube2():
    cam = load_preset("estcube2")
    # 5 deg towards +x lands f tan 5 = 7272.727 * 0.0874887 = 636.281 px right of centre;
    # 3 deg towards +y lands 381.147 px below it (no sign flip, larger row).
    v = np.array([[math.sin(math.radians(5)), 0, math.cos(math.radians(5))],
                  [0, math.sin(math.radians(3)), math.cos(math.radians(3))],
                  [0, 0, 1]])
    x, y, valid = cam.project(v)
    np.testing.assert_allclose(x, [1295.5 + 636.2811892794, 1295.5, 1295.5], atol=1e-6)
    np.testing.assert_allclose(y, [971.5, 971.5 + 381.1474856948, 971.5], atol=1e-6)
    assert valid.all()


def test_plate_scale_estcube2():
    cam = load_preset("estcube2")
    # 2.2 um / 16 mm = 1.375e-4 rad = 28.36 arcsec per pixel at the centre
    sx, sy = cam.plate_scale_arcsec()
    assert sx == pytest.approx(28.3614, abs=1e-4) and sy == sx
    v = cam.unproject([cam.cx - 0.5, cam.cx + 0.5], [cam.cy, cam.cy])
    assert angle(v[0], v[1]) / ARCSEC == pytest.approx(28.3614, abs=1e-3)


def test_distortion_hand_value_lohmann():
    cam = load_preset("lohmann")
    # r^2 = 0.05: radial = 1 - 0.3686*0.05 + 0.3148*0.0025 = 0.982357
    # x_d = 0.2*0.982357 + 2(-0.0023)(0.02) + 0.0003(0.05 + 0.08) = 0.1964184
    # y_d = 0.1*0.982357 + (-0.0023)(0.05 + 0.02) + 2(0.0003)(0.02) = 0.0980867
    xd, yd = cam.distort_normalized(0.2, 0.1)
    assert xd == pytest.approx(0.1964184, abs=1e-12)
    assert yd == pytest.approx(0.0980867, abs=1e-12)
    np.testing.assert_allclose(cam.undistort_normalized(xd, yd), [0.2, 0.1], atol=1e-14)


def test_distortion_jacobian_is_analytic_derivative():
    cam = dataclasses.replace(load_preset("lohmann"), k3=0.05, p2=0.004)
    rng = np.random.default_rng(5)
    x, y = rng.uniform(-0.3, 0.3, 50), rng.uniform(-0.2, 0.2, 50)
    _, _, jxx, jxy, jyy = cam._distort_with_jacobian(x, y)
    h = 1e-6
    dx = [(a - b) / (2 * h) for a, b in zip(cam.distort_normalized(x + h, y),
                                            cam.distort_normalized(x - h, y))]
    dy = [(a - b) / (2 * h) for a, b in zip(cam.distort_normalized(x, y + h),
                                            cam.distort_normalized(x, y - h))]
    np.testing.assert_allclose([jxx, jxy, jxy, jyy], [dx[0], dx[1], dy[0], dy[1]], atol=1e-8)


def test_lohmann_corner_distortion():
    """The digest's ~15 px corner shift: (-12.5, -8.3) px at the bottom-right corner."""
    cam = load_preset("lohmann")
    corners_x = np.array([751.5, -0.5])
    corners_y = np.array([479.5, -0.5])
    xn, yn = (corners_x - cam.cx) / cam.fx_px, (corners_y - cam.cy) / cam.fy_px
    xd, yd = cam.distort_normalized(xn, yn)
    dx, dy = (xd - xn) * cam.fx_px, (yd - yn) * cam.fy_px
    np.testing.assert_allclose([dx[0], dy[0]], [-12.478, -8.308], atol=1e-3)
    # the tangential terms make the opposite corner smaller: (+12.098, +7.378)
    np.testing.assert_allclose([dx[1], dy[1]], [12.098, 7.378], atol=1e-3)
    assert np.hypot(dx, dy) == pytest.approx([14.99, 14.17], abs=0.01)


def test_fov_estcube2():
    cam = load_preset("estcube2")
    h, v, d = cam.fov_deg()
    # 2 atan(2.8512/16), 2 atan(2.1384/16), 2 atan(3.564/16): the digest's 20.2 x 15.2 (25.1)
    assert (h, v, d) == pytest.approx((20.2081, 15.2249, 25.1152), abs=1e-4)
    assert cam.boresight_radius_deg() == pytest.approx(d / 2, abs=1e-9)


def test_fov_lohmann_from_calibrated_focal_length():
    cam = load_preset("lohmann")
    pinhole = dataclasses.replace(cam, k1=0.0, k2=0.0, p1=0.0, p2=0.0)
    h0, v0, _ = pinhole.fov_deg()
    assert h0 == pytest.approx(math.degrees(2 * math.atan(376 / (8.63 / 0.006))), abs=1e-9)
    assert v0 == pytest.approx(math.degrees(2 * math.atan(240 / (8.56 / 0.006))), abs=1e-9)
    h, v, d = cam.fov_deg()
    # barrel distortion squeezes a wider field onto the sensor: 30.0 x 19.3 (35.7) deg,
    # against 29.3 x 19.1 pinhole; the thesis' 31.8 / 30.8 deg figures are lens ratings
    assert (h, v, d) == pytest.approx((30.014, 19.295, 35.707), abs=1e-3)
    assert h > h0 and v > v0


def test_project_validity():
    cam = load_preset("estcube2")
    v = np.array([[0, 0, -1], [1, 0, 1e-3], [0, 0, 1]], dtype=float)
    x, y, valid = cam.project(v)
    assert np.isnan(x[0]) and np.isnan(y[0])
    assert not valid[0] and not valid[1] and valid[2]
    # the frame is half-open: [-0.5, W - 0.5)
    edge = cam.unproject([-0.5 - 1e-7, -0.5 + 1e-7, cam.width - 0.5 - 1e-7,
                          cam.width - 0.5 + 1e-7], cam.cy)
    assert cam.project(edge)[2].tolist() == [False, True, True, False]
    # shape is preserved
    x, y, valid = cam.project(np.zeros((2, 5, 3)) + [0, 0, 1])
    assert x.shape == y.shape == valid.shape == (2, 5)


def test_beyond_fold_radius_is_invalid():
    # k1 < 0 alone folds at r = 1/sqrt(3 |k1|); beyond it r (1 - 0.5 r^2) shrinks again, so
    # a direction at r = 1.3 (52 deg off-axis) would land back inside, at x = cx + 290 px
    cam = dataclasses.replace(load_preset("lohmann"), k1=-0.5, k2=0.0, p1=0.0, p2=0.0)
    assert cam.fold_radius() == pytest.approx(1 / math.sqrt(1.5))
    x, y, valid = cam.project([[1.3, 0.0, 1.0]])
    assert x[0] == pytest.approx(cam.cx + cam.fx_px * (1.3 - 0.5 * 1.3 ** 3), abs=1e-9)
    assert 0 < x[0] < cam.width - 1 and not valid[0]


@pytest.mark.parametrize("bad", [
    [[np.nan, 0, 1]], [[0, 0, np.inf]], [[0, 0, 0]], [0, 1], np.float64(1.0)])
def test_project_bad_vectors(bad):
    with pytest.raises(ValueError):
        load_preset("estcube2").project(bad)


def test_unproject_bad_pixels():
    cam = load_preset("lohmann")
    with pytest.raises(ValueError, match="NaN"):
        cam.unproject([np.nan], [0.0])
    strong = dataclasses.replace(cam, k1=-0.5, k2=0.0)
    with pytest.raises(ValueError, match="does not converge"):
        strong.unproject([100000.0], [0.0])


# ---- validation -----------------------------------------------------------------------

@pytest.mark.parametrize("changes,match", [
    ({"width": 0}, r"width=0 is out of range"),
    ({"height": 2.5}, r"height must be an int"),
    ({"pixel_bits": 11}, r"pixel_bits=11 is not one of"),
    ({"pixel_pitch_um": 0.0}, r"pixel_pitch_um=0.0 must be > 0"),
    ({"focal_length_mm": -16.0}, r"focal_length_mm=-16.0 must be > 0"),
    ({"aperture_mm": 0.0}, r"aperture_mm=0.0 must be > 0"),
    ({"fx_px": 0.0}, r"fx_px=0.0 must be > 0"),
    ({"fy_px": 727.27}, r"fy_px=727.27 px .* disagrees with focal_length_mm"),
    ({"fx_px": np.nan}, r"fx_px=nan is not finite"),
    ({"cx": 2591.5}, r"cx=2591.5 is outside the sensor"),
    ({"cy": -0.6}, r"cy=-0.6 is outside the sensor"),
    ({"qe": 0.0}, r"qe=0.0 is outside \(0, 1\]"),
    ({"qe": 1.2}, r"qe=1.2 is outside"),
    ({"read_noise_e": -1.0}, r"read_noise_e=-1.0 must be >= 0"),
    ({"gain_adu_per_e": 0.0}, r"gain_adu_per_e=0.0 must be > 0"),
    ({"full_well_e": 0.0}, r"full_well_e=0.0 must be > 0"),
    ({"adc_offset_adu": 4095.0}, r"adc_offset_adu=4095.0 must be below"),
    ({"dark_current_e_per_s": -0.1}, r"dark_current_e_per_s=-0.1 must be >= 0"),
    ({"shutter": "electronic"}, r"shutter='electronic' is not one of"),
    ({"row_time_s": 0.0}, r"row_time_s=0.0 must be > 0 for a rolling shutter"),
    ({"psf_sigma_px": 0.0}, r"psf_sigma_px=0.0 must be > 0"),
    ({"exposure_s": 0.0}, r"exposure_s=0.0 must be > 0"),
    ({"k2": "0.1"}, r"k2 must be a number"),
    ({"k1": -3.0}, r"distortion k1=-3.0, .* is not invertible over the frame"),
])
def test_impossible_camera(changes, match):
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(load_preset("estcube2"), **changes)


def test_global_shutter_may_have_zero_row_time():
    cam = dataclasses.replace(load_preset("lohmann"), row_time_s=0.0)
    assert cam.shutter == "global"


def test_default_principal_point_is_geometric_centre():
    kwargs = {f.name: getattr(load_preset("estcube2"), f.name)
              for f in dataclasses.fields(Camera) if f.name not in ("cx", "cy", "meta")}
    cam = Camera(**kwargs)
    assert (cam.cx, cam.cy) == (1295.5, 971.5)
    assert cam == load_preset("estcube2")   # meta takes no part in comparisons


# ---- Dzamba inverse model -------------------------------------------------------------

ST16 = dict(width=2592, height=1944, pixel_pitch_m=2.2e-6, f_m=15.9959e-3,
            m0=1100.5, n0=1207.3, c_s=0.9998, gamma1=1.94e-3, gamma2=-6.61e-3)
"""Table 3.6 typical ST-16 calibration (L1228-1236), without its unusable j1, j2."""


def dzamba_forward(a, f, pitch, m0, n0, c_s, psi1, psi2):
    """The thesis' forward model as printed, Eqs 3.2 and 3.9-3.11 (no radial term)."""
    g = f * a[..., :2] / a[..., 2:]                                  # Eq 3.2
    hx, hy = g[..., 0], g[..., 1]
    # Eq 3.9 with Eq 3.7: h_D = R_DI [h_x, h_y, 0] = [h_x, h_y, psi2 h_x - psi1 h_y]
    s = f / (psi1 * hy - psi2 * hx + f)                              # Eq 3.10
    jx, jy = s * hx, s * hy
    return m0 - jx / pitch, n0 + c_s * jy / pitch                    # Eq 3.11


def dzamba_inverse_printed(m, n, f, pitch, m0, n0, c_s, g1, g2):
    """Eqs 3.14-3.19 exactly as printed (the unknown h of Eq 3.17 replaced by j)."""
    jx, jy = pitch * (m - m0), pitch * c_s * (n - n0)               # Eq 3.14 as printed
    s = f / (jy * g2 - jx * g1 + f)                                  # Eq 3.17 as printed
    a = np.stack([s * jx, s * jy, np.full_like(jx, f)], axis=-1)
    return a / np.linalg.norm(a, axis=-1, keepdims=True)


def test_dzamba_pinhole_matches_camera_and_maps_axes():
    """Zero distortion: Dzamba's model and our pinhole agree at every pixel, with m = row."""
    cam = load_preset("estcube2")
    dz = DzambaCamera(width=2592, height=1944, pixel_pitch_m=2.2e-6, f_m=16e-3,
                      m0=cam.cy, n0=cam.cx)
    x, y = frame_grid(cam, 21)
    assert np.max(angle(dz.unproject(x, y), cam.unproject(x, y))) < 1e-13
    # native frame: X_C = -row, Y_C = column, so ours = (a_Y, -a_X, a_Z)
    a = dz.unproject_native(y, x)
    ours = np.stack([a[..., 1], -a[..., 0], a[..., 2]], axis=-1)
    np.testing.assert_allclose(ours, dz.unproject(x, y), atol=1e-15)
    # a pixel below and right of the principal point has a_X < 0 (negative row) and a_Y > 0
    a = dz.unproject_native(cam.cy + 100, cam.cx + 100)
    assert a[0] < 0 and a[1] > 0


def test_dzamba_corrected_inverse_inverts_printed_forward_exactly():
    """Errata of Eqs 3.14 and 3.17: with gamma = -psi the fixed inverse undoes Eqs 3.9-3.11."""
    dz = DzambaCamera(**ST16)
    rng = np.random.default_rng(3)
    a = dz.unproject(rng.uniform(0, 2591, 500), rng.uniform(0, 1943, 500))
    a_native = np.stack([-a[:, 1], a[:, 0], a[:, 2]], axis=-1)      # ours -> Dzamba's C
    m, n = dzamba_forward(a_native, dz.f_m, dz.pixel_pitch_m, dz.m0, dz.n0, dz.c_s,
                          psi1=-dz.gamma1, psi2=-dz.gamma2)
    assert np.max(angle(dz.unproject_native(m, n), a_native)) < 1e-14
    # printed Eqs 3.14/3.17 miss the same pixels by pixels: mirrored X and a wrong scale
    printed = dzamba_inverse_printed(m, n, dz.f_m, dz.pixel_pitch_m, dz.m0, dz.n0, dz.c_s,
                                     dz.gamma1, dz.gamma2)
    assert np.max(angle(printed, a_native)) > 0.05          # radians: the X mirror
    mirrored = printed * [-1, 1, 1]
    assert np.max(angle(mirrored, a_native)) * dz.f_m / dz.pixel_pitch_m > 0.5   # pixels


def test_dzamba_eq_3_17_denominator_erratum():
    """Printed Eq 3.17 (swapped gamma indices) vs the corrected f - j_z, c_s = 1, X sign fixed."""
    params = dict(ST16, c_s=1.0)
    dz = DzambaCamera(**params)
    m, n = np.array([0.0, 1943.0]), np.array([0.0, 2591.0])
    good = dz.unproject_native(m, n)
    printed = dzamba_inverse_printed(m, n, dz.f_m, dz.pixel_pitch_m, dz.m0, dz.n0, 1.0,
                                     dz.gamma1, dz.gamma2) * [-1, 1, 1]
    err_px = angle(printed, good) * dz.f_m / dz.pixel_pitch_m
    assert np.all(err_px > 1.0)     # first order in gamma * rho / f: pixels at the corners


def test_dzamba_c_s_erratum():
    """Eq 3.11 multiplies by c_s, so the inverse must divide: printed Eq 3.14 misses ~0.5 px."""
    dz = DzambaCamera(**dict(ST16, gamma1=0.0, gamma2=0.0))
    a_native = dz.unproject_native(np.array([1100.5]), np.array([2591.0]))
    m, n = dzamba_forward(a_native, dz.f_m, dz.pixel_pitch_m, dz.m0, dz.n0, dz.c_s, 0.0, 0.0)
    assert n[0] == pytest.approx(2591.0, abs=1e-9)
    # printed form: n recovered as n0 + (n - n0) c_s^2 instead of n
    assert (n[0] - dz.n0) * (1 - dz.c_s ** 2) == pytest.approx(0.55, abs=0.01)


def test_dzamba_forward_round_trip():
    dz = DzambaCamera(**ST16, j1=-500.0, j2=2e6)   # ~ -10 px radial at the corners
    x, y = np.meshgrid(np.linspace(-0.5, 2591.5, 41), np.linspace(-0.5, 1943.5, 41))
    px, py, valid = dz.project(dz.unproject(x, y))
    assert np.max(np.hypot(px - x, py - y)) <= 1e-6
    assert valid[1:-1, 1:-1].all()
    x, y, valid = dz.project([[0.0, 0.0, -1.0], [0.0, 0.0, 1.0]])
    assert np.isnan(x[0]) and not valid[0] and valid[1]


@pytest.mark.parametrize("changes,match", [
    ({"j1": -1.416e7, "j2": -0.108e3}, r"j1=-14160000.0, j2=-108.0 fold the radial map"),
    ({"gamma1": 0.2}, r"gamma1=0.2 exceeds the small-angle limit"),
    ({"m0": 1944.0}, r"m0=1944.0 is outside the sensor"),
    ({"n0": -1.0}, r"n0=-1.0 is outside the sensor"),
    ({"f_m": 0.0}, r"f_m=0.0 must be > 0"),
    ({"c_s": -1.0}, r"c_s=-1.0 must be > 0"),
    ({"pixel_pitch_m": np.nan}, r"pixel_pitch_m=nan is not finite"),
])
def test_dzamba_validation(changes, match):
    """Table 3.6's j1 = -1.416e7 (L1234) folds the map: the printed unit is wrong."""
    with pytest.raises(ValueError, match=match):
        DzambaCamera(**dict(ST16, **changes))
