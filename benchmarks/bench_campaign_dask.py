"""Campaign throughput, side by side in one run: ``--workers 2`` (local processes) against a
Dask ``LocalCluster`` of 2 worker processes (1 thread each, Dask's default settings).

The same rate campaign (seed 0, its own temporary folder each time) runs once per runner to
warm up (the Dask workers import lodestar and read the star database on their first
trial), then ``--repeats`` times per runner, the runners alternating so that the load of a
shared machine falls on both alike.  Each timing is ``run_campaign``'s wall clock:
trials, journal and outputs (the table, the plot).  Prints trials/s (one trial = one frame
at one level) per repeat and their median, and the CPU seconds per trial (this process,
and the local pool's processes or the Dask workers' processes): on a shared machine the
wall clock follows the load, the CPU time much less.

    .venv/bin/python benchmarks/bench_campaign_dask.py [--preset lohmann] [--rates 0 1 2]
        [--trials 8] [--repeats 5]
"""

import argparse
import logging
import resource
import statistics
import tempfile
import time

from dask import distributed

from lodestar.ground.campaign import runner

QUIET = {"dashboard_address": None, "scheduler_kwargs": {"dashboard_address": "127.0.0.1:0"},
         "silence_logs": logging.ERROR}
"""No dashboard, the scheduler's HTTP server on a free port (not 8787), only errors logged."""


def _cpu(client):
    """CPU seconds used so far by this process (the campaign's own work, and the cluster's
    scheduler and nannies, which run in it) and its reaped children (the local pool's
    workers), plus with a Dask ``client`` its workers' processes (the trials, their event
    loop and profiler)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), \
        resource.getrusage(resource.RUSAGE_CHILDREN)
    total = own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime
    if client is not None:
        total += sum(client.run(time.process_time).values())
    return total


def _run(config, n_trials, client=None, **where):
    """``(wall s, CPU s)`` of one campaign."""
    with tempfile.TemporaryDirectory() as out:
        cpu, t = _cpu(client), time.perf_counter()
        runner.run_campaign(config, n_trials, out, progress=False, **where)
        return time.perf_counter() - t, _cpu(client) - cpu


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--preset", default="lohmann")
    parser.add_argument("--rates", nargs="+", type=float, default=[0.0, 1.0, 2.0])
    parser.add_argument("--trials", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config = runner.make_config("rate", [args.preset], seed=0, rates=args.rates)
    n = len(runner.make_tasks(config, args.trials))
    t = time.perf_counter()
    cluster = distributed.LocalCluster(n_workers=2, processes=True, threads_per_worker=1,
                                       **QUIET)
    print(f"LocalCluster of 2 processes started in {time.perf_counter() - t:.1f} s",
          flush=True)
    client = distributed.Client(cluster)
    variants = {"--workers 2": {"workers": 2},
                "--dask (LocalCluster, 2 processes)": {"dask": cluster.scheduler_address,
                                                       "client": client}}
    times = {name: [] for name in variants}
    try:
        for name, where in variants.items():
            wall, cpu = _run(config, args.trials, **where)
            print(f"{name}: warm-up {n / wall:.2f} trials/s, {cpu / n:.2f} CPU s/trial",
                  flush=True)
        for i in range(args.repeats):
            for name, where in variants.items():
                times[name].append(_run(config, args.trials, **where))
                wall, cpu = times[name][-1]
                print(f"{name}: repeat {i + 1} {n / wall:.2f} trials/s, "
                      f"{cpu / n:.2f} CPU s/trial", flush=True)
    finally:
        client.close()
        cluster.close()
    print(f"\n{n} trials per campaign ({args.preset}, rates {args.rates}, "
          f"{args.trials} trials per rate)\n")
    print("| runner | trials/s per repeat | median trials/s | median CPU s per trial |")
    print("|---|---|---|---|")
    for name, runs in times.items():
        rates = ", ".join(f"{n / wall:.2f}" for wall, _cpu in runs)
        wall = statistics.median(w for w, _c in runs)
        cpu = statistics.median(c for _w, c in runs)
        print(f"| {name} | {rates} | {n / wall:.2f} | {cpu / n:.2f} |")


if __name__ == "__main__":
    main()
