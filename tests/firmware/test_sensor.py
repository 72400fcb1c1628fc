"""Sensor set-up over two-wire serial against a register model of each sensor built here from
its datasheet (independently of ``firmware/sensor.py``'s tables): register addresses and
reset values, the fields' limits, read-only registers, and what the registers mean (the
window, blanking, exposure and gain the sensor then uses; the MT9V022's LVDS output format).
A fake ``machine.I2C``-like bus carries 16-bit big-endian words; a wrong address NACKs."""

import pytest

from lodestar.firmware import sensor
from lodestar.firmware import status as S
from lodestar.hdl.boards import BOARDS


class Field:
    """A register: reset value, legal values (a predicate), read-only or not."""

    def __init__(self, reset, legal=lambda v: 0 <= v <= 0xFFFF, read_only=False):
        self.reset, self.legal, self.read_only = reset, legal, read_only


def _rng(low, high, even=False):
    return lambda v: low <= v <= high and not (even and v % 2)


def _p031_gain_ok(v):
    """R0x35: analog gain bits [5:0] (8 .. 32 without the multiplier, up to 63 with it),
    analog multiplier bit 6, digital gain bits [14:8] (0 .. 120); other bits 0."""
    analog, mult, digital = v & 0x3F, (v >> 6) & 1, (v >> 8) & 0x7F
    return v & ~0x7F7F == 0 and 8 <= analog and digital <= 120 and (mult or analog <= 32)


# MT9P031 datasheet register table (reset values; R0x03/R0x04 hold size - 1, R0x06 rows - 1)
MT9P031_MAP = {
    0x00: Field(0x1801, read_only=True),               # chip version
    0x01: Field(0x0036, _rng(0, 2004, even=True)),     # row start
    0x02: Field(0x0010, _rng(0, 2750, even=True)),     # column start
    0x03: Field(0x0797, _rng(1, 2005)),                # row size (height - 1)
    0x04: Field(0x0A1F, _rng(1, 2751)),                # column size (width - 1)
    0x05: Field(0x0000, _rng(0, 4095)),                # horizontal blank (HB - 1, 2 PIXCLK)
    0x06: Field(0x0019, _rng(0, 4095)),                # vertical blank (rows - 1)
    0x07: Field(0x1F82),                               # output control (bit 0 synchronize
    #                                                    changes, bit 1 chip enable)
    0x08: Field(0x0000, _rng(0, 15)),                  # shutter width upper
    0x09: Field(0x0797),                               # shutter width lower
    0x0A: Field(0x0000),                               # pixel clock control
    0x0B: Field(0x0000, _rng(0, 3)),                   # restart (bit 0), pause restart (1)
    0x0C: Field(0x0000, _rng(0, 0x1FFF)),              # shutter delay
    0x0D: Field(0x0000, _rng(0, 1)),                   # reset
    0x10: Field(0x0050, lambda v: v in (0x0050, 0x0051, 0x0053)),   # PLL control
    0x11: Field(0x6404, lambda v: v >> 8 >= 16 and v & 0xFF <= 63),  # PLL M, N - 1
    0x12: Field(0x0000, _rng(0, 127)),                 # PLL P1 - 1
    0x22: Field(0x0000, _rng(0, 0x37)),                # row address mode
    0x23: Field(0x0000, _rng(0, 0x37)),                # column address mode
    0x35: Field(0x0008, _p031_gain_ok),                # global gain
}
P031_SYNCHRONIZED = (0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x08, 0x09, 0x35)
"""Registers whose new values wait while Synchronize_Changes (R0x07[0]) is set."""

