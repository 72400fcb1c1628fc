"""lodestar.firmware.settings: the StarTracker's settings object."""

import inspect
import time

import pytest

from lodestar.firmware import centroids, starid, tracking
from lodestar.firmware import status as S
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import (
    DEFAULT_MAX_STARS,
    DEFAULT_TOLERANCE_PX,
    EXTRACT_OPTIONS,
    ID_OPTIONS,
    Settings,
)
from tests import sim_frames

# the frames and the flight database are made once per worker: one worker runs them
# (pyproject: loadgroup)
pytestmark = pytest.mark.xdist_group("sim_frames")


def test_defaults():
    s = Settings()
    assert s.method == "pyramid" and s.max_stars == DEFAULT_MAX_STARS
    assert s.tolerance_px == DEFAULT_TOLERANCE_PX and s.centroid_sigma_px is None
    assert s.track_min_matches == tracking.DEFAULT_MIN_MATCHES
    assert s.track_max_prob == tracking.DEFAULT_MAX_MISMATCH_PROB
    assert s.extract_options == {} and s.id_options == {} and s.clock is None
    assert Settings(extract_options={"min_pixels": 2}).extract_options == {"min_pixels": 2}


def test_no_settings_is_the_defaults():
    frame = sim_frames.frames()[0]
    db, cam = sim_frames.flight_database(), sim_frames.firmware_camera()
    plain = StarTracker(db, cam).process(frame.packet)
    default = StarTracker(db, cam, Settings()).process(frame.packet)
    assert plain.status == default.status == S.OK
    assert plain.q == default.q and plain.matches == default.matches


NAN, INF = float("nan"), float("inf")


def _failing_clock():
    raise OSError("no timer")


POSITIVE = " must be a positive number"
VELOCITY = "velocity_km_s must be None or 3 finite numbers, km/s, at most 100.0 km/s"
BAD_SETTINGS = [
    ({"tolerance_px": -1}, "tolerance_px" + POSITIVE),
    ({"tolerance_px": 0}, "tolerance_px" + POSITIVE),
    ({"tolerance_px": NAN}, "tolerance_px" + POSITIVE),
    ({"tolerance_px": "2"}, "tolerance_px" + POSITIVE),
    ({"tolerance_px": True}, "tolerance_px" + POSITIVE),
    ({"tolerance_px": None}, "tolerance_px" + POSITIVE),
    ({"tolerance_px": 1000.0}, "tolerance_px must be at most 128 px (0.05 of the field)"),
    ({"centroid_sigma_px": NAN}, "centroid_sigma_px" + POSITIVE + " or None"),
    ({"centroid_sigma_px": 0}, "centroid_sigma_px" + POSITIVE + " or None"),
    ({"centroid_sigma_px": True}, "centroid_sigma_px" + POSITIVE + " or None"),
    ({"min_sigma_px": 0}, "min_sigma_px" + POSITIVE),
    ({"min_sigma_px": None}, "min_sigma_px" + POSITIVE),
    ({"max_stars": 3}, "max_stars must be an int in 4..256"),
    ({"max_stars": 257}, "max_stars must be an int in 4..256"),
    ({"max_stars": 8.0}, "max_stars must be an int in 4..256"),
    ({"max_stars": True}, "max_stars must be an int in 4..256"),
    ({"track_stars": 0}, "track_stars must be None or an int >= 1"),
    ({"track_stars": True}, "track_stars must be None or an int >= 1"),
    ({"track_stars": 1.5}, "track_stars must be None or an int >= 1"),
    ({"max_work": 0}, "max_work must be None or an int >= 1"),
    ({"max_work": True}, "max_work must be None or an int >= 1"),
    ({"max_work": 1.0}, "max_work must be None or an int >= 1"),
    ({"budget": 0}, "budget must be an int >= 1"),
    ({"budget": 1.5}, "budget must be an int >= 1"),
    ({"budget": "2000"}, "budget must be an int >= 1"),
    ({"max_smear_px": 0}, "max_smear_px" + POSITIVE),
    ({"max_smear_px": INF}, "max_smear_px" + POSITIVE),
    ({"max_error_arcsec": 0}, "max_error_arcsec" + POSITIVE + " or None"),
    ({"max_error_arcsec": NAN}, "max_error_arcsec" + POSITIVE + " or None"),
    ({"track_search_deg": -0.1}, "track_search_deg must be a number >= 0"),
    ({"track_search_deg": NAN}, "track_search_deg must be a number >= 0"),
    ({"row_time_s": INF}, "row_time_s must be a finite number"),
    ({"epoch_s": NAN}, "epoch_s must be a finite number"),
    ({"epoch_s": None}, "epoch_s must be a finite number"),
    ({"exposure_s": 0}, "exposure_s" + POSITIVE + " or None"),
    ({"exposure_s": -1.0}, "exposure_s" + POSITIVE + " or None"),
    ({"exposure_s": NAN}, "exposure_s" + POSITIVE + " or None"),
    ({"velocity_km_s": (0, 0)}, VELOCITY),
    ({"velocity_km_s": (300, 0, 0)}, VELOCITY),
    ({"velocity_km_s": "fast"}, VELOCITY),
    ({"velocity_km_s": (10 ** 400, 0, 0)}, VELOCITY),          # no float holds it
    ({"tolerance_px": 10 ** 400}, "tolerance_px" + POSITIVE),
    ({"row_time_s": -10 ** 400}, "row_time_s must be a finite number"),
    ({"extract_options": {"bogus": 1}},
     "extract_options must be a dict of min_pixels, min_sigma_px, max_elongation, "
     "smear_angle_tol, smear_length_ratio, join_across_px, not 'bogus'"),
    ({"extract_options": {"max_stars": 5}}, "extract_options must be a dict of min_pixels, "
     "min_sigma_px, max_elongation, smear_angle_tol, smear_length_ratio, join_across_px, "
     "not 'max_stars'"),                 # the pipeline sets it
    ({"extract_options": {"min_pixels": 0}},
     "extract_options must be a dict whose min_pixels is an int >= 1"),
    ({"extract_options": {"max_elongation": NAN}},
     "extract_options must be a dict whose max_elongation is a positive number"),
    ({"extract_options": [("min_pixels", 2)]}, "extract_options must be a dict of min_pixels, "
     "min_sigma_px, max_elongation, smear_angle_tol, smear_length_ratio, join_across_px"),
    ({"id_options": {"bogus": 1}},
     "id_options must be a dict of max_stars, max_mismatch_prob, distinct_rad, not 'bogus'"),
    ({"id_options": {"max_mismatch_prob": 1.0}},
     "id_options must be a dict whose max_mismatch_prob is a number in (0, 1)"),
    ({"id_options": {"max_stars": 2}},
     "id_options must be a dict whose max_stars is an int in 4..256"),
    ({"id_options": {"distinct_rad": -1.0}},
     "id_options must be a dict whose distinct_rad is a positive number or None"),
    ({"clock": "ticks"}, "clock must be None or a function returning a number"),
    ({"clock": _failing_clock}, "clock must be None or a function returning a number"),
    ({"clock": lambda: None}, "clock must be None or a function returning a number"),
    ({"method": "nonsense"}, "unknown method 'nonsense'"),
    ({"method": None}, "unknown method None"),
    # the first bad setting in the order above is the one reported
    ({"tolerance_px": -1, "max_stars": 2}, "tolerance_px" + POSITIVE),
    ({"max_stars": 2, "budget": 0}, "max_stars must be an int in 4..256"),
    ({"exposure_s": 0, "velocity_km_s": (0, 0)}, "exposure_s" + POSITIVE + " or None"),
    ({"method": "nonsense", "tolerance_px": 0}, "tolerance_px" + POSITIVE),
]


