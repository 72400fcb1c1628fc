"""Truth checks shared by the demo and the campaigns: the right-match and wrong-solution rules."""

import math

from lodestar.contract import BlobRecord
from lodestar.ground.truth import (
    MATCH_MARGIN_PX,
    WRONG_SIGMAS,
    judge,
    match_rows,
    track_meets_box,
)


def record(xmin, xmax, ymin, ymax):
    return BlobRecord(n=9, nsat=0, s0=90, sx=0, sy=0, sxx=0, syy=0, sxy=0, xmin=xmin,
                      xmax=xmax, ymin=ymin, ymax=ymax, peak=50, flags=0)


def test_match_is_right_inside_the_grown_box_only():
    sources = [{"kind": "star", "hip": 105199, "x": 12.0 + MATCH_MARGIN_PX, "y": 20.0},
               {"kind": "false_star", "hip": None, "x": 50.0, "y": 50.0}]
    rows = match_rows([(0, 11.0, 20.0, 105199), (1, 50.0, 50.0, 105199),
                       (0, 11.0, 20.0, 102422)],
                      [record(10, 12, 18, 22), record(49, 51, 49, 51)], sources)
    assert [r["right"] for r in rows] == [True, False, False]
    assert rows[0]["name"] == "Alderamin" and rows[0]["truth_offset_px"] == 3.0
    assert rows[2]["truth_offset_px"] is None


def test_track_through_the_box_makes_a_fragment_right():
    # a streak from (0, 20) to (40, 20): its centroid (20, 20) lies outside the fragment's
    # box at x 30..34, its track passes through it
    track = [[0.0, 20.0], [10.0, 20.0], [20.0, 20.0], [30.0, 20.0], [40.0, 20.0]]
    sources = [{"kind": "star", "hip": 105199, "x": 20.0, "y": 20.0, "track": track}]
    rows = match_rows([(0, 32.0, 20.0, 105199), (1, 32.0, 30.0, 105199)],
                      [record(30, 34, 19, 21), record(30, 34, 29, 31)], sources)
    assert [r["right"] for r in rows] == [True, False]
    assert rows[0]["truth_offset_px"] == 12.0


def test_track_meets_box_between_points():
    # a diagonal segment crossing a 1-px box between its two end points
    assert track_meets_box([[0.0, 0.0], [10.0, 10.0]], (4.6, 4.6, 5.4, 5.4))
    assert not track_meets_box([[0.0, 0.0], [10.0, 10.0]], (6.0, 2.0, 8.0, 3.0))
    assert track_meets_box([[5.0, 5.0]], (5.0, 5.0, 5.0, 5.0))


def test_judge_wrong_imprecise_right():
    def err(x, y, roll):
        return {"x": x, "y": y, "roll": roll, "cross": math.hypot(x, y),
                "total": math.sqrt(x * x + y * y + roll * roll)}

    assert judge(err(1.0, 1.0, 5.0), 1.0, 10.0, 0) == (False, False)
    assert judge(err(1.0, 1.0, 5.0), 1.0, 10.0, 1) == (True, False)     # misidentified
    # 200" of roll: covered by a 100" roll sigma, not by a 30" one, nor by no covariance
    assert judge(err(1.0, 1.0, 200.0), 1.0, 100.0, 0) == (False, True)
    assert judge(err(1.0, 1.0, 200.0), 1.0, 30.0, 0) == (True, False)
    assert judge(err(1.0, 1.0, 200.0), None, None, 0) == (True, False)
    assert judge(err(1.0, 1.0, 200.0), 1.0, float("nan"), 0) == (True, False)
    # each cross-boresight axis against the per-axis sigma
    assert judge(err(190.0, 0.0, 0.0), 40.0, 10.0, 0) == (False, True)
    assert judge(err(0.0, 190.0, 0.0), 30.0, 1000.0, 0) == (True, False)
    assert WRONG_SIGMAS == 5.0
