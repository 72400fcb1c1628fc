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
pixels, ``hblank`` in pixel clocks and ``vblank`` in rows, ``mode`` ``"lvds"`` or
``"parallel"`` (the MT9V022's LVDS is set for the gateware: 10-bit payload, R0xB6[0] = 1).
Every setting is checked against the sensor's limits (:data:`SENSORS`, from the datasheets
as the Linux ``mt9p031``/``mt9v032`` drivers encode them) before anything is written, so a
refused setting leaves the sensor as it was; each write is read back.  Statuses:
``OK``; ``BAD_INPUT`` for a refused setting, a wrong chip version or a bus failure (the
reason says which).  Exposure and gain are manual (the MT9V022's AEC/AGC are switched off);
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
        "hblank": (0x05, 0, 4095),       # pixel clocks
        "vblank": (0x06, 1, 4096),       # rows; register = rows - 1
        "exposure": ((0x08, 0x09), 1, 1048575),   # shutter width, upper and lower words
        "gain": (0x35, 8, 1024),
        "output_control": (0x07, 0x1F82, 0x0002),  # register, default, chip-enable bit
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
        "hblank": (0x05, 43, 1023),
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
        writes.append((spec["hblank"][0], hblank))
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
        reg, default, enable = spec["output_control"]
        # stop read-out while the window changes, then enable the chip again
        writes = [(reg, default & ~enable)] + writes + [(reg, default)]
    return S.OK, "", writes


class Sensor(object):
    """One sensor of ``model`` (:data:`SENSORS`) on ``bus`` at ``address`` (7-bit; default
    the model's)."""

    def __init__(self, bus, model, address=None):
        self.bus = bus
        self.model = model
        spec = SENSORS.get(model)
        self.address = address if address is not None else (spec["address"] if spec else 0)
        self._word = bytearray(2)

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
        for register, word in writes:
            st, reason = self.write(register, word)
            if st != S.OK:
                return st, reason
        return S.OK, ""
