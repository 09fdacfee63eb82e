"""Scale-out benchmark: sweep speed-up on 1 vs 2 worker processes, and memory on a big archive.

1. A sweep of 16 HDD experiments (N = 3600) x 3 windows (48 identify tasks) on a
   ``LocalCluster`` with 1 worker process, then with 2; prints both times and the ratio.
2. An archive whose data are larger than the memory limit given to each worker
   (many long experiments, copies of a few simulated ones), identified with the workers
   limited to ``--memory-limit``; the workers' RSS is sampled with psutil every 50 ms.
   Each task reduces its FRF to a per-experiment error against the true HDD FRF, so the
   result is small: the test is that streaming the archive through the workers keeps
   them under the limit, not that the whole result fits anywhere.

Run: ``.venv/bin/python benchmarks/scale_out.py [--quick]``.  Numbers depend on the
machine (2 cores here, shared) and on what else runs; the speed-up is bounded by 2 and by
the serial parts (graph submission, gathering results).
"""

from __future__ import annotations

import argparse
import functools
import os
import shutil
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import xarray as xr


def _cluster(n_workers, memory_limit="auto"):
    from distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=50, memory_limit=memory_limit)
    client = Client(cluster)
    client.run(lambda: __import__("lcmr_xr.identification"))  # imports are not the benchmark
    return cluster, client


def _time_sweep(exps, windows, n_workers, repeats):
    from lcmr_xr.scaleout import sweep

    cluster, client = _cluster(n_workers)
    try:
        res = sweep(exps, window=windows, degrees=["3-3-3"])
        client.compute(sweep(exps.isel(experiment=[0]), window=windows[:1])).result()  # warm-up
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            client.compute(res).result()
            times.append(time.perf_counter() - t0)
        return min(times)
    finally:
        client.close()
        cluster.close()


class _RssSampler:
    """Peak resident memory per process, sampled in a background thread."""

    def __init__(self, pids, period=0.05):
        import psutil

        self.procs = {pid: psutil.Process(pid) for pid in pids}
        self.peak = {pid: 0 for pid in pids}
        self.period = period
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self):
        while not self._stop.is_set():
            for pid, proc in self.procs.items():
                try:
                    self.peak[pid] = max(self.peak[pid], proc.memory_info().rss)
                except Exception:  # a worker that was restarted: its old pid is gone
                    pass
            time.sleep(self.period)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()


@functools.lru_cache(maxsize=4)
def _truth(case, f0, df, n):
    """The true HDD FRF on an even grid, computed once per worker (every task shares it)."""
    from lcmr_xr import hdd

    return hdd.true_frf(f0 + df * np.arange(n), case=case)


def _error_per_experiment(block, case, window):
    """Median relative error of one block's FRF against the true HDD FRF (a small result)."""
    from lcmr_xr.identification import identify

    frf = identify(block, window=window, covariance=False, errors="ignore")
    f = frf.frequency.values
    truth = _truth(case, float(f[0]), float(f[1] - f[0]), f.size).assign_coords(
        frequency=frf.frequency)
    err = np.abs(frf.P - truth) / np.abs(truth)
    return err.median(["frequency", "output", "input"]).rename("error")


def _memory_run(archive, memory_limit, window, case):
    from lcmr_xr.scaleout import open_archive

    cluster, client = _cluster(2, memory_limit=memory_limit)
    try:
        pids = list(client.run(os.getpid).values())
        # each worker would otherwise keep up to 128 archive files open (xarray's file
        # cache), memory that dask can neither see nor spill
        client.run(lambda: xr.set_options(file_cache_maxsize=4))
        exps = open_archive(archive)
        template = xr.DataArray(np.zeros(exps.sizes["experiment"]), dims="experiment",
                                coords={"experiment": exps.experiment}, name="error").chunk({"experiment": 1})
        lazy = xr.map_blocks(_error_per_experiment, exps, kwargs={"case": case, "window": window},
                             template=template)
        errors = None
        with _RssSampler(pids) as sampler:
            t0 = time.perf_counter()
            try:
                errors = client.compute(lazy).result()
            except Exception as exc:  # KilledWorker: the limit was too small; report, don't hide
                print(f"  FAILED: {type(exc).__name__}: {str(exc)[:160]}")
            elapsed = time.perf_counter() - t0
        return exps, errors, sampler.peak, elapsed
    finally:
        client.close()
        cluster.close()


