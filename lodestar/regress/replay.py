"""Load a regression set (manifest, packets, database recipes), replay it through the flight
API on CPython and on the float32 MicroPython build and compare with the recorded outputs of
each (double and float32) and with the MicroPython replay.  The set and its tolerances:
``docs/regression.md``."""

import hashlib
import json
import math
import os
import tempfile
from importlib import resources
from pathlib import Path

from lodestar.firmware.starid import METHODS
from lodestar.ground import cache, solve
from lodestar.ground.database import build_database
from lodestar.ground.files import write_atomic
from lodestar.ground.onboard import DEFAULT_MAX_MAG, FLIGHT_DENSITY
from lodestar.regress import mcu, qemu
from lodestar.regress import micropython as _micropython

SET_FORMAT = 2
"""Version of the manifest layout (2: the float32 build's expectations, ``float32`` and each
case's ``expected_float32``)."""
DEFAULT_SET = Path(str(resources.files("lodestar.regress") / "data" / "regression"))

TOLERANCES = {"q_rad": 1e-9, "sigma_relative": 1e-7}
"""Recorded into a set and used from there.  ``q_rad``: largest rotation between two
attitudes that count as equal (1e-9 rad = 0.2 milliarcsec); ``sigma_relative``: of the
1-sigma figures and the centroid noise.  CPython and MicroPython give bit-identical results
on the development machine; the margin is for other platforms' ``libm`` (last-bit
differences of ``sin``, ``atan2``...), while a real change of the firmware moves these
figures by orders of magnitude more."""

FLOAT32_TOLERANCES = dict(TOLERANCES)
"""The float32 build against its own recorded outcomes (recorded into a set as
``float32.tolerances``): the double set's, which is bit for bit in effect (1e-9 rad is below
one float32 step of a unit quaternion, 6e-8).  Measured: the same build reproduces every
outcome bit for bit in any order and at any heap, and (in object representation A, which
can be built 64-bit) the 32-bit and the 64-bit x86 builds (SSE arithmetic,
:data:`lodestar.regress.unixport.SSE_COPT`) agreed bit for bit.  A float32
attitude is not stable against last-bit changes (an x87 build moves one by 0.67 arcsec), so
another arithmetic (compiler, ``libm``, FPU) needs its own recording."""

FLOAT32_BOUND = {"q_rad": math.radians(1.0 / 3600.0), "sigma_relative": 1e-2}
"""The float32 outcomes against the double ones (recorded into a set as ``float32.bound``;
:data:`IDENTIFICATION_FIELDS` exactly): 1 arcsec of attitude and 1 % of the 1-sigma figures
and the centroid noise.  Measured on the flight build (object representation C, 22-bit float
significands, :data:`lodestar.regress.unixport.FLIGHT_REPR`) with the fits refined by
``attitude.refine``: attitudes at most 0.25 arcsec from double (estcube2_rest_s4, triangle),
sigmas at most 0.45 %.  Before that refinement QUEST's ``eps / gap`` gave 5.17 arcsec and 1.39 %
(estcube2_rest_s3), and 0.61 arcsec in representation A (24 bits)."""


class RegressionError(Exception):
    """The set cannot be replayed as recorded (missing or altered files, a database recipe
    that no longer gives the recorded image)."""


def sha256(data):
    """The SHA-256 hex digest of bytes."""
    return hashlib.sha256(data).hexdigest()


# --------------------------------------------------------------------------------------
# Databases
# --------------------------------------------------------------------------------------

def database_recipe(fw_camera):
    """The ``build_database`` arguments of the set's database for a firmware camera: the
    flight selection (:data:`lodestar.ground.onboard.FLIGHT_DENSITY`) serving every method."""

    fov_h, fov_v = solve.camera_fov_deg(fw_camera)
    return dict({"fov_h_deg": round(fov_h, 4), "fov_v_deg": round(fov_v, 4),
                 "mag_limit": DEFAULT_MAX_MAG, "methods": list(METHODS)}, **FLIGHT_DENSITY)


