"""Run a campaign: trials in parallel (local processes or Dask), journaled so a stopped
campaign resumes, then its tables and plots.  Studies and outputs: ``docs/campaigns.md``."""

import ctypes
import ctypes.util
import json
import os
import signal
import sys
import threading
import time
from concurrent.futures import ProcessPoolExecutor, as_completed

from lodestar.ground import onboard, truth
from lodestar.ground.campaign import plots, tables, trials
from lodestar.ground.files import write_atomic
from lodestar.ground.onboard import camera_settings
from lodestar.sim import presets
from lodestar.sim.presets import PRESETS

JOURNAL = "journal.jsonl"
DEFAULT_TRIALS = {"rate": 500, "falsestars": 100, "limiting": 30, "accuracy": 300, "fov": 100}
"""Monte-Carlo size per level by default: 500 attitudes per rate resolve availability to
about +-1 % (95 %) near 95 %, and 0.2 % steps near 100 %."""
QUICK = {"trials": 2, "rates": (0.0, 1.0), "false_stars": (0, 5)}
"""``--quick``: a smoke-test campaign (seconds on lohmann)."""
MAX_RATE_DEG_S = 30.0
"""Largest rate accepted about a cross or random axis (a frame then smears over several
degrees)."""
MAX_ROLL_RATE_DEG_S = 360.0
"""Largest rate accepted about the boresight (``--axis roll``): the seed mission's E-sail
spin starts at 360 deg/s, and the stars near the boresight smear little at any rate."""


def levels(study, rates=None, false_stars=trials.FALSE_STARS):
    """The swept levels of ``study`` as task text."""
    if study == "rate":
        return [f"{r:g}" for r in (trials.RATES_DEG_S if rates is None else rates)]
    if study == "limiting":
        return [f"{r:g}" for r in (trials.LIMITING_RATES_DEG_S if rates is None else rates)]
    if study == "falsestars":
        return [f"false={n}" for n in false_stars] + ["noise"]
    if study == "accuracy":
        return ["rest"]
    if study == "fov":
        return [f"{f:g}" for f in trials.FOVS_DEG]
    raise ValueError(f"unknown study {study!r} (known: {', '.join(trials.STUDIES)})")


def make_config(study, presets, seed=0, rates=None, axis="cross", method="pyramid",
                settings="tuned", quick=False, gyro=True):
    """The campaign settings (the journal's header; JSON-ready); ``gyro`` False: the rate
    study's frames are solved without the rate (the firmware fits it).  Raises
    ``ValueError``."""

    if study not in trials.STUDIES:
        raise ValueError(f"unknown study {study!r} (known: {', '.join(trials.STUDIES)})")
    if not presets or any(p not in PRESETS for p in presets) or len(set(presets)) < len(presets):
        raise ValueError(f"presets must be distinct names of {', '.join(PRESETS)}, "
                         f"got {presets!r}")
    if rates is not None:
        if study not in ("rate", "limiting"):
            raise ValueError(f"--rates applies to the rate and limiting studies, not {study}")
        most = MAX_ROLL_RATE_DEG_S if axis == "roll" else MAX_RATE_DEG_S
        if not rates or any(not 0 <= r <= most for r in rates) or \
                len(set(rates)) < len(rates):
            raise ValueError(f"--rates must be distinct numbers in 0..{most:g} "
                             f"deg/s, got {rates!r}")
    if axis not in trials.AXES:
        raise ValueError(f"unknown rate axis {axis!r} (known: {', '.join(trials.AXES)})")
    if method not in trials.METHODS:
        raise ValueError(f"unknown method {method!r} (known: {', '.join(trials.METHODS)})")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise ValueError(f"--seed must be a non-negative integer, got {seed!r}")
    if not gyro and study != "rate":
        raise ValueError(f"--no-gyro applies to the rate study, not {study}")
    if quick and rates is None:
        rates = QUICK["rates"]
    return {"study": study, "seed": seed, "presets": list(presets), "gyro": bool(gyro),
            "levels": levels(study, rates, QUICK["false_stars"] if quick else trials.FALSE_STARS),
            "axis": axis, "method": method, "settings": settings,
            "camera": {p: camera_settings(p, settings) for p in presets}}


def make_tasks(config, n_trials):
    """The task list ``(study, preset, level, trial)`` in table order."""
    if isinstance(n_trials, bool) or not isinstance(n_trials, int) or n_trials < 1:
        raise ValueError(f"--trials must be a positive integer, got {n_trials!r}")
    return [(config["study"], preset, level, trial) for preset in config["presets"]
            for level in config["levels"] for trial in range(n_trials)]


