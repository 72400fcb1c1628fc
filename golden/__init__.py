"""Golden model of the detection contract: the reference the gateware and firmware are held to.

    from lodestar.golden import DetectorConfig, Detector, detect_frame
    cfg = DetectorConfig(width=W, height=H, pixel_bits=12, threshold_mode="fixed",
                         threshold=T, background=B, min_pixels=1, min_sum=0, max_pixels=None)
    res = detect_frame(frame, cfg)       # frame: numpy uint16 array (H, W)
    res.blobs                            # contract.BlobRecord in emission order
    det = Detector(cfg); det.process(frame)

Two independent implementations agree exactly: ``vectorized`` (numpy/scipy, fast) and
``streaming`` (pixel by pixel, union-find); ``wavefront`` is the gateware's algorithm.
"""

from lodestar.contract import DetectionResult

from .config import DetectorConfig
from .detector import ENGINES, Detector, detect_frame

__all__ = ["DetectorConfig", "Detector", "detect_frame", "DetectionResult", "ENGINES"]
