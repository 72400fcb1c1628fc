"""The detection contract: the one source of every limit, width, register and layout.

The gateware (``lodestar.hdl``), the golden models (``lodestar.golden``), the packet codec
(``lodestar.packet``) and the MCU firmware (``lodestar.firmware``) all import these names;
none of them restates a width, a bit offset or a formula.  This module is pure Python that
runs unchanged on CPython and MicroPython: no numpy, typing, dataclasses or itertools.

Conventions
-----------
* Pixel coordinates: ``x`` is the column, ``y`` is the row, both integer indices from 0; the
  centre of pixel ``(x, y)`` is at the integer point ``(x, y)``.  Frames stream in raster
  order: row 0 first, and within a row column 0 first.  A pixel's *raster index* is
  ``y * width + x``.
* Pixel values are unsigned integers ``0 .. full_scale(pixel_bits)``.

Semantics of one frame (given ``T`` and ``B`` for the frame, or per pixel in ``local`` mode)
-------------------------------------------------------------------------------------------
* A pixel is **lit** iff ``p > T``.  Its weight is ``w = max(p - B, 0)``.
* Blobs are the **4-connected** components of the lit pixels (diagonals do not join).
* Per blob (all sums over the blob's pixels)::

      n = number of pixels            nsat = pixels with p == full_scale
      s0 = sum(w)      sx = sum(w*x)    sy = sum(w*y)
      sxx = sum(w*x*x) syy = sum(w*y*y) sxy = sum(w*x*y)
      xmin xmax ymin ymax = bounding box (inclusive)     peak = max(p)

  The centroid is ``(sx / s0, sy / s0)`` in pixel coordinates (computed by the MCU).
* Moment saturation: each moment accumulator (s0 .. sxy) is an unsigned integer of the width
  given by :func:`moment_widths`.  Those widths hold every blob of up to
  ``EXACT_BLOB_PIXELS`` pixels at full scale anywhere in a ``MAX_WIDTH x MAX_HEIGHT`` frame.
  A moment whose true value exceeds its maximum ``2**bits - 1`` reads as that maximum and the
  blob's ``BLOB_MOMENTS_SATURATED`` flag is set.  ``n``, ``nsat``, ``peak`` and the bounding
  box are always exact.  (Saturating addition of non-negative terms is order independent, so
  this is ``min(true value, maximum)`` whatever the order of accumulation or merging.)
* Filters: a blob is emitted only if ``min_pixels <= n <= max_pixels`` and ``s0 >= min_sum``
  (``s0`` as saturated).
* Record order: blobs are emitted in the raster order of each blob's **last pixel** (the
  pixel with the largest raster index).  A streaming detector learns that a blob is complete
  when the scan of the row below passes that pixel's column, so this is also the order in
  which it can emit them; blobs touching the last row complete at the end of the frame.
* Capacities (elaboration parameters of the gateware, fields of the golden config):

  - ``label_capacity``: how many blobs may be *open* (started, not yet complete) at once.
    A new blob that starts while ``label_capacity`` blobs are open is *untracked*: its
    moments are not accumulated, and a blob that merges with an untracked blob becomes
    untracked (the tracked part's label is released).  When an untracked blob completes it
    is counted in ``dropped_labels`` (before filtering: its size is unknown) and nothing is
    emitted for it.  Every emitted record stays exact.  At most
    :func:`max_open_blobs` ``(width)`` blobs can be open at once in any frame, so that
    capacity (the default) can never overflow.
  - ``record_capacity``: how many records one frame may emit.  Blobs that pass the filters
    after the buffer is full are counted in ``dropped_records``.

Threshold modes (integer-only; registers are latched at the start of each frame)
--------------------------------------------------------------------------------
``fixed``  (``MODE_FIXED``)
    ``T = threshold`` and ``B = background`` registers.  The ST-16 baseline (Dzamba 2013) is
    ``T = 120, min_pixels = 6, min_sum = 1000``.
``global`` (``MODE_GLOBAL``)
    ``B`` and ``T`` come from the previous frame's statistics over all its ``N = W*H`` pixels,
    ``S1 = sum(p)`` and ``S2 = sum(p*p)`` (see :func:`global_levels`)::

        B = floor(S1 / N)                                  (the mean, rounded down)
        D = the largest integer d >= 0 with (16 * N * d)**2 <= K**2 * (N*S2 - S1**2)
        T = min(B + D, full_scale)

    where ``K`` is the ``ksigma`` register (unsigned, ``KSIGMA_FRAC_BITS`` = 4 fractional
    bits, so k = K / 16).  ``D = floor(k * sigma)`` exactly, with sigma the population
    standard deviation; it is defined by a comparison, so the datapath needs no square root
    (a bit-serial search over ``d`` during vertical blanking).  Statistics are gathered on
    every complete frame in every mode.  The first frame after reset (or after a frame that
    did not complete) uses the ``threshold`` and ``background`` registers instead and sets
    ``FRAME_GLOBAL_FALLBACK``.  (Ayal's running mu + k sigma, Schumann 2019 section 2.1.)
``local``  (``MODE_LOCAL``)
    Per pixel, from a window of ``L = 2**local_log2_window`` neighbours on the same row (the
    ST-16 128 x 1 scheme, Schumann 2019 L283-291).  The window is centred and excludes the
    pixel itself; at the row ends it slides inward so that it always holds ``L`` real pixels::

        s = clamp(x - L/2, 0, W - 1 - L)
        M = floor((sum(p[y][s .. s+L]) - p[y][x]) / L)     (inclusive: L+1 columns minus x)
        T = min(M + local_offset, full_scale)      B = M

    The frame must be wider than ``L``.  A centred window keeps the threshold symmetric about
    a star, so it does not bias the centroid along the row.

Nothing in this module allocates per pixel; it is shared by gateware generation, golden
models and MCU code.
"""