# ---- journal ---------------------------------------------------------------------------

def _journal_entry(line, first):
    """The header (``first``) or ``(key, result)`` of a journal line, or None when the line
    is not one."""
    try:
        entry = json.loads(line)
    except ValueError:
        return None
    if not isinstance(entry, dict):
        return None
    if first:
        return entry.get("campaign") if isinstance(entry.get("campaign"), dict) else None
    if set(entry) != {"key", "result"} or not isinstance(entry["key"], str):
        return None
    return entry["key"], entry["result"]


def read_journal(path):
    """``(header, {key: result}, good)`` of a journal: ``good`` is its valid part (bytes).
    A last line that is not a result (a write a kill cut short, or junk) is left out of
    ``good``; a bad line before the last raises ``ValueError`` (the journal is damaged)."""
    with open(path, "rb") as fh:
        data = fh.read()
    lines = data.split(b"\n")
    header, results, good = None, {}, 0
    numbered = [(i, line) for i, line in enumerate(lines) if line.strip()]
    for n, (i, line) in enumerate(numbered):
        entry = _journal_entry(line.decode("utf-8", "replace"), first=n == 0)
        if entry is None:
            if n == 0:
                raise ValueError(f"{path}: the first line is not a campaign header (delete "
                                 "the journal to start again)")
            if n == len(numbered) - 1:
                break
            raise ValueError(f"{path}: line {i + 1} is not a result; the journal is damaged "
                             "(delete it to start again)")
        if n == 0:
            header = entry
        else:
            results[entry[0]] = entry[1]
        good = len(b"\n".join(lines[:i + 1])) + 1
    if header is None:
        raise ValueError(f"{path}: empty journal (delete it to start again)")
    return header, results, data[:good]


def open_journal(out_dir, config, resume):
    """``(file, {key: result})``: the journal opened for appending, with the results it
    already holds.  Without ``resume`` an existing journal is an error (nothing is
    overwritten); with it, its settings must equal ``config``."""
    path = os.path.join(out_dir, JOURNAL)
    done = {}
    if os.path.exists(path):
        if not resume:
            raise ValueError(f"{path} exists: pass --resume to continue that campaign, or "
                             "choose another --out")
        header, done, good = read_journal(path)
        if header != config:
            changed = sorted(k for k in set(header) | set(config)
                             if header.get(k) != config.get(k))
            raise ValueError(f"{path} belongs to a campaign with other settings "
                             f"({', '.join(changed)} differ); use the same options or "
                             "another --out")
        if os.path.getsize(path) != len(good):   # repair: keep only the valid records
            write_atomic(path, good)
        return open(path, "a"), done
    os.makedirs(out_dir, exist_ok=True)
    fh = open(path, "w")
    fh.write(json.dumps({"campaign": config}) + "\n")
    fh.flush()
    return fh, done


# ---- execution -------------------------------------------------------------------------

def _die_with_parent(parent):
    """Worker initializer: end this worker when the campaign process ``parent`` ends, however
    it ends (``kill -9`` included).  Linux delivers SIGKILL at the parent's death
    (``PR_SET_PDEATHSIG``); elsewhere, and for a parent that died before the request, a
    daemon thread polls the parent id once a second."""
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    except (OSError, AttributeError):
        pass

    def watch():
        while os.getppid() == parent:
            time.sleep(1.0)
        os._exit(1)

    if os.getppid() != parent:
        os._exit(1)
    threading.Thread(target=watch, daemon=True).start()


_PR_SET_PDEATHSIG = 1


def _run_local(tasks, config, workers, sink):
    if workers == 1:
        for task in tasks:
            sink(*trials.run_task(task, config))
        return

    pool = ProcessPoolExecutor(max_workers=workers, initializer=_die_with_parent,
                               initargs=(os.getpid(),))
    try:
        futures = [pool.submit(trials.run_task, task, config) for task in tasks]
        for future in as_completed(futures):
            sink(*future.result())
    except BaseException:
        _kill_workers(pool)     # else the exit waits for the running trials to finish
        pool.shutdown(wait=False, cancel_futures=True)
        raise
    pool.shutdown()


def _kill_workers(pool):
    """Kill the pool's worker processes (before ``shutdown``, which forgets them)."""
    kill = getattr(pool, "kill_workers", None)      # Python 3.14
    if kill is not None:
        kill()
        return
    for proc in list((getattr(pool, "_processes", None) or {}).values()):
        proc.kill()


class ClusterError(ValueError):
    """The Dask cluster failed the campaign (scheduler gone, a trial's workers died): the
    message says what happened; :func:`run_campaign` adds where the finished tasks are."""


