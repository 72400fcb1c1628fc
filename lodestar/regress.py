"""``lodestar regress``: the firmware regression.  Recorded FPGA packets are replayed through
the flight API on CPython and on MicroPython and diffed against the recorded outputs.

    lodestar regress [--set DIR] [--micropython | --no-micropython]
    lodestar regress --record [--set DIR]

The set (default ``tests/data/regression``, committed; made by
:mod:`lodestar.regress_record`) is a folder with ``manifest.json`` and ``packets/NAME.bin``,
the recorded FPGA packets (``lodestar.packet`` layout): golden detections of simulated
``estcube2`` full frames at several attitudes at rest and turning at 0.5-3 deg/s, one turning
with no gyro, one in tracking mode, one with false stars, hot pixels and cosmic rays, frames
that must fail cleanly (10 deg/s, a 1 ms exposure), ``lohmann`` frames, corrupted packets
(bit flip, truncation, trailing byte, bad magic, empty, a header or a record that breaks the
contract under a valid CRC), a valid packet of two records and a packet of the other camera.
Every packet is replayed with each identification method.

Manifest (JSON):

* ``tolerances``: the comparison's (:data:`TOLERANCES`); ``methods``: the identification
  methods every case is replayed with (:data:`METHODS`);
* ``databases``: per camera, the **recipe** of its star database instead of the image (the
  three methods' database of one camera is 0.8-0.9 MB): the
  :func:`lodestar.ground.database.build_database` arguments (``fov_h_deg``, ``fov_v_deg``
  through the camera model, rounded to 1e-4 deg as :func:`lodestar.solve.load_database`
  rounds them, ``mag_limit``, ``methods``), the image's ``sha256`` and ``bytes``.  The replay
  rebuilds the image (about 1 s), checks its SHA-256 and keeps it in the database cache
  (:func:`lodestar.solve.default_cache_dir`) as ``lodestar-regress-<sha16>.lsdb``;
* ``cameras``: per camera, the :mod:`lodestar.regress_replay` settings (firmware camera
  dict, exposure and line time in s, match tolerance in px, database name);
* ``cases``: ``name``, ``camera``, ``packet`` (path in the set), ``packet_sha256``,
  ``note``, ``expect`` (``"solve"``: every method solves it right; ``"fail"``: no method
  solves it; ``"any"``: whatever the firmware says, as long as a solution is right; or a
  status name every method must return), ``inputs`` (the
  :func:`lodestar.regress_replay.replay` inputs), ``truth`` (simulated frames: ``q``,
  ``ra_deg``, ``dec_deg``, ``roll_deg``, ``rate_deg_s``; else None), ``expected`` (per
  method, :func:`lodestar.regress_replay.outcome`) and ``error_arcsec`` (per method solved,
  the attitude error against the truth at recording, ``cross`` and ``roll``).

Recording (``--record``, :func:`lodestar.regress_record.record`) checks every solution
against the simulator's truth and each case's ``expect`` and writes nothing when one breaks
them: the expected outputs are right ones.  Recording twice gives the same files.

Comparison (each of: expected vs CPython, expected vs MicroPython, CPython vs MicroPython):
``status``, ``mode``, ``n_records``, ``n_stars``, ``matches`` (record index and HIP, in
order) and ``patterns_tried`` exactly; ``q`` to ``q_rad`` (the angle of the rotation between
the two attitudes); ``sigma_cross_arcsec``, ``sigma_roll_arcsec`` and ``centroid_sigma_px``
to ``sigma_relative``; ``reason`` (text for people) is not compared.  The table has one row
per case and method, then the MicroPython heap figures
(:mod:`lodestar.regress_micropython`).  Exit status: 0 when nothing differs; 1 when anything
does, the set is unusable (a missing or altered packet, a database recipe that no longer
gives the recorded image) or the MicroPython run fails; 2 for bad arguments (a ``--set``
folder without a set) or when MicroPython is not installed (``--no-micropython`` replays
on CPython only).
"""

import hashlib
import json
import math
import os
import sys
import tempfile
from pathlib import Path

from lodestar import regress_micropython, regress_replay
from lodestar.firmware.starid import METHODS
from lodestar.flightsolve import DEFAULT_MAX_MAG

SET_FORMAT = 1
"""Version of the manifest layout."""
DEFAULT_SET = Path(__file__).resolve().parents[1] / "tests" / "data" / "regression"

