"""Bad configurations and bad frames raise ValueError naming the field and the reason."""

import numpy as np
import pytest

from lodestar import contract as C
from lodestar.golden import Detector, DetectorConfig, detect_frame


@pytest.mark.parametrize("changes,match", [
    ({"width": 0}, r"width=0 is out of range 1\.\.4096"),
    ({"width": C.MAX_WIDTH + 1}, r"width=4097 .*MAX_WIDTH"),
    ({"height": C.MAX_HEIGHT + 1}, r"height=4097 .*MAX_HEIGHT"),
    ({"width": 2.5}, r"width must be an int"),
    ({"pixel_bits": 14}, r"pixel_bits=14 is not one of"),
    ({"threshold_mode": "adaptive"}, r"threshold_mode='adaptive' is not one of"),
    ({"threshold": 4096}, r"threshold=4096 is out of range 0\.\.4095 \(12-bit"),
    ({"background": -1}, r"background=-1 is out of range"),
    ({"ksigma": 2.01}, r"ksigma=2\.01 is not a multiple of 1/16"),
    ({"ksigma": 16.0}, r"ksigma=16\.0 is out of range"),
    ({"ksigma": True}, r"ksigma must be a finite number"),
    ({"ksigma": float("nan")}, r"ksigma must be a finite number"),
    ({"pixel_bits": 16.0}, r"pixel_bits=16.0 is not one of"),
    ({"local_log2_window": 8}, r"local_log2_window=8 is out of range 1\.\.7"),
    ({"threshold_mode": "local", "width": 128}, r"width=128 must exceed the local window of 128"),
    ({"min_pixels": -1}, r"min_pixels=-1 is out of range"),
    ({"min_pixels": 7, "max_pixels": 6}, r"max_pixels=6 is below min_pixels=7"),
    ({"min_sum": 1 << 40}, r"min_sum=.* is out of range"),
    ({"label_capacity": 0}, r"label_capacity=0 is out of range"),
    ({"label_capacity": 52}, r"label_capacity=52 is out of range 1\.\.51"),
    ({"record_capacity": C.MAX_RECORD_CAPACITY + 1}, r"record_capacity=65536 is out of range"),
])
def test_bad_config(changes, match):
    args = {"width": 100, "height": 10}
    args.update(changes)
    with pytest.raises(ValueError, match=match):
        DetectorConfig(**args)


def test_registers_round_trip_the_config():
    cfg = DetectorConfig(width=64, height=8, threshold_mode="global", ksigma=2.5,
                         max_pixels=None, min_sum=1000)
    regs = cfg.registers()
    assert set(regs) == set(C.REGISTER_BY_NAME)
    assert regs["mode"] == C.MODE_GLOBAL and regs["ksigma"] == 40
    assert regs["max_pixels"] == C.MAX_PIXELS_UNLIMITED
    for name, value in regs.items():
        assert 0 <= value < (1 << C.REGISTER_BY_NAME[name].bits), name
    assert cfg.labels == C.max_open_blobs(64) == 33


CFG = DetectorConfig(width=4, height=3, pixel_bits=10)


@pytest.mark.parametrize("frame,match", [
    ([[0] * 4] * 3, r"frame must be a numpy array, got list"),
    (np.zeros((3, 4), np.float32), r"dtype must be uint8 or uint16, got float32"),
    (np.zeros((3, 4), np.int16), r"dtype must be uint8 or uint16, got int16"),
    (np.zeros((3, 4, 3), np.uint16), r"must be 2-D .* shape \(3, 4, 3\)"),
    (np.zeros((4, 3), np.uint16), r"shape \(4, 3\) does not match .* \(3, 4\)"),
])
def test_bad_frame(frame, match):
    with pytest.raises(ValueError, match=match):
        detect_frame(frame, CFG)


def test_pixel_beyond_pixel_bits_is_located():
    frame = np.zeros((3, 4), np.uint16)
    frame[2, 1] = 1024
    with pytest.raises(ValueError, match=r"pixel \(x=1, y=2\) = 1024 exceeds full scale 1023"):
        detect_frame(frame, CFG)


def test_uint8_frames_are_accepted():
    frame = np.zeros((3, 4), np.uint8)
    frame[1, 1] = 200
    cfg = DetectorConfig(width=4, height=3, pixel_bits=8, threshold=100)
    assert [b.peak for b in detect_frame(frame, cfg).blobs] == [200]


def test_detector_rejects_geometry_change_and_unknown_engine():
    det = Detector(CFG)
    with pytest.raises(ValueError, match="elaboration parameters"):
        det.configure(CFG.replace(width=5))
    det.configure(CFG.replace(threshold=7))
    assert det.cfg.threshold == 7
    with pytest.raises(ValueError, match=r"engine='fpga' is not one of"):
        Detector(CFG, engine="fpga")
