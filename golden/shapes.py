"""Adversarial binary masks for connected-component labelling, and frames made from them.

Every generator is deterministic: it takes ``(height, width)`` plus shape parameters and
returns a C-contiguous numpy ``bool`` array of shape ``(height, width)`` (``True`` = lit).
:func:`to_frame` turns a mask into a pixel frame, and :data:`ADVERSARIAL` maps a name to a
zero-argument callable returning that shape at a moderate default size (24 x 32), so tests
and the gateware co-simulation can iterate over every shape.  Each shape stresses a part of a
streaming single-pass labeller (row buffer, merge table, feature table, completion, label
reuse; ``golden/streaming.py``); what each one stresses: ``docs/golden_models.md``.
"""

import numpy as np

__all__ = [
    "spiral", "comb_down", "comb_up", "nested_u", "staircase", "diagonal_staircase",
    "checkerboard", "vertical_stripes", "random_mask", "edges_and_corners", "full", "empty",
    "serpentine", "w_shape", "sawtooth", "merge_chain", "to_frame", "ADVERSARIAL",
    "PERCOLATION_THRESHOLD",
    "DEFAULT_SHAPE",
]

PERCOLATION_THRESHOLD = 0.5927
"""Site-percolation threshold of the square lattice (4-connectivity), rounded."""

DEFAULT_SHAPE = (24, 32)
"""(height, width) of the masks in :data:`ADVERSARIAL`."""