# MT9V022 datasheet (Rev.H) register table
MT9V022_MAP = {
    0x00: Field(0x1313, read_only=True),               # chip version
    0x01: Field(0x0001, _rng(1, 752)),                 # column start
    0x02: Field(0x0004, _rng(4, 482)),                 # row start
    0x03: Field(0x01E0, _rng(1, 480)),                 # window height
    0x04: Field(0x02F0, _rng(1, 752)),                 # window width
    0x05: Field(0x005E, _rng(43, 1023)),               # horizontal blanking
    0x06: Field(0x002D, _rng(4, 3000)),                # vertical blanking
    0x07: Field(0x0388),                               # chip control
    0x0B: Field(0x01E0, _rng(1, 32767)),               # total shutter width
    0x35: Field(0x0010, _rng(16, 64)),                 # analog gain
    0x0C: Field(0x0000, _rng(0, 3)),                   # reset: bit 0 soft reset
    0xAF: Field(0x0003, _rng(0, 3)),                   # AEC (bit 0) / AGC (bit 1) enable
    0xB1: Field(0x0002, _rng(0, 15)),                  # LVDS master: bit 1 power-down
    0xB2: Field(0x0010),                               # LVDS shift clock control
    0xB3: Field(0x0010),                               # LVDS data control
    0xB6: Field(0x0000, _rng(0, 1)),                   # LVDS payload: bit 0 10-bit pixels
}

ADDRESS = {"mt9p031": 0x5D, "mt9v022": 0x48}


class FakeSensor:
    """The sensor on a fake bus: ``writeto_mem``/``readfrom_mem`` like ``machine.I2C``."""

    def __init__(self, model, chip=None, stuck=(), extclk=25e6):
        self.map = MT9P031_MAP if model == "mt9p031" else MT9V022_MAP
        self.regs = {a: f.reset for a, f in self.map.items()}
        if chip is not None:
            self.regs[0x00] = chip
        self.address, self.stuck = ADDRESS[model], set(stuck)
        self.writes, self.violations = [], []
        self.extclk, self.now_ms, self.pll_powered_ms = extclk, 0.0, None
        self.pending = {}             # synchronized writes held by R0x07[0]
        self.output_stopped = False   # the chip enable was ever cleared

    def sleep_ms(self, ms):
        self.now_ms += ms

    def _check_address(self, addr):
        if addr != self.address:
            raise OSError(19)                 # MicroPython: ENODEV (no ACK)

    def writeto_mem(self, addr, reg, buf):
        self._check_address(addr)
        assert len(buf) == 2
        word = (buf[0] << 8) | buf[1]
        self.writes.append((reg, word))
        field = self.map.get(reg)
        if field is None or field.read_only or not field.legal(word):
            self.violations.append((reg, word))
            return
        if reg in self.stuck:
            return
        if self.map is MT9P031_MAP:
            self._p031_write(reg, word)
        else:
            self.regs[reg] = word

    def _p031_write(self, reg, word):
        if reg == 0x0D and word == 1:                       # soft reset: defaults
            self.regs = {a: f.reset for a, f in self.map.items() if a != 0x00} | {
                0x00: self.regs[0x00], 0x0D: 1}
            self.pending = {}
            return
        if reg == 0x10:
            if word == 0x0051:
                self.pll_powered_ms = self.now_ms
            elif word == 0x0053 and (self.pll_powered_ms is None
                                     or self.now_ms - self.pll_powered_ms < 1.0):
                self.violations.append((reg, word))           # used before it locked
        if reg == 0x07:
            if not word & 0x0002:
                self.output_stopped = True
            if not word & 0x0001:                             # changes applied together
                self.regs.update(self.pending)
                self.pending = {}
        if reg in P031_SYNCHRONIZED and self.regs[0x07] & 0x0001:
            self.pending[reg] = word
            return
        self.regs[reg] = word

    def readfrom_mem_pending(self, reg):
        return self.pending.get(reg, self.regs.get(reg, 0))

    def readfrom_mem(self, addr, reg, n):
        self._check_address(addr)
        word = self.pending.get(reg, self.regs.get(reg, 0))   # a held write reads back
        return bytes([word >> 8, word & 0xFF])[:n]

    # MT9P031 clocks and frame timing, from the datasheet (independently of the driver)
    def pixclk(self):
        """PIXCLK: EXTCLK when the PLL is not used, else EXTCLK x M / N / P1, None when a
        PLL limit is broken (input 2-13.5 MHz, VCO 180-360 MHz, PIXCLK <= 96 MHz)."""
        r = self.regs
        if r[0x10] != 0x0053:
            return self.extclk
        m, n, p1 = r[0x11] >> 8, (r[0x11] & 0xFF) + 1, r[0x12] + 1
        f_in, vco = self.extclk / n, self.extclk * m / n
        if not (2e6 <= f_in <= 13.5e6 and 180e6 <= vco <= 360e6 and vco / p1 <= 96e6):
            return None
        return vco / p1

    def frame_timing(self):
        """(row s, exposure s, frame s) of the registers in effect: datasheet Rev. J frame
        timing, no binning or skipping: tROW = 2 tPIX max(W/2 + max(HB, 450), 486),
        frame = max(H + max(VB, 9), SW + 1) rows, exposure = SW rows - 2 tPIX SO,
        SO = 208 + 98 + SD - 94 (SD = shutter delay + 1)."""
        r = self.regs
        t2 = 2 / self.pixclk()
        w, h = r[0x04] + 1, r[0x03] + 1
        row = t2 * max(w / 2 + max(r[0x05] + 1, 450), 41 + 346 + 99)
        sw = max(1, r[0x08] << 16 | r[0x09])
        rows = max(h + max(r[0x06] + 1, 9), sw + 1)
        return row, sw * row - t2 * (208 + 98 + r[0x0C] + 1 - 94), rows * row

    # what the registers mean
    def window(self):
        r = self.regs
        if self.map is MT9P031_MAP:
            return (r[0x02], r[0x01], r[0x04] + 1, r[0x03] + 1)
        return (r[0x01], r[0x02], r[0x04], r[0x03])

    def exposure(self):
        r = self.regs
        return (r[0x08] << 16 | r[0x09]) if self.map is MT9P031_MAP else r[0x0B]

    def gain(self):
        """The gain as a multiple of 1x (MT9P031 datasheet: analog/8 x (1 + multiplier) x
        (1 + digital/8); MT9V022: R0x35 / 16)."""
        v = self.regs[0x35]
        if self.map is MT9P031_MAP:
            return (v & 0x3F) / 8 * (1 + (v >> 6 & 1)) * (1 + (v >> 8 & 0x7F) / 8)
        return v / 16

    def vblank_rows(self):
        return self.regs[0x06] + 1 if self.map is MT9P031_MAP else self.regs[0x06]

    def lvds_10bit(self):
        """The stand-alone LVDS stream the gateware decodes: LVDS powered up, 10-bit pixel
        payload (R0xB6[0] = 1)."""
        return not self.regs[0xB1] & 0x2 and self.regs[0xB6] & 1


