"""Tests of ``lodestar.firmware.camera`` against the ground model ``lodestar.sim.camera.Camera``:
both presets and random distortions agree to 1e-6 rad (in practice ~1e-15) over dense pixel
grids including the frame's corners and edges, in both directions."""

import dataclasses
import json
import math
from importlib import resources
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.firmware import camera, geometry
from lodestar.firmware import status as S
from lodestar.firmware.camera import Camera
from lodestar.sim.camera import Camera as SimCamera
from lodestar.sim.presets import PRESETS, load_preset

RAD_TOL = 1e-6      # required agreement (rad)
PX_TOL = 1e-6       # round trips (px)


def firmware_camera(sim_cam):
    return Camera(sim_cam.width, sim_cam.height, sim_cam.fx_px, sim_cam.fy_px, sim_cam.cx,
                  sim_cam.cy, sim_cam.k1, sim_cam.k2, sim_cam.k3, sim_cam.p1, sim_cam.p2)


def pixel_grid(width, height, nx=41, ny=31):
    """Pixel centres and the outer edges, corners included."""
    xs = np.unique(np.concatenate([np.linspace(-0.5, width - 0.5, nx), [0, width - 1]]))
    ys = np.unique(np.concatenate([np.linspace(-0.5, height - 0.5, ny), [0, height - 1]]))
    x, y = np.meshgrid(xs, ys)
    return x.ravel(), y.ravel()


def angle(a, b):
    a, b = np.asarray(a, float), np.asarray(b, float)
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b)))


def assert_agree(sim_cam, fw, nx=41, ny=31):
    """Unprojection and projection of ``fw`` equal ``sim_cam``'s over a dense grid."""
    x, y = pixel_grid(sim_cam.width, sim_cam.height, nx, ny)
    expected = sim_cam.unproject(x, y)
    worst = 0.0
    for xi, yi, v in zip(x, y, expected):
        got = fw.pixel_to_vector(float(xi), float(yi))
        assert got is not None, (xi, yi, S.name(fw.last_status))
        assert abs(math.sqrt(sum(c * c for c in got)) - 1) < 1e-12
        worst = max(worst, angle(got, v))
        px = fw.vector_to_pixel(tuple(float(c) for c in v))
        assert px == pytest.approx((xi, yi), abs=PX_TOL)
    assert worst < RAD_TOL
    # forward model against sim.project on random directions across (and beyond) the frame
    rng = np.random.default_rng(0)
    v = sim_cam.unproject(rng.uniform(-0.5, sim_cam.width - 0.5, 200),
                          rng.uniform(-0.5, sim_cam.height - 0.5, 200))
    v = v * rng.uniform(0.1, 10.0, (200, 1))            # any length
    sx, sy, _ = sim_cam.project(v)
    for vi, xi, yi in zip(v, sx, sy):
        assert fw.vector_to_pixel(tuple(map(float, vi))) == pytest.approx((xi, yi), abs=1e-9)
    return worst


@pytest.mark.parametrize("name", PRESETS)
def test_presets_agree_with_sim(name):
    sim_cam = load_preset(name)
    worst = assert_agree(sim_cam, firmware_camera(sim_cam), nx=81, ny=61)
    assert worst < 1e-12


def _random_sim_camera(rng, base):
    """A valid ``lodestar.sim`` camera with random geometry and distortion (None if the sim
    rejects the distortion)."""
    fx = rng.uniform(400, 2000)
    changes = dict(fx_px=fx, fy_px=fx * rng.uniform(0.97, 1.03),
                   focal_length_mm=fx * base.pixel_pitch_um * 1e-3,
                   cx=rng.uniform(0.3, 0.7) * base.width, cy=rng.uniform(0.3, 0.7) * base.height,
                   k1=rng.uniform(-0.8, 0.8), k2=rng.uniform(-0.8, 0.8),
                   k3=rng.uniform(-0.5, 0.5), p1=rng.uniform(-0.01, 0.01),
                   p2=rng.uniform(-0.01, 0.01))
    try:
        return dataclasses.replace(base, **changes), changes
    except ValueError:
        return None, changes


def test_random_distortions_agree_with_sim():
    rng = np.random.default_rng(20240601)
    base = load_preset("lohmann")
    accepted = rejected = 0
    while accepted < 25:
        sim_cam, changes = _random_sim_camera(rng, base)
        args = dict(width=base.width, height=base.height, fx=changes["fx_px"],
                    fy=changes["fy_px"], cx=changes["cx"], cy=changes["cy"],
                    **{k: changes[k] for k in ("k1", "k2", "k3", "p1", "p2")})
        if sim_cam is None:
            # the firmware refuses the same distortions at construction
            with pytest.raises(ValueError, match="not invertible over the frame"):
                Camera(**args)
            rejected += 1
            continue
        fw = Camera(**args)
        sim_fold = sim_cam.fold_radius()
        assert fw.fold_radius() == pytest.approx(sim_fold, rel=1e-9) or \
            fw.fold_radius() == sim_fold == math.inf
        assert_agree(sim_cam, fw, nx=21, ny=15)
        accepted += 1
    assert rejected > 0


