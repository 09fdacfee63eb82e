"""``sweep_to_disk``: run a sweep task by task, writing each result to disk as it finishes.

Why not ``sweep(...).compute()`` then ``save``: the result of 10 000 experiments is about
11.5 GB per setting with covariance, which no client can hold, and a sweep of hours must
not lose what it computed when a machine or a worker dies.  Here every task (one setting,
one chunk of experiments) is written atomically to its own part file in
``.OUTPUT.parts/`` as soon as it finishes; a rerun with the same arguments skips the parts
already there.  When every part exists they are copied, one part at a time, into the
single result file ``OUTPUT`` (the same dataset ``sweep(...).compute()`` returns) and the
parts are removed.  Progress (experiments per second, time left) is reported while it runs.

Where the parts are written: by the task itself, wherever it runs (a thread, a process
of dask's pool, a ``distributed`` worker), when it sees the parts directory of this very
run (``manifest.json`` with this run's ``id``: a shared file system); it then returns only
the part's name.  A worker that cannot see it (a remote cluster without the file system)
returns the result, and this process writes it.  Why: a result is 1.27 MB per experiment
with covariance; sending each to the client and writing it there made the client the
bottleneck (measured 4.3 experiments/s against 11.6 on the same two workers).
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
import sys
import threading
import time
import uuid
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.scaleout.sweep import SETTING_DIMS

__all__ = ["sweep_to_disk"]

_MANIFEST = "manifest.json"
#: One part written at a time per process: netCDF4 (HDF5) crashes when two threads of a
#: process create files at once (measured: a segfault with two task threads).
_WRITE_LOCK = threading.Lock()


def parts_directory(output: Path) -> Path:
    """Where the part files of ``output`` are kept until the sweep completes."""
    return output.with_name(f".{output.name}{cv.ARCHIVE_PARTS_SUFFIX}")


def check_output_name(output, what: str = "output") -> Path:
    """Refuse a sweep result name that does not end in a NetCDF suffix, as
    :func:`lcmr_xr.io.save` refuses it, and say how to resume an interrupted sweep whose
    parts wait under that name.

    A sweep started under such a name (before the rule came in) left its finished parts in
    ``.NAME.parts/`` next to it.  The parts are kept by the sweep's arguments (the
    directory's ``manifest.json``, the part files named by setting and experiments), not by
    the output's name, so renaming the directory along with the output resumes it: the
    message names both new names.

    Parameters
    ----------
    output : str or os.PathLike
        The result file about to be written.
    what : str, default "output"
        How the message names it (``"-o"`` on the command line).

    Returns
    -------
    pathlib.Path
        ``output``.

    Raises
    ------
    ValueError
        The name does not end in ``.nc``, ``.nc4`` or ``.netcdf`` (any case); when
        ``.NAME.parts/`` holds the parts of a sweep, the message names it and the rename.

    Examples
    --------
    >>> check_output_name("result.nc").name
    'result.nc'
    """
    from lcmr_xr.io._guards import NETCDF_SUFFIXES, check_suffix

    output = Path(output)
    try:
        return check_suffix(output, NETCDF_SUFFIXES, what)
    except ValueError as err:
        parts = parts_directory(output)
        if not (parts / _MANIFEST).is_file():
            raise
        renamed = output.with_name((output.stem or "result") + NETCDF_SUFFIXES[0])
        raise ValueError(
            f"{err} {parts} holds the finished parts of a sweep to {output.name} that did not "
            f"complete: to resume it, rename that directory to {parts_directory(renamed)} and "
            f"run the same sweep again with the output {renamed} (the parts are matched by "
            "the sweep's arguments, not by the output's name); or remove the directory to "
            "start afresh."
        ) from None


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


def _manifest(lazy: xr.Dataset, chunks, closed_loop: str, covariance: bool, variables=None) -> dict:
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
        **({"variables": list(variables)} if variables is not None else {}),
    }


def _check_parts(parts: Path, manifest: dict) -> str:
    """Create the parts directory, or check that the parts in it are of this very sweep.

    Returns the run's ``id`` (kept in the manifest, not compared): the tasks write their
    parts only where they find it (see the module's notes).
    """
    from lcmr_xr.io._atomic import atomic_write

    path = parts / _MANIFEST
    if path.is_file():
        found = json.loads(path.read_text())
        run_id = found.pop("id", None)
        if found != manifest:
            diff = sorted(k for k in manifest if found.get(k) != manifest[k])
            raise ValueError(
                f"{parts} holds the parts of another sweep (different {diff}); finish that sweep "
                "with its own arguments, or remove the directory to start this one."
            )
        if run_id is not None:
            return run_id
    if parts.exists() and not parts.is_dir():
        raise FileExistsError(f"{parts} (where the sweep keeps its parts) exists and is a file; "
                              "move it away, or choose another output path.")
    if parts.is_dir() and not path.is_file():
        # not made by a sweep (made by one, it holds the manifest, written first, or at most
        # the manifest's temporary of an interrupted start): the sweep removes the directory
        # when done, so it would delete these files
        foreign = sorted(p.name for p in parts.iterdir()
                         if not (p.name.startswith("." + _MANIFEST + ".") and p.name.endswith(".tmp")))
        if foreign:
            shown = ", ".join(foreign[:5]) + (", ..." if len(foreign) > 5 else "")
            raise FileExistsError(
                f"{parts} (where the sweep keeps its parts, and which it removes when done) "
                f"exists and holds files of no sweep ({shown}); move them away, or choose "
                "another output path.")
    run_id = uuid.uuid4().hex
    parts.mkdir(exist_ok=True)
    atomic_write(path, lambda tmp: Path(tmp).write_text(
        json.dumps({**manifest, "id": run_id}, indent=1)))
    return run_id


class _PartTask:
    """What one task of :func:`sweep_to_disk` writes: experiments ``[start, stop)``.

    A plain class, not a tuple: dask looks inside the tuples of a task for keys."""

    __slots__ = ("start", "stop", "parts", "name", "run_id", "keep", "settings")

    def __init__(self, start, stop, parts, name, run_id, keep, settings):
        self.start, self.stop, self.parts, self.name = int(start), int(stop), parts, name
        self.run_id, self.keep, self.settings = run_id, keep, settings

    def __dask_tokenize__(self):
        return (self.start, self.stop, self.parts, self.name, self.run_id, self.keep,
                sorted(self.settings.items()))


class _Frame:
    """The experiments without their data (coordinates, metadata) and, per data variable
    along ``experiment``, its name, dims and attributes: what a task adds its chunks to."""

    __slots__ = ("dataset", "variables")

    def __init__(self, dataset, variables):
        self.dataset, self.variables = dataset, variables


def _part_from_chunks(frame: _Frame, task: _PartTask, *chunks):
    """A task of :func:`sweep_to_disk` built by :func:`_part_tasks`: the block of
    experiments from the shared ``frame`` and its data ``chunks``, then
    :func:`_identify_to_part`."""
    block = frame.dataset
    if cv.EXPERIMENT in block.dims:  # experiments without labels or metadata: nothing to cut
        block = block.isel({cv.EXPERIMENT: slice(task.start, task.stop)})
    block = block.assign(
        {n: xr.Variable(dims, data, attrs) for (n, dims, attrs), data in zip(frame.variables, chunks)})
    return _identify_to_part(block, task.parts, task.name, task.run_id, task.keep, **task.settings)


def _part_tasks(ds: xr.Dataset, chunks, specs: list) -> list:
    """One delayed task per :class:`_PartTask` of ``specs``, on the dask data of ``ds``.

    The graph is written directly: each task reads its chunk of every data variable along
    ``experiment`` and one object shared by all tasks, the experiments without their data
    (coordinates and metadata, loaded once here).  Why not ``dask.delayed`` of
    ``ds.isel(...)`` per block: that cost about 34 ms per block in this process (``isel``
    and dask's traversal and culling of the whole archive graph for every block; measured
    on a sweep of 23 141 experiments in 2 893 blocks: 99 s and 280 MB of this process's
    memory before the first task could start; 9 s and 120 MB this way).  Data not chunked along ``experiment`` alone take that path.
    """
    import dask
    from dask.base import tokenize
    from dask.delayed import Delayed
    from dask.highlevelgraph import HighLevelGraph

    names = [n for n in ds.data_vars if cv.EXPERIMENT in ds[n].dims]
    keys, arrays = {}, []
    for n in names:
        var = ds[n].variable
        axis = var.get_axis_num(cv.EXPERIMENT) if var.chunks is not None else None
        if axis is None or tuple(var.chunks[axis]) != tuple(chunks) or any(
                len(c) > 1 for i, c in enumerate(var.chunks) if i != axis):
            return [dask.delayed(_identify_to_part, pure=True)(
                ds.isel({cv.EXPERIMENT: slice(t.start, t.stop)}), t.parts, t.name, t.run_id,
                t.keep, **t.settings) for t in specs]
        keys[n] = [(var.data.name,) + tuple(j if d == axis else 0 for d in range(var.ndim))
                   for j in range(len(chunks))]
        arrays.append(var.data)
    frame = _Frame(ds.drop_vars(names).compute(),
                   tuple((n, ds[n].dims, dict(ds[n].attrs)) for n in names))
    token = tokenize(frame.dataset, [a.name for a in arrays], specs)
    frame_key, layer_name = f"sweep-frame-{token}", f"sweep-part-{token}"
    starts = np.concatenate([[0], np.cumsum(chunks)]).astype(int)
    block = {int(a): i for i, a in enumerate(starts[:-1])}
    layer = {frame_key: frame}
    for i, task in enumerate(specs):
        j = block[task.start]
        layer[(layer_name, i)] = (_part_from_chunks, frame_key, task, *[keys[n][j] for n in names])
    graph = HighLevelGraph.from_collections(layer_name, layer, dependencies=arrays)
    return [Delayed((layer_name, i), graph, layer=layer_name) for i in range(len(specs))]


def _kept_variables(lazy: xr.Dataset, variables) -> tuple[str, ...] | None:
    """The checked ``variables=`` of :func:`sweep_to_disk` plus ``experiment_error``, in the
    sweep's order (None: all)."""
    from lcmr_xr.scaleout.sweep import ERROR_VAR

    if variables is None:
        return None
    asked = [variables] if isinstance(variables, str) else list(variables)
    if not asked or not all(isinstance(v, str) for v in asked):
        raise ValueError(f"variables must be names of result variables (e.g. ['P', 'P_std', "
                         f"'P_flag']), got {variables!r}.")
    unknown = sorted(set(asked) - set(lazy.data_vars))
    if unknown:
        raise ValueError(f"variables {unknown} are not in this sweep's result; choose from "
                         f"{sorted(lazy.data_vars)}.")
    return tuple(v for v in lazy.data_vars if v in asked or v == ERROR_VAR)


def _sees_parts(parts: str, run_id: str) -> bool:
    """Whether this process sees the parts directory of the run ``run_id``."""
    try:
        return json.loads((Path(parts) / _MANIFEST).read_text()).get("id") == run_id
    except (OSError, ValueError):
        return False


def _identify_to_part(block, parts: str, name: str, run_id: str, keep=None, **settings):
    """One task of ``sweep_to_disk``: identify ``block`` and write the part file ``name``
    (the data variables ``keep`` only, when given).

    Returns ``name`` once the part is on disk, or the arrays themselves where this process
    cannot see the parts directory (the caller writes them then).
    """
    from lcmr_xr.scaleout.sweep import _block_arrays

    arrays = _block_arrays(block, keep=keep, **settings)
    if not _sees_parts(parts, run_id):
        return arrays
    with _WRITE_LOCK:
        _write_part(Path(parts) / name, arrays)
    return name


def _write_part(path: Path, arrays: dict) -> None:
    """Write ``{name: (dims, values)}`` to the part file ``path`` (atomically) as
    :func:`_read_part` reads it: netCDF4 directly, no coordinates or attributes.

    Why not :func:`lcmr_xr.io.save` of the labelled block: the part only carries the
    values (the result takes its labels from the lazy sweep), and xarray's writer (its
    encoding of 19 variables and their coordinates) cost 5.3-6.0 ms CPU per experiment
    of every variable, this one 2.6 ms (measured, 8 and 16 per task).  The encodings are
    those ``save`` writes for these types, so :func:`_read_part` reads either: complex as the
    ``auto_complex`` compound, bool as int8 with the attribute ``dtype = "bool"``, str as
    variable-length strings; nothing is pre-filled (every value is written).
    """
    import netCDF4

    from lcmr_xr.io._atomic import atomic_write

    def write(tmp):
        with netCDF4.Dataset(tmp, "w", format="NETCDF4", auto_complex=True) as nc:
            for dims, values in arrays.values():
                for d, k in zip(dims, values.shape):
                    if d not in nc.dimensions:
                        nc.createDimension(d, k)
            for name, (dims, values) in arrays.items():
                if values.dtype == bool:
                    var = nc.createVariable(name, np.int8, dims, fill_value=False)
                    var.setncattr("dtype", "bool")
                    values = values.view(np.int8)
                elif values.dtype == object:
                    var = nc.createVariable(name, str, dims)
                else:
                    var = nc.createVariable(name, values.dtype, dims, fill_value=False)
                var.set_auto_maskandscale(False)
                var[...] = values

    atomic_write(path, write)


def _read_part(path: Path, names: list[str], dims: dict, dtypes: dict) -> dict:
    """The data variables ``names`` of one part file, in memory, each with the dims
    ``dims[name]`` (the sweep's setting dims added with size one) and type ``dtypes[name]``.

    Read with netCDF4 directly (one open, ~5 ms): the parts hold only what ``save``
    writes for a sweep result (complex, NaN-filled floats, bools as int8, strings); any
    other encoding is decoded by xarray (an eager open costs ~60 ms per part).
    """
    import netCDF4

    out = {}
    with netCDF4.Dataset(path, auto_complex=True) as nc:
        nc.set_auto_maskandscale(False)
        for name in names:
            var = nc[name]
            if not _plain(var, np.dtype(dtypes[name])):
                return _read_part_xarray(path, names, dims)
            values = np.asarray(var[...]).astype(dtypes[name], copy=False)
            out[name] = _in_order(values, var.dimensions, dims[name])
    return out


def _plain(var, dtype: np.dtype) -> bool:
    """Whether the raw values of the netCDF4 variable ``var`` are its decoded values."""
    attrs = set(var.ncattrs())
    if attrs & {"scale_factor", "add_offset", "missing_value", "calendar"}:
        return False
    if "_FillValue" in attrs and not (dtype.kind in "fc" and np.isnan(var.getncattr("_FillValue"))):
        return False
    if dtype == object:
        return var.dtype is str
    if dtype == bool:
        return var.dtype == np.int8 and "dtype" in attrs and var.getncattr("dtype") == "bool"
    return var.dtype == dtype and "dtype" not in attrs


def _read_part_xarray(path: Path, names: list[str], dims: dict) -> dict:
    from lcmr_xr.io import open_dataset

    part = open_dataset(path)
    return {name: _in_order(part[name].values, part[name].dims, dims[name]) for name in names}


def _in_order(values: np.ndarray, have, want) -> np.ndarray:
    """``values`` (dims ``have``) with the dims ``want``: the missing ones (the sweep's
    setting dims, of size one in a part) added, then transposed."""
    have = list(have) + [d for d in want if d not in have]
    values = values.reshape(values.shape + (1,) * (len(have) - values.ndim))
    return np.transpose(values, [have.index(d) for d in want])


def _assembled(lazy: xr.Dataset, parts: Path, pieces) -> xr.Dataset:
    """The sweep's result with every data variable read from the part files.

    Each numeric variable is a dask array with one block per part, built as a graph
    directly (``from_delayed`` and ``concatenate`` per block took ~60 ms per part); all
    blocks of a part come from one read of that part (one task), so writing the result
    reads every part once and holds a few parts at a time.  String variables (the
    experiments' error messages: small) are read at once.
    """
    import operator

    import dask.array as dsa
    from dask.base import tokenize
    from dask.highlevelgraph import HighLevelGraph

    strings = [name for name in lazy.data_vars if lazy[name].dtype == object]
    names = [name for name in lazy.data_vars if name not in strings]
    dims = {name: lazy[name].dims for name in lazy.data_vars}
    dtypes = {name: lazy[name].dtype for name in lazy.data_vars}
    files = [parts / file for file, _, _ in pieces]
    token = tokenize([str(f) for f in files], names, os.path.getmtime(files[0]))
    reads_name = f"read-sweep-part-{token}"
    reads = {(reads_name, i): (_read_part, f, names, dims, dtypes) for i, f in enumerate(files)}
    bounds = sorted({ab for _, _, ab in pieces})
    exp_block = {ab: i for i, ab in enumerate(bounds)}
    out = lazy.copy()
    for name in names:
        var = lazy[name]
        array_name = f"sweep-{name}-{token}"
        layer = {}
        for i, (_, key, ab) in enumerate(pieces):
            index = tuple(key[SETTING_DIMS.index(d)] if d in SETTING_DIMS
                          else exp_block[ab] if d == cv.EXPERIMENT else 0 for d in var.dims)
            layer[(array_name,) + index] = (operator.getitem, (reads_name, i), name)
        chunks = tuple((1,) * n if d in SETTING_DIMS
                       else tuple(b - a for a, b in bounds) if d == cv.EXPERIMENT else (n,)
                       for d, n in var.sizes.items())
        graph = HighLevelGraph({reads_name: reads, array_name: layer},
                               {reads_name: set(), array_name: {reads_name}})
        out[name] = xr.Variable(var.dims, dsa.Array(graph, array_name, chunks, dtype=var.dtype),
                                var.attrs)
    for name in strings:
        var = lazy[name]
        values = np.empty(var.shape, dtype=object)
        for f, (_, key, (a, b)) in zip(files, pieces):
            where = tuple(slice(key[SETTING_DIMS.index(d)], key[SETTING_DIMS.index(d)] + 1)
                          if d in SETTING_DIMS else slice(a, b) if d == cv.EXPERIMENT
                          else slice(None) for d in var.dims)
            values[where] = _read_part(f, [name], dims, dtypes)[name]
        out[name] = xr.Variable(var.dims, values, var.attrs)
    return out


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
                  denominator=None, variables=None) -> Path:
    """Run a sweep task by task, streaming each result to disk; resumable after a crash.

    Parameters
    ----------
    experiments : xarray.Dataset
        Experiments with an ``experiment`` dim, e.g. from
        :func:`lcmr_xr.scaleout.open_archive`.
    output : str or os.PathLike
        The result NetCDF file (name ending in ``.nc``, ``.nc4`` or ``.netcdf``, checked
        before any work): the dataset :func:`lcmr_xr.scaleout.sweep` returns,
        computed.  Parts are kept in ``.OUTPUT.parts/`` next to it until it is written.
        A name refused for its ending while ``.OUTPUT.parts/`` holds the parts of a sweep
        (started before the rule came in) is refused with the way to resume: rename that
        directory along with the output (:func:`check_output_name`).
    window, degrees, method, closed_loop, covariance, experiments_per_task, denominator
        As for :func:`lcmr_xr.scaleout.sweep` (one task per setting and chunk).
    client : distributed.Client, optional
        Run the tasks on this cluster (local or remote).  A worker that sees the parts
        directory (the same file system) writes its part itself and returns only its
        name; one that does not returns the result, which this process writes, so
        workers need no access to ``output``.  Default: a pool of ``workers`` threads in
        this process.
    workers : int, optional
        Tasks run at once in this process, at least 1 (default: the number of CPUs);
        ignored with ``client``.
    scheduler : {"threads", "processes", "synchronous"}, default "threads"
        Without ``client``: run the tasks on threads, on dask's process pool, or one at a
        time in this thread.
    progress : bool or callable, default True
        ``True``: a progress bar on stderr with experiments per second and the time left;
        a callable is called as ``progress(done, total, experiments_per_second)`` after
        every task (``done`` counts experiment-settings, parts of a previous run included).
    overwrite : bool, default False
        Replace an existing ``output`` (otherwise it is refused).  True or False only.
    variables : sequence of str, optional
        Keep only these variables of the result (``experiment_error`` is always kept),
        e.g. ``["P", "P_std", "P_flag"]``: about 90 kB per HDD experiment (N = 3600) instead of
        1.27 MB, so a sweep of 10 000 experiments writes 0.9 GB per setting instead of
        13 GB.  Default: every variable of :func:`lcmr_xr.scaleout.sweep`.

    Returns
    -------
    pathlib.Path
        ``output``.

    Raises
    ------
    FileExistsError
        ``output`` exists and ``overwrite`` is False; ``.OUTPUT.parts`` exists and was not
        made by a sweep (a file, or a directory of other files: the sweep removes its parts
        directory when done).
    ValueError
        Invalid settings or ``variables`` (before anything runs), no ``experiment`` dim, an ``output`` that
        is the archive ``experiments`` were opened from or lies inside it, or parts of a
        different sweep in the parts directory; a file of the archive that no longer opens
        (removed or moved out after the archive was opened; named).  A damaged file (it
        opens, its values cannot be read) is not raised: its experiment is flagged in
        ``experiment_error`` as :func:`lcmr_xr.scaleout.sweep` flags it (this function
        runs its own computation, never shared with another use of the archive).

    Notes
    -----
    A crash (of this process, a worker, the machine) keeps every finished part; run the
    same call again and only the missing tasks run.  Memory of this process: at most one
    task's result at a time while streaming (none when the tasks write their parts), a
    few parts at a time while assembling the result.

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
    import dask

    from lcmr_xr.io import save
    from lcmr_xr.io._guards import NETCDF_SUFFIXES, check_outputs, same_or_inside
    from lcmr_xr.scaleout import sweep as sweep_lazily
    from lcmr_xr.settings import as_integer, degrees_label
    from lcmr_xr.scaleout.sweep import _chunked, _sources, sweep_settings

    if scheduler not in ("threads", "processes", "synchronous"):
        raise ValueError(f"scheduler must be 'threads', 'processes' or 'synchronous', got "
                         f"{scheduler!r}; for a cluster pass client=distributed.Client(...).")
    if client is not None and not (callable(getattr(client, "compute", None))
                                   and callable(getattr(client, "cancel", None))):
        # an address failed inside ("'str' object has no attribute 'compute'"), parts made
        raise TypeError(f"client must be a distributed.Client, got {client!r} "
                        f"({type(client).__name__}); connect one first, e.g. "
                        "client=distributed.Client('tcp://127.0.0.1:8786').")
    if workers is not None:  # 0 meant "all CPUs", -1 failed in the pool after the parts were made
        workers = as_integer(workers, "workers", minimum=1, example=2)
    if not (isinstance(progress, (bool, np.bool_)) or callable(progress)):
        raise TypeError(f"progress must be True (a bar on stderr), False or a callable "
                        f"progress(done, total, experiments_per_second), got {progress!r} "
                        f"({type(progress).__name__}).")
    progress = bool(progress) if isinstance(progress, np.bool_) else progress
    output = Path(output)
    if not isinstance(experiments, xr.Dataset) or cv.EXPERIMENT not in experiments.dims:
        raise ValueError("sweep_to_disk needs experiments with an 'experiment' dim (e.g. from "
                         "open_archive); for one experiment use sweep(...).compute().")
    source = experiments.encoding.get("source")
    # never write over the archive or inside it: the result, and the parts next to it; the
    # directories the lazy data read count too (astype, isel and the like drop the source)
    archives = list(dict.fromkeys(([source] if source else []) + list(_sources(experiments))))
    check_output_name(output)  # with the way to resume parts left under a refused name
    check_outputs({"output": (output, NETCDF_SUFFIXES)}, inputs=archives,
                  overwrite=overwrite, overwrite_hint="pass overwrite=True (--overwrite) to replace it")
    for archive in archives:
        if same_or_inside(parts_directory(output), archive):
            raise ValueError(f"refusing to keep the parts of {output} in {parts_directory(output)}: "
                             f"it is inside the archive {archive}; choose another output path.")
    lazy = sweep_lazily(experiments, window=window, degrees=degrees, method=method,
                    closed_loop=closed_loop, covariance=covariance,
                    experiments_per_task=experiments_per_task, denominator=denominator)
    keep = _kept_variables(lazy, variables)
    if keep is not None:
        lazy = lazy[list(keep)]
    # the settings as identify takes them (LPM defaults, checked), keyed as the lazy result's coords
    checked = {(m, degrees_label(d), w): st for (m, d, w), st in
               sweep_settings(window=window, degrees=degrees, method=method, closed_loop=closed_loop,
                              covariance=covariance, experiments=experiments,
                              denominator=denominator).items()}
    ds = _chunked(experiments, experiments_per_task)
    places = _sources(ds) or source  # where an experiment's file is (its damage, its name)
    chunks = ds["r"].chunks[ds["r"].get_axis_num(cv.EXPERIMENT)]
    parts = parts_directory(output)
    run_id = _check_parts(parts, _manifest(lazy, chunks, closed_loop, covariance, keep))
    pieces = _pieces(lazy, chunks)
    todo = [p for p in pieces if not (parts / p[0]).is_file()]
    total = len(pieces) and sum(b - a for _, _, (a, b) in pieces)
    bar = _Progress(progress, total, total - sum(b - a for _, _, (a, b) in todo))

    specs = []
    for name, (im, idg, iw), (a, b) in todo:
        st = checked[str(lazy["method"].values[im]), str(lazy["degrees"].values[idg]),
                     int(lazy["window"].values[iw])]
        settings = dict(method=st.method, window=st.window, degrees=st.degrees,
                        closed_loop=st.closed_loop, covariance=st.covariance, source=places,
                        denominator=denominator)
        specs.append(_PartTask(a, b, str(parts.resolve()), name, run_id, keep, settings))
    tasks = _part_tasks(ds, chunks, specs)
    finished = (_run_client(tasks, client) if client is not None
                else _run_local(tasks, workers or os.cpu_count() or 1, scheduler))
    for i, result in finished:
        name, _, (a, b) = todo[i]
        if not isinstance(result, str):  # the worker could not see the parts directory
            with _WRITE_LOCK:
                _write_part(parts / name, result)
        bar.update(b - a)

    # Every part is on disk: write the result, reading each part once (in memory).  In
    # this thread: the parts are on this machine (not necessarily on a cluster's workers),
    # and HDF5 reads of the parts and of the archive's metadata must not overlap (two
    # threads gave "NetCDF: HDF error").
    with dask.config.set(scheduler="synchronous"):
        save(_assembled(lazy, parts, pieces), output)
    shutil.rmtree(parts)
    return output
