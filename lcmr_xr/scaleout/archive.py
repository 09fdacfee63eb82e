"""Archives: a directory with one NetCDF file per experiment, opened as one lazy dataset.

Why one file per experiment: experiments arrive one at a time (a measurement campaign, a
batch of simulations), each file is written atomically on its own, and a single broken or
re-measured experiment is replaced without rewriting the rest.  Opened, the directory
becomes one dataset with a leading ``experiment`` dim, chunked one experiment per chunk,
which is exactly what :func:`lcmr_xr.identify` maps over in parallel.

Experiments of different lengths are refused (not grouped): their FRFs live on different
frequency grids, so they cannot share one dataset without NaN padding that the
identification would choke on, and grouping would hand back several datasets where
callers expect one.  The error lists the lengths and which files have them.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.transforms._coords import even_spacing

__all__ = ["save_archive", "open_archive", "archive_files"]

SUFFIX = ".nc"
#: Dataset attribute that keeps the order of the experiments across save/open; dropped on open.
ORDER_ATTR = "lcmr_archive_index"
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def _file_stem(label) -> str:
    """File name (without suffix) for an ``experiment`` label: portable characters only."""
    text = str(label.item() if isinstance(label, np.generic) else label)
    stem = _UNSAFE.sub("_", text).strip("._")
    return stem or "experiment"


def _split(experiments) -> list[tuple[object, xr.Dataset]]:
    """``[(label, single experiment), ...]`` from a stacked dataset or a sequence of them."""
    if isinstance(experiments, xr.Dataset):
        if cv.EXPERIMENT not in experiments.dims:
            label = experiments.coords[cv.EXPERIMENT].item() if cv.EXPERIMENT in experiments.coords else 0
            return [(label, experiments)]
        labels = (experiments[cv.EXPERIMENT].values if cv.EXPERIMENT in experiments.coords
                  else np.arange(experiments.sizes[cv.EXPERIMENT]))
        return [(lab, experiments.isel({cv.EXPERIMENT: i})) for i, lab in enumerate(labels)]
    try:
        items = list(experiments)
    except TypeError:
        raise TypeError(
            f"experiments must be an experiment Dataset (optionally with an 'experiment' dim) "
            f"or a sequence of them, got {type(experiments).__name__}."
        ) from None
    out = []
    for i, ds in enumerate(items):
        if not isinstance(ds, xr.Dataset):
            raise TypeError(f"item {i} of experiments is a {type(ds).__name__}, not an experiment Dataset.")
        if cv.EXPERIMENT in ds.dims:
            raise ValueError(
                f"item {i} of experiments has an 'experiment' dim of size {ds.sizes[cv.EXPERIMENT]}; "
                "pass either one stacked dataset or a sequence of single experiments."
            )
        label = ds.coords[cv.EXPERIMENT].item() if cv.EXPERIMENT in ds.coords else i
        out.append((label, ds))
    return out


def _shape(ds: xr.Dataset) -> dict:
    """What must agree between the experiments of one archive (besides the data)."""
    n = ds.sizes.get(cv.TIME, 0)
    th = even_spacing(ds[cv.TIME].values, cv.TIME)[1] if n > 1 else float("nan")
    return {
        "N": int(ds.sizes[cv.TIME]),
        "factor": int(np.asarray(ds.attrs.get(cv.FACTOR, -1)).item()),
        "Th": th,
        "inputs": [str(v) for v in ds[cv.INPUT].values],
        "outputs": [str(v) for v in ds[cv.OUTPUT].values],
    }


def _same_shape(a: dict, b: dict) -> bool:
    return (a["N"] == b["N"] and a["factor"] == b["factor"] and a["inputs"] == b["inputs"]
            and a["outputs"] == b["outputs"] and np.isclose(a["Th"], b["Th"], rtol=1e-9))


def _describe(shape: dict) -> str:
    return (f"N={shape['N']}, factor={shape['factor']}, Th={shape['Th']:.6g} s, "
            f"inputs={shape['inputs']}, outputs={shape['outputs']}")


def archive_files(directory) -> list[Path]:
    """NetCDF files of an archive directory, in archive order.

    Parameters
    ----------
    directory : str or os.PathLike
        Archive directory written by :func:`save_archive` (any ``*.nc`` files count).

    Returns
    -------
    list of pathlib.Path
        Ordered by the index :func:`save_archive` recorded, then by name (files written by
        other tools, without the index, come last in name order).

    Examples
    --------
    >>> import tempfile
    >>> with tempfile.TemporaryDirectory() as d:
    ...     archive_files(d)
    []
    """
    directory = Path(directory)
    if directory.is_file():
        raise NotADirectoryError(
            f"archive {directory} is a file, not a directory; an archive is a directory of "
            f"experiment files: give that directory (e.g. {directory.parent}), or open a single "
            "experiment file with lcmr_xr.open_experiment."
        )
    if not directory.is_dir():
        raise FileNotFoundError(f"archive directory {directory} does not exist; check the path "
                                "or write one with lcmr_xr.scaleout.save_archive.")
    keyed = []
    for path in sorted(directory.glob(f"*{SUFFIX}")):
        if path.name.startswith("."):  # temporary files of an interrupted atomic write
            continue
        try:
            with xr.open_dataset(path, engine="netcdf4", decode_cf=False) as ds:  # metadata only
                index = ds.attrs.get(ORDER_ATTR)
        except (OSError, ValueError, RuntimeError, KeyError, IndexError) as err:
            raise ValueError(
                f"{path} in archive {directory} is not a readable NetCDF file (truncated, "
                f"corrupt, or another format: {err}); move it out of the archive directory."
            ) from err
        keyed.append((0 if index is not None else 1, int(index) if index is not None else 0, path.name, path))
    return [k[-1] for k in sorted(keyed)]


def _existing_shapes(files) -> dict:
    shapes = {}
    for path in files:
        with xr.open_dataset(path, engine="netcdf4") as ds:
            shapes[path] = (_shape(ds), ds.attrs.get(ORDER_ATTR))
    return shapes


def save_archive(experiments, directory, *, overwrite: bool = False) -> list[Path]:
    """Write experiments to an archive directory, one NetCDF file per experiment.

    Parameters
    ----------
    experiments : xarray.Dataset or sequence of xarray.Dataset
        A stacked experiment dataset with an ``experiment`` dim, or single experiments.
        Every one is validated (:func:`lcmr_xr.experiment.validate_experiment`).
    directory : str or os.PathLike
        Target directory; created if missing.
    overwrite : bool, default False
        Replace existing files even when their content has a different shape.  Without it
        an existing file is only replaced by an experiment of the same shape (length,
        factor, sample time, channel labels), e.g. a re-measurement.

    Returns
    -------
    list of pathlib.Path
        The files written, in order.

    Notes
    -----
    File names come from the ``experiment`` coordinate (its position when there is none),
    with every character other than letters, digits, ``.``, ``_``, ``-`` replaced by ``_``.
    Each file is written atomically with :func:`lcmr_xr.io.save`.  The position of each
    experiment is recorded in the file attribute ``lcmr_archive_index`` so
    :func:`open_archive` returns them in the order given (new files are appended after
    those already in the directory).  All experiments of an archive must have the same
    shape; a mismatch with the files already there is refused before anything is written.

    Examples
    --------
    >>> import numpy as np, tempfile
    >>> from lcmr_xr.experiment import experiment
    >>> ds = experiment(np.ones((2, 8, 1)), np.ones((2, 8, 1)), np.ones((2, 4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     [p.name for p in save_archive(ds, d)]
    ['0.nc', '1.nc']
    """
    from lcmr_xr.experiment import validate_experiment
    from lcmr_xr.io import save

    items = _split(experiments)
    if not items:
        raise ValueError("experiments is empty: nothing to archive.")
    names, shapes = [], []
    for label, ds in items:
        try:
            validate_experiment(ds)
        except ValueError as err:
            raise ValueError(f"experiment {label!r}: {err}") from err
        names.append(_file_stem(label) + SUFFIX)
        shapes.append(_shape(ds))
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(
            f"experiment labels map to the same file names {dupes} (after replacing unsafe "
            "characters); give the experiments unique labels, e.g. "
            "ds.assign_coords(experiment=[f'run{i}' for i in range(n)])."
        )
    first = shapes[0]
    lengths = {}
    for (label, _), shape in zip(items, shapes):
        lengths.setdefault(shape["N"], []).append(str(label))
        if not _same_shape(shape, first) and shape["N"] == first["N"]:
            raise ValueError(
                f"experiment {label!r} ({_describe(shape)}) does not match the first one "
                f"({_describe(first)}); an archive holds experiments of one shape. Save it to "
                "another directory."
            )
    if len(lengths) > 1:
        raise ValueError(_length_message(lengths, "the experiments to archive"))

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    existing = _existing_shapes(archive_files(directory))
    targets = {directory / n for n in names}
    conflicts = [f"{p.name} ({_describe(s)})" for p, (s, _) in existing.items()
                 if not _same_shape(s, first) and (p not in targets or not overwrite)]
    if conflicts:
        raise ValueError(
            f"{directory} already holds experiments of another shape than the new ones "
            f"({_describe(first)}): {conflicts[:5]}{' ...' if len(conflicts) > 5 else ''}. "
            "An archive holds experiments of one shape: use a new directory, remove those "
            "files, or pass overwrite=True to replace files of the same name."
        )
    kept = [idx for p, (_, idx) in existing.items() if p not in targets and idx is not None]
    start = int(max(kept)) + 1 if kept else 0
    written = []
    for i, ((label, ds), name) in enumerate(zip(items, names)):
        out = ds.copy(deep=False)
        if cv.EXPERIMENT not in out.coords:
            out = out.assign_coords({cv.EXPERIMENT: label})
        if not out[cv.EXPERIMENT].attrs:
            out[cv.EXPERIMENT].attrs.update(cv.label_attrs("experiment"))
        out.attrs = {**out.attrs, ORDER_ATTR: start + i}
        written.append(save(out, directory / name))
    return written


def _length_message(lengths: dict, where: str) -> str:
    listing = "; ".join(
        f"N={n}: {len(labels)} ({', '.join(labels[:4])}{', ...' if len(labels) > 4 else ''})"
        for n, labels in sorted(lengths.items())
    )
    return (
        f"{where} have different lengths ({listing}). Experiments of different lengths have "
        "different frequency grids and cannot share one dataset: put each length in its own "
        "archive directory (save_archive(group, directory_per_length)) and sweep them "
        "separately."
    )


def open_archive(directory, chunks=None) -> xr.Dataset:
    """Open an archive directory as one lazy experiment dataset with an ``experiment`` dim.

    Parameters
    ----------
    directory : str or os.PathLike
        Directory written by :func:`save_archive` (``*.nc`` experiment files).
    chunks : dict, optional
        Dask chunks per file.  Default ``None``: each file is one chunk (one experiment per
        chunk along ``experiment``, whole records along ``time``), which is what
        :func:`lcmr_xr.identify` needs; ``time``/``slow_time`` must stay in one chunk.

    Returns
    -------
    xarray.Dataset
        Dask-backed experiment dataset (``lcmr-xr-1``), ``experiment`` coordinate from the
        files (their labels), in archive order; validated with
        :func:`lcmr_xr.experiment.validate_experiment`.

    Raises
    ------
    FileNotFoundError
        The directory does not exist or holds no ``*.nc`` file.
    ValueError
        A file is not an experiment file, or the experiments differ in length, factor,
        sample time or channel labels (the message lists them and says what to do).

    Notes
    -----
    This is :func:`xarray.open_mfdataset` with ``combine="nested"`` and
    ``concat_dim="experiment"`` spelled out: each file is opened lazily with
    :func:`lcmr_xr.io.open_dataset` (which restores the attribute types that
    :func:`lcmr_xr.io.save` flattened) and the files are combined with
    :func:`xarray.combine_nested` and ``join="exact"``.  The metadata of every file is read
    first, so a mismatch is reported before any data are read.  The NaN/inf check of the
    validation reads the data once, streaming one chunk at a time on the current dask
    scheduler.

    Examples
    --------
    >>> import numpy as np, tempfile
    >>> from lcmr_xr.experiment import experiment
    >>> ds = experiment(np.ones((3, 8, 1)), np.ones((3, 8, 1)), np.ones((3, 4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     _ = save_archive(ds, d)
    ...     arc = open_archive(d)
    ...     dict(arc.r.sizes), arc.r.chunks is not None
    ({'experiment': 3, 'time': 8, 'input': 1}, True)
    """
    from lcmr_xr.experiment import validate_experiment
    from lcmr_xr.io import open_dataset

    files = archive_files(directory)
    if not files:
        raise FileNotFoundError(
            f"archive directory {directory} holds no {SUFFIX} files; write experiments into it "
            "with lcmr_xr.scaleout.save_archive."
        )
    # Every file is opened once, lazily (metadata only), and these handles are both checked
    # and combined: opening the same HDF5 file again with a second handle while the first
    # is alive has crashed netCDF4/HDF5 in this environment (segfault on a second open).
    parts, shapes = [], {}
    for path in files:
        ds = open_dataset(path, chunks={} if chunks is None else chunks)
        if ds.attrs.get("conventions") != cv.CONVENTIONS or any(v not in ds for v in ("r", "u", "y")):
            raise ValueError(
                f"{path} is not an lcmr-xr-1 experiment file (conventions "
                f"{ds.attrs.get('conventions')!r}, variables {sorted(ds.data_vars)}); move it "
                "out of the archive directory."
            )
        shapes[path] = _shape(ds)
        ds.attrs.pop(ORDER_ATTR, None)
        if cv.EXPERIMENT not in ds.coords:  # a file written by another tool
            ds = ds.assign_coords({cv.EXPERIMENT: ((), path.stem, cv.label_attrs("experiment"))})
        parts.append(ds)
    lengths = {}
    for path, shape in shapes.items():
        lengths.setdefault(shape["N"], []).append(path.name)
    if len(lengths) > 1:
        raise ValueError(_length_message(lengths, f"the files of {directory}"))
    first_path, first = files[0], shapes[files[0]]
    for path, shape in shapes.items():
        if not _same_shape(shape, first):
            raise ValueError(
                f"{path.name} ({_describe(shape)}) does not match {first_path.name} "
                f"({_describe(first)}); an archive holds experiments of one shape. Move it to "
                "another directory."
            )
    # The files were checked to agree on coords and shape, so "override" skips re-comparing
    # the (identical) time coordinates of every file; join="exact" still refuses misalignment.
    # Attributes that differ between files (a seed, a date) are dropped, not taken from the
    # first file, so the combined attrs never misdescribe the other experiments.
    combined = xr.combine_nested(
        parts, concat_dim=cv.EXPERIMENT, data_vars="all", coords="minimal",
        compat="override", join="exact", combine_attrs="drop_conflicts",
    )
    try:
        return validate_experiment(combined)
    except ValueError as err:
        raise ValueError(f"archive {directory}: {err}") from err
