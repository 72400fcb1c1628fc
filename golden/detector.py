"""Public entry points of the golden model: ``Detector`` (stateful) and ``detect_frame``."""

from . import streaming, vectorized
from .frame import check_frame

ENGINES = {"vectorized": vectorized.detect, "streaming": streaming.detect}
"""The two independent implementations; they must agree exactly on every frame."""


class Detector:
    """Detects a sequence of frames, carrying state across them as the gateware does.

    The state is the frame counter (starts at 0) and, for global mode, the statistics of the
    previous frame.  ``engine`` picks the implementation: ``"vectorized"`` (fast, default)
    or ``"streaming"`` (the pixel-by-pixel reference model).
    """

    def __init__(self, cfg, engine="vectorized"):
        if engine not in ENGINES:
            raise ValueError(f"engine={engine!r} is not one of {sorted(ENGINES)}")
        self.cfg = cfg
        self.engine = engine
        self.frame_counter = 0
        self.prev_stats = None

    def reset(self):
        """Forget all state, as a gateware reset does (the next global frame falls back)."""
        self.frame_counter = 0
        self.prev_stats = None

    def configure(self, cfg):
        """Change the runtime registers between frames; the geometry must stay the same."""
        if (cfg.width, cfg.height, cfg.pixel_bits) != (self.cfg.width, self.cfg.height,
                                                       self.cfg.pixel_bits):
            raise ValueError("configure: width, height and pixel_bits are elaboration "
                             "parameters and cannot change between frames; use a new Detector")
        self.cfg = cfg

    def process(self, frame):
        """Detect one frame (numpy ``uint16``/``uint8`` array of shape (height, width))."""
        frame = check_frame(frame, self.cfg)
        result, stats = ENGINES[self.engine](frame, self.cfg, self.prev_stats)
        result.frame_counter = self.frame_counter
        self.frame_counter = (self.frame_counter + 1) & 0xFFFFFFFF
        self.prev_stats = stats
        return result


def detect_frame(frame, cfg, engine="vectorized"):
    """Detect a single frame from reset (global mode uses the fixed registers)."""
    return Detector(cfg, engine).process(frame)