TYPICAL = {
    "mt9p031": dict(exposure=800, gain=24, window=(16, 54, 2592, 1944), hblank=450,
                    vblank=26, mode="parallel"),
    "mt9v022": dict(exposure=300, gain=32, window=(1, 4, 752, 480), hblank=94, vblank=45,
                    mode="lvds"),
}


@pytest.mark.parametrize("model", sorted(TYPICAL))
def test_configure_sets_what_the_sensor_uses(model):
    fake = FakeSensor(model)
    settings = TYPICAL[model]
    assert sensor.Sensor(fake, model).configure(**settings) == (S.OK, "")
    assert fake.violations == []
    assert fake.window() == settings["window"]
    assert fake.exposure() == settings["exposure"]
    assert fake.vblank_rows() == settings["vblank"]
    if model == "mt9p031":
        assert fake.regs[0x05] == settings["hblank"] - 1  # HB - 1, in 2-PIXCLK units
        assert fake.gain() == settings["gain"] / 8
        assert fake.regs[0x07] == 0x1F82                  # changes applied together
        assert fake.regs[0x0A] & 0x8000 == 0              # PIXCLK edge as the gateware's
        assert fake.writes[0] == (0x07, 0x1F83)           # held while they are written
        assert not fake.output_stopped                    # the read-out never stopped
    else:
        assert fake.regs[0x05] == settings["hblank"]
        assert fake.gain() == settings["gain"] / 16
        assert fake.lvds_10bit()
        assert fake.regs[0xAF] == 0                       # manual exposure and gain
        assert fake.regs[0x07] & 0x0008                   # master mode
        assert fake.regs[0x07] & 0x0020 == 0              # stand-alone, not stereoscopy


