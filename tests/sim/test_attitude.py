"""Attitude helpers: pointing, roll convention, round trips, uniformity, bad inputs."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import kstest

from lodestar.sim.attitude import (
    boresight,
    from_radec_roll,
    random_attitude,
    to_radec_roll,
)
from lodestar.sim.presets import load_preset


def radec_vector(ra_deg, dec_deg):
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    return np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=-1)


def test_known_matrix_at_origin():
    # boresight at (0, 0): x_cam = -east = -Y, y_cam = -north = -Z, z_cam = +X
    a = Rotation.from_quat(from_radec_roll(0.0, 0.0, 0.0)).as_matrix()
    np.testing.assert_allclose(a, [[0, -1, 0], [0, 0, -1], [1, 0, 0]], atol=1e-15)


def test_boresight_points_at_radec():
    rng = np.random.default_rng(1)
    ra, dec, roll = rng.uniform(0, 360, 200), rng.uniform(-90, 90, 200), rng.uniform(-180, 180, 200)
    q = from_radec_roll(ra, dec, roll)
    assert q.shape == (200, 4)
    np.testing.assert_allclose(boresight(q), radec_vector(ra, dec), atol=1e-14)
    v_cam = Rotation.from_quat(q).apply(radec_vector(ra, dec))
    np.testing.assert_allclose(v_cam, np.tile([0.0, 0.0, 1.0], (200, 1)), atol=1e-14)


@pytest.mark.parametrize("roll,north_cam,east_cam", [
    (0.0, [0, -1, 0], [-1, 0, 0]),      # north up, east left on the display
    (90.0, [-1, 0, 0], [0, 1, 0]),      # north turned counter-clockwise to the left
    (180.0, [0, 1, 0], [1, 0, 0]),
])
def test_roll_convention(roll, north_cam, east_cam):
    ra, dec = 123.0, 37.0
    r = Rotation.from_quat(from_radec_roll(ra, dec, roll))
    north = [-np.sin(np.radians(dec)) * np.cos(np.radians(ra)),
             -np.sin(np.radians(dec)) * np.sin(np.radians(ra)), np.cos(np.radians(dec))]
    east = [-np.sin(np.radians(ra)), np.cos(np.radians(ra)), 0.0]
    np.testing.assert_allclose(r.apply(north), north_cam, atol=1e-14)
    np.testing.assert_allclose(r.apply(east), east_cam, atol=1e-14)


def test_positive_roll_is_right_handed_about_boresight():
    q0, q1 = from_radec_roll(10.0, 20.0, 0.0), from_radec_roll(10.0, 20.0, 30.0)
    # A1 = Rz(roll)^T A0 in the camera frame: the camera turned +30 deg about +z
    delta = Rotation.from_quat(q0) * Rotation.from_quat(q1).inv()
    np.testing.assert_allclose(delta.as_rotvec(), [0, 0, np.radians(30.0)], atol=1e-14)


def test_stars_land_where_the_sky_says():
    """Through the estcube2 camera at roll 0, a star north of the boresight is above the
    centre (smaller row) and a star east of it is left of the centre (smaller column)."""
    cam = load_preset("estcube2")
    r = Rotation.from_quat(from_radec_roll(80.0, 10.0, 0.0))
    x, y, valid = cam.project(r.apply(radec_vector([80.0, 81.0], [11.0, 10.0])))
    assert valid.all()
    assert y[0] < cam.cy - 100 and abs(x[0] - cam.cx) < 1e-6
    assert x[1] < cam.cx - 100


def test_radec_roll_round_trip():
    rng = np.random.default_rng(2)
    ra, dec, roll = rng.uniform(0, 360, 500), rng.uniform(-89.9, 89.9, 500), \
        rng.uniform(-179.9, 180, 500)
    ra2, dec2, roll2 = to_radec_roll(from_radec_roll(ra, dec, roll))
    np.testing.assert_allclose(ra2, ra, atol=1e-9)
    np.testing.assert_allclose(dec2, dec, atol=1e-9)
    np.testing.assert_allclose(roll2, roll, atol=1e-9)
    assert np.all((ra2 >= 0) & (ra2 < 360)) and np.all((roll2 > -180) & (roll2 <= 180))


def test_quaternion_round_trip_including_poles():
    rng = np.random.default_rng(3)
    q = np.vstack([random_attitude(rng, 300),
                   from_radec_roll([0.0, 45.0, 200.0], [90.0, -90.0, 90.0], [10.0, -20.0, 0.0])])
    q2 = from_radec_roll(*to_radec_roll(q))
    err = (Rotation.from_quat(q) * Rotation.from_quat(q2).inv()).magnitude()
    assert np.max(err) < 1e-12


def test_scalar_shapes():
    q = from_radec_roll(10.0, 20.0, 30.0)
    assert q.shape == (4,) and boresight(q).shape == (3,)
    ra, dec, roll = to_radec_roll(q)
    assert np.ndim(ra) == np.ndim(dec) == np.ndim(roll) == 0
    assert (float(ra), float(dec), float(roll)) == pytest.approx((10.0, 20.0, 30.0))


def test_random_attitude_is_uniform():
    rng = np.random.default_rng(4)
    q = random_attitude(rng, 4000)
    assert q.shape == (4000, 4) and np.all(q[:, 3] >= 0)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-15)
    b = boresight(q)
    assert kstest(b[:, 2], "uniform", args=(-1, 2)).pvalue > 1e-3      # uniform on the sphere
    ra, _, roll = to_radec_roll(q)
    assert kstest(ra, "uniform", args=(0, 360)).pvalue > 1e-3
    assert kstest(roll, "uniform", args=(-180, 360)).pvalue > 1e-3
    # Haar measure: the rotation angle t has density (1 - cos t) / pi, i.e. E[cos t] = -1/2
    assert np.mean(np.cos(Rotation.from_quat(q).magnitude())) == pytest.approx(-0.5, abs=0.03)
    one = random_attitude(np.random.default_rng(5))
    assert one.shape == (4,)
    np.testing.assert_array_equal(one, random_attitude(np.random.default_rng(5)))


@pytest.mark.parametrize("q,match", [
    ([np.nan, 0, 0, 1], "NaN"),
    ([0, 0, 0, np.inf], "NaN or inf"),
    ([1, 1, 0, 0], "not unit length"),
    ([0, 0, 0, 0], "not unit length"),
    ([0, 0, 1], r"shape \(4,\) or \(N, 4\)"),
])
def test_bad_quaternions(q, match):
    for f in (boresight, to_radec_roll):
        with pytest.raises(ValueError, match=match):
            f(q)


@pytest.mark.parametrize("args,match", [
    ((np.nan, 0, 0), "finite"),
    ((0, np.inf, 0), "finite"),
    ((0, 0, np.nan), "finite"),
    ((0, 90.5, 0), r"dec must lie in \[-90, 90\]"),
])
def test_bad_pointing(args, match):
    with pytest.raises(ValueError, match=match):
        from_radec_roll(*args)
