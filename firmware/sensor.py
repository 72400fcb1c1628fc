"""Image sensor set-up from the MCU over two-wire serial: MT9P031 (parallel) and MT9V022
(stand-alone LVDS or parallel); never raises on bad settings or a failing bus.

    cam = sensor.Sensor(machine.I2C(1), "mt9v022")
    st, reason = cam.configure(exposure=480, gain=16, window=(1, 4, 752, 480),
                               hblank=94, vblank=45, mode="lvds")

``bus``: any object with ``machine.I2C``'s ``writeto_mem(addr, reg, buf)`` and
``readfrom_mem(addr, reg, n)`` (8-bit register addresses, 16-bit registers sent big-endian,
as both sensors use them); tests use a fake bus with a register model of each sensor.
Settings, in the sensor's own units: ``exposure`` in row times (the integration time is
rows x row time), ``gain`` in the sensor's gain steps (MT9P031: 1/8, 8 = 1x ... 1024 = 128x,
the step coarsening above 4x and 8x as the gain stages do; MT9V022: analog 1/16, 16 = 1x ...
64 = 4x), ``window`` = ``(column, row, width, height)`` of the read-out window in array
pixels, ``hblank`` in the datasheet's blanking units (MT9P031: HB, 2 PIXCLK each, written as
HB - 1, at least ``HBmin`` = 450 without binning as the Linux ``mt9p031`` driver sets it;
MT9V022: pixel clocks) and ``vblank`` in rows, ``mode`` ``"lvds"`` or
``"parallel"`` (the MT9V022's LVDS is set for the gateware: 10-bit payload, R0xB6[0] = 1).
Every setting is checked against the sensor's limits (:data:`SENSORS`, from the datasheets
as the Linux ``mt9p031``/``mt9v032`` drivers encode them) before anything is written, so a
refused setting leaves the sensor as it was; each write is read back.  Statuses:
``OK``; ``BAD_INPUT`` for a refused setting, a wrong chip version or a bus failure (the
reason says which).  On the MT9P031 the writes of one ``configure`` are framed by the
output control's Synchronize_Changes bit (R0x07[0]): they take effect together at a frame
boundary and the read-out never stops (the chip enable, R0x07[1], stays set).

Start-up (:meth:`Sensor.start`, MT9P031): the board holds RESET_BAR with EXTCLK running
and releases it; then the chip version, a soft reset (R0x0D = 1, 0), the PLL for the pixel
clock (:func:`p031_pll`: R0x10 = 0x0051 power, R0x11 = M << 8 | N - 1, R0x12 = P1 - 1, the
1 ms lock wait, R0x10 = 0x0053 use), the settings, and a restart (R0x0B = 1);
:meth:`Sensor.stop` pauses (R0x0B = 2, 3).  :func:`p031_timing` and :meth:`Sensor.timing`
give the row time, exposure and frame period that registers produce (the datasheet's frame
timing formulas), for ``Settings.row_time_s`` and ``exposure_s``; :func:`p031_flight`
gives the settings of a frame period and an exposure (10 Hz at full frame by default).
Exposure and gain are manual (the MT9V022's AEC/AGC are switched off);
PIXCLK is left on its default edge (data launched on the falling edge, which the
MT9P031 front end samples on the rising one).  The frame the sensor sends must be the
gateware's ``width x height`` and its vertical blanking at least the detector's
``min_vblank`` clocks (``docs/sensors_and_link.md``, Sensor set-up).  The board releases
RESET_BAR once, when its PLL first locks; the MT9P031 answers on the bus 850,000 EXTCLK cycles
later (34 ms at 25 MHz, the Linux driver's wait), the MT9V022 10 SYSCLK cycles later.
Pure Python for CPython and MicroPython: no numpy, typing, dataclasses or f-strings.
"""

from lodestar.firmware import status as S

MT9P031 = "mt9p031"
MT9V022 = "mt9v022"
MODES = ("parallel", "lvds")

