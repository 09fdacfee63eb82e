"""``sweep_to_disk``: run a sweep task by task, writing each result to disk as it finishes.

Why not ``sweep(...).compute()`` then ``save``: the result of 10 000 experiments is about
11.5 GB per setting with covariance, which no client can hold, and a sweep of hours must
not lose what it computed when a machine or a worker dies.  Here every task (one setting,
one chunk of experiments) is written atomically to its own part file in
``.OUTPUT.parts/`` as soon as it finishes; a rerun with the same arguments skips the parts
already there.  When every part exists they are copied, one chunk at a time, into the
single result file ``OUTPUT`` (the same dataset ``sweep(...).compute()`` returns) and the
parts are removed.  Progress (experiments per second, time left) is reported while it runs.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import sys
import time
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv

__all__ = ["sweep_to_disk"]

_MANIFEST = "manifest.json"


def parts_directory(output: Path) -> Path:
    """Where the part files of ``output`` are kept until the sweep completes."""
    return output.with_name(f".{output.name}{cv.ARCHIVE_PARTS_SUFFIX}")


def _pieces(lazy: xr.Dataset, chunks: tuple[int, ...]):
    """``[(name, (i_method, i_degrees, i_window), (start, stop))]`` of every task."""
    bounds = np.concatenate([[0], np.cumsum(chunks)]).astype(int)
    out = []
    for im in range(lazy.sizes["method"]):
        for idg in range(lazy.sizes["degrees"]):
            for iw in range(lazy.sizes["window"]):
                for a, b in zip(bounds[:-1], bounds[1:]):
                    out.append((f"{im}_{idg}_{iw}_{a:08d}_{b:08d}.nc", (im, idg, iw), (int(a), int(b))))
    return out


def _manifest(lazy: xr.Dataset, chunks, closed_loop: str, covariance: bool) -> dict:
    labels = "\n".join(map(str, lazy[cv.EXPERIMENT].values.tolist()))
    return {
        "method": [str(v) for v in lazy["method"].values],
        "degrees": [str(v) for v in lazy["degrees"].values],
        "window": [int(v) for v in lazy["window"].values],
        "closed_loop": closed_loop,
        "covariance": bool(covariance),
        "chunks": [int(c) for c in chunks],
        "experiments": hashlib.sha1(labels.encode()).hexdigest(),
        # only when instrumented: the parts of least-squares sweeps keep their old manifest
        **({"denominator_fit": [[str(v) for v in row] for row in lazy["denominator_fit"].values]}
           if (lazy["denominator_fit"] == "iv").any() else {}),
    }


def _check_parts(parts: Path, manifest: dict) -> None:
    """Create the parts directory, or check that the parts in it are of this very sweep."""
    from lcmr_xr.io._atomic import atomic_write

    path = parts / _MANIFEST
    if path.is_file():
        found = json.loads(path.read_text())
        if found != manifest:
            diff = sorted(k for k in manifest if found.get(k) != manifest[k])
            raise ValueError(
                f"{parts} holds the parts of another sweep (different {diff}); finish that sweep "
                "with its own arguments, or remove the directory to start this one."
            )
        return
    parts.mkdir(exist_ok=True)
    atomic_write(path, lambda tmp: Path(tmp).write_text(json.dumps(manifest, indent=1)))


class _Progress:
    """Progress in experiments per second (``progress=True``) or a callback.

    On a terminal one bar is redrawn at most once a second; otherwise (logs, pipes, CI)
    a plain line is written every 10 % (as :func:`lcmr_xr._cli_support.progress` does),
    so nothing relies on carriage returns.
    """

    def __init__(self, progress, total: int, done: int, out=None):
        from lcmr_xr._cli_support import _is_terminal

        self.callback = progress if callable(progress) else None
        self.show = progress is True
        self.total, self.done, self.start_done = total, done, done
        self.t0 = time.perf_counter()
        self.last = -np.inf
        self.out = out or sys.stderr
        self.terminal = _is_terminal(self.out)
        self.next_percent = 0
        if self.show and done:
            print(f"resuming: {done} of {total} experiment-settings already on disk", file=self.out)

    def rate(self) -> float:
        elapsed = time.perf_counter() - self.t0
        return (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0

    def update(self, n: int) -> None:
        self.done += n
        if self.callback is not None:
            self.callback(self.done, self.total, self.rate())
        if not self.show:
            return
        frac = self.done / self.total if self.total else 1.0
        final = self.done >= self.total
        now = time.perf_counter()
        if self.terminal and now - self.last < 1.0 and not final:
            return
        if not self.terminal and int(100 * frac) < self.next_percent and not final:
            return
        self.last = now
        self.next_percent = (int(100 * frac) // 10 + 1) * 10
        rate = self.rate()
        left = (self.total - self.done) / rate if rate > 0 else float("inf")
        text = (f"{100 * frac:3.0f}% Completed | {self.done}/{self.total} experiment-settings | "
                f"{rate:.2f} experiments/s | {left:.0f} s left")
        if self.terminal:
            bar = "#" * int(round(40 * frac))
            print(f"\r[{bar:<40}] | {text}", end="\n" if final else "", file=self.out, flush=True)
        else:
            print(text, file=self.out, flush=True)


def _read_strings(path: Path, name: str) -> np.ndarray:
    import netCDF4

    with netCDF4.Dataset(path) as nc:
        return np.asarray(nc[name][:], dtype=object)


def _run_local(tasks, workers: int, scheduler: str):
    """Yield ``(index, result)`` as tasks finish, on a pool of threads in this process.

    ``scheduler="processes"``: each thread hands its task to dask's process pool.
    """
    from concurrent.futures import ThreadPoolExecutor, as_completed

    import dask

    if scheduler == "synchronous":
        workers = 1
    inner = "processes" if scheduler == "processes" else "synchronous"

    def run(task):
        return dask.compute(task, scheduler=inner)[0]

    pool = ThreadPoolExecutor(max_workers=workers)
    try:
        futures = {pool.submit(run, task): i for i, task in enumerate(tasks)}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _run_client(tasks, client):
    """Yield ``(index, result)`` as tasks finish on a ``distributed`` cluster."""
    from distributed import as_completed

    futures = client.compute(tasks)
    index = {fut.key: i for i, fut in enumerate(futures)}
    try:
        for fut, result in as_completed(futures, with_results=True):
            yield index[fut.key], result
            fut.release()
    finally:
        client.cancel(futures)


def sweep_to_disk(experiments: xr.Dataset, output, *, window=(30,), degrees=None, method=("lrm",),
                  closed_loop: str = "indirect", covariance: bool = True,
                  experiments_per_task: int | None = None, client=None, workers: int | None = None,
                  scheduler: str = "threads", progress=True, overwrite: bool = False,
                  denominator=None) -> Path:
    """Run a sweep task by task, streaming each result to disk; resumable after a crash.

    Parameters
    ----------
    experiments : xarray.Dataset
        Experiments with an ``experiment`` dim, e.g. from
        :func:`lcmr_xr.scaleout.open_archive`.
    output : str or os.PathLike
        The result NetCDF file: the dataset :func:`lcmr_xr.scaleout.sweep` returns,
        computed.  Parts are kept in ``.OUTPUT.parts/`` next to it until it is written.
    window, degrees, method, closed_loop, covariance, experiments_per_task, denominator
        As for :func:`lcmr_xr.scaleout.sweep` (one task per setting and chunk).
    client : distributed.Client, optional
        Run the tasks on this cluster (local or remote); results travel to this process
        and are written here, so the workers need no access to ``output``.  Default: a
        pool of ``workers`` threads in this process.
    workers : int, optional
        Tasks run at once in this process (default: the number of CPUs); ignored with
        ``client``.
    scheduler : {"threads", "processes", "synchronous"}, default "threads"
        Without ``client``: run the tasks on threads, on dask's process pool, or one at a
        time in this thread.
    progress : bool or callable, default True
        ``True``: a progress bar on stderr with experiments per second and the time left;
        a callable is called as ``progress(done, total, experiments_per_second)`` after
        every task (``done`` counts experiment-settings, parts of a previous run included).
    overwrite : bool, default False
        Replace an existing ``output`` (otherwise it is refused).

    Returns
    -------
    pathlib.Path
        ``output``.

    Raises
    ------
    FileExistsError
        ``output`` exists and ``overwrite`` is False.
    ValueError
        Invalid settings (before anything runs), no ``experiment`` dim, an ``output`` that
        is the archive ``experiments`` were opened from or lies inside it, or parts of a
        different sweep in the parts directory.

    Notes
    -----
    A crash (of this process, a worker, the machine) keeps every finished part; run the
    same call again and only the missing tasks run.  Memory of this process: one task's
    result at a time while streaming, one chunk at a time while assembling the result.

    Examples
    --------
    >>> import tempfile, os, xarray as xr
    >>> from lcmr_xr import hdd
    >>> exps = xr.concat([hdd.simulate(n_samples=1200, seed=s) for s in (0, 1)], "experiment")
    >>> with tempfile.TemporaryDirectory() as d:
    ...     out = sweep_to_disk(exps, os.path.join(d, "sweep.nc"), window=[20, 30], progress=False)
    ...     dict(xr.open_dataset(out).P.sizes)
    {'method': 1, 'degrees': 1, 'window': 2, 'experiment': 2, 'frequency': 601, 'output': 1, 'input': 2}
    """
    import os

    import dask

    from lcmr_xr.io import open_dataset, save
    from lcmr_xr.io._guards import check_outputs, same_or_inside
    from lcmr_xr.scaleout import sweep as sweep_lazily
    from lcmr_xr.settings import degrees_label
    from lcmr_xr.scaleout.sweep import (ERROR_VAR, SETTING_DIMS, _chunked, _identify_block,
                                        sweep_settings)

    if scheduler not in ("threads", "processes", "synchronous"):
        raise ValueError(f"scheduler must be 'threads', 'processes' or 'synchronous', got "
                         f"{scheduler!r}; for a cluster pass client=distributed.Client(...).")
    output = Path(output)
    if not isinstance(experiments, xr.Dataset) or cv.EXPERIMENT not in experiments.dims:
        raise ValueError("sweep_to_disk needs experiments with an 'experiment' dim (e.g. from "
                         "open_archive); for one experiment use sweep(...).compute().")
    source = experiments.encoding.get("source")
    # never write over the archive or inside it: the result, and the parts next to it
    check_outputs({"output": (output, None)}, inputs=[source] if source else [],
                  overwrite=overwrite, overwrite_hint="pass overwrite=True (--overwrite) to replace it")
    if source and same_or_inside(parts_directory(output), source):
        raise ValueError(f"refusing to keep the parts of {output} in {parts_directory(output)}: it is "
                         f"inside the archive {source}; choose another output path.")
    lazy = sweep_lazily(experiments, window=window, degrees=degrees, method=method,
                    closed_loop=closed_loop, covariance=covariance,
                    experiments_per_task=experiments_per_task, denominator=denominator)
    # the settings as identify takes them (LPM defaults, checked), keyed as the lazy result's coords
    checked = {(m, degrees_label(d), w): st for (m, d, w), st in
               sweep_settings(window=window, degrees=degrees, method=method, closed_loop=closed_loop,
                              covariance=covariance, experiments=experiments,
                              denominator=denominator).items()}
    ds = _chunked(experiments, experiments_per_task)
    chunks = ds["r"].chunks[ds["r"].get_axis_num(cv.EXPERIMENT)]
    parts = parts_directory(output)
    _check_parts(parts, _manifest(lazy, chunks, closed_loop, covariance))
    pieces = _pieces(lazy, chunks)
    todo = [p for p in pieces if not (parts / p[0]).is_file()]
    total = len(pieces) and sum(b - a for _, _, (a, b) in pieces)
    bar = _Progress(progress, total, total - sum(b - a for _, _, (a, b) in todo))

    tasks = []
    for _, (im, idg, iw), (a, b) in todo:
        st = checked[str(lazy["method"].values[im]), str(lazy["degrees"].values[idg]),
                     int(lazy["window"].values[iw])]
        settings = dict(method=st.method, window=st.window, degrees=st.degrees,
                        closed_loop=st.closed_loop, covariance=st.covariance, source=source,
                        denominator=denominator)
        block = ds.isel({cv.EXPERIMENT: slice(a, b)})
        tasks.append(dask.delayed(_identify_block, pure=True)(block, **settings))
    finished = (_run_client(tasks, client) if client is not None
                else _run_local(tasks, workers or os.cpu_count() or 1, scheduler))
    for i, result in finished:
        name, _, (a, b) = todo[i]
        save(result, parts / name)
        bar.update(b - a)

    # Every part is on disk: assemble the result chunk by chunk (lazily opened parts).
    opened = {name: open_dataset(parts / name, chunks={}) for name, _, _ in pieces}
    try:
        nested = []
        for im in range(lazy.sizes["method"]):
            per_degree = []
            for idg in range(lazy.sizes["degrees"]):
                per_window = []
                for iw in range(lazy.sizes["window"]):
                    blocks = [opened[n] for n, key, _ in pieces if key == (im, idg, iw)]
                    per_window.append(xr.concat(blocks, cv.EXPERIMENT, data_vars="all",
                                                coords="minimal", compat="override", join="exact",
                                                combine_attrs="override"))
                per_degree.append(per_window)
            nested.append(per_degree)
        combined = xr.combine_nested(nested, concat_dim=list(SETTING_DIMS), data_vars="all",
                                     coords="minimal", compat="override", join="exact",
                                     combine_attrs="override")
        result = lazy.copy()
        for name in lazy.data_vars:
            result[name] = (combined[name].transpose(*lazy[name].dims)
                            .assign_attrs(lazy[name].attrs).variable)
        # the messages are small, and read lazily h5netcdf's variable-length strings would
        # come back cut to dask's guessed width
        # (pieces run setting by setting, experiments in order within each)
        errors = np.concatenate([_read_strings(parts / n, ERROR_VAR) for n, _, _ in pieces])
        result[ERROR_VAR] = (lazy[ERROR_VAR].dims, errors.reshape(lazy[ERROR_VAR].shape),
                             lazy[ERROR_VAR].attrs)
        save(result, output)
    finally:
        for part in opened.values():
            part.close()
    shutil.rmtree(parts)
    return output