def main(argv=None):
    from lcmr_xr import hdd
    from lcmr_xr.scaleout import open_archive, save_archive

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="smaller sizes (a smoke run)")
    ap.add_argument("--memory-limit", default="500MB", help="per-worker limit of part 2")
    ap.add_argument("--long-n", type=int, default=36000, help="samples per archived experiment")
    ap.add_argument("--copies", type=int, default=850, help="experiments in the big archive")
    ap.add_argument("--skip-speedup", action="store_true", help="only the memory part")
    ap.add_argument("--skip-memory", action="store_true", help="only the speed-up part")
    args = ap.parse_args(argv)

    n_exp, windows, repeats = (4, [20, 30], 1) if args.quick else (16, [20, 30, 40], 2)
    # One identify task (N=36000, no covariance) peaks about 30 MB above a process's
    # base; a worker process sits near 240-300 MB over a long run (measured; one process
    # identifying 80 archived experiments in a loop stays within 238-261 MB: no leak).  So
    # 850 such experiments (~1.1 GB in memory, ~1.5 GB on disk) are more than both workers'
    # limits together (2 x 500 MB).  Dask pauses a worker at 80 % of its limit, and a
    # worker's own unmanaged memory cannot be spilled: with 400 MB (pause at 320 MB) a long
    # run reached 330 MB on one worker and slowed to a crawl instead of failing.  Measured
    # with these defaults: 1102 MB in memory (1484 MB on disk) identified in 1033 s, peak
    # worker RSS 372 MB and 337 MB.
    long_n, copies, sims = (args.long_n, 40, 2) if args.quick else (args.long_n, args.copies, 4)
    tmp = Path(tempfile.mkdtemp(prefix="lcmr-scaleout-"))
    try:
        # ---- 1. speed-up
        if not args.skip_speedup:
            t0 = time.perf_counter()
            exps = xr.concat([hdd.simulate(n_samples=3600, seed=s) for s in range(n_exp)], "experiment")
            exps = exps.assign_coords(experiment=("experiment", [f"seed{s:02d}" for s in range(n_exp)],
                                                  {"units": "1", "long_name": "experiment"}))
            save_archive(exps, tmp / "sweep")
            print(f"simulated and archived {n_exp} HDD experiments (N=3600) in "
                  f"{time.perf_counter() - t0:.1f} s")
            archived = open_archive(tmp / "sweep")
            t1 = _time_sweep(archived, windows, 1, repeats)
            t2 = _time_sweep(archived, windows, 2, repeats)
            print(f"sweep {n_exp} experiments x {len(windows)} windows ({n_exp * len(windows)} tasks), "
                  f"best of {repeats}:")
            print(f"  1 worker process : {t1:7.2f} s")
            print(f"  2 worker processes: {t2:7.2f} s")
            print(f"  speed-up          : {t1 / t2:7.2f}x (goal >= 1.7x on 2 cores)")

        # ---- 2. memory on an archive larger than the workers' memory limit
        if args.skip_memory:
            return
        base = [hdd.simulate(n_samples=long_n, seed=100 + s) for s in range(sims)]
        items = [base[i % sims].assign_coords(experiment=f"long{i:04d}") for i in range(copies)]
        save_archive(items, tmp / "big")
        size = sum(p.stat().st_size for p in (tmp / "big").glob("*.nc"))
        limit = _parse_bytes(args.memory_limit)
        exps, errors, peak, elapsed = _memory_run(tmp / "big", args.memory_limit, 30, 2)
        worst = max(peak.values())
        print(f"archive of {copies} experiments (N={long_n}; {sims} distinct simulations, copied): "
              f"{size / 1e6:.0f} MB on disk, {exps.nbytes / 1e6:.0f} MB in memory "
              f"({exps.nbytes / limit:.1f}x the per-worker limit {limit / 1e6:.0f} MB, "
              f"{exps.nbytes / (2 * limit):.1f}x both workers')")
        if errors is not None:
            print(f"  identified on 2 workers in {elapsed:.1f} s; median error vs true FRF "
                  f"{float(errors.median()):.2e}")
        print("  peak worker RSS: " + ", ".join(f"{v / 1e6:.0f} MB" for v in peak.values())
              + f" -> {'under' if worst < limit else 'OVER'} the limit of {limit / 1e6:.0f} MB")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def _parse_bytes(text):
    from dask.utils import parse_bytes

    return parse_bytes(text)


if __name__ == "__main__":
    main()