def build_image(recipe):
    """The database image (bytes) of a recipe (a set recorded before the flight selection
    has none: every star to the magnitude limit)."""

    density = {k: recipe[k] for k in FLIGHT_DENSITY if k in recipe}
    return build_database(fov_h_deg=recipe["fov_h_deg"], fov_v_deg=recipe["fov_v_deg"],
                          mag_limit=recipe["mag_limit"], methods=tuple(recipe["methods"]),
                          **density)


def _cache_dir(cache_dir):

    return Path(cache_dir) if cache_dir is not None else cache.default_cache_dir()


def _cache_path(directory, digest):
    return directory / f"lodestar-regress-{digest[:16]}.lsdb"


def cache_image(image, cache_dir=None):
    """Keep a database image in the cache (``cache_dir``, default
    :func:`lodestar.ground.cache.default_cache_dir`), written atomically; returns its path (a
    temporary file when the cache is not writable)."""

    directory = _cache_dir(cache_dir)
    target = _cache_path(directory, sha256(image))
    try:
        write_atomic(target, image, folders=True)
        return target
    except OSError:
        fd, tmp = tempfile.mkstemp(prefix="lodestar-regress-", suffix=".lsdb")
        with os.fdopen(fd, "wb") as f:
            f.write(image)
        return Path(tmp)


def database_files(manifest, cache_dir=None):
    """``{name: path}`` of the set's database images: from the cache when the file there has
    the recorded SHA-256, else rebuilt from the recipe and cached (:func:`cache_image`).
    Raises :class:`RegressionError` when a rebuilt image differs from the recorded one."""
    directory = _cache_dir(cache_dir)
    out = {}
    for name, entry in manifest["databases"].items():
        target = _cache_path(directory, entry["sha256"])
        try:
            if sha256(target.read_bytes()) == entry["sha256"]:
                out[name] = target
                continue
        except OSError:
            pass
        image = build_image(entry["recipe"])
        if sha256(image) != entry["sha256"]:
            raise RegressionError(
                f"database {name}: the recipe {entry['recipe']} now builds an image of "
                f"{len(image)} B with SHA-256 {sha256(image)[:16]}..., the set recorded "
                f"{entry['bytes']} B with {entry['sha256'][:16]}... (the catalogue or the "
                "builder changed): check the change, then re-record with `lodestar regress "
                "--record`")
        out[name] = cache_image(image, cache_dir)
    return out


# --------------------------------------------------------------------------------------
# The set on disk
# --------------------------------------------------------------------------------------

def load_set(set_dir):
    """The manifest of the set in ``set_dir``, its packet files checked against their
    SHA-256 (raises :class:`RegressionError`)."""
    set_dir = Path(set_dir)
    path = set_dir / "manifest.json"
    try:
        manifest = json.loads(path.read_text())
    except OSError as exc:
        raise RegressionError(f"no regression set in {set_dir}: {exc}") from None
    except ValueError as exc:
        raise RegressionError(f"{path}: not JSON: {exc}") from None
    if manifest.get("format") != SET_FORMAT:
        raise RegressionError(f"{path}: set format {manifest.get('format')!r}, this lodestar "
                              f"reads {SET_FORMAT}")
    for case in manifest["cases"]:
        try:
            data = (set_dir / case["packet"]).read_bytes()
        except OSError as exc:
            raise RegressionError(f"case {case['name']}: {exc}") from None
        if sha256(data) != case["packet_sha256"]:
            raise RegressionError(f"case {case['name']}: {case['packet']} is not the recorded "
                                  "packet (SHA-256 differs)")
    return manifest


def packets(manifest, set_dir):
    """``{case name: packet bytes}``."""
    return {case["name"]: (Path(set_dir) / case["packet"]).read_bytes()
            for case in manifest["cases"]}


# --------------------------------------------------------------------------------------
# Replay and comparison
# --------------------------------------------------------------------------------------