def _run_dask(tasks, config, address, sink):
    """Run ``tasks`` on the Dask scheduler at ``address``, calling ``sink`` as each result
    arrives.  A worker lost mid-trial is the scheduler's business (it runs the trial again
    elsewhere, up to ``distributed.scheduler.allowed-failures`` times); a scheduler lost,
    or a trial whose workers kept dying, raises :class:`ClusterError`."""
    try:
        from dask.distributed import CancelledError, Client, KilledWorker, as_completed
    except ImportError:
        raise ValueError("--dask needs dask.distributed, the optional extra: pip install "
                         "'lodestar[dask]'") from None
    try:
        client = Client(address, timeout="20s")
    except OSError as exc:
        raise ValueError(f"--dask: cannot reach the scheduler at {address}: {exc}") from None
    lost = failed = False
    try:
        if not client.scheduler_info().get("workers"):
            print(f"lodestar campaign: the scheduler at {address} has no workers yet; "
                  "waiting for some (dask worker ADDRESS)", file=sys.stderr)
        futures = client.map(trials.run_task, tasks, config=config, pure=False)
        names = {future.key: trials.task_key(task) for future, task in zip(futures, tasks)}
        for future in as_completed(futures):
            try:
                sink(*future.result())
            except CancelledError as exc:
                reason = getattr(exc, "reason", "unknown")     # distributed >= 2024.6
                lost = reason == "scheduler-connection-lost" or client.status == "connecting"
                if lost:
                    raise ClusterError(f"--dask: lost the scheduler at {address} (it "
                                       "stopped, or the network did)") from None
                raise ClusterError(f"--dask: trial {names.get(future.key, future.key)} was "
                                   f"cancelled on the cluster ({reason})") from None
            except KilledWorker as exc:
                raise ClusterError(
                    f"--dask: trial {names.get(exc.task, exc.task)} lost its worker "
                    f"{exc.allowed_failures + 1} time(s), the last at "
                    f"{getattr(exc.last_worker, 'address', '?')} (the scheduler's "
                    f"allowed-failures is {exc.allowed_failures}): see the worker logs "
                    "(out of memory?)") from None
    except BaseException:
        failed = True
        raise
    finally:
        _close_client(client, lost, failed)


def _close_client(client, lost, failed):
    """Close ``client``; when the campaign ``failed``, an error of the close itself is
    dropped (the campaign's error is the one to report).  After a ``lost`` scheduler the
    client is retrying the connection, and closing it cancels that retry, which
    ``distributed.client`` logs as an error with a traceback: the campaign has already said
    what happened in one line, so that logger is muted for the close."""
    import logging

    log = logging.getLogger("distributed.client")
    disabled = log.disabled
    log.disabled = disabled or lost
    try:
        if failed:
            client.close(timeout=10)
        else:
            client.close()
    except Exception:
        if not failed:
            raise
    finally:
        log.disabled = disabled


def run_campaign(config, n_trials, out_dir, workers=1, dask=None, resume=False,
                 max_tasks=None, progress=True):
    """Run the campaign's pending tasks (at most ``max_tasks``), journaling each result;
    notes (resuming, stopped) go to stderr.  Returns ``(rows, paths)``: the table and the
    files written, or ``(None, [])`` when tasks remain (stopped by ``max_tasks``).  Raises
    ``ValueError`` for bad arguments."""
    tasks = make_tasks(config, n_trials)
    if dask is None and (isinstance(workers, bool) or not isinstance(workers, int) or
                         workers < 1):
        raise ValueError(f"--workers must be a positive integer, got {workers!r}")
    if max_tasks is not None and (not isinstance(max_tasks, int) or max_tasks < 1):
        raise ValueError(f"--max-tasks must be a positive integer, got {max_tasks!r}")
    journal, results = open_journal(out_dir, config, resume)
    keys = {trials.task_key(t) for t in tasks}
    pending = [t for t in tasks if trials.task_key(t) not in results]
    if results:
        print(f"lodestar campaign: resuming: {len(keys & set(results))} of {len(tasks)} "
              f"tasks already in {journal.name}", file=sys.stderr)
    pending.sort(key=lambda t: t[3])        # trial by trial: balanced levels at any time
    todo = pending if max_tasks is None else pending[:max_tasks]
    bar = _progress(len(tasks), len(tasks) - len(pending), config["study"], progress)
    try:
        def sink(key, result):
            results[key] = result
            journal.write(json.dumps({"key": key, "result": result}) + "\n")
            journal.flush()
            bar.update(1)

        if todo:
            _prepare_databases(config)
            if dask is not None:
                try:
                    _run_dask(todo, config, dask, sink)
                except ClusterError as exc:
                    raise ValueError(
                        f"{exc}; {journal.name} holds {len(keys & set(results))} of "
                        f"{len(tasks)} tasks: run again with --resume (on a cluster, or "
                        "locally with --workers)") from None
            else:
                _run_local(todo, config, min(workers, len(todo)), sink)
    finally:
        bar.close()
        journal.close()
    if len(todo) < len(pending):
        print(f"lodestar campaign: stopped after {len(todo)} tasks; "
              f"{len(pending) - len(todo)} remain: run again with --resume", file=sys.stderr)
        return None, []
    return write_outputs(config, tasks, results, out_dir)


