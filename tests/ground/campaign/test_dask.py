"""``lodestar campaign --dask``: the campaign on Dask clusters of worker processes gives the
local runner's results trial for trial, survives a worker killed mid-campaign, and ends on a
lost scheduler with a one-line message and a journal that ``--resume`` finishes.

Every wait is bounded by :data:`TIMEOUT` (a hung cluster fails the test), every process
started here is ended here (checked), and the clusters run without their dashboards (no
port to take, no warning about a port in use).  The campaign is the ``test_runner`` one: the
lohmann preset, rates 0 and 1 deg/s, 2 trials, seed 3 (4 tasks of about a second each)."""

import json
import logging
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from dask import distributed

from lodestar.cli import main
from lodestar.ground.campaign import runner

pytestmark = pytest.mark.skipif(not Path("/proc/self/stat").exists(),
                                reason="the process checks read Linux /proc")

TIMEOUT = 120
"""Seconds any one wait on a cluster may take (its start, a campaign, its close): a bound
for a hung cluster, far above a campaign's few seconds."""
TRIALS = 2
CAMPAIGN_ARGS = ["rate", "--presets", "lohmann", "--rates", "0", "1", "--trials", str(TRIALS),
                 "--seed", "3", "--no-progress"]


QUIET = {"dashboard_address": None, "scheduler_kwargs": {"dashboard_address": "127.0.0.1:0"},
         "silence_logs": logging.ERROR}
"""``LocalCluster`` options: no dashboard, and the scheduler's HTTP server (health and
metrics, started even without a dashboard) on a free port rather than 8787, which another
cluster may hold (a warning); the nannies log the killed worker and its restart as warnings,
the very events the tests cause, so only errors show."""


def rate_config():
    """The settings of :data:`CAMPAIGN_ARGS`."""
    return runner.make_config("rate", ["lohmann"], seed=3, rates=[0.0, 1.0])


def journal_lines(out):
    """The journal's result lines as ``[(key, result)]``, in file order (duplicates kept)."""
    text = (Path(out) / runner.JOURNAL).read_text()
    entries = [json.loads(line) for line in text.splitlines()[1:]]
    return [(entry["key"], entry["result"]) for entry in entries]


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The campaign run by the local runner in this process: ``(rows, {key: result})``."""
    out = tmp_path_factory.mktemp("local")
    rows, _paths = runner.run_campaign(rate_config(), TRIALS, str(out), workers=1,
                                       progress=False)
    return rows, dict(journal_lines(out))


def _proc_stat(pid):
    """``(state, ppid, pgrp)`` of a process, or None when it is gone."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except (OSError, IndexError):
        return None
    return fields[0], int(fields[1]), int(fields[2])


def _living(match):
    """Process ids, not zombies, whose ``(state, ppid, pgrp)`` satisfies ``match``."""
    out = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            stat = _proc_stat(int(entry.name))
            if stat is not None and stat[0] != "Z" and match(stat):
                out.append(int(entry.name))
    return out


def _children():
    """This process's children, less multiprocessing's resource tracker: the spawn start
    method starts it once, and it ends with this process, by design."""
    out = set()
    for pid in _living(lambda stat: stat[1] == os.getpid()):
        try:
            command = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"multiprocessing.resource_tracker" not in command:
            out.add(pid)
    return out


def _wait_gone(pids, timeout=30):
    """The pids of ``pids`` still alive after waiting up to ``timeout`` s for them to end."""
    deadline = time.monotonic() + timeout
    while True:
        alive = [p for p in pids if (_proc_stat(p) or ("Z",))[0] != "Z"]
        if not alive or time.monotonic() > deadline:
            return alive
        time.sleep(0.1)


class Background:
    """``fn(*args, **kwargs)`` run in a daemon thread (a hung one does not keep the test
    process alive; closing its cluster ends it)."""

    def __init__(self, fn, *args, **kwargs):
        self.name, self.box = fn.__name__, {}

        def target():
            try:
                self.box["value"] = fn(*args, **kwargs)
            except BaseException as exc:      # re-raised by result(), in the test's thread
                self.box["error"] = exc

        self.thread = threading.Thread(target=target, daemon=True)
        self.thread.start()

    def done(self):
        return not self.thread.is_alive()

    def result(self, timeout=TIMEOUT):
        """The call's value (or its exception, raised); the test fails when the call has
        not returned within ``timeout`` s."""
        self.thread.join(timeout)
        if self.thread.is_alive():
            pytest.fail(f"{self.name} did not return within {timeout} s (a hung cluster?)")
        if "error" in self.box:
            raise self.box["error"]
        return self.box["value"]


def bounded(fn, *args, **kwargs):
    """``fn(*args, **kwargs)``, failing the test after :data:`TIMEOUT` s."""
    return Background(fn, *args, **kwargs).result()