def replay_cpython(manifest, set_dir, db_files, methods=None):
    """``{(case, method): outcome}`` of every case on this interpreter."""
    methods = manifest["methods"] if methods is None else methods
    databases = {name: mcu.open_database(str(path))
                 for name, path in db_files.items()}
    trackers = {}
    for cam, settings in manifest["cameras"].items():
        for method in methods:
            trackers[cam, method] = mcu.make_tracker(
                databases[settings["database"]], settings, method)
    data = packets(manifest, set_dir)
    return {(case["name"], method): mcu.replay(trackers[case["camera"], method],
                                                          data[case["name"]], case["inputs"])
            for case in manifest["cases"] for method in methods}


def rotation_angle(q1, q2):
    """Angle (rad) of the rotation between two unit quaternions (sign-independent)."""
    dot = abs(sum(a * b for a, b in zip(q1, q2)))
    # |q1 x q2| part: the sine of half the angle, accurate for small angles
    w1, w2 = q1[3], q2[3]
    v = [w1 * q2[i] - w2 * q1[i] for i in range(3)]
    c = (q1[1] * q2[2] - q1[2] * q2[1], q1[2] * q2[0] - q1[0] * q2[2],
         q1[0] * q2[1] - q1[1] * q2[0])
    s = math.sqrt(sum((v[i] - c[i]) ** 2 for i in range(3)))
    return 2.0 * math.atan2(s, dot)


EXACT_FIELDS = ("status", "mode", "n_records", "n_stars", "matches", "patterns_tried",
                "min_sum")
SIGMA_FIELDS = ("sigma_cross_arcsec", "sigma_roll_arcsec", "centroid_sigma_px", "t_epoch_s")
"""Fields compared within ``sigma_relative``: the 1-sigma figures and the instant the attitude
holds for (``t_epoch_s``, a weighted mean of the stars' instants without a gyro)."""
IDENTIFICATION_FIELDS = ("status", "mode", "matches", "min_sum")
"""The fields a float32 outcome shares exactly with the double one (:func:`float32_vs_double`):
the status, the identified stars and the next frame's record budget (integers)."""


def differences(a, b, tolerances, exact=EXACT_FIELDS):
    """What differs between two outcomes beyond ``tolerances`` (list of texts; empty when
    they agree): the ``exact`` fields exactly, the attitude and the sigma fields within
    ``tolerances`` (``docs/regression.md``, Comparison)."""
    out = []
    for name in exact:
        if a[name] != b[name]:
            if name == "matches":
                x, y = a[name], b[name]
                i = next((k for k in range(min(len(x), len(y))) if x[k] != y[k]),
                         min(len(x), len(y)))
                out.append(f"matches: {len(x)} vs {len(y)}, from #{i} "
                           f"{x[i] if i < len(x) else None} vs {y[i] if i < len(y) else None}")
            else:
                out.append(f"{name} {a[name]!r} vs {b[name]!r}")
    if (a["q"] is None) != (b["q"] is None):
        out.append(f"q {a['q']!r} vs {b['q']!r}")
    elif a["q"] is not None:
        angle = rotation_angle(a["q"], b["q"])
        if not angle <= tolerances["q_rad"]:
            out.append(f"attitude differs by {angle:.3g} rad (tolerance "
                       f"{tolerances['q_rad']:g})")
    for name in SIGMA_FIELDS:
        x, y = a.get(name), b.get(name)
        if (x is None) != (y is None):
            out.append(f"{name} {x!r} vs {y!r}")
        elif x is not None and not abs(x - y) <= tolerances["sigma_relative"] * max(abs(x),
                                                                                   abs(y)):
            out.append(f"{name} {x!r} vs {y!r}")
    return out


def float32_vs_double(f32, double, bound):
    """What differs between a float32 outcome and the double one beyond ``bound`` (list of
    texts): :data:`IDENTIFICATION_FIELDS` exactly, the attitude and the sigma fields within
    the bound (:data:`FLOAT32_BOUND`)."""
    return differences(f32, double, bound, exact=IDENTIFICATION_FIELDS)


