"""Annotated pictures: catalogue predictions land on the simulator's stars (at rest and
turning), and the picture shows boxes, labels, markers and the legend in their colours."""

import math

import numpy as np
import pytest
from PIL import Image

from lodestar.contract import BlobRecord
from lodestar.ground import annotate
from lodestar.ground.onboard import firmware_camera
from lodestar.sim import attitude, scene
from lodestar.sim.goldenset import window_camera
from lodestar.sim.presets import load_preset

WINDOW = (976, 732, 640, 480)


def _sim(rate_deg_s, seed):
    cam = window_camera(load_preset("estcube2"), WINDOW)
    q = attitude.from_radec_roll(83.8, -5.4, 10.0)      # Orion: bright stars in any window
    return cam, q, scene.simulate(cam, q, rate_deg_s, seed=seed)


@pytest.mark.parametrize("rate, tol_px", [((0.0, 0.0, 0.0), 0.01), ((0.6, 0.8, 0.5), 0.3)])
def test_predicted_pixels_land_on_the_true_centroids(rate, tol_px):
    cam, q, sim = _sim(rate, 3)
    predicted = annotate.predict_pixels(q, firmware_camera(cam), 6.0,
                                        omega=[math.radians(w) for w in rate],
                                        exposure_s=sim.truth["exposure_s"],
                                        row_time_s=sim.truth["row_time_s"])
    truth = {s["hip"]: s for s in sim.truth["sources"] if s["vmag"] <= 6.0}
    # stars near the edge are cut by the frame, so their true centroid moves inwards
    inner = {h: s for h, s in truth.items() if 20 < s["x"] < cam.width - 20 and
             20 < s["y"] < cam.height - 20}
    assert len(inner) >= 3
    by_hip = {hip: (x, y) for x, y, hip, _v in predicted}
    assert [v for *_xy, _h, v in predicted] == sorted(v for *_xy, _h, v in predicted)
    for hip, s in inner.items():
        x, y = by_hip[hip]
        assert math.hypot(x - s["x"], y - s["y"]) < tol_px, hip


def _record(x0, x1, y0, y1):
    return BlobRecord(n=1, nsat=0, s0=1, sx=x0, sy=y0, sxx=0, syy=0, sxy=0, xmin=x0, xmax=x1,
                      ymin=y0, ymax=y1, peak=1, flags=0)


def test_picture_elements_and_colours(tmp_path):
    frame = np.full((240, 320), 100, np.uint16)
    frame[100:103, 200:203] = 2000
    records = [_record(200, 202, 100, 102), _record(50, 52, 150, 152)]
    path = tmp_path / "a.png"
    annotate.save_annotated(path, frame, records=records, identified=[0],
                            labels=[(201, 101, "HIP 1 Right", True),
                                    (51, 151, "HIP 2 Wrong", False)],
                            markers={"truth": [(201.0, 101.0)], "solution": [(51.0, 151.0)]},
                            legend=["legend line"])
    img = np.asarray(Image.open(path).convert("RGB"))
    assert img.shape == (240, 320, 3)
    m = annotate.BOX_MARGIN_PX
    c = annotate.COLOURS
    assert tuple(img[101, 200 - m]) == c["identified"]         # left edge of box 0
    assert tuple(img[150 - m, 50 - m]) == c["record"]          # corner of box 1
    assert tuple(img[151, 51]) == c["solution"]                # cross centre
    colours = {tuple(p) for p in img.reshape(-1, 3)}
    assert {c["truth"], c["wrong"], c["legend"]} <= colours
    assert tuple(img[0, 0]) == (0, 0, 0)                        # legend background


def test_bad_arguments(tmp_path):
    frame = np.zeros((20, 20), np.uint16)
    with pytest.raises(ValueError, match="unknown marker sets"):
        annotate.save_annotated(tmp_path / "x.png", frame, markers={"stars": []})
    with pytest.raises(ValueError, match="2-D"):
        annotate.save_annotated(tmp_path / "x.png", np.zeros((3, 4, 5), np.uint16))
    with pytest.raises(FileNotFoundError, match="does not exist"):    # never made
        annotate.save_annotated(tmp_path / "new" / "x.png", frame)
    assert not (tmp_path / "new").exists()
    (tmp_path / "file").write_text("not a folder")
    with pytest.raises(OSError):
        annotate.save_annotated(tmp_path / "file" / "x.png", frame)