def _progress(total, done, name, enabled):
    from tqdm import tqdm

    return tqdm(total=total, initial=done, desc=f"campaign {name}", unit="frame",
                disable=not enabled, file=sys.stderr, smoothing=0.05)


def _prepare_databases(config):
    """Build (or read) the star databases once before the workers start, so that parallel
    workers do not all build the same cache file."""

    methods = trials.METHODS if config["study"] == "falsestars" else (config["method"],)
    for preset in config["presets"]:
        if config["study"] == "fov":
            for level in config["levels"]:
                trials.fov_database(onboard.firmware_camera(trials.fov_camera(preset,
                                                                              float(level))),
                               config["method"])
            continue
        cam = onboard.firmware_camera(presets.load_preset(preset))
        for method in methods:
            onboard.star_database(cam, method=method)


def write_outputs(config, tasks, results, out_dir):
    """The table as JSON and CSV and the plot: ``(rows, paths)``."""
    study = config["study"]
    rows = tables.tables(study, tasks, results, config)
    base = os.path.join(out_dir, f"campaign_{study}")
    per_level = len(tasks) // max(1, len(config["presets"]) * len(config["levels"]))
    summary = {"campaign": config, "trials_per_level": per_level,
               "wrong_arcsec": truth.WRONG_ARCSEC,
               "wrong_sigmas": truth.WRONG_SIGMAS, "table": rows,
               "references": {"dzamba_table_4_1": {f"{k:g}": v for k, v in
                                                   tables.DZAMBA_TABLE_4_1.items()},
                              "schumann_5dps_sky_pct": tables.SCHUMANN_5DPS_PCT,
                              "schumann_smear_model": tables.SCHUMANN_SMEAR}}
    write_atomic(base + ".json", json.dumps(summary, indent=1))
    tables.write_csv(base + ".csv", rows)
    title = f"{per_level} trials/level, seed {config['seed']}, {config['axis']} axis" + \
        ("" if config.get("gyro", True) else ", no gyro")
    pngs = plots.PLOTS[study](rows, out_dir, title)
    return rows, [base + ".json", base + ".csv"] + pngs


# ---- command line ----------------------------------------------------------------------

COLUMNS = {
    "rate": ("preset", "rate_deg_s", "trials", "right", "wrong", "failed", "imprecise",
             "availability_pct",
             "cross_1sigma", "roll_1sigma", "sigma_cross_rms", "sigma_roll_rms",
             "dzamba_st16_n3_pct"),
    "falsestars": ("preset", "sweep", "level", "method", "trials", "right", "wrong", "failed",
                   "wrong_matches", "availability_pct"),
    "limiting": ("preset", "rate_deg_s", "frames", "stars", "m50_sim", "eq57_m_t",
                 "schumann_m_rot"),
    "accuracy": ("preset", "stars_kept", "trials", "right", "wrong", "mean_matches",
                 "cross_1sigma", "sigma_cross_rms", "ratio_cross", "roll_1sigma",
                 "sigma_roll_rms", "ratio_roll"),
    "fov": ("preset", "fov_deg", "aperture_mm", "render_mag", "db_stars", "trials", "right",
            "wrong", "failed", "availability_pct", "ci_low_pct", "cross_1sigma",
            "roll_1sigma", "solve_ms_p50", "solve_ms_p95"),
}
"""Columns printed on the terminal (the CSV has all)."""


def format_table(study, rows):
    """The table's main columns as aligned text."""
    cols = COLUMNS[study]

    def cell(v):
        if v is None:
            return "-"
        return f"{v:.2f}" if isinstance(v, float) else str(v)

    body = [[cell(r[c]) for c in cols] for r in rows]
    widths = [max(len(c), *(len(b[i]) for b in body)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.rjust(w) for c, w in zip(cols, widths))]
    lines += ["  ".join(v.rjust(w) for v, w in zip(b, widths)) for b in body]
    return "\n".join(lines)
