"""Bounded work (issue 19, item 2): every identification ends within its deterministic
work budget, whatever its input; parameters whose work has no bound are refused."""

import math

import numpy as np
import pytest

from lodestar.firmware import starid
from lodestar.firmware import status as S
from lodestar.firmware.pipeline import StarTracker
from lodestar.firmware.settings import MAX_STARS, Settings
from lodestar.firmware.starid.search import DEFAULT_MAX_WORK
from lodestar.ground.solve import solve_centroids
from lodestar.sim.attitude import random_attitude
from lodestar.sim.centroids import centroid_scene


def _scene(camera, catalogue, seed, **kw):
    rng = np.random.default_rng(seed)
    scene = centroid_scene(camera, random_attitude(rng), rng, catalogue, **kw)
    return [tuple(v) for v in scene.vectors.tolist()]


def test_a_wide_tolerance_ends_within_the_work_budget(starid_setup, method):
    """A tolerance 40 times the pipeline's (100 px of estcube2: minutes before) ends with a
    status inside the budget: each step is charged before it is done, so only a search
    that ends ``BUDGET_EXHAUSTED`` has a count past its limit."""
    camera, catalogue, db = starid_setup
    vectors = _scene(camera, catalogue, 3, noise_px=1.0, n_false=10, max_stars=30)
    for tolerance in (0.049 * db.fov_h, 0.02 * db.fov_h):
        sol = starid.identify(vectors, db, method=method, tolerance_rad=tolerance,
                              budget=10 ** 6, max_work=200000)
        assert sol.status in (S.BUDGET_EXHAUSTED, S.NO_MATCH, S.AMBIGUOUS, S.OK)
        assert sol.work <= 200000 or sol.status == S.BUDGET_EXHAUSTED
        assert sol.work > 0 or sol.status == S.NO_MATCH


def test_exhausting_the_work_budget_is_a_status(starid_setup, method):
    camera, catalogue, db = starid_setup
    vectors = _scene(camera, catalogue, 5, noise_px=0.3)
    assert starid.identify(vectors, db, method=method, max_work=1).status == \
        S.BUDGET_EXHAUSTED
    ok = starid.identify(vectors, db, method=method)
    assert ok.status == S.OK
    for bad in (0, -5, 2.5, True):
        assert starid.identify(vectors, db, method=method, max_work=bad).status == S.BAD_INPUT


def test_each_method_has_its_default_work_budget(starid_setup, method):
    """``max_work=None`` (the default) is the method's own ``MAX_WORK``: Pyramid's bounds a
    search at 2 s of F401 time, the others keep the shared default."""
    camera, catalogue, db = starid_setup
    module = starid.method(method)
    assert module.MAX_WORK == (20000 if method == "pyramid" else DEFAULT_MAX_WORK)
    if method != "pyramid":
        return                  # a hostile search within 5 M units takes minutes here
    vectors = _scene(camera, catalogue, 3, noise_px=1.0, n_false=10, max_stars=30)
    tolerance = 0.02 * db.fov_h
    sol = starid.identify(vectors, db, method=method, tolerance_rad=tolerance, budget=10 ** 6)
    assert sol.status == S.BUDGET_EXHAUSTED and module.MAX_WORK < sol.work
    same = starid.identify(vectors, db, method=method, tolerance_rad=tolerance, budget=10 ** 6,
                           max_work=module.MAX_WORK)
    assert (same.status, same.work) == (sol.status, sol.work)


def test_a_tolerance_that_matches_anything_is_refused(starid_setup, method):
    camera, catalogue, db = starid_setup
    vectors = _scene(camera, catalogue, 5, noise_px=0.3)
    for tolerance in (1e9, 0.051 * db.fov_h, math.inf):
        assert starid.identify(vectors, db, method=method,
                               tolerance_rad=tolerance).status == S.BAD_INPUT


def test_star_tracker_refuses_unbounded_settings(starid_database_of, firmware_camera):
    """``tolerance_px=1e9``, ``max_stars=10**5`` and a bad ``max_work`` are configuration
    errors (``BAD_INPUT``) before any frame, with a reason naming the setting."""
    _camera, _catalogue, db = starid_database_of("pyramid")
    for settings, word in ((Settings(tolerance_px=1e9), "tolerance_px"),
                           (Settings(max_stars=10 ** 5), "max_stars"),
                           (Settings(max_stars=MAX_STARS + 1), "max_stars"),
                           (Settings(max_work=0), "max_work")):
        tracker = StarTracker(db, firmware_camera, settings)
        result = tracker.process(b"")
        assert result.status == S.BAD_INPUT and word in result.reason, result.reason
    assert StarTracker(db, firmware_camera, Settings(max_stars=MAX_STARS)).status == S.OK


@pytest.mark.parametrize("width, height, fov", [(16, 16, 90.0), (128, 96, 40.0),
                                                (160, 120, 20.0)])
def test_tiny_frames_at_wide_fields_end_with_a_status(width, height, fov, work_spent,
                                                      tmp_path):
    """The ground solve of random centroids on tiny frames (over 90 s before) ends with a
    status, never an attitude, within the work budget."""
    rng = np.random.default_rng(0)
    cents = [(float(x), float(y), float(f)) for x, y, f in
             zip(rng.uniform(0, width, 30), rng.uniform(0, height, 30),
                 rng.uniform(100, 1000, 30))]
    result = solve_centroids(cents, width, height, fov, cache_dir=tmp_path)
    assert result.status != S.OK or result.matches
    assert all(work <= limit for work, limit in work_spent) or \
        result.status == S.BUDGET_EXHAUSTED