def test_each_bad_setting_has_its_status_and_reason():
    """The status and reason of each bad setting, pinned (a StarTracker built with it)."""
    image, cam = sim_frames.flight_image(), sim_frames.firmware_camera()
    for options, reason in BAD_SETTINGS:
        tracker = StarTracker(image, cam, Settings(**options))
        assert (S.name(tracker.status), tracker.reason) == ("BAD_INPUT", reason), options
    tracker = StarTracker(image, cam, Settings(method="triangle"))
    assert (S.name(tracker.status), tracker.reason) == \
        ("DATABASE_UNSUPPORTED", "the database does not serve method 'triangle'")


def test_the_keyword_options_are_the_functions_keywords():
    """``EXTRACT_OPTIONS`` and ``ID_OPTIONS`` name keywords the functions take, so every
    accepted dict is one the pipeline can pass."""
    extract = inspect.signature(centroids.extract).parameters
    assert all(name in extract for name, _check in EXTRACT_OPTIONS)
    for method in starid.METHODS:
        identify = inspect.signature(starid.method(method).identify).parameters
        assert all(name in identify for name, _check in ID_OPTIONS), method


def test_edge_settings_are_accepted():
    image, cam = sim_frames.flight_image(), sim_frames.firmware_camera()
    for options, track_stars in (({"budget": True}, 8), ({"track_search_deg": 0}, 8),
                                 ({"extract_options": {"min_pixels": 2, "join_across_px": 0},
                                   "id_options": {"max_mismatch_prob": 1e-6,
                                                  "distinct_rad": None},
                                   "clock": time.perf_counter}, 8),
                                 ({"track_stars": None, "centroid_sigma_px": None,
                                   "exposure_s": None}, None),
                                 ({"max_stars": 256, "track_stars": 300}, 256)):
        tracker = StarTracker(image, cam, Settings(**options))
        assert tracker.status == S.OK and tracker.track_stars == track_stars, options


def test_the_camera_and_the_settings_type_are_checked_before_the_settings():
    image, cam = sim_frames.flight_image(), sim_frames.firmware_camera()
    for camera, settings, reason in (
            ("estcube2", Settings(tolerance_px=-1), "camera must be a firmware Camera or a dict"),
            ({"width": 2592}, Settings(max_stars=2), "camera: camera parameter height is missing"),
            (cam, {"method": "pyramid"}, "settings must be a firmware Settings or None")):
        tracker = StarTracker(image, camera, settings)
        assert (S.name(tracker.status), tracker.reason) == ("BAD_INPUT", reason)
    tracker = StarTracker(b"LSDB", cam, Settings(method="nonsense"))   # the database first
    assert tracker.status == S.DATABASE_BAD_LENGTH and tracker.reason.startswith("database:")