TOLERANCES = {"q_rad": 1e-9, "sigma_relative": 1e-7}
"""Recorded into a set and used from there.  ``q_rad``: largest rotation between two
attitudes that count as equal (1e-9 rad = 0.2 milliarcsec); ``sigma_relative``: of the
1-sigma figures and the centroid noise.  CPython and MicroPython give bit-identical results
on the development machine; the margin is for other platforms' ``libm`` (last-bit
differences of ``sin``, ``atan2``...), while a real change of the firmware moves these
figures by orders of magnitude more."""


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
    """The ``build_database`` arguments of the set's database for a firmware camera."""
    from lodestar import solve as ground_solve

    fov_h, fov_v = ground_solve.camera_fov_deg(fw_camera)
    return {"fov_h_deg": round(fov_h, 4), "fov_v_deg": round(fov_v, 4),
            "mag_limit": DEFAULT_MAX_MAG, "methods": list(METHODS)}


def build_image(recipe):
    """The database image (bytes) of a recipe."""
    from lodestar.ground.database import build_database

    return build_database(fov_h_deg=recipe["fov_h_deg"], fov_v_deg=recipe["fov_v_deg"],
                          mag_limit=recipe["mag_limit"], methods=tuple(recipe["methods"]))


def _cache_dir(cache_dir):
    from lodestar import solve as ground_solve

    return Path(cache_dir) if cache_dir is not None else ground_solve.default_cache_dir()


def _cache_path(directory, digest):
    return directory / f"lodestar-regress-{digest[:16]}.lsdb"


