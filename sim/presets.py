"""Camera presets, loaded from ``lodestar/sim/data/presets.json``.

Each preset is data: a ``camera`` block of :class:`~lodestar.sim.camera.Camera` fields, a
``meta`` block of extras (``sensor``, ``lens``, ``board``, ``fpga``, ``reserved_low_codes`` =
the lowest legal pixel code, ``0`` when none is reserved; MT9V022 codes 0-3 read as 4) and a
``source`` block citing the thesis line, datasheet or assumption behind every camera field.
``load_preset`` returns the ``Camera`` with ``meta`` holding the ``meta`` block plus
``description`` and ``source``.
"""

import dataclasses
import json
import math
from functools import lru_cache
from importlib import resources

from lodestar.sim.camera import Camera

DEFAULT_PRESET = "estcube2"
"""The default camera: ESTCube-2 (MT9P031 + 16 mm f/1.2)."""


@lru_cache(maxsize=1)
def _presets():
    text = resources.files("lodestar.sim").joinpath("data/presets.json").read_text("utf-8")
    return json.loads(text)


PRESETS = tuple(_presets())
"""Names of the available presets."""


def load_preset(name=DEFAULT_PRESET):
    """The :class:`Camera` of preset ``name``; an unknown name raises ``ValueError``."""
    if name not in PRESETS:
        raise ValueError(f"unknown camera preset {name!r}; known presets: {', '.join(PRESETS)}")
    entry = _presets()[name]
    meta = dict(entry["meta"], description=entry["description"], source=entry["source"])
    return Camera(name=name, meta=meta, **entry["camera"])


def pinhole(name, fov_deg, width=None, height=None):
    """The sensor of preset ``name`` (pixels, noise, shutter, PSF in pixels, exposure), cut to
    ``width x height`` when given, behind a centred, distortion-free lens of the preset's
    f-number whose horizontal FOV is ``fov_deg``: focal length ``(W / 2) / tan(fov / 2)``
    pixels, aperture the focal length over the f-number."""
    base = load_preset(name)
    w = base.width if width is None else width
    h = base.height if height is None else height
    f_px = (w / 2) / math.tan(math.radians(fov_deg) / 2)
    f_mm = f_px * base.pixel_pitch_um * 1e-3
    return dataclasses.replace(base, width=w, height=h, fx_px=f_px, fy_px=f_px, cx=None,
                               cy=None, k1=0.0, k2=0.0, k3=0.0, p1=0.0, p2=0.0,
                               focal_length_mm=f_mm, aperture_mm=f_mm / base.f_number)
