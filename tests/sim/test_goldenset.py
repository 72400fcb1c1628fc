"""The committed golden image set: the golden model reproduces every expected result exactly."""

import json

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.golden import detect_frame
from lodestar.sim import goldenset
from tests import DATA

SMALL = DATA / "golden_small"
DOCS = sorted(SMALL.glob("*.json"))


def test_the_set_is_complete_and_small():
    names = {p.stem for p in DOCS}
    expected = {s.name for s in goldenset.SETS["small"]}
    expected |= {name for name, *_ in goldenset.shape_frames()}
    assert names == expected
    assert sum(p.stat().st_size for p in SMALL.iterdir()) < 6e6


@pytest.mark.parametrize("path", DOCS, ids=[p.stem for p in DOCS])
@pytest.mark.parametrize("engine", ["vectorized", "streaming"])
def test_golden_output_is_reproduced_exactly(path, engine):
    frame, doc, cfg = goldenset.load_frame_doc(path)
    assert frame.shape == (cfg.height, cfg.width)
    res = detect_frame(frame, cfg, engine=engine)
    assert goldenset.result_dict(res) == doc["expected"]


def test_simulated_frames_find_their_stars():
    """Every record of the rest frames holds a truth source inside its bounding box (a blob
    of blended stars holds several: its centroid lies between them)."""
    for name in ("estcube2_dense_rest", "lohmann_orion_rest", "estcube2_orion_saturated"):
        frame, doc, cfg = goldenset.load_frame_doc(SMALL / f"{name}.json")
        xs = np.array([s["x"] for s in doc["truth"]["sources"]])
        ys = np.array([s["y"] for s in doc["truth"]["sources"]])
        records = doc["expected"]["records"]
        assert records
        for r in records:
            inside = (xs > r["xmin"] - 1) & (xs < r["xmax"] + 1) & \
                (ys > r["ymin"] - 1) & (ys < r["ymax"] + 1)
            assert inside.any(), (name, r)
    saturated = goldenset.load_frame_doc(SMALL / "estcube2_orion_saturated.json")[1]
    assert any(r["nsat"] > 0 for r in saturated["expected"]["records"])


def test_generation_is_deterministic(tmp_path):
    spec = goldenset.SETS["small"][1]
    a, truth_a, cfg_a = goldenset.render_spec(spec)
    b, truth_b, cfg_b = goldenset.render_spec(spec)
    assert np.array_equal(a, b) and truth_a == truth_b and cfg_a == cfg_b
    doc = goldenset.write_frame(tmp_path, spec.name, a, truth_a, cfg_a)
    frame, doc2, cfg = goldenset.load_frame_doc(tmp_path / f"{spec.name}.json")
    assert np.array_equal(frame, a) and doc2 == json.loads(json.dumps(doc)) and cfg == cfg_a
    assert int(frame.max()) <= C.full_scale(cfg.pixel_bits)


def test_window_camera_and_bad_set():
    from lodestar.sim import presets
    cam = presets.load_preset("estcube2")
    win = goldenset.window_camera(cam, (1200, 900, 640, 480))
    x, y, _ = win.project(cam.unproject(np.array([1230.0]), np.array([920.0])))
    assert (x[0], y[0]) == pytest.approx((30.0, 20.0), abs=1e-9)
    with pytest.raises(ValueError, match="does not fit"):
        goldenset.window_camera(cam, (2590, 0, 64, 48))
    with pytest.raises(ValueError, match="unknown golden set"):
        goldenset.generate("huge", "/nonexistent")
