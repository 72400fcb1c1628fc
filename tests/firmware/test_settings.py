"""lodestar.firmware.settings: the StarTracker's settings object."""

from lodestar.firmware import status as S
from lodestar.firmware import tracking
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import DEFAULT_MAX_STARS, DEFAULT_TOLERANCE_PX, Settings
from tests import sim_frames as SF


def test_defaults():
    s = Settings()
    assert s.method == "pyramid" and s.max_stars == DEFAULT_MAX_STARS
    assert s.tolerance_px == DEFAULT_TOLERANCE_PX and s.centroid_sigma_px is None
    assert s.track_min_matches == tracking.DEFAULT_MIN_MATCHES
    assert s.track_max_prob == tracking.DEFAULT_MAX_MISMATCH_PROB
    assert s.extract_options == {} and s.id_options == {} and s.clock is None
    assert Settings(extract_options={"min_pixels": 2}).extract_options == {"min_pixels": 2}


def test_no_settings_is_the_defaults():
    frame = SF.frames()[0]
    db, cam = SF.flight_database(), SF.firmware_camera()
    plain = StarTracker(db, cam).process(frame.packet)
    default = StarTracker(db, cam, Settings()).process(frame.packet)
    assert plain.status == default.status == S.OK
    assert plain.q == default.q and plain.matches == default.matches
