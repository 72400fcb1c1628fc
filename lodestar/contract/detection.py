"""Detection: frame limits, accumulator widths, threshold modes and formulas, the runtime
registers and the blob filters.  Semantics (lit pixels, 4-connectivity, moments, saturation,
record order, capacities, threshold modes): ``docs/contract.md``; pixel coordinates:
``docs/conventions.md``."""

from lodestar.contract.integers import bits_for, isqrt

# --------------------------------------------------------------------------------------
# Frames and pixels
# --------------------------------------------------------------------------------------

MAX_WIDTH = 4096
"""Largest frame width in pixels the contract (and every width below) supports."""
MAX_HEIGHT = 4096
"""Largest frame height in pixels."""
X_BITS = bits_for(MAX_WIDTH - 1)
"""Bits of a column index (12)."""
Y_BITS = bits_for(MAX_HEIGHT - 1)
"""Bits of a row index (12)."""

SENSOR_TABLE = (("mt9p031", 12), ("mt9v022", 10))
"""The sensors and the pixel width each delivers: ``mt9p031`` parallel 12-bit, ``mt9v022``
stand-alone LVDS 10-bit (their front ends: ``lodestar.hdl.boards.FRONTENDS``).  A tuple, so
that the order is the same under MicroPython, whose dicts do not keep it."""
SENSORS = tuple(name for name, _ in SENSOR_TABLE)
SENSOR_PIXEL_BITS = dict(SENSOR_TABLE)
FILE_PIXEL_BITS = (8, 16)
"""Further pixel widths of image files (8-bit and 16-bit PNG/TIFF/FITS)."""
PIXEL_BITS = (8, 10, 12, 16)
"""Every pixel width the detector accepts."""
MAX_PIXEL_BITS = 16


def full_scale(pixel_bits):
    """Largest pixel value (the saturation level) for ``pixel_bits``-bit pixels."""
    return (1 << pixel_bits) - 1


def check_geometry(width, height, pixel_bits=None):
    """Raise ``ValueError`` unless ``width x height`` frames (of ``pixel_bits``-bit pixels,
    when given) are within the contract: every width of the gateware derives from them."""
    if pixel_bits is not None and pixel_bits not in PIXEL_BITS:
        raise ValueError("pixel_bits={} is not one of {}".format(pixel_bits, PIXEL_BITS))
    if not (1 <= width <= MAX_WIDTH and 1 <= height <= MAX_HEIGHT):
        raise ValueError("frame {}x{} is outside the contract's 1..{} x 1..{}".format(
            width, height, MAX_WIDTH, MAX_HEIGHT))


# --------------------------------------------------------------------------------------
# Blob features and accumulator widths
# --------------------------------------------------------------------------------------

EXACT_BLOB_PIXELS = 4096
"""Moments are exact for every blob of up to this many pixels at full scale."""

COUNT_BITS = bits_for(MAX_WIDTH * MAX_HEIGHT)
"""Bits of a pixel count (``n``, ``nsat``): exact up to a full-frame blob (25)."""

MOMENTS = ("s0", "sx", "sy", "sxx", "syy", "sxy")
"""The saturating moment accumulators, in record order."""


def moment_widths(pixel_bits):
    """Bits of each moment accumulator for ``pixel_bits``-bit pixels, as a dict.

    Sized so that a blob of ``EXACT_BLOB_PIXELS`` pixels at full scale at the far corner of a
    ``MAX_WIDTH x MAX_HEIGHT`` frame is exact; larger values saturate (module docstring).
    """
    if pixel_bits not in PIXEL_BITS:
        raise ValueError("pixel_bits must be one of {}, got {}".format(PIXEL_BITS, pixel_bits))
    w = EXACT_BLOB_PIXELS * full_scale(pixel_bits)
    xm = MAX_WIDTH - 1
    ym = MAX_HEIGHT - 1
    return {
        "s0": bits_for(w),
        "sx": bits_for(w * xm),
        "sy": bits_for(w * ym),
        "sxx": bits_for(w * xm * xm),
        "syy": bits_for(w * ym * ym),
        "sxy": bits_for(w * xm * ym),
    }


