"""Fixtures of the firmware tests: the firmware camera, the star-identification set-up per
method (``method`` runs a test once per :data:`lodestar.firmware.starid.METHODS`), scoring,
hard scenes and the heap-budget measurement."""

import functools
import tracemalloc

import numpy as np
import pytest

from lodestar.firmware import starid
from lodestar.firmware import status as S
from lodestar.firmware.database import Database
from lodestar.firmware.settings import DEFAULT_TOLERANCE_PX
from lodestar.firmware.starid.search import DEFAULT_MAX_WORK
from lodestar.ground.database import build_database
from lodestar.sim.attitude import random_attitude
from lodestar.sim.catalogue import load
from lodestar.sim.centroids import attitude_error_deg, centroid_scene
from lodestar.sim.presets import load_preset
from tests import sim_frames

MAX_ERR_DEG = 0.05
"""An accepted attitude further than this from the truth is a wrong solution."""


def outcome(sol, scene):
    """``"correct"``, ``"wrong"`` (attitude off or a star misnamed) or ``"no-solve"``."""
    if sol.status != S.OK:
        return "no-solve"
    if attitude_error_deg(sol.q, scene.q) > MAX_ERR_DEG:
        return "wrong"
    if any(hip not in scene.components[o] for o, hip in sol.matches):
        return "wrong"
    return "correct"


HEAP_BUDGET = 96 * 1024
"""Issue budget, bytes: the peak heap of one solve under MicroPython.  The MicroPython
WebAssembly port cannot show a peak (it collects only between top-level calls), so the tests
bound it by the CPython ``tracemalloc`` live peak of the same call: every CPython object is
larger than its 32-bit MicroPython counterpart (a float 24 B against 16 B, a tuple
56 + 8 n B against about 8 + 4 n, lists and dicts alike)."""


def live_peak(call):
    """``tracemalloc`` live peak (bytes above the start) of one ``call()``, after a first
    call that warms up imports and first-use allocations."""
    call()
    tracemalloc.start()
    try:
        base = tracemalloc.get_traced_memory()[0]
        call()
        return tracemalloc.get_traced_memory()[1] - base
    finally:
        tracemalloc.stop()


def hard_scenes(camera, catalogue, n, seed):
    """``n`` hard centroid scenes: 30 observed stars of which 10 are false, 1 px centroid
    noise, 10 % of the stars dropped."""
    rng = np.random.default_rng(seed)
    return [centroid_scene(camera, random_attitude(rng), rng, catalogue, noise_px=1.0,
                           n_false=10, drop_fraction=0.1, max_stars=30) for _ in range(n)]


def pipeline_tolerance_rad(camera):
    """The flight pipeline's default match tolerance for ``camera`` (rad)."""
    return DEFAULT_TOLERANCE_PX / camera.fx_px


def _identify_within_heap_budget(method, camera, catalogue, db):
    """Three :func:`hard_scenes` solve with ``method`` at the pipeline's tolerance, each
    within :data:`HEAP_BUDGET` of live peak (the bound of the MicroPython peak).  The work
    budget is the shared 5,000,000 units, not Pyramid's flight budget: a hard scene of a
    dense wide-field database takes up to 213,000 units (about 11 s of F401 time), and
    this checks the heap of a search that runs that long."""
    tol = pipeline_tolerance_rad(camera)
    for scene in hard_scenes(camera, catalogue, 3, seed=3):
        v = scene.vectors.tolist()
        assert starid.identify(v, db, method=method, tolerance_rad=tol,
                               max_work=DEFAULT_MAX_WORK).status == S.OK
        peak = live_peak(lambda: starid.identify(v, db, method=method, tolerance_rad=tol,
                                                 max_work=DEFAULT_MAX_WORK))
        assert peak < HEAP_BUDGET, (method, camera.name, peak)


def _streaked(vectors, rng, half_rad, every=1, keep_first=0):
    """Observed directions seen as partial tracks: from star ``keep_first`` on, every
    ``every``-th vector is moved along a random tangent ``u`` by a uniform offset within
    ``+-half_rad`` pushed to at least ``half_rad / 2`` (beyond any point tolerance when
    ``half_rad`` is large).  Returns ``(vectors, streaks)`` with ``streaks[o] = (ux, uy, uz,
    half_rad)`` for a moved star, None for the others (:mod:`lodestar.firmware.starid.verify`)."""
    out, streaks = [], []
    for o, v in enumerate(np.asarray(vectors, dtype=float)):
        if o < keep_first or (o - keep_first) % every:
            out.append(v.tolist())
            streaks.append(None)
            continue
        t = np.cross(v, rng.normal(size=3))
        u = t / np.linalg.norm(t)
        shift = rng.uniform(0.5, 1.0) * half_rad * rng.choice([-1.0, 1.0])
        w = v + shift * u
        out.append((w / np.linalg.norm(w)).tolist())
        streaks.append((float(u[0]), float(u[1]), float(u[2]), float(half_rad)))
    return out, streaks


TOL = 3.0e-4
"""Identification tolerance of the star-id tests, rad: about 2.2 px of estcube2 (28.4"/px),
more than 4 sigma of 0.5 px centroid noise."""


@functools.lru_cache(maxsize=None)
def starid_database(method):
    """``(camera, catalogue, Database)``: estcube2 with a V <= 6 database serving ``method``
    alone."""
    cam = load_preset("estcube2")
    cat = load()
    return cam, cat, Database(build_database(cat, cam, mag_limit=6.0, methods=(method,)))


@pytest.fixture(params=starid.METHODS)
def method(request):
    """Each identification method of the registry in turn."""
    return request.param


@pytest.fixture
def starid_setup(method):
    """``(camera, catalogue, Database)`` of :func:`starid_database` for ``method``."""
    return starid_database(method)


@pytest.fixture(scope="session")
def tol():
    """:data:`TOL`."""
    return TOL


@pytest.fixture(scope="session")
def starid_database_of():
    """:func:`starid_database` (the set-up of any method)."""
    return starid_database


@pytest.fixture(scope="session")
def firmware_camera():
    """The estcube2 camera as the firmware models it (:class:`lodestar.firmware.camera`)."""
    return sim_frames.firmware_camera()


@pytest.fixture(scope="session")
def scene_outcome():
    """:func:`outcome`: scores an identification against its scene."""
    return outcome


@pytest.fixture(scope="session")
def heap_budget_check():
    """``check(method, camera, catalogue, db)``: hard scenes solve within the heap budget."""
    return _identify_within_heap_budget


@pytest.fixture(scope="session")
def streaked():
    """``streaked(vectors, rng, half_rad, every=1, keep_first=0)``: stars seen as partial
    tracks (``(vectors, streaks)``)."""
    return _streaked


@pytest.fixture(scope="session")
def hard_scene_tools():
    """``(HEAP_BUDGET, hard_scenes, live_peak, pipeline_tolerance_rad)`` for the tracking
    tests."""
    return HEAP_BUDGET, hard_scenes, live_peak, pipeline_tolerance_rad
