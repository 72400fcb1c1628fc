"""The ground star-database cache: keys, folders, and files that are not what their name
says."""

import math

from lodestar.ground import cache
from lodestar.ground.database import build_database


def test_cache_key_and_default_directory(monkeypatch, tmp_path):
    k = cache.cache_key(20.2, 15.2, 6.0, "pyramid")
    assert k == cache.cache_key(20.20001, 15.2, 6.0, "pyramid")
    assert k != cache.cache_key(20.3, 15.2, 6.0, "pyramid")
    assert k != cache.cache_key(20.2, 15.2, 6.5, "pyramid")
    assert k != cache.cache_key(20.2, 15.2, 6.0, "triangle")
    monkeypatch.setenv("LODESTAR_CACHE_DIR", str(tmp_path / "x"))
    assert cache.default_cache_dir() == tmp_path / "x"
    monkeypatch.delenv("LODESTAR_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache.default_cache_dir() == tmp_path / "xdg" / "lodestar"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache.default_cache_dir() == tmp_path / "home" / ".cache" / "lodestar"


def test_a_file_of_another_field_under_the_key_is_rebuilt(tmp_path, monkeypatch):
    """Issue 19, item 8: a database of another FOV (or depth) in the cache under this key's
    name is rebuilt and replaced, not reported as a mismatch forever."""
    monkeypatch.setattr(cache, "_MEMORY", {})
    db, path = cache.load_database(20.0, 15.0, 4.5, cache_dir=tmp_path)
    assert path is not None and path.is_file()
    path.write_bytes(build_database(fov_h_deg=12.0, fov_v_deg=9.0, mag_limit=4.5))
    monkeypatch.setattr(cache, "_MEMORY", {})
    db, again = cache.load_database(20.0, 15.0, 4.5, cache_dir=tmp_path)
    assert again == path
    assert math.isclose(db.fov_h, math.radians(20.0), rel_tol=1e-6)
    monkeypatch.setattr(cache, "_MEMORY", {})
    db, _ = cache.load_database(20.0, 15.0, 4.5, cache_dir=tmp_path)
    assert math.isclose(db.fov_h, math.radians(20.0), rel_tol=1e-6)   # the file was replaced
    assert not list(tmp_path.glob("*.tmp"))


def test_density_databases_have_their_own_key(tmp_path, monkeypatch):
    """The density selection is part of the key; a cached file of another selection under
    the key's name is rebuilt; ``max_mag`` None (the whole catalogue) has a key too."""
    dense = {"verification_stars_per_fov": 20, "pattern_stars_per_fov": 6}
    plain = cache.cache_key(20.0, 15.0, 6.0, "pyramid")
    keyed = cache.cache_key(20.0, 15.0, 6.0, "pyramid", dense)
    assert keyed != plain
    assert keyed != cache.cache_key(20.0, 15.0, 6.0, "pyramid",
                                           dict(dense, pattern_stars_per_fov=7))
    assert cache.cache_key(20.0, 15.0, None, "pyramid", dense) != keyed
    monkeypatch.setattr(cache, "_MEMORY", {})
    db, path = cache.load_database(20.0, 15.0, 6.0, cache_dir=tmp_path, density=dense)
    assert db.pattern_per_region == 6 and db.n_stars < 5041
    path.write_bytes(build_database(fov_h_deg=20.0, fov_v_deg=15.0, mag_limit=6.0))
    monkeypatch.setattr(cache, "_MEMORY", {})
    again, _ = cache.load_database(20.0, 15.0, 6.0, cache_dir=tmp_path, density=dense)
    assert again.pattern_per_region == 6 and again.n_stars == db.n_stars
