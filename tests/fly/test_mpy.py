"""The executive as another process, its peripherals served by the twin line by line: with
CPython as the MCU's interpreter the loop gives exactly the in-process loop's steps (the
protocol loses nothing); on the flight MCU's MicroPython (slow: the 32-bit unix port, built
once) it boots, solves lost in space, tracks and reports no wrong attitude."""

import sys

import pytest

from lodestar.fly import twin
from tests.fly.conftest import make_twin

KEYS = ("status", "mode", "error_arcsec", "records", "frame", "solve", "mcu_ms", "reported",
        "reported_error_arcsec", "sigma_cross_arcsec", "sigma_roll_arcsec")


def test_remote_cpython_gives_the_in_process_steps(small_camera):
    local = make_twin(small_camera)
    remote = make_twin(small_camera, micropython=sys.executable)
    try:
        a, b = local.run(4), remote.run(4)
    finally:
        remote.close()
    assert [[r[k] for k in KEYS] for r in a] == [[r[k] for k in KEYS] for r in b]
    assert any(r["status"] == "OK" for r in b)
    assert list(remote.exe.health) == list(local.exe.health)
    assert list(remote.link.counters) == list(local.link.counters)


@pytest.mark.slow
def test_the_executive_on_the_flight_micropython(small_camera):
    from lodestar.regress import unixport

    reason = unixport.unavailable_reason()
    if reason:
        pytest.skip("MicroPython unix port unavailable: " + reason)
    loop = make_twin(small_camera, micropython=unixport.float32_build())
    try:
        rows = loop.run(18)
    finally:
        loop.close()
    s = twin.summary(rows, loop)
    assert s["wrong"] == 0 and s["lost_in_space_solves"] == 1 and s["tracking_solves"] >= 3
