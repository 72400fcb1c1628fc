"""cedar-solve's side of ``benchmarks/bench_peers.py``, run by the Python of a separate
environment that holds cedar-solve 0.5.1 at its own pins (numpy < 2, Pillow < 9: lodestar
cannot share them, and its code uses ``np.math``, which numpy 2 removed).  Imports numpy and
cedar-solve's ``tetra3`` only.

    CEDAR_PYTHON peers_cedar_worker.py SCENES.npz CATALOGUE.dat DATABASE.npz FOV_DEG

``SCENES.npz``: ``rows`` (all centroids, ``(x, y, flux)``, pixel centres at integers,
brightest first per scene), ``starts`` (each scene's first row, and the total), ``probes``
(``(n, 2, 2)`` pixels to return directions for), ``size`` (width, height).  The database is
generated at cedar's defaults for ``FOV_DEG`` from ``CATALOGUE.dat`` (``hip_main.dat``
columns, no proper motion) unless ``DATABASE.npz`` exists.  Prints one JSON object:
``{"min_fov", "max_fov", "results": [{"ms", "ra", "dec"} ...]}`` (ra/dec of the probes in
degrees, None when not solved; ms = the solve call's wall time).
"""

import json
import logging
import sys
import time
from pathlib import Path

import numpy as np
import tetra3


def main(scenes_path, catalogue_path, database_path, fov_deg):
    logging.getLogger("tetra3.Tetra3").setLevel(logging.WARNING)
    fov = float(fov_deg)
    database = Path(database_path)
    t3 = tetra3.Tetra3(load_database=None)
    if not database.exists():
        t3.generate_database(max_fov=fov, star_catalog=catalogue_path,
                             epoch_proper_motion=None, save_as=database)
    t3.load_database(database)        # (a generated database lacks num_patterns until read)
    data = np.load(scenes_path)
    width, height = (int(v) for v in data["size"])
    starts = data["starts"]
    results = []
    for i in range(len(starts) - 1):
        rows = data["rows"][starts[i]:starts[i + 1]]
        # cedar: (y, x) from the top-left corner of the image, pixel centres at +0.5
        yx = rows[:, [1, 0]] + 0.5
        target = data["probes"][i][:, [1, 0]] + 0.5
        t0 = time.perf_counter()
        res = t3.solve_from_centroids(yx, (height, width), fov_estimate=fov,
                                      target_pixel=target)
        ms = (time.perf_counter() - t0) * 1e3
        solved = res.get("RA") is not None
        results.append({"ms": ms,
                        "ra": [float(v) for v in res["RA_target"]] if solved else None,
                        "dec": [float(v) for v in res["Dec_target"]] if solved else None})
    props = t3.database_properties
    print(json.dumps({"min_fov": float(props["min_fov"]), "max_fov": float(props["max_fov"]),
                      "results": results}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main(*sys.argv[1:]))