def _check_size(height, width, min_height=1, min_width=1):
    for name, value, lo in (("height", height, min_height), ("width", width, min_width)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
            raise ValueError(f"{name} must be an int, got {value!r}")
        if value < lo:
            raise ValueError(f"{name}={value} is too small for this shape (minimum {lo})")


def _check_positive(name, value):
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 1:
        raise ValueError(f"{name} must be a positive int, got {value!r}")


def empty(height, width):
    """No pixel lit."""
    _check_size(height, width)
    return np.zeros((height, width), dtype=bool)


def full(height, width):
    """Every pixel lit: one blob of ``height * width`` pixels."""
    _check_size(height, width)
    return np.ones((height, width), dtype=bool)


def spiral(height, width):
    """A single 4-connected simple path winding clockwise inward from the top-left corner.

    Consecutive rings are separated by one dark pixel, and no two pixels of the path are
    4-adjacent unless they are consecutive on it (the path is an induced path).
    """
    _check_size(height, width)
    m = np.zeros((height, width), dtype=bool)
    y, x = 0, 0
    m[y, x] = True
    dirs = ((0, 1), (1, 0), (0, -1), (-1, 0))  # right, down, left, up (clockwise)
    d = 0

    def can_move(y, x, dy, dx):
        ny, nx = y + dy, x + dx
        if not (0 <= ny < height and 0 <= nx < width) or m[ny, nx]:
            return False
        for ey, ex in dirs:  # the new pixel may touch only the pixel it comes from
            qy, qx = ny + ey, nx + ex
            if (qy, qx) != (y, x) and 0 <= qy < height and 0 <= qx < width and m[qy, qx]:
                return False
        return True

    turns_without_move = 0
    while turns_without_move < 2:
        dy, dx = dirs[d]
        if can_move(y, x, dy, dx):
            y, x = y + dy, x + dx
            m[y, x] = True
            turns_without_move = 0
        else:
            d = (d + 1) % 4
            turns_without_move += 1
    return m


def merge_chain(height, width):
    """A spine on row 0; odd rows lit at columns ``4j+2, 4j+3``, even rows ``>= 2`` at
    columns ``4j+1, 4j+2``.  One blob; each run of an even row starts under a dark pixel and
    merges at its second pixel, so the blob's root changes ``~width/4`` times per even row."""
    _check_size(height, width)
    m = np.zeros((height, width), dtype=bool)
    m[0, :] = True
    x = np.arange(width)
    odd = (x % 4 == 2) | (x % 4 == 3)
    even = ((x % 4 == 1) & (x + 1 < width)) | (x % 4 == 2)  # no piece cut off at the edge
    m[1::2, :] = odd
    m[2::2, :] = even
    return m


def comb_down(height, width, pitch=2):
    """Teeth at columns ``0, pitch, 2*pitch, ...`` over rows ``0 .. height-2``, joined only by
    a full spine on the last row (the comb opens upward; the teeth merge on the LAST row).
    One blob."""
    _check_size(height, width)
    _check_positive("pitch", pitch)
    m = np.zeros((height, width), dtype=bool)
    m[:, ::pitch] = True
    m[-1, :] = True
    return m


def comb_up(height, width, pitch=2):
    """A full spine on the first row with teeth hanging down at columns ``0, pitch, ...``
    (the teeth are joined on the FIRST row).  One blob."""
    _check_size(height, width)
    _check_positive("pitch", pitch)
    m = np.zeros((height, width), dtype=bool)
    m[:, ::pitch] = True
    m[0, :] = True
    return m


def nested_u_count(height, width):
    """Number of U's :func:`nested_u` draws in a ``height x width`` frame."""
    k = 0
    while 2 * k + 1 <= width - 1 - 2 * k and height - 1 - 2 * k >= 0:
        k += 1
    return k


def nested_u(height, width, depth=None):
    """Concentric U's: U ``k`` has arms at columns ``2k`` and ``width-1-2k`` from row 0 down
    to its bottom row ``height-1-2k``, which joins them.  One blob per U, each merging at its
    bottom.  ``depth`` limits the number of U's (default: as many as fit,
    :func:`nested_u_count`)."""
    _check_size(height, width, 1, 2)
    count = nested_u_count(height, width)
    if depth is not None:
        _check_positive("depth", depth)
        count = min(count, depth)
    m = np.zeros((height, width), dtype=bool)
    for k in range(count):
        left, right, bottom = 2 * k, width - 1 - 2 * k, height - 1 - 2 * k
        m[:bottom + 1, left] = True
        m[:bottom + 1, right] = True
        m[bottom, left:right + 1] = True
    return m


def staircase(height, width, step=2, period=None, direction="right"):
    """Parallel 4-connected stairs descending to the right (``direction="right"``) or left.

    Row ``y`` of stair ``k`` lights columns ``c .. c + step`` with ``c = k*period + y*step``
    (mirrored for ``"left"``); consecutive rows of a stair share one column.  ``period``
    (default ``2*step + 2``) must be at least ``2*step + 2`` so that neighbouring stairs
    neither overlap nor touch diagonally: one blob per stair, see :func:`staircase_index`.
    """
    _check_size(height, width)
    _check_positive("step", step)
    if period is None:
        period = 2 * step + 2
    _check_positive("period", period)
    if period < 2 * step + 2:
        raise ValueError(f"period={period} must be >= 2*step+2 = {2 * step + 2} to keep the "
                         "stairs apart")
    if direction not in ("right", "left"):
        raise ValueError(f"direction must be 'right' or 'left', got {direction!r}")
    return staircase_index(height, width, step, period, direction) >= 0


def staircase_index(height, width, step=2, period=None, direction="right"):
    """Per pixel, the index of the stair of :func:`staircase` it belongs to, or -1 if dark
    (int64 array; stair indices may be negative-offset, they are only distinct per stair)."""
    if period is None:
        period = 2 * step + 2
    y, x = np.mgrid[0:height, 0:width]
    if direction == "left":
        x = width - 1 - x
    off = x - y * step
    k = np.floor_divide(off, period)
    lit = (off - k * period) <= step
    # shift indices so that every stair index is >= 0 (off >= -(height-1)*step)
    k = k - (-(height - 1) * step) // period
    return np.where(lit, k, -1).astype(np.int64)


def diagonal_staircase(height, width, cell=2, period=3, anti=False):
    """Square ``cell x cell`` cells along diagonals, touching only at their corners.

    Cell ``(i, j)`` (rows ``i*cell ..``, columns ``j*cell ..``) is lit iff ``(j - i) % period
    == 0`` (``(i + j) % period == 0`` if ``anti``: descending to the left).  ``period >= 2``.
    Under 4-connectivity every lit cell is its own blob (cells clipped at the frame edge
    included).
    """
    _check_size(height, width)
    _check_positive("cell", cell)
    if isinstance(period, bool) or not isinstance(period, (int, np.integer)) or period < 2:
        raise ValueError(f"period must be an int >= 2, got {period!r}")
    i = np.arange(height)[:, None] // cell
    j = np.arange(width)[None, :] // cell
    key = (i + j) if anti else (j - i)
    return np.ascontiguousarray(key % period == 0)


def checkerboard(height, width, phase=0):
    """Pixel ``(x, y)`` lit iff ``(x + y) % 2 == phase``: every lit pixel is its own blob."""
    _check_size(height, width)
    if phase not in (0, 1):
        raise ValueError(f"phase must be 0 or 1, got {phase!r}")
    y, x = np.mgrid[0:height, 0:width]
    return np.ascontiguousarray((x + y) % 2 == phase)


def vertical_stripes(height, width, period=2, phase=0):
    """Columns ``x`` with ``x % period == phase`` lit over the full height: one blob per lit
    column, all open at once."""
    _check_size(height, width)
    _check_positive("period", period)
    if not 0 <= phase < period:
        raise ValueError(f"phase must be in 0..{period - 1}, got {phase!r}")
    m = np.zeros((height, width), dtype=bool)
    m[:, phase::period] = True
    return m


def random_mask(height, width, density, seed=0):
    """Each pixel lit independently with probability ``density`` (numpy PCG64, ``seed``)."""
    _check_size(height, width)
    if not 0.0 <= density <= 1.0:
        raise ValueError(f"density must be in 0..1, got {density!r}")
    rng = np.random.default_rng(seed)
    return np.ascontiguousarray(rng.random((height, width)) < density)


def edges_and_corners(height, width):
    """Single pixels in the four corners, and on each edge a single pixel and a small blob.

    Needs ``height >= 9`` and ``width >= 9``.  The pieces are separated by dark pixels:
    the 4 corner pixels; top edge: a 1x2 bar and a pixel; bottom edge: a 2x2 square and a
    pixel; left edge: a 2x1 bar and a 1x2 bar; right edge: a 2x2 square and a pixel.
    Exactly 12 blobs, every one touching an edge.
    """
    _check_size(height, width, 9, 9)
    m = np.zeros((height, width), dtype=bool)
    h, w = height, width
    # corners
    m[0, 0] = m[0, w - 1] = m[h - 1, 0] = m[h - 1, w - 1] = True
    a, b = w // 3, (2 * w) // 3          # columns for top/bottom pieces (>= 3 apart, >= 3 in)
    c, d = h // 3, (2 * h) // 3          # rows for left/right pieces
    # top edge: 1x2 horizontal bar and a single pixel
    m[0, a:a + 2] = True
    m[0, b] = True
    # bottom edge: a 2x2 square and a single pixel
    m[h - 2:h, a:a + 2] = True
    m[h - 1, b] = True
    # left edge: a 2x1 vertical bar and a 1x2 horizontal bar
    m[c:c + 2, 0] = True
    m[d, 0:2] = True
    # right edge: a 2x2 square and a single pixel
    m[c:c + 2, w - 2:w] = True
    m[d, w - 1] = True
    return m


def serpentine(height, width, along="rows"):
    """A boustrophedon path: every other row (``along="rows"``) or column fully lit, joined
    alternately at the right and left end (bottom and top end for columns).  One blob."""
    _check_size(height, width)
    if along not in ("rows", "columns"):
        raise ValueError(f"along must be 'rows' or 'columns', got {along!r}")
    if along == "columns":
        return _serpentine_columns(height, width)
    m = np.zeros((height, width), dtype=bool)
    m[::2, :] = True
    for y in range(1, height, 2):
        m[y, width - 1 if (y // 2) % 2 == 0 else 0] = True
    return m


def _serpentine_columns(height, width):
    m = np.zeros((height, width), dtype=bool)
    m[:, ::2] = True
    for x in range(1, width, 2):
        # turn at the bottom first: every other join is on the last row
        m[height - 1 if (x // 2) % 2 == 0 else 0, x] = True
    return m


def w_shape(height, width, half_period=3):
    """A zig-zag line with peaks on row 0 and valleys on the last row (a row of W's).

    The line's row is a triangle wave of ``x``: 0 at ``x = 0, 2*half_period, ...``, the last
    row at ``x = half_period, 3*half_period, ...``.  Each step between columns is drawn as a
    vertical segment in the column further from the valley, so a valley column is lit only
    on the last row and the two strokes beside it meet only there.  One blob, but one open
    blob per peak until the last row, where every valley merges two of them.
    """
    _check_size(height, width, 2, 1)
    _check_positive("half_period", half_period)
    span = height - 1

    def row(x):
        phase = x % (2 * half_period)
        if phase > half_period:
            phase = 2 * half_period - phase
        return (phase * span) // half_period

    m = np.zeros((height, width), dtype=bool)
    for x in range(width):
        m[row(x), x] = True
    for x in range(width - 1):
        r0, r1 = row(x), row(x + 1)
        if r1 > r0:      # descending: segment in column x
            m[r0:r1 + 1, x] = True
        elif r1 < r0:    # ascending: segment in column x + 1
            m[r1:r0 + 1, x + 1] = True
    return m


def sawtooth(height, width, tooth=4):
    """Ramp teeth rising to the right on a full-width bar in the last row.

    Teeth are ``tooth`` columns wide, separated by one dark column; column ``j`` (``0 ..
    tooth-1``) of a tooth is lit from row ``height-2 - (j+1)*(height-2)//tooth`` (clipped at
    0) down to the bar.  One blob.
    """
    _check_size(height, width, 2, 1)
    _check_positive("tooth", tooth)
    m = np.zeros((height, width), dtype=bool)
    m[-1, :] = True
    body = height - 1  # rows 0 .. height-2 hold the teeth
    for x in range(width):
        j = x % (tooth + 1)
        if j == tooth:
            continue  # gap column
        top = body - max(1, ((j + 1) * body) // tooth)
        m[max(top, 0):, x] = True
    return m


def to_frame(mask, lit_value, dark_value=0, dtype=np.uint16):
    """A frame with ``lit_value`` on lit pixels and ``dark_value`` elsewhere.

    ``lit_value`` and ``dark_value`` are scalars or arrays broadcastable to the mask (e.g.
    random pixel values).  Returns a C-contiguous array of ``dtype``; values that do not fit
    ``dtype`` raise ``ValueError`` instead of wrapping around.
    """
    mask = np.asarray(mask, dtype=bool)
    if mask.ndim != 2:
        raise ValueError(f"mask must be 2-D, got shape {mask.shape}")
    values = np.where(mask, np.asarray(lit_value), np.asarray(dark_value))
    if not (np.issubdtype(values.dtype, np.integer) or values.dtype == np.bool_):
        raise ValueError(f"pixel values must be integers, got dtype {values.dtype}")
    info = np.iinfo(dtype)
    if values.size and (values.min() < info.min or values.max() > info.max):
        raise ValueError(f"pixel values {values.min()}..{values.max()} do not fit "
                         f"{np.dtype(dtype)}")
    return np.ascontiguousarray(values.astype(dtype))


def _registry():
    h, w = DEFAULT_SHAPE
    reg = {
        "spiral": lambda: spiral(h, w),
        "merge_chain": lambda: merge_chain(h, w),
        "comb_down": lambda: comb_down(h, w),
        "comb_down_pitch3": lambda: comb_down(h, w, pitch=3),
        "comb_up": lambda: comb_up(h, w),
        "nested_u": lambda: nested_u(h, w),
        "staircase_right": lambda: staircase(h, w, step=1, direction="right"),
        "staircase_left": lambda: staircase(h, w, step=2, direction="left"),
        "diagonal_staircase": lambda: diagonal_staircase(h, w, cell=1, period=2 + 1),
        "diagonal_staircase_cells": lambda: diagonal_staircase(h, w, cell=3, period=2),
        "diagonal_staircase_anti": lambda: diagonal_staircase(h, w, cell=2, period=3,
                                                              anti=True),
        "checkerboard": lambda: checkerboard(h, w),
        "checkerboard_odd": lambda: checkerboard(h, w, phase=1),
        "vertical_stripes": lambda: vertical_stripes(h, w),
        "vertical_stripes_odd": lambda: vertical_stripes(h, w, phase=1),
        "edges_and_corners": lambda: edges_and_corners(h, w),
        "full": lambda: full(h, w),
        "empty": lambda: empty(h, w),
        "serpentine_rows": lambda: serpentine(h, w, "rows"),
        "serpentine_columns": lambda: serpentine(h, w, "columns"),
        "w_shape": lambda: w_shape(h, w),
        "w_shape_wide": lambda: w_shape(h, w, half_period=8),
        "sawtooth": lambda: sawtooth(h, w),
    }
    for i, density in enumerate((0.3, 0.5, PERCOLATION_THRESHOLD, 0.7, 0.8)):
        reg[f"random_{density}"] = (lambda d=density, s=i: random_mask(h, w, d, seed=1000 + s))
    return reg


ADVERSARIAL = _registry()
"""Every shape at a moderate default size: name -> zero-argument callable returning a mask."""