def test_mt9v022_parallel_mode_powers_lvds_down():
    fake = FakeSensor("mt9v022")
    settings = dict(TYPICAL["mt9v022"], mode="parallel")
    assert sensor.Sensor(fake, "mt9v022").configure(**settings)[0] == S.OK
    assert fake.regs[0xB1] & 0x2 and not fake.lvds_10bit() and fake.violations == []


def test_mt9p031_every_gain_step():
    """Each gain the stages can make is set exactly; every other value is refused unwritten."""
    made = 0
    for g in range(0, 1100):
        fake = FakeSensor("mt9p031")
        st, reason = sensor.Sensor(fake, "mt9p031").configure(gain=g)
        if st == S.OK:
            made += 1
            assert fake.gain() == g / 8 and fake.violations == [], g
        else:
            assert st == S.BAD_INPUT and "gain" in reason and fake.writes == [], g
            assert not (8 <= g <= 32 or (32 < g <= 64 and g % 2 == 0)
                        or (64 < g <= 1024 and g % 8 == 0)), g
    assert made == 25 + 16 + 120


@pytest.mark.parametrize("model,settings,word", [
    ("mt9p031", dict(window=(15, 54, 2592, 1944)), "even"),
    ("mt9p031", dict(window=(16, 54, 2740, 1944)), "past"),
    ("mt9p031", dict(window=(16, 54, 2592)), "window"),
    ("mt9p031", dict(exposure=0), "exposure"),
    ("mt9p031", dict(exposure=1 << 20), "exposure"),
    ("mt9p031", dict(vblank=0), "vblank"),
    ("mt9p031", dict(hblank=4097), "hblank"),
    ("mt9p031", dict(hblank=449), "hblank"),           # below HBmin (Linux: 450)
    ("mt9p031", dict(mode="lvds"), "mode"),
    ("mt9p031", dict(exposure=True), "exposure"),
    ("mt9p031", dict(shutter=5), "setting"),
    ("mt9v022", dict(window=(1, 4, 600, 480), hblank=43), "660"),
    ("mt9v022", dict(window=(1, 4, 752, 480)), "both"),
    ("mt9v022", dict(window=(2, 4, 752, 480), hblank=94), "past"),
    ("mt9v022", dict(window=(1, 3, 752, 480), hblank=94), "row"),
    ("mt9v022", dict(gain=65), "gain"),
    ("mt9v022", dict(gain=15), "gain"),
    ("mt9v022", dict(vblank=3001), "vblank"),
    ("mt9v022", dict(exposure=32768), "exposure"),
    ("mt9v022", dict(mode="serial"), "mode"),
])
def test_bad_settings_are_refused_before_any_write(model, settings, word):
    fake = FakeSensor(model)
    st, reason = sensor.Sensor(fake, model).configure(**settings)
    assert st == S.BAD_INPUT and word in reason, reason
    assert fake.writes == [] and fake.regs == {a: f.reset for a, f in fake.map.items()}


def test_wrong_chip_bus_failure_and_lost_write():
    fake = FakeSensor("mt9p031", chip=0x1313)            # an MT9V022 where an MT9P031 is due
    st, reason = sensor.Sensor(fake, "mt9p031").configure(gain=16)
    assert st == S.BAD_INPUT and "chip version 0x1313" in reason and fake.writes == []
    fake = FakeSensor("mt9v022")
    st, reason = sensor.Sensor(fake, "mt9v022", address=0x5C).configure(gain=16)
    assert st == S.BAD_INPUT and reason.startswith("bus:")
    fake = FakeSensor("mt9v022", stuck={0xB6})           # the payload write does not land
    st, reason = sensor.Sensor(fake, "mt9v022").configure(mode="lvds")
    assert st == S.BAD_INPUT and "R0xB6 reads 0x0000 after writing 0x0001" in reason
    assert sensor.Sensor(fake, "ov7670").configure(gain=1)[0] == S.BAD_INPUT


