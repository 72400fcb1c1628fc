"""Golden image sets: simulated and adversarial frames with truth and the expected detection.

Each frame is written as ``NAME.png`` (16-bit greyscale PNG, ``sim.imageio``) and
``NAME.json`` holding the truth (``scene.simulate``'s, or the shape's name), the detector
configuration (every ``DetectorConfig`` field) and the golden model's expected result
(header fields and records, as ``lodestar.contract`` names them).  The gateware
co-simulation and the firmware regression replay these files.

Sets:

``small``  committed in ``tests/data/golden_small`` (a few MB): sensor *windows* of both
           cameras (the MT9P031 and MT9V022 read out regions of interest), at rest and
           0.5/1/2/5 deg/s, sparse and dense fields, hot pixels, saturated stars, cosmic
           rays, plus the adversarial detection shapes;
``full``   regenerated on demand (``lodestar goldenset full --out DIR``): full frames of both
           presets over the same cases.
"""

import dataclasses
import json
from pathlib import Path

import numpy as np

from lodestar import contract as C
from lodestar.golden import DetectorConfig, detect_frame, shapes

from . import attitude, imageio, presets, scene, sensor

SPARSE = (192.86, 27.13, 0.0)     # near the north galactic pole (Coma Berenices)
DENSE = (299.0, 35.0, 30.0)       # Milky Way in Cygnus
ORION = (83.8, -5.4, 10.0)        # bright stars (Betelgeuse, Rigel, the belt): saturation


@dataclasses.dataclass(frozen=True)
class FrameSpec:
    """One simulated frame of a set.  ``window``: (x0, y0, width, height) sensor region of
    interest or None for the full frame; ``pointing``: (ra, dec, roll) deg of the *full*
    sensor's boresight; ``rate``: deg/s about camera (x, y, z)."""

    name: str
    preset: str
    pointing: tuple
    rate: tuple = (0.0, 0.0, 0.0)
    window: tuple | None = None
    exposure_s: float | None = None
    hot_pixels: bool = False
    cosmic_rays: int = 0
    false_stars: int = 0
    seed: int = 0


def window_camera(cam, window):
    """The camera of a sensor region of interest: same optics, principal point shifted."""
    if window is None:
        return cam
    x0, y0, w, h = window
    if not (0 <= x0 and 0 <= y0 and x0 + w <= cam.width and y0 + h <= cam.height):
        raise ValueError(f"window {window} does not fit the {cam.width}x{cam.height} sensor")
    return dataclasses.replace(cam, width=w, height=h, cx=cam.cx - x0, cy=cam.cy - y0,
                               name=f"{cam.name}[{x0}:{x0 + w},{y0}:{y0 + h}]")


def _cases(window_e, window_l):
    """The frame specs of a set, with the given windows (None: full frames)."""
    specs = []
    for rate in (0.0, 0.5, 1.0, 2.0, 5.0):
        specs.append(FrameSpec(f"estcube2_sparse_{rate:g}dps", "estcube2", SPARSE,
                               (rate * 0.8, rate * 0.6, 0.0), window_e, seed=11))
    specs += [
        FrameSpec("estcube2_dense_rest", "estcube2", DENSE, window=window_e, seed=12),
        FrameSpec("estcube2_orion_saturated", "estcube2", ORION, window=window_e,
                  exposure_s=0.3, seed=13),
        FrameSpec("estcube2_hot_cosmic", "estcube2", DENSE, (0.0, 0.0, 1.0), window_e,
                  hot_pixels=True, cosmic_rays=8, false_stars=3, seed=14),
        FrameSpec("lohmann_orion_rest", "lohmann", ORION, window=window_l, seed=21),
        FrameSpec("lohmann_dense_1dps", "lohmann", DENSE, (0.7, 0.7, 0.0), window_l,
                  exposure_s=0.2, hot_pixels=True, cosmic_rays=4, seed=22),
    ]
    return specs