# Each sensor: I2C address (7-bit, default strapping), chip version register and values,
# register addresses, read-out window limits, blanking and exposure limits.
SENSORS = {
    MT9P031: {
        "address": 0x5D,                 # S_ADDR high; 0x48 with S_ADDR low
        "chip_version": (0x00, (0x1801,)),
        "array": (2752, 2004),           # columns, rows addressable by the window
        "even_start": True,              # window start on even column/row (Bayer phase)
        "column": (0x02, 0, 2750),
        "row": (0x01, 0, 2004),
        "width": (0x04, 2, 2752),        # register = width - 1
        "height": (0x03, 2, 2006),       # register = height - 1
        "size_minus_one": True,
        "hblank": (0x05, 450, 4096),     # HB, 2 PIXCLK units; register = HB - 1
        "vblank": (0x06, 9, 4096),       # rows (VBmin 9); register = rows - 1
        "exposure": ((0x08, 0x09), 1, 1048575),   # shutter width, upper and lower words
        "gain": (0x35, 8, 1024),
        "output_control": (0x07, 0x1F82, 0x0001),  # register, default, synchronize bit
        "min_row_time": 0,
        "modes": ("parallel",),
    },
    MT9V022: {
        "address": 0x48,                 # S_CTRL_ADR0/1 low (0x90 as an 8-bit address)
        "chip_version": (0x00, (0x1311, 0x1313)),
        "array": (753, 485),
        "even_start": False,
        "column": (0x01, 1, 752),
        "row": (0x02, 4, 482),
        "width": (0x04, 1, 752),
        "height": (0x03, 1, 480),
        "size_minus_one": False,
        "hblank": (0x05, 43, 1023),      # pixel clocks
        "vblank": (0x06, 4, 3000),
        "exposure": ((0x0B,), 1, 32767), # total shutter width
        "gain": (0x35, 16, 64),
        "min_row_time": 660,             # width + hblank, pixel clocks
        "modes": MODES,
    },
}
"""Register map and limits per sensor (sources: MT9P031 and MT9V022 datasheets; Linux
``drivers/media/i2c/mt9p031.c`` and ``mt9v032.c``, which encode the same limits)."""

# MT9V022 registers beyond the window (datasheet Rev.H, Table 6 and "LVDS Output Format")
V022_CHIP_CONTROL = 0x07
V022_CHIP_CONTROL_RUN = 0x0188   # master mode (bit 3), parallel output on (bit 7),
#                                  sequential read-out (bit 8); stereoscopy off (bit 5 = 0)
V022_AEC_AGC = 0xAF              # bit 0 AEC, bit 1 AGC: both off for manual settings
V022_LVDS_MASTER = 0xB1          # bit 1: LVDS power-down (default 0x0002)
V022_LVDS_DATA = 0xB3            # bit 4: LVDS data receiver power-down (stereo slave input)
V022_LVDS_PAYLOAD = 0xB6         # bit 0: 10-bit pixel payload (default 0: 8-bit + LV/FV)
V022_LVDS_POWER_DOWN = 0x0002
V022_RECEIVER_POWER_DOWN = 0x0010
V022_LVDS_10BIT = 0x0001

_SETTINGS = ("exposure", "gain", "window", "hblank", "vblank", "mode")


def _is_int(value):
    return isinstance(value, int) and not isinstance(value, bool)


def _refuse(name, value, why):
    return S.BAD_INPUT, "{} {!r} refused: {}".format(name, value, why), None