_MP_SCRIPT = """
from lodestar.firmware import sensor

class Bus:
    def __init__(self, chip):
        self.regs = {0: chip}
        self.log = []
    def writeto_mem(self, addr, reg, buf):
        self.regs[reg] = (buf[0] << 8) | buf[1]
        self.log.append((addr, reg, self.regs[reg]))
    def readfrom_mem(self, addr, reg, n):
        w = self.regs.get(reg, 0)
        return bytes([w >> 8, w & 0xFF])

for model, chip, settings in CASES:
    bus = Bus(chip)
    st, reason = sensor.Sensor(bus, model).configure(**settings)
    print(repr((st, reason, bus.log)))
"""


def test_configure_runs_unchanged_on_micropython(micropython):
    """The same writes and statuses on MicroPython 1.27 as on CPython (a bare bus that stores
    what it is sent), for the typical settings and a refused one."""
    cases = [("mt9p031", 0x1801, TYPICAL["mt9p031"]), ("mt9v022", 0x1313, TYPICAL["mt9v022"]),
             ("mt9v022", 0x1313, {"gain": 65})]
    script = "CASES = " + repr(cases) + "\n" + _MP_SCRIPT
    code, out = micropython(script)
    assert code == 0, out
    expected = []
    for model, chip, settings in cases:
        ns = {}
        exec(compile(_MP_SCRIPT.split("for model")[0], "bus", "exec"), ns)
        bus = ns["Bus"](chip)
        st, reason = sensor.Sensor(bus, model).configure(**settings)
        expected.append(repr((st, reason, bus.log)))
    assert out.split("\n")[:len(cases)] == expected


def test_mt9p031_pll_settings_respect_the_limits():
    """From 25 MHz the PLL gives 95.83 MHz (M 23, N 2, P1 3; exactly 96 MHz needs an input
    clock below 2 MHz); every EXTCLK and target in range gives a setting the register model
    accepts, never above the target or 96 MHz."""
    assert sensor.p031_pll(25_000_000, 96_000_000) == (23, 2, 3, 95_833_333)
    for ext in (6e6, 10e6, 20e6, 24e6, 25e6, 27e6):
        for target in (48e6, 64e6, 80e6, 96e6, 120e6):
            m, n, p1, pix = sensor.p031_pll(int(ext), int(target))
            fake = FakeSensor("mt9p031", extclk=ext)
            fake.regs.update({0x10: 0x0053, 0x11: m << 8 | (n - 1), 0x12: p1 - 1})
            assert fake.pixclk() is not None and abs(fake.pixclk() - pix) < 1
            assert pix <= min(target, 96e6) and pix > 0.9 * min(target, 96e6), (ext, target)
    assert sensor.p031_pll(30_000_000, 96_000_000) is None          # EXTCLK above 27 MHz


def test_mt9p031_start_runs_the_power_up_sequence_and_gives_10_hz():
    fake = FakeSensor("mt9p031")
    st, reason, settings = sensor.p031_flight(0.1)
    assert st == sensor.S.OK, reason
    cam = sensor.Sensor(fake, "mt9p031", sleep_ms=fake.sleep_ms)
    assert cam.start(settings) == (S.OK, "")
    assert fake.violations == []
    regs = [r for r, _ in fake.writes]
    # soft reset, PLL powered, configured, locked (1 ms), used; restart last
    assert regs[:6] == [0x0D, 0x0D, 0x10, 0x11, 0x12, 0x10]
    assert fake.writes[-1] == (0x0B, 1)
    assert abs(fake.pixclk() - 70_000_000) < 1 and cam.pixclk_hz == 70_000_000
    row, exposure, frame = fake.frame_timing()
    assert frame <= 0.1 and frame > 0.099                       # 10 Hz at full frame
    assert abs(exposure - 0.1) < 2 * row
    assert row == pytest.approx(2 * (1296 + 450) / 70_000_000)
    st, _reason, got = cam.timing()
    assert st == S.OK and got == pytest.approx((row, exposure, frame), rel=1e-8)
    assert cam.stop() == (S.OK, "") and fake.regs[0x0B] == 3
    # the driver's own defaults (PLL to 70 MHz, every other register at its reset value,
    # full frame) support 10 Hz too: 98.3 ms
    fake = FakeSensor("mt9p031")
    cam = sensor.Sensor(fake, "mt9p031", sleep_ms=fake.sleep_ms)
    assert cam.start({}) == (S.OK, "") and fake.window() == (16, 54, 2592, 1944)
    st, _reason, got = cam.timing()
    assert st == S.OK and got[2] == pytest.approx(fake.frame_timing()[2], rel=1e-8)
    assert 0.098 < got[2] <= 0.1


