"""Input checks for frames and the per-frame pixel statistics of global mode."""

import numpy as np

from lodestar import contract as C

_ACCEPTED_DTYPES = (np.uint8, np.uint16)


def check_frame(frame, cfg):
    """Return ``frame`` as a C-contiguous ``uint16`` array, or raise ``ValueError``.

    The frame must be a 2-D numpy array of unsigned 8- or 16-bit integers, of shape
    ``(cfg.height, cfg.width)``, with every pixel at most ``full_scale(cfg.pixel_bits)``.
    """
    if not isinstance(frame, np.ndarray):
        raise ValueError(f"frame must be a numpy array, got {type(frame).__name__}")
    if frame.dtype.type not in _ACCEPTED_DTYPES:
        raise ValueError(f"frame dtype must be uint8 or uint16, got {frame.dtype}")
    if frame.ndim != 2:
        raise ValueError(f"frame must be 2-D (rows, columns), got shape {frame.shape}")
    if frame.shape != (cfg.height, cfg.width):
        raise ValueError(f"frame shape {frame.shape} does not match the config "
                         f"(height, width) = ({cfg.height}, {cfg.width})")
    fs = C.full_scale(cfg.pixel_bits)
    if frame.size and int(frame.max()) > fs:
        y, x = np.unravel_index(int(np.argmax(frame)), frame.shape)
        raise ValueError(f"pixel (x={x}, y={y}) = {int(frame[y, x])} exceeds full scale {fs} "
                         f"of {cfg.pixel_bits}-bit pixels")
    return np.ascontiguousarray(frame, dtype=np.uint16)


class FrameStats:
    """Statistics of one complete frame for global mode: ``n`` pixels, ``s1 = sum(p)``,
    ``s2 = sum(p*p)`` (exact Python integers)."""

    __slots__ = ("n", "s1", "s2")

    def __init__(self, n, s1, s2):
        self.n, self.s1, self.s2 = n, s1, s2

    def __eq__(self, other):
        return (self.n, self.s1, self.s2) == (other.n, other.s1, other.s2)

    def __repr__(self):
        return f"FrameStats(n={self.n}, s1={self.s1}, s2={self.s2})"


def frame_levels(cfg, prev_stats):
    """Frame-level ``(T, B, flags)`` for fixed and global mode (local mode: per pixel).

    Global mode uses ``prev_stats`` (the previous complete frame) or, without it, the fixed
    registers and ``FRAME_GLOBAL_FALLBACK``.
    """
    if cfg.threshold_mode == "global":
        if prev_stats is None:
            return cfg.threshold, cfg.background, C.FRAME_GLOBAL_FALLBACK
        t, b = C.global_levels(prev_stats.n, prev_stats.s1, prev_stats.s2, cfg.ksigma_reg,
                               cfg.pixel_bits)
        return t, b, 0
    if cfg.threshold_mode == "local":
        return cfg.local_offset, 0, 0
    return cfg.threshold, cfg.background, 0
