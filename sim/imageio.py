"""Frame files: 16-bit PNG (lossless, opened by every image tool and astropy users alike)
and preview pictures.

Frames are ``uint16`` arrays indexed ``[y, x]``; the significant bit depth travels in the
truth JSON, not in the PNG.
"""

import io

import numpy as np
from PIL import Image, ImageDraw


def frame_png(frame):
    """The bytes of a ``uint16`` (or ``uint8``) frame as a greyscale PNG of the same depth."""
    frame = np.asarray(frame)
    if frame.ndim != 2 or frame.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"frame must be a 2-D uint8/uint16 array, got {frame.dtype} "
                         f"{frame.shape}")
    return _png(Image.fromarray(frame))


def save_frame(path, frame):
    """Write :func:`frame_png` of ``frame`` to ``path``."""
    data = frame_png(frame)
    with open(path, "wb") as fh:
        fh.write(data)


def _png(img, **options):
    buf = io.BytesIO()
    img.save(buf, format="PNG", **options)
    return buf.getvalue()


def load_frame(path):
    """Read a greyscale 8- or 16-bit PNG written by :func:`save_frame` as ``uint16``."""
    with Image.open(path) as im:
        if im.mode not in ("L", "I;16", "I;16B", "I"):
            raise ValueError(f"{path}: expected a greyscale 8- or 16-bit image, got mode "
                             f"{im.mode}")
        data = np.asarray(im)
    if data.dtype.kind not in "ui" or data.min(initial=0) < 0 or data.max(initial=0) > 65535:
        raise ValueError(f"{path}: pixel values do not fit 16 bits")
    return np.ascontiguousarray(data, dtype=np.uint16)


def stretch(frame, low_pct=50.0, high_pct=99.95):
    """8-bit view of a frame for people: percentile stretch with a square-root curve."""
    lo, hi = np.percentile(frame, [low_pct, high_pct])
    scaled = np.clip((frame.astype(np.float64) - lo) / max(hi - lo, 1.0), 0.0, 1.0)
    return (np.sqrt(scaled) * 255).astype(np.uint8)


def preview_png(frame, marks=(), radius=8):
    """PNG bytes of a stretched RGB preview with a circle around each ``(x, y, label)`` in
    ``marks``."""
    img = Image.fromarray(stretch(frame)).convert("RGB")
    draw = ImageDraw.Draw(img)
    for x, y, label in marks:
        draw.ellipse((x - radius, y - radius, x + radius, y + radius), outline=(255, 80, 80))
        if label:
            draw.text((x + radius + 2, y - radius), str(label), fill=(255, 200, 80))
    return _png(img)