def test_mt9p031_exposure_change_is_synchronized_not_stopped():
    fake = FakeSensor("mt9p031")
    cam = sensor.Sensor(fake, "mt9p031", sleep_ms=fake.sleep_ms)
    assert cam.start(sensor.p031_flight(0.05)[2])[0] == S.OK
    before = fake.frame_timing()
    fake.writes.clear()
    assert cam.configure(exposure=1000, gain=16) == (S.OK, "")
    assert fake.writes[0] == (0x07, 0x1F83) and fake.writes[-1] == (0x07, 0x1F82)
    assert not fake.output_stopped and fake.violations == []
    row, exposure, frame = fake.frame_timing()
    assert row == before[0] and frame == before[2]
    assert exposure == pytest.approx(1000 * row - 2 * 213 / 70_000_000)


def test_pixel_clock_is_the_boards():
    """The PLL setting the firmware programs gives the pixel clock the MT9P031 boards'
    gateware is built for (``hdl.boards``), below their ``sync``."""
    pix = sensor.p031_pll(sensor.EXTCLK_HZ, sensor.PIXCLK_HZ)
    assert pix == (28, 2, 5, 70_000_000)
    for board in BOARDS.values():
        if board.sensor == sensor.MT9P031:
            assert (board.pixel_hz, board.sensor_clk_hz) == (pix[3], sensor.EXTCLK_HZ)
            assert board.sync_hz > board.pixel_hz


def test_default_timing_without_the_pll_is_quarter_speed():
    """The issue's finding, by the model: EXTCLK 25 MHz straight through gives 0.275 s."""
    fake = FakeSensor("mt9p031")
    fake.regs[0x05] = 449
    assert fake.frame_timing()[2] == pytest.approx(1970 * 2 * 1746 / 25e6)


def test_start_refuses_and_reports():
    fake = FakeSensor("mt9p031", chip=0x1313)
    st, reason = sensor.Sensor(fake, "mt9p031").start(sensor.p031_flight(0.1)[2])
    assert st == S.BAD_INPUT and "chip version" in reason and fake.writes == []
    st, reason = sensor.Sensor(FakeSensor("mt9p031"), "mt9p031").start({}, extclk_hz=40e6)
    assert st == S.BAD_INPUT and "PLL" in reason
    fake = FakeSensor("mt9p031", stuck={0x11})                   # the PLL write is lost
    st, reason = sensor.Sensor(fake, "mt9p031").start({})
    assert st == S.BAD_INPUT and "R0x11" in reason
    assert sensor.p031_flight(0.1, frame_s=0.05)[0] == S.BAD_INPUT
    fake = FakeSensor("mt9v022")
    cam = sensor.Sensor(fake, "mt9v022", sleep_ms=fake.sleep_ms)
    assert cam.start(TYPICAL["mt9v022"], extclk_hz=26_600_000) == (S.OK, "")
    st, _r, (row, exposure, frame) = cam.timing()
    assert row == pytest.approx((752 + 94) / 26.6e6) and exposure == pytest.approx(300 * row)
    assert frame == pytest.approx((480 + 45) * row)
