"""The MT9P031 on the twin's two-wire bus: a register model written from the datasheet
(Rev. J register list and frame timing), independently of the firmware's driver tables, that
answers ``machine.I2C``'s ``writeto_mem``/``readfrom_mem`` and says what the next frame will
be (window, exposure, gain, row time, frame period).

Modelled: reset values; read-only chip version; out-of-range words ignored (counted in
``violations``); soft reset (R0x0D = 1: every register to its reset value); the PLL
(R0x10-R0x12; PIXCLK = EXTCLK x M / (N x P1) once R0x10 selects it, EXTCLK when bypassed,
a violation if it is selected less than 1 ms after it was powered); Synchronize_Changes
(R0x07[0]: writes to the window, blanking, shutter and gain registers wait and take effect
together when it clears); restart (R0x0B[0]) and pause (R0x0B[1]).  A write lands at once;
the frame that starts next uses the registers in effect then (:meth:`MT9P031.frame_settings`).
``answering = False`` makes every access raise ``OSError(19)`` (no ACK), as a sensor that
stopped answering.  Times: the model's clock is the twin's (``sleep_ms`` passes through
``now_s``).
"""

ADDRESS = 0x5D
CHIP_VERSION = 0x1801
EXTCLK_HZ = 25000000
"""The board's EXTCLK (the FPGA's PLL output)."""

_RESET = {0x00: CHIP_VERSION, 0x01: 0x0036, 0x02: 0x0010, 0x03: 0x0797, 0x04: 0x0A1F,
          0x05: 0x0000, 0x06: 0x0019, 0x07: 0x1F82, 0x08: 0x0000, 0x09: 0x0797,
          0x0A: 0x0000, 0x0B: 0x0000, 0x0C: 0x0000, 0x0D: 0x0000, 0x10: 0x0050,
          0x11: 0x6404, 0x12: 0x0000, 0x22: 0x0000, 0x23: 0x0000, 0x35: 0x0008}
"""Reset values of the modelled registers (datasheet register list)."""
_LIMITS = {0x01: (0, 2004), 0x02: (0, 2750), 0x03: (1, 2005), 0x04: (1, 2751),
           0x05: (0, 4095), 0x06: (0, 4095), 0x08: (0, 15), 0x0B: (0, 3), 0x0C: (0, 0x1FFF),
           0x0D: (0, 1), 0x12: (0, 127), 0x22: (0, 0x37), 0x23: (0, 0x37)}
_SYNCHRONIZED = (0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x08, 0x09, 0x35)
"""Registers whose writes wait while Synchronize_Changes is set."""


def _legal(reg, word):
    if reg == 0x00 or reg not in _RESET:
        return False
    if reg == 0x10:
        return word in (0x0050, 0x0051, 0x0053)
    if reg == 0x11:
        return word >> 8 >= 16 and word & 0xFF <= 63
    if reg == 0x35:
        analog, mult, digital = word & 0x3F, (word >> 6) & 1, (word >> 8) & 0x7F
        return word & ~0x7F7F == 0 and analog >= 8 and digital <= 120 and (mult or analog <= 32)
    low, high = _LIMITS.get(reg, (0, 0xFFFF))
    return low <= word <= high


class MT9P031:
    """The chip (module docstring).  ``now_s``: a function giving the twin's time (s)."""

    def __init__(self, now_s, address=ADDRESS, extclk_hz=EXTCLK_HZ):
        self.now_s = now_s
        self.address = address
        self.extclk_hz = extclk_hz
        self.regs = dict(_RESET)
        self.pending = {}
        self.violations = []
        self.writes = 0
        self.answering = True
        self.pll_powered_s = None
        self.paused = False

    def _check(self, addr):
        if addr != self.address or not self.answering:
            raise OSError(19)

    def writeto_mem(self, addr, reg, buf):
        self._check(addr)
        if len(buf) != 2:
            raise OSError(5)
        word = (buf[0] << 8) | buf[1]
        self.writes += 1
        if not _legal(reg, word):
            self.violations.append((reg, word))
            return
        if reg == 0x0D and word == 1:
            self.regs = dict(_RESET)
            self.regs[0x0D] = 1
            self.pending = {}
            self.pll_powered_s = None
            return
        if reg == 0x10:
            if word == 0x0051:
                self.pll_powered_s = self.now_s()
            elif word == 0x0053 and (self.pll_powered_s is None
                                     or self.now_s() - self.pll_powered_s < 1e-3):
                self.violations.append((reg, word))
                return
        if reg == 0x07 and not word & 1:
            self.regs.update(self.pending)
            self.pending = {}
        if reg == 0x0B:
            self.paused = bool(word & 2)
        if reg in _SYNCHRONIZED and self.regs[0x07] & 1:
            self.pending[reg] = word
            return
        self.regs[reg] = word

    def readfrom_mem(self, addr, reg, n):
        self._check(addr)
        word = self.pending.get(reg, self.regs.get(reg, 0))
        return bytes((word >> 8, word & 0xFF))[:n]

    # ---- what the registers make -----------------------------------------------------------

    def pixclk_hz(self):
        """PIXCLK (Hz): EXTCLK with the PLL bypassed, else EXTCLK x M / (N x P1); None
        when a PLL limit is broken (input 2-13.5 MHz, VCO 180-360 MHz, output <= 96 MHz)."""
        r = self.regs
        if r[0x10] != 0x0053:
            return float(self.extclk_hz)
        m, n, p1 = r[0x11] >> 8, (r[0x11] & 0xFF) + 1, r[0x12] + 1
        f_in, vco = self.extclk_hz / n, self.extclk_hz * m / n
        if not (2e6 <= f_in <= 13.5e6 and 180e6 <= vco <= 360e6 and vco / p1 <= 96e6):
            return None
        return vco / p1

    def frame_settings(self):
        """The next frame, or None while the sensor streams nothing (in soft reset, paused,
        PLL out of its limits): ``{"window": (column, row, width, height), "row_s",
        "exposure_s", "frame_s", "gain"}`` (gain as a multiple of 1x: analog / 8 x (1 +
        multiplier) x (1 + digital / 8)).  Frame timing without binning or skipping:
        tROW = 2 tPIX max(W / 2 + max(HB, 450), 486), frame = max(H + max(VB, 9), SW + 1)
        rows, exposure = SW rows - 2 tPIX (208 + 98 + SD - 94), SD = R0x0C + 1."""
        r = self.regs
        pix = self.pixclk_hz()
        if pix is None or r[0x0D] or self.paused:
            return None
        t2 = 2.0 / pix
        w, h = r[0x04] + 1, r[0x03] + 1
        row = t2 * max(w / 2 + max(r[0x05] + 1, 450), 41 + 346 + 99)
        sw = max(1, (r[0x08] << 16) | r[0x09])
        rows = max(h + max(r[0x06] + 1, 9), sw + 1)
        g = r[0x35]
        gain = (g & 0x3F) / 8 * (1 + ((g >> 6) & 1)) * (1 + ((g >> 8) & 0x7F) / 8)
        return {"window": (r[0x02], r[0x01], w, h), "row_s": row,
                "exposure_s": sw * row - t2 * (208 + 98 + r[0x0C] + 1 - 94),
                "frame_s": rows * row, "gain": gain}