# --------------------------------------------------------------------------------------
# Helpers (pure integer arithmetic, MicroPython-safe)
# --------------------------------------------------------------------------------------


def bits_for(value):
    """Number of bits of an unsigned integer able to hold ``value`` (>= 1 for value 0)."""
    if value < 0:
        raise ValueError("bits_for: value must be >= 0, got {}".format(value))
    n = 1
    while value >> n:
        n += 1
    return n


def isqrt(value):
    """Integer square root: the largest ``r`` with ``r * r <= value`` (``value >= 0``)."""
    if value < 0:
        raise ValueError("isqrt: value must be >= 0, got {}".format(value))
    if value < 2:
        return value
    r = 1 << ((bits_for(value) + 1) // 2)
    while True:
        nr = (r + value // r) // 2
        if nr >= r:
            return r
        r = nr


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

SENSOR_PIXEL_BITS = (10, 12)
"""Pixel widths the sensors deliver: MT9V022 10-bit, MT9P031 12-bit."""
FILE_PIXEL_BITS = (8, 16)
"""Further pixel widths of image files (8-bit and 16-bit PNG/TIFF/FITS)."""
PIXEL_BITS = (8, 10, 12, 16)
"""Every pixel width the detector accepts."""
MAX_PIXEL_BITS = 16


def full_scale(pixel_bits):
    """Largest pixel value (the saturation level) for ``pixel_bits``-bit pixels."""
    return (1 << pixel_bits) - 1


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


# Blob record flags
BLOB_MOMENTS_SATURATED = 1 << 0
"""At least one moment of this blob saturated (true value above the accumulator maximum)."""
BLOB_FLAGS_DEFINED = BLOB_MOMENTS_SATURATED


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


def max_open_blobs(width):
    """Most blobs that can be open at once in a frame ``width`` pixels wide: ``width//2 + 1``.

    An open blob has a pixel in the *wavefront*, the last ``width`` pixels in raster order.
    When a blob starts at column x, its left and upper neighbours are dark, so the wavefront
    holds at most ``ceil((x-1)/2) + ceil((width-x-1)/2) <= width/2`` other blobs (alternate
    lit and dark pixels), plus the new one.  ``tests/test_contract.py`` checks this bound
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
)
"""The runtime register bank, written by the MCU between frames."""

REGISTER_BY_NAME = {}
for _r in REGISTERS:
    REGISTER_BY_NAME[_r.name] = _r
del _r

MAX_PIXELS_UNLIMITED = REGISTER_BY_NAME["max_pixels"].reset
"""``max_pixels`` register value that no blob can exceed."""


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


# --------------------------------------------------------------------------------------
# Frame flags
# --------------------------------------------------------------------------------------

FRAME_LABEL_OVERFLOW = 1 << 0
"""More blobs were open at once than ``label_capacity``; see ``dropped_labels``."""
FRAME_RECORD_OVERFLOW = 1 << 1
"""More blobs passed the filters than ``record_capacity``; see ``dropped_records``."""
FRAME_GLOBAL_FALLBACK = 1 << 2
"""Global mode without statistics from a complete previous frame: fixed registers used."""
FRAME_TRUNCATED = 1 << 3
"""Gateware only: the frame ended (or was reset) before its last pixel; records are partial."""
FRAME_LINE_ERROR = 1 << 4
"""Gateware only: a line arrived shorter or longer than the frame width."""
FRAME_FLAGS_DEFINED = (FRAME_LABEL_OVERFLOW | FRAME_RECORD_OVERFLOW | FRAME_GLOBAL_FALLBACK
                       | FRAME_TRUNCATED | FRAME_LINE_ERROR)


# --------------------------------------------------------------------------------------
# Blob record and packet layout
# --------------------------------------------------------------------------------------

_PACKET_MOMENTS = moment_widths(MAX_PIXEL_BITS)

RECORD_FIELDS = (
    ("n", COUNT_BITS),
    ("nsat", COUNT_BITS),
    ("s0", _PACKET_MOMENTS["s0"]),
    ("sx", _PACKET_MOMENTS["sx"]),
    ("sy", _PACKET_MOMENTS["sy"]),
    ("sxx", _PACKET_MOMENTS["sxx"]),
    ("syy", _PACKET_MOMENTS["syy"]),
    ("sxy", _PACKET_MOMENTS["sxy"]),
    ("xmin", X_BITS),
    ("xmax", X_BITS),
    ("ymin", Y_BITS),
    ("ymax", Y_BITS),
    ("peak", MAX_PIXEL_BITS),
    ("flags", 6),
)
"""One blob record in the packet: (field, bits), MSB first, big-endian bit order.

Widths are those of the widest pixels (16 bits); narrower sensors leave high bits zero.
The record is a whole number of bytes (``RECORD_BYTES``)."""

RECORD_NAMES = tuple(name for name, _ in RECORD_FIELDS)
RECORD_BITS = sum(bits for _, bits in RECORD_FIELDS)
RECORD_BYTES = RECORD_BITS // 8

PACKET_MAGIC = 0x4C53  # "LS"
PACKET_VERSION = 1

HEADER_FIELDS = (
    ("magic", 16),
    ("version", 8),
    ("mode", 8),
    ("frame_counter", 32),
    ("width", 16),
    ("height", 16),
    ("pixel_bits", 8),
    ("flags", 8),
    ("threshold", MAX_PIXEL_BITS),
    ("background", MAX_PIXEL_BITS),
    ("n_blobs", 32),
    ("n_filtered", 32),
    ("dropped_records", 32),
    ("dropped_labels", 32),
    ("n_records", 16),
)
"""Frame header, first in the packet: (field, bits), MSB first.

``threshold``/``background`` are T and B in effect for the frame (in local mode, where they
vary per pixel, ``threshold`` carries the ``local_offset`` register and ``background`` 0).
``n_blobs`` counts tracked blobs that completed (measured), ``n_filtered`` those of them the
filters rejected, ``dropped_records`` those that passed but found the record buffer full,
``dropped_labels`` the untracked blobs lost to label overflow, ``n_records`` the records that
follow.  So ``n_records == n_blobs - n_filtered - dropped_records``."""

HEADER_NAMES = tuple(name for name, _ in HEADER_FIELDS)
HEADER_BITS = sum(bits for _, bits in HEADER_FIELDS)
HEADER_BYTES = HEADER_BITS // 8

CRC_BITS = 32
"""Trailer: CRC-32 (ISO-HDLC / zlib: reflected polynomial 0xEDB88320, init and final XOR
0xFFFFFFFF) over header and records, stored big-endian."""
CRC_BYTES = CRC_BITS // 8


def packet_bytes(n_records):
    """Total length in bytes of a packet carrying ``n_records`` records."""
    return HEADER_BYTES + n_records * RECORD_BYTES + CRC_BYTES


class BlobRecord(object):
    """One blob as the gateware reports it: integer fields named by ``RECORD_NAMES``.

    Records compare equal when every field is equal, and hash alike, so sets of records can
    be compared as multisets (``collections.Counter``).
    """

    __slots__ = RECORD_NAMES

    def __init__(self, n, nsat, s0, sx, sy, sxx, syy, sxy, xmin, xmax, ymin, ymax, peak, flags):
        self.n = n
        self.nsat = nsat
        self.s0 = s0
        self.sx = sx
        self.sy = sy
        self.sxx = sxx
        self.syy = syy
        self.sxy = sxy
        self.xmin = xmin
        self.xmax = xmax
        self.ymin = ymin
        self.ymax = ymax
        self.peak = peak
        self.flags = flags

    def as_tuple(self):
        """Field values in ``RECORD_NAMES`` order."""
        return tuple(getattr(self, name) for name in RECORD_NAMES)

    def __eq__(self, other):
        return isinstance(other, BlobRecord) and self.as_tuple() == other.as_tuple()

    def __ne__(self, other):
        return not self.__eq__(other)

    def __hash__(self):
        return hash(self.as_tuple())

    def __repr__(self):
        return "BlobRecord({})".format(
            ", ".join("{}={}".format(name, getattr(self, name)) for name in RECORD_NAMES))


# The layouts must be whole bytes; checked at import so a bad edit fails everywhere at once.
if RECORD_BITS % 8 or HEADER_BITS % 8:
    raise AssertionError("contract: record and header layouts must be whole bytes")


def passes_filters(n, s0, min_pixels, min_sum, max_pixels):
    """True iff a blob of ``n`` pixels and (saturated) weight sum ``s0`` is emitted."""
    return min_pixels <= n <= max_pixels and s0 >= min_sum