def moment_max(pixel_bits):
    """Saturation value (``2**bits - 1``) of each moment accumulator, as a dict."""
    widths = moment_widths(pixel_bits)
    out = {}
    for name in MOMENTS:
        out[name] = (1 << widths[name]) - 1
    return out


# --------------------------------------------------------------------------------------
# Threshold modes and runtime registers
# --------------------------------------------------------------------------------------

MODE_FIXED = 0
MODE_GLOBAL = 1
MODE_LOCAL = 2
MODE_NAMES = ("fixed", "global", "local")
"""Mode names indexed by mode number."""

KSIGMA_BITS = 8
"""Width of the ``ksigma`` register (unsigned fixed point)."""
KSIGMA_FRAC_BITS = 4
"""Fractional bits of ``ksigma``: k = register / 16, so 0 .. 15.9375 in steps of 1/16."""

LOCAL_LOG2_WINDOW_MIN = 1
LOCAL_LOG2_WINDOW_MAX = 7
"""The local window holds 2 .. 128 pixels (128 is the ST-16 window)."""

MAX_RECORD_CAPACITY = 65535
"""Largest record capacity (the packet's record count is 16 bits)."""
DEFAULT_RECORD_CAPACITY = 512
"""Default records per frame: hundreds of stars plus margin."""
FLIGHT_RECORD_CAPACITY = 100
"""Records per frame of the flight gateware (ESTCube-2), the one value both sides use: the
estcube2 board builds its detector with this ``record_capacity``
(``lodestar.hdl.boards.ESTCube2Board``) and the MCU's link sizes its packet buffer for it
(``firmware/link.py``: ``packet_bytes(100)``, 4,840 bytes), so a full frame always fits the
buffer and never leaves bytes in the FPGA's stream.  Why 100: the heap is the binding
budget (``docs/mcu_board.md``: the flight stack already needs 58-64 KiB of the F401's
64-72 KiB, and every 10 records more cost 480 bytes of it), while a tracking frame carries
8-10 records (the ``min_sum`` record budget, ``docs/firmware.md``) and a lost-in-space frame
(``min_sum`` = 0) all its blobs: simulated estcube2 frames at rest hold 29-178 blobs, 57 at
the median and at most 100 in 95 of 100, and Pyramid needs far fewer than 100 stars.  A
frame with more loses the rest in raster order, flagged ``FRAME_RECORD_OVERFLOW`` and
counted in its trailer (``dropped_records``), and is still solved from the others."""


def max_open_blobs(width):
    """Most blobs that can be open at once in a frame ``width`` pixels wide: ``width//2 + 1``.

    An open blob has a pixel in the *wavefront*, the last ``width`` pixels in raster order.
    When a blob starts at column x, its left and upper neighbours are dark, so the wavefront
    holds at most ``ceil((x-1)/2) + ceil((width-x-1)/2) <= width/2`` other blobs (alternate
    lit and dark pixels), plus the new one.  ``tests/contract/test_detection.py`` checks this bound
    exhaustively on small frames against the streaming model.
    """
    return width // 2 + 1


class Register(object):
    """One runtime register: name, word address, field width in bits and reset value."""

    __slots__ = ("name", "address", "bits", "reset", "doc")

    def __init__(self, name, address, bits, reset, doc):
        self.name = name
        self.address = address
        self.bits = bits
        self.reset = reset
        self.doc = doc

    def __repr__(self):
        return "Register({}, address={}, bits={}, reset={})".format(
            self.name, self.address, self.bits, self.reset)


REGISTER_WORD_BITS = 32
"""Every register occupies one 32-bit word of the register bank; fields are LSB-aligned."""