def _until(condition, what, timeout=TIMEOUT, poll=0.02):
    """Wait for ``condition()`` to be true, failing the test after ``timeout`` s."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            pytest.fail(f"timed out after {timeout} s waiting for {what}")
        time.sleep(poll)


@pytest.fixture(scope="module")
def cluster():
    """A ``LocalCluster`` of 2 worker processes (1 thread each) under their nannies; closed,
    and none of its processes left, at the end of the module."""
    before = _children()
    local = distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                     timeout=TIMEOUT, **QUIET)
    started = _children() - before
    try:
        yield local
    finally:
        local.close(timeout=TIMEOUT)
        assert not _wait_gone((_children() - before) | started), "worker processes left"


@pytest.fixture
def client(cluster):
    """A client of :func:`cluster` for the test's own look at it."""
    with distributed.Client(cluster.scheduler_address, timeout=TIMEOUT) as c:
        yield c


def test_a_cluster_of_two_processes_gives_the_local_results(reference, cluster, client,
                                                            tmp_path):
    """Trial for trial the local runner's results, the trials run by both worker
    processes (neither of them this process)."""
    rows, results = reference
    pids = client.run(os.getpid)
    assert len(set(pids.values())) == 2 and os.getpid() not in pids.values()
    done_before = client.run(lambda dask_worker: dask_worker.state.executed_count)
    rows2, paths = bounded(runner.run_campaign, rate_config(), TRIALS, str(tmp_path),
                           dask=cluster.scheduler_address, progress=False)
    done = client.run(lambda dask_worker: dask_worker.state.executed_count)
    assert all(done[w] > done_before[w] for w in pids), (done_before, done)
    assert rows2 == rows and len(paths) == 3
    assert dict(journal_lines(tmp_path)) == results


def _kill_a_busy_worker(client, journal):
    """Once the journal holds a result, SIGKILL the worker process holding the most trials:
    its address and pid."""
    pids = client.run(os.getpid)
    _until(lambda: journal.is_file() and journal.read_text().count("\n") >= 2,
           "the first result", poll=0.005)
    busy = client.processing()
    victim = max(pids, key=lambda w: len(busy.get(w, ())))
    assert busy.get(victim), "the campaign ended before a worker could be killed"
    os.kill(pids[victim], signal.SIGKILL)
    return victim, pids[victim]


def test_a_worker_killed_mid_campaign(reference, cluster, client, tmp_path):
    """A worker process killed (SIGKILL) while it holds trials: the scheduler runs them
    again elsewhere, the campaign completes with every trial journaled once, and the results
    are those of an uninterrupted run."""
    rows, results = reference
    campaign = Background(runner.run_campaign, rate_config(), TRIALS, str(tmp_path),
                          dask=cluster.scheduler_address, progress=False)
    victim, pid = _kill_a_busy_worker(client, tmp_path / runner.JOURNAL)
    rows2, paths = campaign.result()
    assert rows2 == rows and len(paths) == 3
    lines = journal_lines(tmp_path)
    assert sorted(k for k, _ in lines) == sorted(results)        # every trial once
    assert dict(lines) == results
    removed = [msg for _t, msg in client.get_events("all")
               if msg.get("action") == "remove-worker" and msg.get("worker") == victim]
    assert removed and removed[0]["processing-tasks"] and not removed[0]["expected"], removed
    assert not _wait_gone([pid])
    client.wait_for_workers(2, timeout=TIMEOUT)      # its nanny started a new one


def test_a_trial_whose_workers_keep_dying_is_a_clear_error(reference, cluster, client,
                                                           tmp_path):
    """With ``allowed-failures`` 0 the scheduler gives up on a trial whose worker died: the
    campaign stops with a one-line error naming the trial, and resumes on the cluster."""
    rows, results = reference
    cluster.scheduler.allowed_failures = 0
    try:
        campaign = Background(runner.run_campaign, rate_config(), TRIALS, str(tmp_path),
                              dask=cluster.scheduler_address, progress=False)
        _kill_a_busy_worker(client, tmp_path / runner.JOURNAL)
        with pytest.raises(ValueError) as error:
            campaign.result()
    finally:
        cluster.scheduler.allowed_failures = 3
    message = str(error.value)
    assert "\n" not in message, message
    assert message.startswith("--dask: trial rate/lohmann/") and "lost its worker 1 time" \
        in message and "run again with --resume" in message, message
    client.wait_for_workers(2, timeout=TIMEOUT)
    rows2, _paths = bounded(runner.run_campaign, rate_config(), TRIALS, str(tmp_path),
                            resume=True, dask=cluster.scheduler_address, progress=False)
    assert rows2 == rows and dict(journal_lines(tmp_path)) == results


def _start(args, log, **kwargs):
    """A process in its own session (so that its group, workers included, can be ended)."""
    with open(log, "w") as fh:
        return subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT,
                                start_new_session=True, **kwargs)


