"""Truth checks shared by the demo and the campaigns: the right-match rule."""

from lodestar.campaign_truth import MATCH_MARGIN_PX, match_rows
from lodestar.contract import BlobRecord


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