def compare(manifest, cpython, micropython=None, float32=None):
    """One row per case and method: ``case``, ``method``, ``expected``, ``cpython``,
    ``micropython`` (outcomes; the last None when not run), ``mp`` (the MicroPython
    measurements, or None), ``expected_float32``, ``float32`` (the float32 build's outcome,
    :func:`lodestar.regress.unixport.float32_outcomes`; None when not run) and ``problems``
    (texts; empty when everything agrees).  With several MicroPython repeats the first is
    compared."""
    tol = manifest["tolerances"]
    f32_tol, f32_bound = manifest["float32"]["tolerances"], manifest["float32"]["bound"]
    mp = {}
    if micropython is not None:
        for r in micropython["results"]:
            mp.setdefault((r["case"], r["method"]), r)
    rows = []
    for case in manifest["cases"]:
        for method in manifest["methods"]:
            key = (case["name"], method)
            expected = case["expected"][method]
            got = cpython.get(key)
            problems = []
            if got is None:
                problems.append("CPython: not replayed")
            else:
                problems += ["CPython vs expected: " + d
                             for d in differences(expected, got, tol)]
            m = mp.get(key)
            if micropython is not None:
                if m is None:
                    problems.append("MicroPython: not replayed")
                else:
                    problems += ["MicroPython vs expected: " + d
                                 for d in differences(expected, m["out"], tol)]
                    if got is not None:
                        problems += ["MicroPython vs CPython: " + d
                                     for d in differences(got, m["out"], tol)]
            expected_f32 = case["expected_float32"][method]
            f32 = None if float32 is None else float32.get(key)
            if float32 is not None:
                if f32 is None:
                    problems.append("float32: not replayed")
                else:
                    problems += ["float32 vs expected_float32: " + d
                                 for d in differences(expected_f32, f32, f32_tol)]
                    problems += ["float32 vs expected (double): " + d
                                 for d in float32_vs_double(f32, expected, f32_bound)]
            rows.append({"case": case["name"], "method": method, "expected": expected,
                         "cpython": got, "micropython": None if m is None else m["out"],
                         "mp": m, "expected_float32": expected_f32, "float32": f32,
                         "problems": problems})
    return rows


def _angle_text(a, b):
    if a is None or b is None or a["q"] is None or b["q"] is None:
        return "-"
    return f"{rotation_angle(a['q'], b['q']) * 180 / math.pi * 3600e3:.3f}"


def format_table(rows, micropython, float32=False):
    """The comparison as text: one line per row, then every difference.  Columns: case,
    method, the expected status and number of matched stars (``ids``), per interpreter
    ``same`` or ``DIFF`` and ``dq``, the angle between its attitude and the expected one in
    milliarcseconds; with ``float32`` (the build was replayed) ``f32-dbl``, the angle between
    the float32 expectation and the double one (mas); with ``micropython`` ``mp-cp``
    (MicroPython against CPython, mas), the MicroPython solve time (ms) and allocation (KB,
    :mod:`lodestar.regress.micropython`)."""
    head = (f"{'case':<28} {'method':<8} {'expected':<17} {'ids':>3} {'CPython':<8} "
            f"{'dq mas':>7}")
    if float32:
        head += f" {'float32':<8} {'dq mas':>7} {'f32-dbl':>7}"
    if micropython is not None:
        head += f" {'MicroPy':<8} {'dq mas':>7} {'mp-cp':>7} {'ms':>6} {'alloc KB':>8}"
    lines = [head, "-" * len(head)]
    for r in rows:
        e, c, m = r["expected"], r["cpython"], r["micropython"]
        line = (f"{r['case']:<28} {r['method']:<8} {e['status_name']:<17} "
                f"{len(e['matches']):>3} {_verdict(c, r, 'CPython'):<8} "
                f"{_angle_text(e, c):>7}")
        if float32:
            ef, f = r["expected_float32"], r["float32"]
            line += (f" {_verdict(f, r, 'float32'):<8} {_angle_text(ef, f):>7} "
                     f"{_angle_text(e, ef):>7}")
        if micropython is not None:
            meas = r["mp"]
            line += (f" {_verdict(m, r, 'MicroPython'):<8} {_angle_text(e, m):>7} "
                     f"{_angle_text(c, m):>7} "
                     f"{'-' if meas is None else format(meas['ms'], '.1f'):>6} "
                     f"{'-' if meas is None else format(meas['alloc'] / 1024, '.0f'):>8}")
        lines.append(line)
    bad = [r for r in rows if r["problems"]]
    lines.append("")
    if bad:
        lines.append(f"{len(bad)} of {len(rows)} replays differ:")
        for r in bad:
            for p in r["problems"]:
                lines.append(f"  {r['case']} / {r['method']}: {p}")
    else:
        names = ["CPython"] + (["the Cortex-M4F build"] if float32 else []) + \
            (["MicroPython"] if micropython is not None else [])
        names = ", ".join(names[:-1]) + " and " + names[-1] if len(names) > 1 else names[0]
        lines.append(f"all {len(rows)} replays agree with the recorded outputs on {names}")
    return "\n".join(lines)


