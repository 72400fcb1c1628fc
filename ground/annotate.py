"""Annotated pictures of a solved frame: what the detector found, what the firmware
identified, and where the catalogue says the stars are.

    from lodestar.ground.annotate import predict_pixels, save_annotated
    points = predict_pixels(q, camera, max_mag=6.0)            # [(x, y, hip, vmag)]
    save_annotated("out.png", frame, records=blobs, labels=[(x, y, "HIP 677 Alpheratz", True)],
                   markers={"solution": [(x, y), ...]}, legend=["seed 0", ...])

Pixel coordinates, quaternions and rates: ``docs/conventions.md``; the picture's pixel
``(x, y)`` is the frame's, drawn at full resolution.

Picture: the frame stretched for people (:func:`lodestar.sim.imageio.stretch` between
:data:`STRETCH_PERCENTILES`), every
detector record boxed (its bounding box grown by :data:`BOX_MARGIN_PX`; yellow, green when
the record was identified), each identified star labelled (green when right or when no
truth is known, red when the truth says it is wrong), marker sets drawn with
:data:`MARKER_STYLES` (``truth``: cyan circles; ``solution``: magenta crosses) and the legend
on black in the top-left corner.  Written as an RGB PNG.
"""

import io
import math

import numpy as np

from lodestar.ground.files import write_atomic
from lodestar.sim import attitude, catalogue
from lodestar.sim.imageio import stretch

BOX_MARGIN_PX = 3
"""Pixels added around each record's bounding box so the box does not hide the star."""

STRETCH_PERCENTILES = (90.0, 99.99)
"""Black and white points of the display stretch: most of the sky is black, so the stars
and the marks stand out."""

COLOURS = {"record": (230, 200, 40), "identified": (60, 230, 60), "wrong": (255, 60, 60),
           "truth": (40, 220, 255), "solution": (255, 60, 255), "legend": (255, 255, 255)}
"""RGB colours of the picture's elements."""

MARKER_STYLES = {"truth": ("circle", "truth"), "solution": ("cross", "solution")}
"""Marker set name -> (shape, colour name)."""


def _font(size):
    from PIL import ImageFont
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):        # Pillow without FreeType: the fixed bitmap font
        return ImageFont.load_default()


def predict_pixels(q, camera, max_mag=6.0, omega=None, exposure_s=0.0, row_time_s=0.0):
    """Pixels where the catalogue stars of ``V <= max_mag`` appear at attitude ``q``.

    ``camera``: a :class:`lodestar.firmware.camera.Camera` (pixel <-> vector model).
    ``q``: the attitude at the start of row 0's exposure.  With ``omega`` (rad/s, camera
    frame) each star is moved to the mean instant of its own exposure, ``exposure_s / 2 +
    y * row_time_s`` (``y`` its row; one fixed-point step), where the detector's centroid
    of its smeared image lies: the inverse of the flight pipeline's rate compensation.
    Returns ``[(x, y, hip, vmag)]`` of the stars inside the frame, brightest first."""
    from scipy.spatial.transform import Rotation


    ra, dec, _ = attitude.to_radec_roll(np.asarray(q, dtype=float))
    corners = [camera.pixel_to_vector(x, y) for x in (-0.5, camera.width - 0.5)
               for y in (-0.5, camera.height - 0.5)]
    corners = [v for v in corners if v is not None]
    radius = max((math.degrees(math.acos(min(1.0, v[2]))) for v in corners), default=90.0)
    stars = catalogue.load().brighter_than(max_mag).cone(float(ra), float(dec), radius + 0.5)
    v_cam = Rotation.from_quat(np.asarray(q, dtype=float)).apply(stars.unit_vectors())
    w = None if omega is None else np.asarray(omega, dtype=float)
    out = []
    for v, hip, vmag in zip(v_cam, stars.hip, stars.vmag):
        if v[2] <= 0:
            continue
        p = camera.vector_to_pixel(tuple(float(c) for c in v))
        if p is not None and w is not None and np.any(w):
            t = 0.5 * exposure_s + p[1] * row_time_s
            moved = Rotation.from_rotvec(-w * t).apply(v)
            p = camera.vector_to_pixel(tuple(float(c) for c in moved))
        if p is not None and camera.in_frame(p[0], p[1]):
            out.append((float(p[0]), float(p[1]), int(hip), float(vmag)))
    out.sort(key=lambda s: s[3])
    return out


def save_annotated(path, frame, records=(), labels=(), markers=None, legend=(),
                   identified=()):
    """Write the annotated picture of ``frame`` (2-D integer array) to ``path`` (PNG).

    ``records``: ``contract.BlobRecord`` objects (boxed); ``identified``: indices into
    ``records`` of the identified ones (boxed in green).  ``labels``: ``(x, y, text, right)``
    with ``right`` True, False (drawn red) or None (no truth).  ``markers``: ``{set name:
    [(x, y), ...]}`` with the names of :data:`MARKER_STYLES`.  ``legend``: lines of text.
    Raises ``ValueError`` for an unknown marker set or a frame that is not 2-D, ``OSError``
    when the file cannot be written."""
    from PIL import Image, ImageDraw

    frame = np.asarray(frame)
    if frame.ndim != 2 or frame.size == 0:
        raise ValueError(f"frame must be a non-empty 2-D array, got shape {frame.shape}")
    markers = markers or {}
    unknown = sorted(set(markers) - set(MARKER_STYLES))
    if unknown:
        raise ValueError(f"unknown marker sets {unknown} (known: {sorted(MARKER_STYLES)})")
    height, width = frame.shape
    img = Image.fromarray(stretch(frame, *STRETCH_PERCENTILES)).convert("RGB")
    draw = ImageDraw.Draw(img)
    size = max(12, width // 120)
    font = _font(size)
    line = max(1, width // 1000)
    box_line = line + 1
    chosen = set(identified)
    m = BOX_MARGIN_PX
    for i, rec in enumerate(records):
        colour = COLOURS["identified" if i in chosen else "record"]
        draw.rectangle((rec.xmin - m, rec.ymin - m, rec.xmax + m, rec.ymax + m),
                       outline=colour, width=box_line)
    r = max(8, size)
    for name, points in markers.items():
        shape, colour_name = MARKER_STYLES[name]
        colour = COLOURS[colour_name]
        for x, y in points:
            if shape == "circle":
                draw.ellipse((x - r, y - r, x + r, y + r), outline=colour, width=line)
            else:
                h = r // 2
                draw.line((x - h, y, x + h, y), fill=colour, width=line)
                draw.line((x, y - h, x, y + h), fill=colour, width=line)
    for x, y, text, right in labels:
        colour = COLOURS["wrong" if right is False else "identified"]
        draw.text((x + r + 4, y - r - size), text, fill=colour, font=font,
                  stroke_width=max(1, size // 10), stroke_fill=(0, 0, 0))
    if legend:
        step = int(size * 1.3)
        right = max(draw.textlength(text, font=font) for text in legend)
        draw.rectangle((0, 0, size + right, size + step * len(legend)), fill=(0, 0, 0))
        y = size // 2
        for text in legend:
            draw.text((size // 2, y), text, fill=COLOURS["legend"], font=font,
                      stroke_width=max(1, size // 10), stroke_fill=(0, 0, 0))
            y += step
    buf = io.BytesIO()
    img.save(buf, format="PNG", compress_level=1)
    write_atomic(path, buf.getvalue())