def p031_gain_register(gain):
    """R0x35 word of an MT9P031 gain in 1/8 steps, or None if the gain is not one the gain
    stages make: 8 .. 32 (analog, x1 .. x4), even 34 .. 64 (analog x2 multiplier), multiples
    of 8 from 72 to 1024 (analog x8 and digital gain ``(gain - 64) / 8`` eighths)."""
    if 8 <= gain <= 32:
        return gain
    if 32 < gain <= 64 and gain % 2 == 0:
        return 0x40 | (gain >> 1)
    if 64 < gain <= 1024 and gain % 8 == 0:
        return ((gain - 64) // 8) << 8 | 0x40 | 32
    return None


def plan(model, settings):
    """``(status, reason, writes)``: the register writes ``[(register, word)]``, in order,
    that apply ``settings`` (a dict of the module's setting names; absent ones are left as
    they are) to a sensor of ``model``; ``writes`` is None when a setting is refused."""
    spec = SENSORS.get(model)
    if spec is None:
        return S.BAD_INPUT, "unknown sensor {!r}".format(model), None
    for name in settings:
        if name not in _SETTINGS:
            return _refuse("setting", name, "not one of " + ", ".join(_SETTINGS))
    writes = []
    window = settings.get("window")
    hblank = settings.get("hblank")
    if spec["min_row_time"] and (window is None) != (hblank is None):
        return _refuse("window/hblank", window if hblank is None else hblank,
                       "give both: the row (width + hblank) must last {} clocks".format(
                           spec["min_row_time"]))
    if window is not None:
        if not isinstance(window, tuple) or len(window) != 4 or \
                not all(_is_int(v) for v in window):
            return _refuse("window", window, "give (column, row, width, height) as integers")
        sizes = (("column", window[0]), ("row", window[1]), ("width", window[2]),
                 ("height", window[3]))
        for name, value in sizes:
            _reg, low, high = spec[name]
            if not low <= value <= high:
                return _refuse(name, value, "outside {} .. {}".format(low, high))
        if window[0] + window[2] > spec["array"][0] or window[1] + window[3] > spec["array"][1]:
            return _refuse("window", window, "extends past the {} x {} array".format(
                spec["array"][0], spec["array"][1]))
        if spec["even_start"] and (window[0] % 2 or window[1] % 2):
            return _refuse("window", window, "column and row must be even")
        less = 1 if spec["size_minus_one"] else 0
        for name, value in sizes:
            writes.append((spec[name][0], value - less if name in ("width", "height")
                           else value))
    if hblank is not None:
        _reg, low, high = spec["hblank"]
        if not _is_int(hblank) or not low <= hblank <= high:
            return _refuse("hblank", hblank, "outside {} .. {}".format(low, high))
        if window is not None and window[2] + hblank < spec["min_row_time"]:
            return _refuse("hblank", hblank, "width + hblank below the {}-clock row".format(
                spec["min_row_time"]))
        writes.append((spec["hblank"][0], hblank - 1 if model == MT9P031 else hblank))
    vblank = settings.get("vblank")
    if vblank is not None:
        _reg, low, high = spec["vblank"]
        if not _is_int(vblank) or not low <= vblank <= high:
            return _refuse("vblank", vblank, "outside {} .. {} rows".format(low, high))
        writes.append((spec["vblank"][0], vblank - 1 if model == MT9P031 else vblank))
    exposure = settings.get("exposure")
    if exposure is not None:
        regs, low, high = spec["exposure"]
        if not _is_int(exposure) or not low <= exposure <= high:
            return _refuse("exposure", exposure, "outside {} .. {} rows".format(low, high))
        if len(regs) == 2:
            writes += [(regs[0], exposure >> 16), (regs[1], exposure & 0xFFFF)]
        else:
            writes.append((regs[0], exposure))
    gain = settings.get("gain")
    if gain is not None:
        reg, low, high = spec["gain"]
        word = None
        if _is_int(gain) and low <= gain <= high:
            word = p031_gain_register(gain) if model == MT9P031 else gain
        if word is None:
            return _refuse("gain", gain, "not a gain step of the {} in {} .. {}".format(
                model, low, high))
        writes.append((reg, word))
    mode = settings.get("mode")
    if mode is not None:
        if mode not in spec["modes"]:
            return _refuse("mode", mode, "the {} has {}".format(model, ", ".join(spec["modes"])))
        if model == MT9V022:
            lvds = mode == "lvds"
            writes += [(V022_LVDS_DATA, V022_RECEIVER_POWER_DOWN),
                       (V022_LVDS_PAYLOAD, V022_LVDS_10BIT if lvds else 0),
                       (V022_LVDS_MASTER, 0 if lvds else V022_LVDS_POWER_DOWN)]
    if model == MT9V022 and writes:
        writes = [(V022_AEC_AGC, 0)] + writes + [(V022_CHIP_CONTROL, V022_CHIP_CONTROL_RUN)]
    elif writes:
        reg, default, sync = spec["output_control"]
        # hold the changes until the bit clears, then apply them together at a frame start
        writes = [(reg, default | sync)] + writes + [(reg, default)]
    return S.OK, "", writes

# MT9P031 registers beyond the window (datasheet register list; Linux mt9p031.c)
P031_RESTART = 0x0B              # bit 0 restart, bit 1 pause restart
P031_SHUTTER_DELAY = 0x0C
P031_RESET = 0x0D                # 1: soft reset (registers to defaults), 0: run
P031_PLL_CONTROL = 0x10
P031_PLL_POWER = 0x0051          # PLL powered, bypassed
P031_PLL_USE = 0x0053            # PLL powered and used
P031_PLL_CONFIG_1 = 0x11         # M << 8 | (N - 1)
P031_PLL_CONFIG_2 = 0x12         # P1 - 1
P031_ROW_MODE = 0x22             # row bin [5:4], row skip [2:0]
P031_COLUMN_MODE = 0x23          # column bin [5:4], column skip [2:0]
P031_RESET_CYCLES = 850000
"""EXTCLK cycles from RESET_BAR's release to the first bus access (34 ms at 25 MHz)."""
P031_PLL_LOCK_MS = 1
"""The PLL's lock time before it is selected (the Linux driver waits 1-2 ms)."""
P031_PLL = {"ext": (6000000, 27000000), "int": (2000000, 13500000),
            "vco": (180000000, 360000000), "pix_max": 96000000, "n": (1, 64),
            "m": (16, 255), "p1": (1, 128)}
"""The PLL's limits (Hz and divider ranges; the Linux driver's ``aptina_pll_limits``):
PIXCLK = EXTCLK x M / (N x P1), EXTCLK / N and EXTCLK x M / N within ``int`` and ``vco``."""
EXTCLK_HZ = 25000000
"""The board's EXTCLK (the FPGA's sensor clock output)."""
PIXCLK_HZ = 70000000
"""Pixel clock asked of the PLL: the gateware's operating point (M 28, N 2, P1 5 from 25 MHz;
the boards' ``sync`` is 75 MHz, ``docs/synthesis.md``): a full frame every 97.4 ms at the
least blanking, 10 Hz with 60 rows of it (the MT9P031 reaches 96 MHz; 25 MHz gives 95.83)."""
P031_HB_MIN = 450
"""HBmin without binning: 346 x (Row_Bin + 1) + 64 + Wdc / 2, Wdc = 80 dark columns."""
P031_VB_MIN = 9
P031_SO_BASE = 208 + 98 - 94
"""Shutter overhead SO = 208 x (Row_Bin + 1) + 98 + min(SD, SDmax) - 94 (2 PIXCLK units),
SD = Shutter_Delay + 1; here the constant part for Row_Bin 0."""


def p031_pll(ext_hz, pix_hz):
    """``(m, n, p1, pixclk_hz)``: the PLL setting whose pixel clock is the highest not above
    ``pix_hz`` (at most 96 MHz) from ``ext_hz`` within :data:`P031_PLL`, or None.  Exact
    products only: ``ext_hz x m`` divisible by ``n x p1`` is not required, the Hz are
    rounded down."""
    lim = P031_PLL
    if not lim["ext"][0] <= ext_hz <= lim["ext"][1]:
        return None
    target = min(pix_hz, lim["pix_max"])
    best = None
    for n in range(lim["n"][0], lim["n"][1] + 1):
        f_int = ext_hz // n
        if f_int < lim["int"][0]:
            break
        if f_int > lim["int"][1]:
            continue
        p1_low = max(lim["p1"][0], -(-lim["vco"][0] // target))
        p1_high = min(lim["p1"][1], lim["vco"][1] // max(1, target) + 1)
        for p1 in range(p1_low, p1_high + 1):
            m = target * n * p1 // ext_hz
            if not lim["m"][0] <= m <= lim["m"][1]:
                continue
            vco = ext_hz * m // n
            if not lim["vco"][0] <= vco <= lim["vco"][1]:
                continue
            pix = vco // p1
            if pix <= target and (best is None or pix > best[3]):
                best = (m, n, p1, pix)
    return best


def p031_timing(regs, pixclk_hz):
    """``(row_time_s, exposure_s, frame_s)`` of MT9P031 register words ``regs`` (a dict by
    register address; an absent one at its reset value) at ``pixclk_hz``: the datasheet's
    frame timing with W = 2 ceil((Column_Size + 1) / (2 (Column_Skip + 1))), the row
    2 tPIXCLK max(W / 2 + max(HB, HBmin), 41 + 346 (Row_Bin + 1) + 99), the frame
    max(H + max(VB, VBmin), SW + 1) rows, the exposure SW rows - SO x 2 tPIXCLK."""
    def reg(address, reset):
        value = regs.get(address)
        return reset if value is None else value
    col_mode = reg(P031_COLUMN_MODE, 0)
    row_mode = reg(P031_ROW_MODE, 0)
    col_skip, col_bin = col_mode & 7, (col_mode >> 4) & 3
    row_skip, row_bin = row_mode & 7, (row_mode >> 4) & 3
    w = 2 * (-(-(reg(0x04, 2591) + 1) // (2 * (col_skip + 1))))
    h = 2 * (-(-(reg(0x03, 1943) + 1) // (2 * (row_skip + 1))))
    hb = reg(0x05, 0) + 1
    hb_min = 346 * (row_bin + 1) + 64 + (80 >> col_bin) // 2
    vb = reg(0x06, 25) + 1
    sw = max(1, (reg(0x08, 0) << 16) | reg(0x09, 1943))
    sd = reg(P031_SHUTTER_DELAY, 0) + 1
    so = 208 * (row_bin + 1) + 98 + min(sd, 1232 if sw < 3 else 1504) - 94
    units = max(w // 2 + max(hb, hb_min), 41 + 346 * (row_bin + 1) + 99)
    t2 = 2.0 / pixclk_hz
    row = units * t2
    rows = max(h + max(vb, P031_VB_MIN), sw + 1)
    return row, sw * row - so * t2, rows * row


def p031_flight(exposure_s, frame_s=0.1, pixclk_hz=None, window=(16, 54, 2592, 1944),
                gain=8):
    """``(status, reason, settings)``: :meth:`Sensor.configure` settings for a frame every
    ``frame_s`` (vertical blanking filling it, at the minimum HB) with the exposure nearest
    ``exposure_s`` that fits (at most the frame less one row), at ``pixclk_hz`` (default:
    the PLL's from :data:`EXTCLK_HZ`)."""
    if pixclk_hz is None:
        pixclk_hz = p031_pll(EXTCLK_HZ, PIXCLK_HZ)[3]
    units = max(window[2] // 2 + P031_HB_MIN, 41 + 346 + 99)
    row = 2.0 * units / pixclk_hz
    rows = int(frame_s / row)
    vblank = rows - window[3]
    if vblank < P031_VB_MIN:
        return S.BAD_INPUT, "a {} s frame is shorter than the read-out".format(frame_s), None
    if vblank > 4096:
        vblank = 4096
    so = 2.0 * (P031_SO_BASE + 1) / pixclk_hz
    sw = int((exposure_s + so) / row + 0.5)
    sw = max(1, min(sw, window[3] + vblank - 1))
    return S.OK, "", {"window": window, "hblank": P031_HB_MIN, "vblank": vblank,
                      "exposure": sw, "gain": gain, "mode": "parallel"}


class Sensor(object):
    """One sensor of ``model`` (:data:`SENSORS`) on ``bus`` at ``address`` (7-bit; default
    the model's)."""

    def __init__(self, bus, model, address=None, sleep_ms=None):
        self.bus = bus
        self.model = model
        spec = SENSORS.get(model)
        self.address = address if address is not None else (spec["address"] if spec else 0)
        self._word = bytearray(2)
        self.sleep_ms = sleep_ms
        self.pixclk_hz = None          # after start(): the PLL's pixel clock

    def _sleep(self, ms):
        if self.sleep_ms is not None:
            self.sleep_ms(ms)

    def _write_all(self, writes):
        for register, word in writes:
            st, reason = self.write(register, word)
            if st != S.OK:
                return st, reason
        return S.OK, ""

    def start(self, settings, extclk_hz=EXTCLK_HZ, pixclk_hz=PIXCLK_HZ):
        """MT9P031 power-up after the board released RESET_BAR (EXTCLK running, at least
        :data:`P031_RESET_CYCLES` cycles ago): chip version, soft reset, the PLL (with its
        lock wait), ``settings`` (a dict for :meth:`configure`), restart.  ``(status,
        reason)``; :attr:`pixclk_hz` is the pixel clock after it.  The MT9V022 has no PLL:
        chip version, soft reset (R0x0C), settings."""
        if self.model == MT9V022:
            st, reason = self.identify()
            if st == S.OK:
                # R0x0C bit 0 soft reset (self-clearing: not read back)
                try:
                    self.bus.writeto_mem(self.address, 0x0C, b"\x00\x01")
                except OSError as exc:
                    return S.BAD_INPUT, "bus: reset failed ({})".format(exc)
                self._sleep(1)
                st, reason = self.configure(**settings)
            self.pixclk_hz = extclk_hz
            return st, reason
        pll = p031_pll(extclk_hz, pixclk_hz)
        if pll is None:
            return S.BAD_INPUT, "no PLL setting for {} Hz from {} Hz".format(pixclk_hz,
                                                                          extclk_hz)
        st, reason, writes = plan(self.model, settings)
        if st != S.OK:
            return st, reason
        st, reason = self.identify()
        if st != S.OK:
            return st, reason
        m, n, p1, pix = pll
        steps = ((P031_RESET, 1), (P031_RESET, 0), (P031_PLL_CONTROL, P031_PLL_POWER),
                 (P031_PLL_CONFIG_1, (m << 8) | (n - 1)), (P031_PLL_CONFIG_2, p1 - 1))
        st, reason = self._write_all(steps)
        if st != S.OK:
            return st, reason
        self._sleep(P031_PLL_LOCK_MS)
        st, reason = self._write_all(((P031_PLL_CONTROL, P031_PLL_USE),))
        if st != S.OK:
            return st, reason
        self.pixclk_hz = pix
        st, reason = self._write_all(writes)
        if st != S.OK:
            return st, reason
        return self._write_all(((P031_RESTART, 1),))

    def stop(self):
        """MT9P031: pause at the next frame start (R0x0B = 2, then 3): ``(status, reason)``."""
        try:
            for word in (2, 3):
                self._word[0] = 0
                self._word[1] = word
                self.bus.writeto_mem(self.address, P031_RESTART, self._word)
        except OSError as exc:
            return S.BAD_INPUT, "bus: pause failed ({})".format(exc)
        return S.OK, ""

    def timing(self, pixclk_hz=None):
        """``(status, reason, (row_time_s, exposure_s, frame_s))`` the sensor's registers
        produce, read back from the chip (MT9P031: :func:`p031_timing`; MT9V022: row =
        (width + hblank) PIXCLK, frame = (height + vblank) rows, exposure = shutter rows)."""
        pix = pixclk_hz if pixclk_hz is not None else self.pixclk_hz
        if not pix:
            return S.BAD_INPUT, "pixel clock unknown (start() not run)", None
        if self.model == MT9P031:
            addresses = (0x03, 0x04, 0x05, 0x06, 0x08, 0x09, P031_SHUTTER_DELAY,
                         P031_ROW_MODE, P031_COLUMN_MODE)
        else:
            addresses = (0x03, 0x04, 0x05, 0x06, 0x0B)
        regs = {}
        for a in addresses:
            st, reason, word = self.read(a)
            if st != S.OK:
                return st, reason, None
            regs[a] = word
        if self.model == MT9P031:
            return S.OK, "", p031_timing(regs, pix)
        row = (regs[0x04] + regs[0x05]) / pix
        return S.OK, "", (row, regs[0x0B] * row, (regs[0x03] + regs[0x06]) * row)

    def read(self, register):
        """``(status, reason, word)`` of a 16-bit register (big-endian on the bus)."""
        try:
            data = self.bus.readfrom_mem(self.address, register, 2)
        except OSError as exc:
            return S.BAD_INPUT, "bus: reading R0x{:02X} failed ({})".format(register, exc), None
        if len(data) != 2:
            return S.BAD_INPUT, "bus: R0x{:02X} gave {} bytes".format(register, len(data)), None
        return S.OK, "", (data[0] << 8) | data[1]

    def write(self, register, word):
        """Write a 16-bit word (big-endian) and read it back: ``(status, reason)``."""
        self._word[0] = word >> 8
        self._word[1] = word & 0xFF
        try:
            self.bus.writeto_mem(self.address, register, self._word)
        except OSError as exc:
            return S.BAD_INPUT, "bus: writing R0x{:02X} failed ({})".format(register, exc)
        st, reason, back = self.read(register)
        if st != S.OK:
            return st, reason
        if back != word:
            return S.BAD_INPUT, "bus: R0x{:02X} reads 0x{:04X} after writing 0x{:04X}".format(
                register, back, word)
        return S.OK, ""

    def identify(self):
        """``(status, reason)``: OK if the chip version register holds one of the model's."""
        spec = SENSORS.get(self.model)
        if spec is None:
            return S.BAD_INPUT, "unknown sensor {!r}".format(self.model)
        register, versions = spec["chip_version"]
        st, reason, word = self.read(register)
        if st != S.OK:
            return st, reason
        if word not in versions:
            return S.BAD_INPUT, "chip version 0x{:04X} is not an {}".format(word, self.model)
        return S.OK, ""

    def configure(self, **settings):
        """Check the chip, then apply ``settings`` (module docstring): ``(status, reason)``.
        Nothing is written if a setting is refused or the chip is not the model."""
        st, reason, writes = plan(self.model, settings)
        if st != S.OK:
            return st, reason
        st, reason = self.identify()
        if st != S.OK:
            return st, reason
        return self._write_all(writes)
