"""Archive benchmark: open, append, sweep graph, identify throughput and memory per task.

In one run (HDD experiments, N = 3600, window 30, degrees 3-3-3, with ``P_std``):

1. ``open_archive`` time and client memory (RSS growth of a fresh process) for 100, 1 600
   and 10 000 experiments, consolidated and as a directory of files (the directory form
   up to ``--files-max`` experiments: 10 000 files take minutes to write and to open);
2. ``append_to_archive`` of one experiment into the largest consolidated archive;
3. the time to build the graph of a sweep of the largest archive x 3 windows;
4. identify throughput: plain ``identify`` calls in this process, ``sweep_to_disk`` on one
   core, and on 2-worker ``LocalCluster``s (distributed's defaults, and
   :func:`lcmr_xr.scaleout.local_cluster`); the time of one ``identify`` inside a worker
   of each against a plain process with the workers' thread settings;
5. peak memory of one task (``tracemalloc``: numpy's allocations) against the data size.

The experiments are copies of one simulated experiment with a small random perturbation
(cheap to make; identify costs the same).  Everything is written to a temporary
directory that is removed at the end.  Timings on a shared machine vary: compare the
numbers of one run with each other.

Run: ``.venv/bin/python benchmarks/archive.py [--quick] [--files-max 10000]``.

Measured on the 2-core machine while other jobs kept it at a load of 7-12 (so absolute
times are slow; compare within the run), ``--files-max 100 --identify 8``:
open consolidated 100 / 1 600 / 10 000: 0.44 s +3.7 MB / 0.47 s +4.1 MB / 0.31 s +7.9 MB;
directory of 100 files 29 s +82 MB; append into 10 000: median 52 ms; one identify in a
worker / plain process (1 BLAS thread): 2.57x with distributed's defaults, 1.48x with
``local_cluster``; peak traced memory 105 MB per identify with P_std, 114 MB for a task of
8 experiments.  After the merge with issue 17 (settings checked by sweep_settings,
structure from result_template: no probe identify), ``--sizes 10000 --files-max 0
--skip-throughput`` at a load of about 2.5: the sweep of 10 005 experiments x 3 windows
is built in 2.35 s (110 191 tasks), 0.31 s of it the fixed cost.  Before the new index
coordinates (frequency, ...) were kept out of the blocks it took 5.1 s (10.6 s at a
higher load): map_blocks pickled them once per block to tokenize them.  After merging
window='auto' (three more result variables): 4.32 s, 127 093 tasks, at a load of 4-5.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

N = 3600
WINDOW = 30


def _base():
    from lcmr_xr import hdd

    return hdd.simulate(n_samples=N, seed=1)


def _perturbed(base, i, rng):
    exp = base.copy(deep=False)
    for name in ("r", "u", "y"):
        scale = 1e-3 * float(np.std(base[name].values))
        exp[name] = base[name] + scale * rng.standard_normal(base[name].shape)
    return exp.assign_coords(experiment=f"e{i:05d}").assign_attrs(seed=i)


def make_consolidated(path: Path, n: int, base, batch: int = 250) -> None:
    """``n`` perturbed copies of ``base`` written with the library's own append path."""
    from lcmr_xr.scaleout import save_archive
    from lcmr_xr.scaleout.consolidated import append_rows, metadata_of

    rng = np.random.default_rng(0)
    save_archive([_perturbed(base, 0, rng)], path)
    for start in range(1, n, batch):
        rows = [(f"e{i:05d}", _perturbed(base, i, rng)) for i in range(start, min(n, start + batch))]
        append_rows(path, rows, [metadata_of(label, ds) for label, ds in rows], expected_count=start)


def make_directory(path: Path, n: int, base) -> None:
    """``n`` experiment files: one written by save_archive, copied and relabelled (same data)."""
    import netCDF4

    from lcmr_xr.scaleout import save_archive
    from lcmr_xr.scaleout.archive import ORDER_ATTR

    first = save_archive([base.assign_coords(experiment="e00000").assign_attrs(seed=0)], path,
                         layout="files")[0]
    for i in range(1, n):
        target = path / f"e{i:05d}.nc"
        shutil.copyfile(first, target)
        with netCDF4.Dataset(target, "a") as nc:
            nc["experiment"][0] = f"e{i:05d}"  # a scalar vlen string: index 0
            nc.setncattr(ORDER_ATTR, np.int64(i))
            nc.setncattr("seed", np.int64(i))


