"""lodestar.firmware.starid.search: the q-method fit and the streak checks shared by the
methods (the search itself runs in every ``test_methods.py`` case)."""

import inspect

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from lodestar.contract import stardb
from lodestar.firmware import quaternion, starid
from lodestar.firmware import status as S
from lodestar.firmware.starid import search
from lodestar.sim.attitude import random_attitude
from lodestar.sim.centroids import attitude_error_deg


def test_fit_attitude_matches_scipy_convention():
    rng = np.random.default_rng(0)
    for _ in range(50):
        q = random_attitude(rng)
        ref = rng.normal(size=(6, 3))
        ref /= np.linalg.norm(ref, axis=1, keepdims=True)
        obs = Rotation.from_quat(q).apply(ref) + rng.normal(0, 1e-5, (6, 3))
        est = search.fit_attitude(obs.tolist(), ref.tolist())
        assert attitude_error_deg(est, q) < 0.01
        assert np.allclose(np.array(quaternion.matrix(q)).reshape(3, 3),
                           Rotation.from_quat(q).as_matrix(), atol=1e-12)
    # narrow field (all vectors within 10 deg of one direction), 180 deg rotations
    for q in ([1.0, 0, 0, 0], [0, 0, 1.0, 0], random_attitude(rng)):
        d = rng.normal(0, 0.1, (5, 3)) + [0, 0, 1]
        ref = d / np.linalg.norm(d, axis=1, keepdims=True)
        obs = Rotation.from_quat(q).apply(ref)
        assert attitude_error_deg(search.fit_attitude(obs.tolist(), ref.tolist()), q) < 1e-5


def test_streaks_are_checked():
    assert search.streaks_valid(None, 3)
    assert search.streaks_valid([None, (0.0, 1.0, 0.0, 1e-4), None], 3)
    for bad in ([None, None], [None, (0.0, 1.0, 0.0), None], [None, (0, 1, 0, -1e-4), None],
                [None, (0, 1, float("nan"), 1e-4), None], 5, [None, "abcd", None]):
        assert not search.streaks_valid(bad, 3), bad


def test_every_method_declares_the_search_interface():
    """``Search`` declares the hooks :func:`identify_with` calls; each method of the
    contract's table overrides them with one constructor order."""
    base = search.Search([(0.0, 0.0, 1.0)] * 3, None, 1e-4, 1e-9, 2e-3, None, 16)
    assert base.n == 3 and base.refuses(base.b, None, 16) is None
    with pytest.raises(NotImplementedError):
        base.patterns()
    with pytest.raises(NotImplementedError):
        base.try_pattern((0, 1, 2))
    for name in stardb.METHODS:
        cls = starid.method(name)._Search
        assert issubclass(cls, search.Search) and cls.BIT == stardb.METHOD_NAMES[name]
        assert cls.try_pattern is not search.Search.try_pattern
        assert cls.patterns is not search.Search.patterns
        assert inspect.signature(cls.__init__) == inspect.signature(search.Search.__init__)


def test_a_search_that_cannot_verify_tries_no_pattern(starid_database_of, tol):
    _cam, _cat, db = starid_database_of("pyramid")
    rng = np.random.default_rng(3)
    d = rng.normal(0, 0.05, (4, 3)) + [0, 0, 1]
    b = (d / np.linalg.norm(d, axis=1, keepdims=True)).tolist()
    streaks = [tuple(v) + (h * tol,) for v, h in zip(([1.0, 0, 0],) * 4, (0.6, 1.5, 1.5, 6.9))]
    sol = starid.identify(b, db, "pyramid", tol, streaks=streaks)
    assert (sol.status, sol.patterns_tried, sol.work) == (S.NO_MATCH, 0, 0)
    assert sol.probability >= 1e-9
    # allowed a probability it can reach, the same stars are searched
    sol = starid.identify(b, db, "pyramid", tol, streaks=streaks,
                          max_mismatch_prob=2 * sol.probability)
    assert sol.patterns_tried >= 1 and sol.work > 0