def _end_group(proc):
    """End ``proc``'s process group (SIGTERM, then SIGKILL); the pids still alive."""
    members = _living(lambda stat: stat[2] == proc.pid)
    for sig in (signal.SIGTERM, signal.SIGKILL):
        try:
            os.killpg(proc.pid, sig)
        except ProcessLookupError:
            break
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            continue
        if not _wait_gone(members, timeout=10):
            break
    return _wait_gone(members + _living(lambda stat: stat[2] == proc.pid), timeout=5)


def test_a_lost_scheduler_ends_the_command_and_resume_finishes(reference, cluster, tmp_path):
    """``dask scheduler`` and ``dask worker`` as docs/campaigns.md starts them (one worker
    process, so that trials remain for a good while after the first result); the scheduler
    killed (SIGKILL) mid-campaign: ``lodestar campaign --dask`` exits 2 with one line, no
    output file is written, and the journal resumes on another cluster (for one task) and
    then locally, to the uninterrupted results."""
    rows, results = reference
    scheduler_file = tmp_path / "scheduler.json"
    scheduler = _start([sys.executable, "-m", "dask", "scheduler", "--host", "127.0.0.1",
                        "--port", "0", "--no-dashboard", "--dashboard-address", "127.0.0.1:0",
                        "--scheduler-file", str(scheduler_file)], tmp_path / "scheduler.log")
    workers = _start([sys.executable, "-m", "dask", "worker", "--scheduler-file",
                      str(scheduler_file), "--nworkers", "1", "--nthreads", "1",
                      "--no-dashboard", "--host", "127.0.0.1"], tmp_path / "workers.log")
    try:
        _until(lambda: scheduler_file.is_file() and scheduler_file.stat().st_size,
               "the scheduler file", poll=0.1)
        address = json.loads(scheduler_file.read_text())["address"]
        with distributed.Client(address, timeout=TIMEOUT) as look:
            look.wait_for_workers(1, timeout=TIMEOUT)
        out = tmp_path / "campaign"
        journal = out / runner.JOURNAL
        command = subprocess.Popen([sys.executable, "-m", "lodestar", "campaign",
                                    *CAMPAIGN_ARGS, "--out", str(out), "--dask", address],
                                   stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            _until(lambda: command.poll() is not None or (
                journal.is_file() and journal.read_text().count("\n") >= 2),
                "the first result", poll=0.005)
            os.killpg(scheduler.pid, signal.SIGKILL)
            stdout, stderr = command.communicate(timeout=TIMEOUT)
        finally:
            if command.poll() is None:
                command.kill()
                command.wait(timeout=10)
        assert command.returncode == 2, (stdout, stderr)
        assert stderr.splitlines() == [stderr.strip()], stderr        # one line
        assert stderr.startswith(f"lodestar campaign: error: --dask: lost the scheduler at "
                                 f"{address}"), stderr
        assert "run again with --resume" in stderr
        done = dict(journal_lines(out))
        assert 1 <= len(done) < len(results) and f"{len(done)} of 4 tasks" in stderr
        assert all(results[k] == v for k, v in done.items())
        assert sorted(p.name for p in out.iterdir()) == [runner.JOURNAL]
    finally:
        left = _end_group(scheduler) + _end_group(workers)
    assert not left, f"processes left: {left}"

    assert bounded(runner.run_campaign, rate_config(), TRIALS, str(out), resume=True,
                   dask=cluster.scheduler_address, max_tasks=1, progress=False) == (None, [])
    assert main(["campaign", *CAMPAIGN_ARGS, "--out", str(out), "--resume",
                 "--workers", "1"]) == 0
    lines = journal_lines(out)
    assert sorted(k for k, _ in lines) == sorted(results) and dict(lines) == results
    summary = json.loads((out / "campaign_rate.json").read_text())
    assert summary["table"] == json.loads(json.dumps(rows))


def test_a_scheduler_without_workers_is_said(tmp_path, capsys):
    """A scheduler with no worker: a note that the campaign waits for workers; the
    scheduler closed then ends the campaign with the lost-scheduler error."""
    with distributed.LocalCluster(n_workers=0, processes=False, timeout=TIMEOUT,
                                  **QUIET) as empty:
        campaign = Background(runner.run_campaign, rate_config(), 1, str(tmp_path),
                              dask=empty.scheduler_address, progress=False)
        seen = []
        _until(lambda: seen.append(capsys.readouterr().err) or "no workers yet" in seen[-1]
               or campaign.done(), "the note")
    with pytest.raises(ValueError, match="lost the scheduler"):
        campaign.result()
    assert "waiting for some" in seen[-1]


def test_dask_missing_is_a_clear_message(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "dask.distributed", None)
    with pytest.raises(ValueError, match=r"pip install 'lodestar\[dask\]'"):
        runner.run_campaign(rate_config(), 1, str(tmp_path), dask="tcp://127.0.0.1:1",
                            progress=False)