_OPEN = """
import json, sys, time, psutil
import dask.array, h5netcdf, netCDF4, xarray  # imports are not the open
from lcmr_xr.scaleout import open_archive
proc = psutil.Process(); before = proc.memory_info().rss
t0 = time.perf_counter(); ds = open_archive(sys.argv[1]); dt = time.perf_counter() - t0
print(json.dumps({"seconds": dt, "mb": (proc.memory_info().rss - before) / 1e6,
                  "experiments": ds.sizes["experiment"]}))
"""


def time_open(path: Path) -> dict:
    """Open time and RSS growth of ``open_archive`` in a fresh process."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1]),
                                                        os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", _OPEN, str(path)], capture_output=True, text=True,
                         env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def timed_identify(path: str, repeat: int = 3) -> float:
    """Best time of one ``identify`` of the first archived experiment (run where called)."""
    from lcmr_xr.identification import identify
    from lcmr_xr.scaleout import open_archive

    arc = open_archive(path)
    exp = arc.isel(experiment=0).compute()
    arc.close()
    identify(exp, window=WINDOW, errors="ignore")  # warm-up
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        identify(exp, window=WINDOW, errors="ignore")
        best = min(best, time.perf_counter() - t0)
    return best


def task_memory(path: str, per_task: int) -> dict:
    """Peak traced memory (MB) of one identify and of one sweep task of ``per_task`` experiments."""
    import tracemalloc

    from lcmr_xr.identification import identify
    from lcmr_xr.scaleout import open_archive
    from lcmr_xr.scaleout.sweep import _identify_block

    arc = open_archive(path)
    block = arc.isel(experiment=slice(0, per_task)).compute()
    arc.close()
    one = block.isel(experiment=0)
    identify(one, window=WINDOW, errors="ignore")  # warm-up (imports, caches)
    out = {"data_mb": one[["r", "u", "y"]].nbytes / 1e6, "block_data_mb": block[["r", "u", "y"]].nbytes / 1e6}
    for key, run in (("identify_mb", lambda: identify(one, window=WINDOW, errors="ignore")),
                     ("task_mb", lambda: _identify_block(block, window=WINDOW))):
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        result = run()
        out[key] = (tracemalloc.get_traced_memory()[1] - base) / 1e6
        tracemalloc.stop()
        del result
    return out


def _in_fresh_process(fn, *args, environ=None):
    """``fn(*args)`` in a new (spawned) process with ``environ`` added to its environment."""
    import multiprocessing as mp
    from concurrent.futures import ProcessPoolExecutor

    saved = dict(os.environ)
    os.environ.update(environ or {})
    try:
        with ProcessPoolExecutor(1, mp_context=mp.get_context("spawn")) as pool:
            return pool.submit(fn, *args).result()
    finally:
        os.environ.clear()
        os.environ.update(saved)


def throughput(path: Path, n: int, tmp: Path) -> None:
    from distributed import Client, LocalCluster

    from lcmr_xr.identification import identify
    from lcmr_xr.scaleout import local_cluster, open_archive, sweep_to_disk

    arc = open_archive(path).isel(experiment=slice(0, n))
    exps = [arc.isel(experiment=i).compute() for i in range(n)]
    identify(exps[0], window=WINDOW, errors="ignore")
    t0 = time.perf_counter()
    for exp in exps:
        identify(exp, window=WINDOW, errors="ignore")
    plain = n / (time.perf_counter() - t0)
    t0 = time.perf_counter()
    sweep_to_disk(arc, tmp / "one.nc", window=[WINDOW], scheduler="synchronous", progress=False)
    one_core = n / (time.perf_counter() - t0)
    print(f"identify {n} experiments (window {WINDOW}, 3-3-3, P_std), experiments per second:")
    print(f"  plain identify calls, this process (default threads): {plain:6.2f}")
    print(f"  sweep_to_disk, one core (synchronous)               : {one_core:6.2f}")
    workers = (("LocalCluster, distributed defaults", lambda: LocalCluster(
        n_workers=2, threads_per_worker=1, dashboard_address=None, silence_logs=50)),
        ("lcmr_xr.scaleout.local_cluster      ", lambda: local_cluster(2, silence_logs=50)))
    per_task = {}
    for name, make in workers:
        with make() as cluster, Client(cluster) as client:
            client.run(lambda: __import__("lcmr_xr.identification"))
            t0 = time.perf_counter()
            sweep_to_disk(arc, tmp / "two.nc", window=[WINDOW], client=client, progress=False,
                          overwrite=True)
            rate = n / (time.perf_counter() - t0)
            first = sorted(client.scheduler_info()["workers"])[0]  # one worker: the other idles
            per_task[name] = client.run(timed_identify, str(path), workers=[first])[first]
        print(f"  sweep_to_disk, 2 workers, {name}: {rate:6.2f}")
    threads = {k: "1" for k in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")}
    plain_task = _in_fresh_process(timed_identify, str(path), environ=threads)
    print("one identify call, best of 3 (ratio to a plain process with the workers' 1 BLAS thread):")
    print(f"  plain process                       : {plain_task:6.3f} s")
    for name, seconds in per_task.items():
        print(f"  worker of {name}: {seconds:6.3f} s ({seconds / plain_task:4.2f}x; goal <= 1.2x)")
    arc.close()


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[100, 1600, 10000],
                    help="archive sizes (experiments) to open (default 100 1600 10000)")
    ap.add_argument("--files-max", type=int, default=1600,
                    help="largest directory archive to write and open (default 1600)")
    ap.add_argument("--identify", type=int, default=16, help="experiments identified per throughput run")
    ap.add_argument("--per-task", type=int, default=8, help="experiments per task of the memory run")
    ap.add_argument("--skip-throughput", action="store_true", help="skip parts 4 and 5")
    ap.add_argument("--quick", action="store_true", help="sizes 20 100, 4 experiments identified")
    args = ap.parse_args(argv)
    if args.quick:
        args.sizes, args.identify, args.files_max = [20, 100], 4, 100
    from lcmr_xr.scaleout import append_to_archive, open_archive, sweep

    base = _base()
    tmp = Path(tempfile.mkdtemp(prefix="lcmr-archive-bench-"))
    try:
        print(f"open_archive (fresh process; N = {N}, {base[['r', 'u', 'y']].nbytes / 1e3:.0f} kB per experiment):")
        print(f"  {'experiments':>11} | {'consolidated':>22} | {'directory of files':>22}")
        largest = None
        for n in sorted(args.sizes):
            t0 = time.perf_counter()
            make_consolidated(tmp / f"c{n}.nc", n, base)
            made = time.perf_counter() - t0
            c = time_open(tmp / f"c{n}.nc")
            row = f"  {n:>11} | {c['seconds']:7.3f} s {c['mb']:+7.1f} MB | "
            if n <= args.files_max:
                make_directory(tmp / f"d{n}", n, base)
                d = time_open(tmp / f"d{n}")
                row += f"{d['seconds']:7.2f} s {d['mb']:+7.1f} MB"
                shutil.rmtree(tmp / f"d{n}")
            else:
                row += "  (skipped: --files-max)"
            print(row + f"   [consolidated written in {made:.1f} s]")
            if largest is not None:
                (tmp / f"c{largest}.nc").unlink()
            largest = n

        path = tmp / f"c{largest}.nc"
        times = []
        for i in range(5):
            exp = base.assign_coords(experiment=f"new{i}").assign_attrs(seed=-1 - i)
            t0 = time.perf_counter()
            append_to_archive(exp, path)
            times.append(time.perf_counter() - t0)
        print(f"append_to_archive into {largest} experiments: median {np.median(times) * 1e3:.0f} ms "
              f"(min {min(times) * 1e3:.0f}, max {max(times) * 1e3:.0f}; goal < 100 ms)")

        arc = open_archive(path)
        built = {}
        for n in (1, arc.sizes["experiment"]):  # 1: what the settings checks cost alone
            t0 = time.perf_counter()
            lazy = sweep(arc.isel(experiment=slice(0, n)), window=[20, 30, 40])
            built[n] = time.perf_counter() - t0
        print(f"sweep graph of {n} experiments x 3 windows: {built[n]:.2f} s, "
              f"{len(lazy.__dask_graph__())} tasks, of which {built[1]:.2f} s are the fixed cost "
              "(settings checks and result templates, as for 1 experiment); goal < 5 s")
        arc.close()
        del lazy

        if not args.skip_throughput:
            throughput(path, args.identify, tmp)
            mem = _in_fresh_process(task_memory, str(path), args.per_task)
            bound = 10 * mem["data_mb"] + 100
            print(f"peak memory (tracemalloc) with P_std, data {mem['data_mb']:.3f} MB per experiment:")
            print(f"  one identify: {mem['identify_mb']:.1f} MB; one task of {args.per_task} "
                  f"experiments ({mem['block_data_mb']:.2f} MB of data): {mem['task_mb']:.1f} MB "
                  f"(goal: 10 x data + 100 MB = {bound:.0f} MB for one experiment)")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    main()