@pytest.mark.parametrize("k1, k2, k3", [
    (-0.5, 0.0, 0.0), (0.0, -0.3, 0.0), (0.0, 0.0, -0.2), (0.2, -0.5, 0.1), (0.5, 0.5, 0.5),
    (-0.3686, 0.3148, 0.0), (0.1, -1.0, 2.0), (-1.0, 3.0, -3.0),
])
def test_fold_radius_matches_sim(k1, k2, k3):
    got = camera._smallest_positive_root(1.0, 3 * k1, 5 * k2, 7 * k3)
    # the sim's method reads only the coefficients (many of these fail its frame check)
    expected = SimCamera.fold_radius(SimpleNamespace(k1=k1, k2=k2, k3=k3))
    if expected == math.inf:
        assert got is None
    else:
        assert math.sqrt(got) == pytest.approx(expected, rel=1e-12)


def test_from_dict_accepts_the_preset_camera_block():
    text = resources.files("lodestar.sim").joinpath("data/presets.json").read_text("utf-8")
    for name, entry in json.loads(text).items():
        fw = Camera.from_dict(entry["camera"])
        assert fw.as_dict() == firmware_camera(load_preset(name)).as_dict()
        assert Camera.from_dict(fw.as_dict()).as_dict() == fw.as_dict()
    fw = Camera.from_dict({"width": 100, "height": 80, "fx": 500, "fy": 500})
    assert (fw.cx, fw.cy, fw.k1) == (49.5, 39.5, 0.0)
    assert "Camera(width=100" in repr(fw)


@pytest.mark.parametrize("params, message", [
    ({"width": 100, "height": 80, "fx": 500}, "fy is missing"),
    ({"width": 100, "height": 80, "fx": 500, "fx_px": 500, "fy": 1}, "fx given twice"),
    ({"width": 0, "height": 80, "fx": 500, "fy": 500}, "width must be an int"),
    ({"width": 100.0, "height": 80, "fx": 500, "fy": 500}, "width must be an int"),
    ({"width": 100, "height": 5000, "fx": 500, "fy": 500}, "height must be an int"),
    ({"width": 100, "height": 80, "fx": -5, "fy": 500}, "must be > 0"),
    ({"width": 100, "height": 80, "fx": 500, "fy": float("nan")}, "fy must be a finite"),
    ({"width": 100, "height": 80, "fx": 500, "fy": 500, "k1": "0"}, "k1 must be a finite"),
    ({"width": 100, "height": 80, "fx": 500, "fy": 500, "k1": True}, "k1 must be a finite"),
    ({"width": 752, "height": 480, "fx": 300, "fy": 300, "k1": -1.0},
     "not invertible over the frame"),
])
def test_invalid_parameters_raise(params, message):
    with pytest.raises(ValueError, match=message):
        Camera.from_dict(params)


def test_failures_return_none_with_a_status():
    cam = Camera(752, 480, 500.0, 500.0, k1=-0.1)    # fold radius 1.83 (r^2 = 10/3)
    assert cam.pixel_to_vector(375.5, 239.5) == pytest.approx((0.0, 0.0, 1.0))
    assert cam.last_status == S.OK
    assert cam.pixel_to_vector(float("nan"), 3.0) is None
    assert cam.last_status == S.BAD_INPUT
    assert cam.pixel_to_vector(None, 3.0) is None and cam.last_status == S.BAD_INPUT
    assert cam.pixel_to_vector(1e6, 0.0) is None              # beyond the fold
    assert cam.last_status == S.CAMERA_NOT_CONVERGED
    assert cam.vector_to_pixel((0.0, 0.0, -1.0)) is None
    assert cam.last_status == S.CAMERA_OUT_OF_VIEW
    assert cam.vector_to_pixel((1.0, 0.0, 0.0)) is None
    assert cam.vector_to_pixel((10.0, 0.0, 1.0)) is None      # r = 10 > fold radius
    assert cam.last_status == S.CAMERA_OUT_OF_VIEW
    for bad in [(1.0, 2.0), None, (float("inf"), 0.0, 1.0), ("a", 0, 1)]:
        assert cam.vector_to_pixel(bad) is None
        assert cam.last_status == S.BAD_INPUT
    assert cam.vector_to_pixel([0.0, 0.0, 2.0]) == pytest.approx((375.5, 239.5))