def _verdict(got, row, interpreter):
    if got is None:
        return "-"
    return "DIFF" if any(p.startswith(interpreter) for p in row["problems"]) else "same"


def format_resident(micropython):
    """The MicroPython heap figures of a replay (:mod:`lodestar.regress.micropython`) as one
    line of text."""
    res = micropython["resident"]
    results = micropython["results"]
    live = [r["live_before"] for r in results] + [micropython["live_end"]]
    alloc = max(r["alloc"] for r in results) if results else 0
    return (f"MicroPython heap: {res['code'] / 1024:.0f} KB after the imports, "
            f"{res['databases'] / 1024:.0f} KB with the databases open, "
            f"{res['trackers'] / 1024:.0f} KB with the trackers; live between solves at most "
            f"{max(live) / 1024:.0f} KB; one solve allocates at most {alloc / 1024:.0f} KB "
            "(every boxed float counted; an upper bound of its peak)")


# --------------------------------------------------------------------------------------
# The command
# --------------------------------------------------------------------------------------

def regress(set_dir=DEFAULT_SET, micropython=True, cache_dir=None, float32=True):
    """Replay the set: ``(rows, micropython result or None)`` (:func:`compare`,
    :func:`lodestar.regress.micropython.replay`); ``float32``: also on the flight MCU's
    build, the Cortex-M4F image under QEMU (:func:`lodestar.regress.qemu.expectation_build`,
    built into ``cache_dir``, the database cache), in one QEMU run.  Raises
    :class:`RegressionError` for an unusable set,
    :class:`lodestar.regress.qemu.Unavailable` when that build cannot be made here and
    ``_micropython.MicroPythonError`` when MicroPython is asked for and unavailable or
    fails (the Cortex-M4F build or replay included)."""
    manifest = load_set(set_dir)
    if float32:
        reason = qemu.unavailable_reason()
        if reason is not None:
            raise qemu.Unavailable(f"the Cortex-M4F build is unavailable: {reason} (or run "
                                   "with --no-float32)")
    if micropython:
        reason = _micropython.unavailable_reason()
        if reason is not None:
            raise _micropython.MicroPythonError(
                f"MicroPython unavailable: {reason} (or run with --no-micropython)")
    db_files = database_files(manifest, cache_dir)
    cpython = replay_cpython(manifest, set_dir, db_files)
    f32 = None
    if float32:
        elf = qemu.expectation_build(manifest, set_dir, db_files, cache_dir)
        f32 = qemu.float32_outcomes(elf, manifest, db_files)
    mp = None
    if micropython:
        mp = _micropython.replay(manifest, set_dir, db_files, manifest["methods"])
    return compare(manifest, cpython, mp, f32), mp
