"""Firmware runs under MicroPython that the tests share: source literals of CPython values,
and the star identification of recorded scenes, checked against the CPython solutions."""

import base64
import math

from lodestar.firmware import starid
from lodestar.sim.attitude import random_attitude
from lodestar.sim.centroids import centroid_scene


def lit(value):
    """Python source for ``value`` (None, bool, int, float, str, bytes, tuple, list, dict)."""
    if isinstance(value, float):
        if math.isnan(value):
            return "float('nan')"
        if math.isinf(value):
            return "float('inf')" if value > 0 else "-float('inf')"
        return repr(value)
    if value is None or isinstance(value, (bool, int, str, bytes)):
        return repr(value)
    if isinstance(value, tuple):
        return "(" + "".join(lit(v) + ", " for v in value) + ")"
    if isinstance(value, list):
        return "[" + ", ".join(lit(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(lit(k) + ": " + lit(v) for k, v in value.items()) + "}"
    raise TypeError("no literal for {!r}".format(value))


_HEADER = r'''
import binascii
import gc
import sys
from lodestar.firmware import database, starid, status
print("IMPLEMENTATION", sys.implementation.name, sys.implementation.version)
'''

_SOLVE = r'''
with open("/db.bin", "wb") as f:
    f.write(binascii.a2b_base64(IMAGE_B64))
IMAGE_B64 = None
#@split
gc.collect()
base = gc.mem_alloc()
db, code, reason = database.load("/db.bin")
assert code == status.OK, reason
#@split
gc.collect()
print("DBMEM", gc.mem_alloc() - base)
for scene, expected in zip(SCENES, EXPECTED):
    sol = starid.identify(scene, db, method=METHOD, tolerance_rad=TOL, budget=BUDGET)
    got = (sol.status, sol.matches, sol.patterns_tried)
    assert got == expected[:3], (got, expected)
    if sol.q is not None:
        d = max(abs(a - b) for a, b in zip(sol.q, expected[3]))
        assert d < 1e-9, d
print("SOLVED", len(SCENES))
db.close()
'''


def solved_scenes(camera, catalogue, db, method, rng, n, false_every, tol, budget):
    """``(scenes, expected)``: ``n`` centroid scenes (0.3 px noise, ``k % false_every``
    false stars, 10 % dropped, 20 stars kept; the last one mirrored) as vector lists, and
    their CPython solutions ``(status, matches, patterns_tried, q)``."""
    scenes, expected = [], []
    for k in range(n):
        scene = centroid_scene(camera, random_attitude(rng), rng, catalogue, noise_px=0.3,
                               n_false=k % false_every, drop_fraction=0.1, max_stars=20)
        vectors = [tuple(v) for v in scene.vectors.tolist()]
        if k == n - 1:
            vectors = [(-x, y, z) for x, y, z in vectors]          # a mirror image
        sol = starid.identify(vectors, db, method=method, tolerance_rad=tol, budget=budget)
        scenes.append(vectors)
        expected.append((sol.status, sol.matches, sol.patterns_tried, sol.q))
    return scenes, expected


def identify_under_micropython(micropython, image, method, scenes, expected, tol, budget,
                               checks="", epilogue="", data=None):
    """Run ``checks``, then the identification of ``scenes`` from the database ``image``
    (written to ``/db.bin``) with ``method``, then ``epilogue`` under MicroPython; each
    solution must equal ``expected``.  ``data``: more ``{name: value}`` for the script.
    Returns ``(exit status, output)``."""
    values = {"TOL": tol, "BUDGET": budget, "METHOD": method, "SCENES": scenes,
              "EXPECTED": expected, "IMAGE_B64": base64.b64encode(image)}
    values.update(data or {})
    script = "\n".join(name + " = " + lit(value) for name, value in values.items())
    return micropython(script + _HEADER + checks + _SOLVE + epilogue + 'print("DONE")\n',
                       heapsize=16 << 20, timeout=600)
