"""Detector configuration: frame geometry, threshold mode, filters and capacities.

``DetectorConfig`` holds the values the gateware takes as elaboration parameters (geometry,
pixel width, capacities) and as runtime registers (everything else), validated against the
contract.  Every invalid value raises ``ValueError`` naming the field and the reason.
"""

import math
from dataclasses import MISSING, dataclass, fields, replace

from lodestar import contract as C


def _require_int(name, value):
    if isinstance(value, bool) or not isinstance(value, int):
        raise ValueError(f"{name} must be an int, got {value!r}")


def _require_range(name, value, lo, hi, why=""):
    _require_int(name, value)
    if not lo <= value <= hi:
        raise ValueError(f"{name}={value} is out of range {lo}..{hi}{why}")


@dataclass(frozen=True)
class DetectorConfig:
    """One detector set-up.  Units: pixels and raw detector counts (ADU).

    ``ksigma`` is k of the global mode, a multiple of 1/16 (the register has
    ``KSIGMA_FRAC_BITS`` fractional bits).  ``max_pixels=None`` means no upper size limit.
    ``label_capacity=None`` means ``max_open_blobs(width)``, the capacity that can never
    overflow.  See ``lodestar.contract`` for the semantics of every field.
    """

    width: int
    height: int
    pixel_bits: int = 12
    threshold_mode: str = "fixed"
    threshold: int = C.REGISTER_BY_NAME["threshold"].reset
    background: int = C.REGISTER_BY_NAME["background"].reset
    ksigma: float = C.REGISTER_BY_NAME["ksigma"].reset / (1 << C.KSIGMA_FRAC_BITS)
    local_log2_window: int = C.REGISTER_BY_NAME["local_log2_window"].reset
    local_offset: int = C.REGISTER_BY_NAME["local_offset"].reset
    min_pixels: int = C.REGISTER_BY_NAME["min_pixels"].reset
    min_sum: int = C.REGISTER_BY_NAME["min_sum"].reset
    max_pixels: int | None = None
    label_capacity: int | None = None
    record_capacity: int = C.DEFAULT_RECORD_CAPACITY

    @classmethod
    def from_fields(cls, values):
        """The config of ``values``, a dict of field names (a JSON object, say); raises
        ``ValueError`` naming what is not a dict, an unknown field or a missing one."""
        if not isinstance(values, dict):
            raise ValueError(f"expected an object of DetectorConfig fields, got "
                             f"{type(values).__name__}")
        known = [f.name for f in fields(cls)]
        unknown = sorted(set(values) - set(known))
        if unknown:
            raise ValueError(f"unknown fields {', '.join(unknown)} (known: {', '.join(known)})")
        missing = [f.name for f in fields(cls)
                   if f.default is MISSING and f.name not in values]
        if missing:
            raise ValueError(f"missing fields {', '.join(missing)}")
        return cls(**values)

    def __post_init__(self):
        _require_range("width", self.width, 1, C.MAX_WIDTH, " (contract MAX_WIDTH)")
        _require_range("height", self.height, 1, C.MAX_HEIGHT, " (contract MAX_HEIGHT)")
        if isinstance(self.pixel_bits, bool) or not isinstance(self.pixel_bits, int) or \
                self.pixel_bits not in C.PIXEL_BITS:
            raise ValueError(f"pixel_bits={self.pixel_bits!r} is not one of {C.PIXEL_BITS}")
        if self.threshold_mode not in C.MODE_NAMES:
            raise ValueError(
                f"threshold_mode={self.threshold_mode!r} is not one of {C.MODE_NAMES}")
        pixels = f" ({self.pixel_bits}-bit pixels)"
        self._require_register("threshold", self.threshold, pixels)
        self._require_register("background", self.background, pixels)
        if isinstance(self.ksigma, bool) or not isinstance(self.ksigma, (int, float)) or \
                not math.isfinite(self.ksigma):
            raise ValueError(f"ksigma must be a finite number, got {self.ksigma!r}")
        kreg = self.ksigma * (1 << C.KSIGMA_FRAC_BITS)
        if kreg != int(kreg):
            raise ValueError(f"ksigma={self.ksigma} is not a multiple of "
                             f"1/{1 << C.KSIGMA_FRAC_BITS} (the register has "
                             f"{C.KSIGMA_FRAC_BITS} fractional bits)")
        klow, khigh = C.register_range("ksigma", self.pixel_bits)
        if not klow <= kreg <= khigh:
            raise ValueError(f"ksigma={self.ksigma} is out of range "
                             f"{klow}..{khigh / (1 << C.KSIGMA_FRAC_BITS)}")
        self._require_register("local_log2_window", self.local_log2_window)
        self._require_register("local_offset", self.local_offset, pixels)
        if self.threshold_mode == "local" and self.width <= (1 << self.local_log2_window):
            raise ValueError(
                f"width={self.width} must exceed the local window of "
                f"{1 << self.local_log2_window} pixels (local_log2_window="
                f"{self.local_log2_window})")
        self._require_register("min_pixels", self.min_pixels)
        self._require_register("min_sum", self.min_sum)
        if self.max_pixels is not None:
            self._require_register("max_pixels", self.max_pixels)
            if self.max_pixels < self.min_pixels:
                raise ValueError(f"max_pixels={self.max_pixels} is below min_pixels="
                                 f"{self.min_pixels}: no blob could ever be emitted")
        if self.label_capacity is not None:
            _require_range("label_capacity", self.label_capacity, 1,
                           C.max_open_blobs(self.width),
                           " (more than max_open_blobs(width) can never be used)")
        _require_range("record_capacity", self.record_capacity, 0, C.MAX_RECORD_CAPACITY)

    def _require_register(self, name, value, why=""):
        """``value`` of the register ``name`` within ``contract.register_range``."""
        low, high = C.register_range(name, self.pixel_bits)
        _require_range(name, value, low, high, why)

    # -- values as the gateware sees them ------------------------------------------------
    @property
    def mode(self):
        """Mode number (``MODE_FIXED``, ``MODE_GLOBAL`` or ``MODE_LOCAL``)."""
        return C.MODE_NAMES.index(self.threshold_mode)

    @property
    def ksigma_reg(self):
        """Raw ``ksigma`` register value (k * 16)."""
        return int(self.ksigma * (1 << C.KSIGMA_FRAC_BITS))

    @property
    def labels(self):
        """Effective label capacity (``label_capacity`` or ``max_open_blobs(width)``)."""
        if self.label_capacity is None:
            return C.max_open_blobs(self.width)
        return self.label_capacity

    @property
    def max_pixels_reg(self):
        """Raw ``max_pixels`` register value (``MAX_PIXELS_UNLIMITED`` for None)."""
        return C.MAX_PIXELS_UNLIMITED if self.max_pixels is None else self.max_pixels

    def registers(self):
        """Runtime register values by name, as the MCU writes them into the register bank."""
        return {
            "mode": self.mode,
            "threshold": self.threshold,
            "background": self.background,
            "ksigma": self.ksigma_reg,
            "local_log2_window": self.local_log2_window,
            "local_offset": self.local_offset,
            "min_pixels": self.min_pixels,
            "min_sum": self.min_sum,
            "max_pixels": self.max_pixels_reg,
            "sensor_reset": 0,          # the board's, not the detector's: the sensor runs
        }

    def replace(self, **changes):
        """A copy with some fields changed (validated again)."""
        return replace(self, **changes)
