"""The MT9P031 register model against the firmware's driver: the power-up sequence without a
violation gives the 96 MHz pixel clock and the 10 Hz flight frame; synchronized changes land
together; a soft reset restores the defaults; a PLL selected before it locked, an illegal
word and a sensor that stops answering are seen."""

import pytest

from lodestar.firmware import sensor
from lodestar.firmware import status as S
from lodestar.fly import mt9p031


class _Now:
    def __init__(self):
        self.t = 0.0

    def __call__(self):
        return self.t

    def sleep_ms(self, ms):
        self.t += ms / 1000.0


def _chip():
    now = _Now()
    chip = mt9p031.MT9P031(now)
    return chip, sensor.Sensor(chip, sensor.MT9P031, sleep_ms=now.sleep_ms)


def test_start_gives_the_flight_frame_the_driver_expects():
    chip, cam = _chip()
    assert chip.frame_settings()["frame_s"] > 0.25          # 25 MHz without the PLL
    st, _reason, settings = sensor.p031_flight(0.1)
    assert cam.start(settings) == (S.OK, "")
    assert chip.violations == [] and chip.pixclk_hz() == pytest.approx(sensor.PIXCLK_HZ, rel=1e-4)
    got = chip.frame_settings()
    st, _reason, (row, exposure, frame) = cam.timing()
    assert st == S.OK and got["window"] == settings["window"] and got["gain"] == 1.0
    # the same to the firmware's pixel clock in whole Hz
    assert (got["row_s"], got["exposure_s"], got["frame_s"]) == pytest.approx(
        (row, exposure, frame), rel=1e-8)
    assert got["frame_s"] == pytest.approx(0.1, rel=1e-3)
    assert got["exposure_s"] == pytest.approx(0.1, rel=1e-3)


def test_synchronized_changes_land_together_and_gain():
    chip, cam = _chip()
    cam.start(sensor.p031_flight(0.1)[2])
    before = chip.frame_settings()["exposure_s"]
    assert cam.configure(exposure=1000, gain=24) == (S.OK, "")
    got = chip.frame_settings()
    assert got["gain"] == 3.0 and got["exposure_s"] < before / 2 and not chip.pending


def test_soft_reset_pll_lock_illegal_words_and_silence():
    chip, cam = _chip()
    cam.start(sensor.p031_flight(0.1)[2])
    chip.writeto_mem(mt9p031.ADDRESS, 0x0D, b"\x00\x01")
    assert chip.frame_settings() is None                   # held in reset
    chip.writeto_mem(mt9p031.ADDRESS, 0x0D, b"\x00\x00")
    assert chip.regs[0x09] == 0x0797 and chip.pixclk_hz() == 25e6
    chip.writeto_mem(mt9p031.ADDRESS, 0x10, b"\x00\x51")
    chip.writeto_mem(mt9p031.ADDRESS, 0x10, b"\x00\x53")   # no lock wait
    chip.writeto_mem(mt9p031.ADDRESS, 0x00, b"\x12\x34")   # read-only
    assert chip.violations == [(0x10, 0x53), (0x00, 0x1234)]
    chip.answering = False
    assert cam.identify()[0] == S.BAD_INPUT
    with pytest.raises(OSError):
        chip.readfrom_mem(0x48, 0x00, 2)