def test_in_frame():
    cam = Camera(10, 8, 100.0, 100.0)
    assert cam.in_frame(-0.5, -0.5) and cam.in_frame(9.49, 7.49)
    assert not cam.in_frame(9.5, 0) and not cam.in_frame(0, 7.5) and not cam.in_frame(-0.51, 0)


@pytest.mark.parametrize("name", PRESETS)
def test_smear_matches_rotating_the_direction(name):
    """``smear_px`` equals the track of ``lodestar.sim``'s motion model, ``v(t) =
    exp(-[omega x] t) v(0)``, from ``-T/2`` to ``+T/2`` about the centroid's direction."""
    sim_cam = load_preset(name)
    fw = firmware_camera(sim_cam)
    rng = np.random.default_rng(5)
    exposure = 0.2
    for _ in range(20):
        omega = rng.normal(0.0, math.radians(2.0), 3)
        x, y = rng.uniform(0, sim_cam.width - 1), rng.uniform(0, sim_cam.height - 1)
        v_mid = sim_cam.unproject(x, y)
        ends = [Rotation.from_rotvec(-omega * t).apply(v_mid) for t in (-exposure / 2,
                                                                        exposure / 2)]
        px, py, _ = sim_cam.project(np.array(ends))
        got = fw.smear_px(x, y, tuple(omega), exposure)
        assert got == pytest.approx((px[1] - px[0], py[1] - py[0]), abs=1e-6)
    # a rate about +y moves stars towards -x (dv/dt = -omega x v); length ~ rate * T * f
    dx, dy = fw.smear_px(sim_cam.cx, sim_cam.cy, (0.0, 0.01, 0.0), 1.0)
    assert dx == pytest.approx(-0.01 * sim_cam.fx_px, rel=1e-4) and abs(dy) < 1e-9
    assert fw.smear_px(10.0, 10.0, (0.0, 0.0, 0.0), 0.1) == (0.0, 0.0)
    assert fw.smear_px(float("nan"), 10.0, (0.0, 0.0, 1.0), 0.1) is None
    for omega, exposure in [((float("nan"), 0.0, 0.0), 0.1), ((0.0, 0.0), 0.1), (None, 0.1),
                            ((0.0, 0.0, 1.0), float("inf"))]:
        assert fw.smear_px(10.0, 10.0, omega, exposure) is None
        assert fw.last_status == S.BAD_INPUT


@pytest.mark.parametrize("name", PRESETS)
def test_smear_function_is_smear_px_for_one_rate(name):
    fw = firmware_camera(load_preset(name))
    rng = np.random.default_rng(6)
    omega = tuple(rng.normal(0.0, math.radians(2.0), 3))
    smear = fw.smear_function(omega, 0.1)
    for _ in range(10):
        x, y = rng.uniform(0, fw.width - 1), rng.uniform(0, fw.height - 1)
        assert smear(x, y) == fw.smear_px(x, y, omega, 0.1)
    assert fw.smear_function((0.0, 0.0, 0.0), 0.1)(5.0, 5.0) == (0.0, 0.0)
    assert fw.smear_function((0.0, 0.0), 0.1) is None
    assert fw.smear_function(omega, float("nan")) is None


@pytest.mark.parametrize("distorted", [False, True])
def test_pixel_tangent_is_the_direction_s_derivative(distorted):
    """A pinhole's tangent is the analytic derivative (a central difference over +-1e-3 px
    within 1e-7); a distorted camera's the difference over one pixel (the central one over
    +-0.5 px within 1e-3: the undistortion's Newton tolerance)."""
    cam = Camera(2592, 1944, 3000.0, 3000.0, k1=-0.05 if distorted else 0.0)
    rng = np.random.default_rng(7)
    for _ in range(20):
        x, y = rng.uniform(0, 2591), rng.uniform(0, 1943)
        phi = rng.uniform(0, 2 * math.pi)
        ex, ey = math.cos(phi), math.sin(phi)
        h = 0.5 if distorted else 1e-3
        a = np.array(cam.pixel_to_vector(x - h * ex, y - h * ey))
        b = np.array(cam.pixel_to_vector(x + h * ex, y + h * ey))
        d = (b - a) / (2 * h)
        t = cam.pixel_tangent(x, y, ex, ey)
        tol = 1e-3 if distorted else 1e-7
        assert np.allclose(t[:3], d / np.linalg.norm(d), atol=tol)
        assert t[3] == pytest.approx(np.linalg.norm(d), rel=tol)
    assert Camera(752, 480, 1000.0, 1000.0).pixel_tangent(10.0, 10.0, 0.0, 0.0) is None


def test_float_epsilon_and_tolerance_floors():
    assert geometry.EPS == np.finfo(float).eps
    cam = Camera(752, 480, 1000.0, 1000.0)
    assert cam._step_px == camera.NEWTON_STEP_PX and cam._residual_px == camera.NEWTON_RESIDUAL_PX