REGISTERS = (
    Register("mode", 0, 2, MODE_FIXED, "threshold mode: MODE_FIXED, MODE_GLOBAL or MODE_LOCAL"),
    Register("threshold", 1, MAX_PIXEL_BITS, 120,
             "T in fixed mode, and in global mode's fallback frame (ST-16: 120)"),
    Register("background", 2, MAX_PIXEL_BITS, 0, "B in fixed mode and the global fallback"),
    Register("ksigma", 3, KSIGMA_BITS, 3 << KSIGMA_FRAC_BITS,
             "global mode k, unsigned with KSIGMA_FRAC_BITS fractional bits"),
    Register("local_log2_window", 4, 3, LOCAL_LOG2_WINDOW_MAX,
             "local mode window length L = 2**value"),
    Register("local_offset", 5, MAX_PIXEL_BITS, 16, "local mode: T = window mean + offset"),
    Register("min_pixels", 6, COUNT_BITS, 1, "filter: emit only blobs with n >= min_pixels"),
    Register("min_sum", 7, moment_widths(MAX_PIXEL_BITS)["s0"], 0,
             "filter: emit only blobs with s0 >= min_sum"),
    Register("max_pixels", 8, COUNT_BITS, (1 << COUNT_BITS) - 1,
             "filter: emit only blobs with n <= max_pixels (reset: no limit)"),
    Register("sensor_reset", 9, 1, 0,
             "1: hold the image sensor's RESET_BAR low; acts at once, not at a frame start; "
             "the board keeps RESET_BAR low SENSOR_RESET_S after the request ends, counted "
             "while the sensor's master clock runs (status: OVF_LINK_DOWN while it is low)"),
)
"""The runtime register bank, written by the MCU (the detector's registers between frames)."""

SENSOR_RESET_S = 1e-3
"""Shortest time the board holds the sensor's RESET_BAR low with its master clock running:
at power-up once the clock is up, and after every ``sensor_reset`` request (MT9P031: the
datasheet's power-up sequence wants RESET_BAR low with EXTCLK running before it rises; the
MCU then waits its own settling time before the first two-wire access)."""

REGISTER_BY_NAME = {}
for _r in REGISTERS:
    REGISTER_BY_NAME[_r.name] = _r
del _r

MAX_PIXELS_UNLIMITED = REGISTER_BY_NAME["max_pixels"].reset
"""``max_pixels`` register value that no blob can exceed."""


def register_range(name, pixel_bits):
    """``(lowest, highest)`` value the register ``name`` accepts with ``pixel_bits``-bit
    pixels: its field's range, narrowed to a mode number for ``mode``, to
    ``LOCAL_LOG2_WINDOW_MIN .. MAX`` for ``local_log2_window`` and to the pixel's full scale
    for ``threshold``, ``background`` and ``local_offset``.  The register bank refuses other
    values and the golden models' configuration rejects them."""
    if name == "mode":
        return 0, len(MODE_NAMES) - 1
    if name == "local_log2_window":
        return LOCAL_LOG2_WINDOW_MIN, LOCAL_LOG2_WINDOW_MAX
    if name in ("threshold", "background", "local_offset"):
        return 0, full_scale(pixel_bits)
    return 0, (1 << REGISTER_BY_NAME[name].bits) - 1


def global_levels(n, s1, s2, ksigma_reg, pixel_bits):
    """``(T, B)`` for global mode from the previous frame's statistics (module docstring).

    ``n`` pixels, ``s1 = sum(p)``, ``s2 = sum(p*p)``, ``ksigma_reg`` the raw register value.
    The golden models call this; the gateware implements the same comparison bit-serially.
    """
    if n <= 0:
        raise ValueError("global_levels: pixel count must be > 0, got {}".format(n))
    b = s1 // n
    var_n2 = n * s2 - s1 * s1  # N**2 * variance, exact and >= 0
    if var_n2 < 0:
        raise ValueError("global_levels: inconsistent statistics (N*S2 < S1**2)")
    step = (1 << KSIGMA_FRAC_BITS) * n
    # Largest d with (step * d)**2 <= K**2 * var_n2  <=>  step * d <= isqrt(K**2 * var_n2).
    d = isqrt(ksigma_reg * ksigma_reg * var_n2) // step
    return min(b + d, full_scale(pixel_bits)), b


def local_window_start(x, width, log2_window):
    """First column of the local window of pixel ``x`` (the window spans ``L + 1`` columns)."""
    half = 1 << (log2_window - 1)
    s = x - half
    last = width - 1 - (1 << log2_window)
    if s > last:
        s = last
    if s < 0:
        s = 0
    return s


def passes_filters(n, s0, min_pixels, min_sum, max_pixels):
    """True iff a blob of ``n`` pixels and (saturated) weight sum ``s0`` is emitted."""
    return min_pixels <= n <= max_pixels and s0 >= min_sum