SETS = {
    "small": _cases((976, 732, 640, 480), (0, 0, 752, 480)),
    "full": _cases(None, None),
}
"""Named sets of ``FrameSpec``; adversarial shapes are added to every set."""


def render_spec(spec):
    """``(frame, truth, DetectorConfig)`` of a simulated frame spec."""
    full = presets.load_preset(spec.preset)
    cam = window_camera(full, spec.window)
    q = attitude.from_radec_roll(*spec.pointing)
    defects = None
    if spec.hot_pixels:
        defects = sensor.SensorDefects.generate(cam.height, cam.width, seed=spec.seed,
                                                hot_fraction=2e-4, hot_dark_factor=2000.0)
    extras = scene.Extras(false_stars=spec.false_stars, cosmic_rays=spec.cosmic_rays)
    sim = scene.simulate(cam, q, spec.rate, spec.exposure_s, spec.seed, defects=defects,
                         extras=extras)
    sim.truth["spec"] = dataclasses.asdict(spec)
    return sim.frame, sim.truth, scene.detector_config(cam, sim.truth["exposure_s"])


def shape_frames(pixel_bits=12):
    """``(name, frame, truth, DetectorConfig)`` of every adversarial shape."""
    rng = np.random.default_rng(7)
    fs = C.full_scale(pixel_bits)
    out = []
    for name, make in sorted(shapes.ADVERSARIAL.items()):
        mask = make()
        lit = rng.integers(101, fs + 1, mask.shape)
        dark = rng.integers(0, 101, mask.shape)
        frame = shapes.to_frame(mask, lit, dark)
        cfg = DetectorConfig(width=mask.shape[1], height=mask.shape[0], pixel_bits=pixel_bits,
                             threshold=100, background=50)
        out.append((f"shape_{name}", frame, {"shape": name}, cfg))
    return out


def config_dict(cfg):
    """A ``DetectorConfig`` as a JSON-ready dict (every field)."""
    return {f.name: getattr(cfg, f.name) for f in dataclasses.fields(cfg)}


def result_dict(res):
    """A ``DetectionResult`` as a JSON-ready dict: header fields and records.  The header's
    ``timestamp`` is left out: it is the gateware's clock, which no model of the detection
    predicts (``DetectionResult`` equality leaves it out too)."""
    header = {k: v for k, v in res.header().items() if k != "timestamp"}
    return {"header": header,
            "records": [dict(zip(C.RECORD_NAMES, b.as_tuple())) for b in res.blobs]}


def write_frame(out_dir, name, frame, truth, cfg):
    """Write ``NAME.png`` and ``NAME.json`` (truth, config, expected detection)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    imageio.save_frame(out_dir / f"{name}.png", frame)
    doc = {"name": name, "truth": truth, "detector": config_dict(cfg),
           "expected": result_dict(detect_frame(frame, cfg))}
    (out_dir / f"{name}.json").write_text(json.dumps(doc, indent=1) + "\n")
    return doc


def generate(set_name, out_dir, progress=None):
    """Write the named set into ``out_dir``; returns the list of frame names."""
    if set_name not in SETS:
        raise ValueError(f"unknown golden set {set_name!r}; known: {', '.join(SETS)}")
    names = []
    for spec in SETS[set_name]:
        frame, truth, cfg = render_spec(spec)
        write_frame(out_dir, spec.name, frame, truth, cfg)
        names.append(spec.name)
        if progress:
            progress(spec.name)
    for name, frame, truth, cfg in shape_frames():
        write_frame(out_dir, name, frame, truth, cfg)
        names.append(name)
    return names


def load_frame_doc(json_path):
    """``(frame, doc, DetectorConfig)`` of one written golden frame."""
    json_path = Path(json_path)
    doc = json.loads(json_path.read_text())
    frame = imageio.load_frame(json_path.with_suffix(".png"))
    return frame, doc, DetectorConfig(**doc["detector"])
