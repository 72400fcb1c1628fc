"""Camera files: one calibrated camera as JSON, written by ``lodestar calibrate`` and read by
``lodestar solve --camera``, ``lodestar db build --camera`` and the flight software.

Layout (``docs/calibration.md``)::

    {"lodestar_camera": 1,
     "camera": {"width": W, "height": H, "fx": .., "fy": .., "cx": .., "cy": ..,
                "k1": .., "k2": .., "k3": .., "p1": .., "p2": ..},
     "sigma": {"fx": .., ...},            # 1-sigma of the fitted parameters (optional)
     "calibration": {...}}                # how it was fitted (optional, free form)

``camera`` holds exactly the arguments of :class:`lodestar.firmware.camera.Camera` (pixels
of the full image, pixel centres and axes as ``docs/conventions.md``), so the MCU builds its
camera with ``Camera.from_dict(json.load(f)["camera"])`` and no other field.
"""

import json
import math
from pathlib import Path

from lodestar.firmware.camera import Camera
from lodestar.ground.database import check_fov
from lodestar.ground.files import write_atomic
from lodestar.ground.solve import camera_fov_deg

FORMAT_KEY = "lodestar_camera"
FORMAT_VERSION = 1
SUFFIXES = (".json",)
MAX_BYTES = 1 << 20
"""Largest camera file read (a camera file is a few kilobytes)."""


def read_camera_file(path):
    """The :class:`~lodestar.firmware.camera.Camera` of a camera file.  Raises ``ValueError``
    naming the file and the problem (not JSON, not a camera file, another version, a missing
    or invalid parameter, a distortion that is not invertible over the frame, a field of
    view outside :data:`lodestar.contract.stardb.FOV_RANGE_DEG`) or ``OSError``
    when it cannot be read."""
    with open(path, "rb") as fh:
        data = fh.read(MAX_BYTES + 1)
    if len(data) > MAX_BYTES:
        raise ValueError(f"{path}: larger than {MAX_BYTES} bytes: not a camera file")
    try:
        doc = json.loads(data.decode("utf-8"), parse_constant=_no_constant)
    except (UnicodeDecodeError, json.JSONDecodeError, ValueError) as exc:
        raise ValueError(f"{path}: not a JSON camera file ({exc})") from None
    except RecursionError:                  # [[[[...]]]] deeper than the parser goes
        raise ValueError(f"{path}: not a JSON camera file (nested too deep)") from None
    if not isinstance(doc, dict) or FORMAT_KEY not in doc:
        raise ValueError(f"{path}: not a camera file (no \"{FORMAT_KEY}\" key)")
    if doc[FORMAT_KEY] != FORMAT_VERSION:
        raise ValueError(f"{path}: camera file version {doc[FORMAT_KEY]!r}; this lodestar "
                         f"reads version {FORMAT_VERSION}")
    params = doc.get("camera")
    if not isinstance(params, dict):
        raise ValueError(f"{path}: \"camera\" must be an object of camera parameters")
    unknown = sorted(set(params) - set(Camera(1, 1, 1.0, 1.0).as_dict()))
    if unknown:
        raise ValueError(f"{path}: unknown camera parameter(s) {', '.join(unknown)}")
    try:
        camera = Camera.from_dict(params)
        check_fov(camera_fov_deg(camera)[0], "the camera's horizontal FOV")
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{path}: {exc}") from None
    return camera


def _no_constant(name):
    raise ValueError(f"{name} is not a number a camera file may hold")


def camera_document(camera, sigma=None, calibration=None):
    """The JSON object of a camera file for a firmware ``camera`` with optional ``sigma``
    (parameter -> 1-sigma) and ``calibration`` (JSON-ready dict)."""
    doc = {FORMAT_KEY: FORMAT_VERSION,
           "camera": {k: (v if isinstance(v, int) else float(v))
                      for k, v in camera.as_dict().items()}}
    if sigma:
        doc["sigma"] = {k: float(v) for k, v in sigma.items()}
    if calibration:
        doc["calibration"] = calibration
    for value in doc["camera"].values():
        if not math.isfinite(value):
            raise ValueError("a camera parameter is not finite")
    return doc


def write_camera_file(path, camera, sigma=None, calibration=None, force=False):
    """Write a camera file atomically (:func:`lodestar.ground.files.write_atomic`).  Raises
    ``ValueError`` when ``path`` does not end in ``.json`` or exists and ``force`` is
    false."""
    path = Path(path)
    if path.suffix.lower() not in SUFFIXES:
        raise ValueError(f"--out {path}: the camera file must end in {' or '.join(SUFFIXES)}")
    if path.exists() and not force:
        raise ValueError(f"--out {path} exists; give --force to replace it")
    text = json.dumps(camera_document(camera, sigma, calibration), indent=1,
                      allow_nan=False) + "\n"
    write_atomic(path, text)