def cache_image(image, cache_dir=None):
    """Keep a database image in the cache (``cache_dir``, default
    :func:`lodestar.solve.default_cache_dir`), written atomically; returns its path (a
    temporary file when the cache is not writable)."""
    from lodestar.solve import write_atomic

    directory = _cache_dir(cache_dir)
    target = _cache_path(directory, sha256(image))
    try:
        write_atomic(target, image)
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
    databases = {name: regress_replay.open_database(str(path))
                 for name, path in db_files.items()}
    trackers = {}
    for cam, settings in manifest["cameras"].items():
        for method in methods:
            trackers[cam, method] = regress_replay.make_tracker(
                databases[settings["database"]], settings, method)
    data = packets(manifest, set_dir)
    return {(case["name"], method): regress_replay.replay(trackers[case["camera"], method],
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


EXACT_FIELDS = ("status", "mode", "n_records", "n_stars", "matches", "patterns_tried")
SIGMA_FIELDS = ("sigma_cross_arcsec", "sigma_roll_arcsec", "centroid_sigma_px")


def differences(a, b, tolerances):
    """What differs between two outcomes beyond ``tolerances`` (list of texts; empty when
    they agree).  The fields and rules are in the module docstring."""
    out = []
    for name in EXACT_FIELDS:
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
        x, y = a[name], b[name]
        if (x is None) != (y is None):
            out.append(f"{name} {x!r} vs {y!r}")
        elif x is not None and not abs(x - y) <= tolerances["sigma_relative"] * max(abs(x),
                                                                                   abs(y)):
            out.append(f"{name} {x!r} vs {y!r}")
    return out


def compare(manifest, cpython, micropython=None):
    """One row per case and method: ``case``, ``method``, ``expected``, ``cpython``,
    ``micropython`` (outcomes; the last None when not run), ``mp`` (the MicroPython
    measurements, or None) and ``problems`` (texts; empty when everything agrees).  With
    several MicroPython repeats the first is compared."""
    tol = manifest["tolerances"]
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
            rows.append({"case": case["name"], "method": method, "expected": expected,
                         "cpython": got, "micropython": None if m is None else m["out"],
                         "mp": m, "problems": problems})
    return rows


def _angle_text(a, b):
    if a is None or b is None or a["q"] is None or b["q"] is None:
        return "-"
    return f"{rotation_angle(a['q'], b['q']) * 180 / math.pi * 3600e3:.3f}"


def format_table(rows, micropython):
    """The comparison as text: one line per row, then every difference.  Columns: case,
    method, the expected status and number of matched stars (``ids``), per interpreter
    ``same`` or ``DIFF`` and ``dq``, the angle between its attitude and the expected one in
    milliarcseconds, then ``mp-cp`` (MicroPython against CPython, mas), the MicroPython solve
    time (ms) and allocation (KB, :mod:`lodestar.regress_micropython`)."""
    head = (f"{'case':<28} {'method':<8} {'expected':<17} {'ids':>3} {'CPython':<8} "
            f"{'dq mas':>7}")
    if micropython is not None:
        head += f" {'MicroPy':<8} {'dq mas':>7} {'mp-cp':>7} {'ms':>6} {'alloc KB':>8}"
    lines = [head, "-" * len(head)]
    for r in rows:
        e, c, m = r["expected"], r["cpython"], r["micropython"]
        line = (f"{r['case']:<28} {r['method']:<8} {e['status_name']:<17} "
                f"{len(e['matches']):>3} {_verdict(c, r, 'CPython'):<8} "
                f"{_angle_text(e, c):>7}")
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
        interpreters = "CPython and MicroPython" if micropython is not None else "CPython"
        lines.append(f"all {len(rows)} replays agree with the recorded outputs on "
                     f"{interpreters}")
    return "\n".join(lines)


def _verdict(got, row, interpreter):
    if got is None:
        return "-"
    return "DIFF" if any(p.startswith(interpreter) for p in row["problems"]) else "same"


def format_resident(micropython):
    """The MicroPython heap figures of a replay (:mod:`lodestar.regress_micropython`) as one
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

def regress(set_dir=DEFAULT_SET, micropython=True, cache_dir=None):
    """Replay the set: ``(rows, micropython result or None)`` (:func:`compare`,
    :func:`lodestar.regress_micropython.replay`).  Raises :class:`RegressionError` for an
    unusable set and ``regress_micropython.MicroPythonError`` when MicroPython is asked for
    and unavailable or fails."""
    manifest = load_set(set_dir)
    if micropython:
        reason = regress_micropython.unavailable_reason()
        if reason is not None:
            raise regress_micropython.MicroPythonError(
                f"MicroPython unavailable: {reason} (or run with --no-micropython)")
    db_files = database_files(manifest, cache_dir)
    cpython = replay_cpython(manifest, set_dir, db_files)
    mp = None
    if micropython:
        mp = regress_micropython.replay(manifest, set_dir, db_files, manifest["methods"])
    return compare(manifest, cpython, mp), mp


def add_parser(sub):
    """Register ``regress`` on an argparse subparsers object."""
    import argparse

    p = sub.add_parser("regress", help="replay the recorded FPGA packets on CPython and "
                                       "MicroPython and diff against the expected outputs",
                       description="Firmware regression: replay the recorded packets through "
                                   "the flight API on CPython and MicroPython and compare "
                                   "with the recorded outputs (exit status 1 on any "
                                   "difference).")
    p.add_argument("--set", dest="set_dir", default=str(DEFAULT_SET), metavar="DIR",
                   help="the regression set (default: tests/data/regression)")
    p.add_argument("--micropython", action=argparse.BooleanOptionalAction, default=True,
                   help="also replay on MicroPython (Node.js and `npm ci --prefix "
                        "tools/micropython`; default: yes)")
    p.add_argument("--record", action="store_true",
                   help="(re)generate the set in --set instead of replaying it")
    p.set_defaults(func=run)


def run(args):
    """The ``regress`` command: 0 when every replay agrees, 1 when any differs or the set is
    unusable, 2 for a folder with no set or a missing MicroPython."""
    if args.record:
        from lodestar import regress_record

        try:
            manifest = regress_record.record(args.set_dir, log=sys.stderr)
        except RegressionError as exc:
            print(f"lodestar regress: {exc}", file=sys.stderr)
            return 1
        print(f"recorded {len(manifest['cases'])} packets x {len(manifest['methods'])} "
              f"methods in {args.set_dir}")
        return 0
    if not (Path(args.set_dir) / "manifest.json").is_file():
        print(f"lodestar regress: error: no regression set in {args.set_dir} (no "
              "manifest.json; `lodestar regress --record --set DIR` makes one)",
              file=sys.stderr)
        return 2
    try:
        rows, mp = regress(args.set_dir, args.micropython)
    except RegressionError as exc:
        print(f"lodestar regress: {exc}", file=sys.stderr)
        return 1
    except regress_micropython.MicroPythonError as exc:
        print(f"lodestar regress: {exc}", file=sys.stderr)
        return 1 if regress_micropython.unavailable_reason() is None else 2
    print(format_table(rows, mp))
    if mp is not None:
        print(format_resident(mp))
    return 1 if any(r["problems"] for r in rows) else 0
