"""Tests of ``lodestar.firmware.aberration`` against astropy: the apparent (GCRS) direction
of a star at an observation time is the ICRS one aberrated by the Earth's barycentric
velocity, to 0.1" (light deflection, which astropy includes, is below 0.02" more than 45 deg
from the Sun), in double and in single precision; and back."""

import math

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import GCRS, SkyCoord, get_body_barycentric_posvel, get_sun
from astropy.time import Time

from lodestar.firmware import aberration
from lodestar.sim.scene import apparent

RAD_TO_ARCSEC = 180.0 * 3600.0 / math.pi


def angle_arcsec(a, b):
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    return math.atan2(np.linalg.norm(np.cross(a, b)), float(np.dot(a, b))) * RAD_TO_ARCSEC


def earth_velocity_km_s(t):
    """The Earth's barycentric velocity at ``t``, km/s, ICRS axes (astropy)."""
    vel = get_body_barycentric_posvel("earth", t)[1]
    return vel.xyz.to_value(u.km / u.s)


def astropy_case(when, n=40, seed=1):
    """``(ICRS unit vectors, GCRS unit vectors, velocity km/s)`` of ``n`` random directions
    more than 45 deg from the Sun at time ``when``."""
    t = Time(when, scale="utc")
    rng = np.random.default_rng(seed)
    ra = rng.uniform(0.0, 360.0, 4 * n)
    dec = np.degrees(np.arcsin(rng.uniform(-1.0, 1.0, 4 * n)))
    icrs = SkyCoord(ra=ra * u.deg, dec=dec * u.deg, frame="icrs")
    sun = get_sun(t).transform_to("icrs")
    far = icrs.separation(sun).deg > 45.0
    icrs = icrs[far][:n]
    gcrs = icrs.transform_to(GCRS(obstime=t))
    return (icrs.cartesian.xyz.value.T, gcrs.cartesian.xyz.value.T, earth_velocity_km_s(t))


@pytest.mark.parametrize("when", ["2026-03-20T12:00:00", "2026-11-26T13:00:00"])
def test_aberration_reproduces_astropy_gcrs_to_0_1_arcsec(when):
    icrs, gcrs, v = astropy_case(when)
    b = aberration.beta(v)
    assert 29.0 < np.linalg.norm(v) < 31.0
    shifts, errors, errors32, back = [], [], [], []
    b32 = tuple(np.float32(x) for x in b)
    for u_icrs, p_true in zip(icrs, gcrs):
        shifts.append(angle_arcsec(u_icrs, p_true))
        p = aberration.aberrate(tuple(u_icrs), b)
        errors.append(angle_arcsec(p, p_true))
        # single precision, as the MCU computes it: inputs and every operation float32
        p32 = aberration.aberrate(tuple(np.float32(x) for x in u_icrs), b32)
        assert all(isinstance(x, np.float32) for x in p32)
        errors32.append(angle_arcsec(p32, p_true))
        back.append(angle_arcsec(aberration.deaberrate(tuple(p_true), b), u_icrs))
    print(f"\n{when}: shift max {max(shifts):.2f}\", error max {max(errors):.4f}\" "
          f"(float32 {max(errors32):.4f}\"), inverse max {max(back):.4f}\"")
    assert max(shifts) > 15.0                 # the correction is there to be wrong
    assert max(errors) < 0.1 and max(errors32) < 0.1 and max(back) < 0.1


def test_first_order_form_matches_the_exact_one():
    """The sim's exact relativistic formula and the firmware's first-order form agree to
    ``beta^2`` at the fastest accepted speed and to 0.003" at the Earth's."""
    rng = np.random.default_rng(3)
    dirs = rng.normal(size=(200, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    for speed, limit in ((30.0, 0.003), (aberration.MAX_SPEED_KM_S, 0.03)):
        v = speed * np.array([0.6, -0.48, 0.64])
        exact = apparent(dirs, v)
        b = aberration.beta(v)
        worst = max(angle_arcsec(aberration.aberrate(tuple(d), b), e) for d, e in zip(dirs, exact))
        assert worst < limit, (speed, worst)
        assert abs(np.linalg.norm(aberration.aberrate(tuple(dirs[0]), b)) - 1.0) < 2e-7


def test_beta_accepts_only_plausible_velocities():
    assert aberration.beta((0.0, 0.0, 0.0)) == (0.0, 0.0, 0.0)
    assert aberration.beta([29.8, 0, 0])[0] == pytest.approx(29.8 / 299792.458)
    for bad in (None, "fast", (1.0, 2.0), (float("nan"), 0, 0), (float("inf"), 0, 0),
                (aberration.MAX_SPEED_KM_S + 1, 0, 0), ("a", 0, 0), (10 ** 400, 0, 0)):
        assert aberration.beta(bad) is None, bad


def test_aberration_under_micropython(micropython):
    """MicroPython 1.27 computes what CPython does (the same module, unchanged)."""
    rng = np.random.default_rng(5)
    dirs = rng.normal(size=(5, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    v = [12.5, -25.0, 8.0]
    script = ("from lodestar.firmware import aberration\n"
              f"B = aberration.beta({v!r})\n"
              "print('BETA', B, aberration.beta((1e3, 0, 0)))\n"
              f"for d in {dirs.tolist()!r}:\n"
              "    p = aberration.aberrate(d, B)\n"
              "    print('P', list(p), list(aberration.deaberrate(p, B)))\n")
    code, out = micropython(script)
    assert code == 0, out
    b = aberration.beta(v)
    got_b = [line for line in out.splitlines() if line.startswith("BETA")][0]
    assert got_b.endswith("None") and str(b[0])[:10] in got_b
    rows = [line.split(" ", 1)[1] for line in out.splitlines() if line.startswith("P ")]
    assert len(rows) == len(dirs)
    for d, row in zip(dirs, rows):
        p, back = eval(row.replace("] [", "], ["))
        assert p == pytest.approx(list(aberration.aberrate(tuple(d), b)), abs=1e-15)
        assert back == pytest.approx(list(aberration.deaberrate(aberration.aberrate(tuple(d), b),
                                                                b)), abs=1e-15)
