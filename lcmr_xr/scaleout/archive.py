"""Archives of experiments: one consolidated NetCDF file (default) or a directory of files.

Two layouts, opened alike by :func:`open_archive` as one lazy dataset with a leading
``experiment`` dim:

consolidated (default)
    One NetCDF-4 file, every experiment along an unlimited ``experiment`` dim in chunks of
    one experiment, labels and metadata (seed, case, date, drive id, scalar coordinates) as
    coordinates along ``experiment``.  Opens in a fraction of a second whatever it holds;
    :func:`append_to_archive` adds one experiment without rewriting the others.  Layout and
    the choice of NetCDF over Zarr: :mod:`lcmr_xr.scaleout.consolidated`.
files
    A directory with one NetCDF file per experiment (the first layout; still read and
    written).  Each file is written atomically on its own and a re-measured experiment is
    replaced alone.  The library's writers keep a hidden header index in the directory
    (:mod:`lcmr_xr.scaleout.dirindex`), from which opening takes the header facts of every
    file that has not changed since; the other files' headers are read (a few ms each
    with h5py, see :mod:`lcmr_xr.scaleout.directory`: 10 000 files without an index take
    most of a minute, and such an open says so).  :func:`index_archive` (``lcmr-xr
    archive index DIR``) writes the index of a directory written otherwise.  Appending
    costs the same whatever the directory holds (one file checked, one journal file of
    the index added).  ``lcmr-xr archive consolidate DIR -o
    ARCHIVE.nc`` (or :func:`consolidate_archive`) turns one into a consolidated file.

Experiments of different lengths are refused (not grouped): their FRFs live on different
frequency grids, so they cannot share one dataset without NaN padding that the
identification would choke on, and grouping would hand back several datasets where
callers expect one.  The error lists the lengths and which files have them.

Opening reads metadata only.  The NaN/inf check that has to read the data runs inside the
identify tasks of :func:`lcmr_xr.scaleout.sweep`, where a bad experiment becomes a flagged
result (``experiment_error`` names its file and the reason) instead of failing the sweep.
"""

from __future__ import annotations

import math
import os
import re
import warnings
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.scaleout import consolidated as con
from lcmr_xr.scaleout import dirindex
from lcmr_xr.scaleout import directory as dirx
from lcmr_xr.settings import as_bool
from lcmr_xr.transforms._coords import even_spacing

__all__ = ["save_archive", "open_archive", "append_to_archive", "consolidate_archive", "index_archive",
           "archive_files"]

#: The ending the writers give a new experiment file of a directory archive (``LABEL.nc``);
#: the directory holds every visible name ending in any of
#: :data:`lcmr_xr.io._guards.NETCDF_SUFFIXES`, any case (:func:`dirindex.plain_name`).
SUFFIX = ".nc"
#: Dataset attribute that keeps the order of the experiments across save/open; dropped on open.
ORDER_ATTR = cv.ARCHIVE_ORDER_ATTR
_UNSAFE = re.compile(r"[^A-Za-z0-9._-]+")


def _file_stem(label) -> str:
    """File name (without suffix) for an ``experiment`` label: portable characters only."""
    text = str(label.item() if isinstance(label, np.generic) else label)
    stem = _UNSAFE.sub("_", text).strip("._")
    return stem or "experiment"


def _label_kind(label) -> str:
    """``"integer"`` or ``"text"``: the two kinds of ``experiment`` label an archive keeps
    (any other type is named as it is).  One archive holds one kind: a mixed coordinate
    would come back from ``open_archive`` as text, ``7`` silently turned into ``"7"``."""
    if isinstance(label, (bool, np.bool_)):
        return "boolean"
    if isinstance(label, (int, np.integer)):
        return "integer"
    if isinstance(label, (str, np.str_)):
        return "text"
    return type(label).__name__


_RELABEL = ("Relabel the new experiments, e.g. ds.assign_coords(experiment=str(label)), or "
            "write them to another archive.")


def _check_label_kinds(rows, where: str, remedy: str = _RELABEL) -> None:
    """Refuse ``[(label, name), ...]`` holding labels of more than one kind (see
    :func:`_label_kind`); the message names one of each and the remedy."""
    kinds: dict = {}
    for label, name in rows:
        kinds.setdefault(_label_kind(label), (label, name))
    if len(kinds) > 1:
        shown = ", ".join(f"{kind} {label!r} ({name})" for kind, (label, name) in kinds.items())
        raise ValueError(
            f"{where} mix experiment labels of different kinds: {shown}; an archive's labels "
            "are of one kind, e.g. all integers or all text (mixed, they would all be read "
            f"back as text). {remedy}"
        )


def _split(experiments) -> list[tuple[object, xr.Dataset]]:
    """``[(label, single experiment), ...]`` from a stacked dataset or a sequence of them."""
    if isinstance(experiments, xr.Dataset):
        if cv.EXPERIMENT not in experiments.dims:
            label = experiments.coords[cv.EXPERIMENT].item() if cv.EXPERIMENT in experiments.coords else 0
            return [(label, experiments)]
        labels = (experiments[cv.EXPERIMENT].values if cv.EXPERIMENT in experiments.coords
                  else np.arange(experiments.sizes[cv.EXPERIMENT]))
        return [(lab, experiments.isel({cv.EXPERIMENT: i})) for i, lab in enumerate(labels.tolist())]
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
    # Sample times agree to 1e-9 relative (rounding of a stored coordinate), with no
    # absolute slack: np.isclose's default atol of 1e-8 s is 0.1 % of the HDD's 9.9 us,
    # and let an experiment sampled 0.05 % slower join a consolidated archive unnoticed.
    return (a["N"] == b["N"] and a["factor"] == b["factor"] and a["inputs"] == b["inputs"]
            and a["outputs"] == b["outputs"]
            and (math.isclose(a["Th"], b["Th"], rel_tol=1e-9, abs_tol=0.0)
                 or (math.isnan(a["Th"]) and math.isnan(b["Th"]))))


def _describe(shape: dict) -> str:
    return (f"N={shape['N']}, factor={shape['factor']}, Th={shape['Th']:.6g} s, "
            f"inputs={shape['inputs']}, outputs={shape['outputs']}")


def archive_files(directory) -> list[Path]:
    """NetCDF files of an archive directory, in archive order.

    Parameters
    ----------
    directory : str or os.PathLike
        Archive directory written by :func:`save_archive` (every visible file whose name
        ends in ``.nc``, ``.nc4`` or ``.netcdf``, any case, counts).

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
    paths = _nc_files(directory)
    known = dirindex.read_index(directory) if paths and dirindex.ENABLED else None
    keyed, load = [], dirindex.loader()
    for path in paths:
        st, text, order = _entry(known, path)
        if text is not None and order is None:  # a base written before the orders were kept
            try:
                order = load(text)["attrs"].get(ORDER_ATTR, -1)
            except (ValueError, TypeError, KeyError, AttributeError):
                text = None
        if text is None:
            index = dirx.order_index(path, directory)
        else:
            index = dirx.order_value(order, path)
            index = None if index is None or index < 0 else index  # -1: the file has none
        keyed.append((0 if index is not None else 1, index if index is not None else 0, path.name, path))
    return [k[-1] for k in sorted(keyed)]


def _nc_files(directory) -> list[Path]:
    """The NetCDF files of an archive directory in name order: every visible name ending in
    ``.nc``, ``.nc4`` or ``.netcdf``, any case (:func:`lcmr_xr.scaleout.dirindex.plain_name`),
    so never the hidden index, its journal or the temporaries of interrupted atomic writes;
    refuse a path that is no directory."""
    directory = Path(directory)
    return [directory / name for name in _nc_names(directory)]


def _nc_names(directory: Path) -> list[str]:
    """The names of :func:`_nc_files` (strings)."""
    if directory.is_file():
        raise NotADirectoryError(
            f"archive {directory} is a file, not a directory; an archive is a directory of "
            f"experiment files: give that directory (e.g. {directory.parent}), or open a single "
            "experiment file with lcmr_xr.open_experiment."
        )
    if not directory.is_dir():
        raise FileNotFoundError(f"archive directory {directory} does not exist; check the path "
                                "or write one with lcmr_xr.scaleout.save_archive.")
    # names sorted as strings (as sorted paths of one directory), without pathlib's glob;
    # the index's rule (dirindex.plain_name): visible names ending in a NetCDF suffix, any case
    return sorted(name for name in os.listdir(directory) if dirindex.plain_name(name))


def _entry(known, path: Path) -> tuple:
    """``(stat, text, order)`` of ``path`` from the directory's index ``known``; ``text``
    and ``order`` are None where its entry is missing or out of date, ``stat`` where the
    file vanished."""
    try:
        st = os.stat(path)
    except OSError:
        return None, None, None
    found = dirindex.trusted(known, path.name, st)
    return (st, None, None) if found is None else (st, *found)


#: An open that reads the headers of more files than this (no index, or files added or
#: copied by other tools) warns once, with the remedy (index_archive) and the time it saves.
UNINDEXED_WARN = 300
#: Seconds an open takes per file read from its header, and per file taken from the index
#: (measured with benchmarks/scale_out.py, warm page cache; for the warning's estimate).
HEADER_SECONDS, INDEXED_SECONDS = 5e-3, 6e-5


def _summaries(directory: Path, paths: list[Path]):
    """``(path, stat, summary)`` of each file: from the directory's index where its entry
    matches the file (:mod:`lcmr_xr.scaleout.dirindex`), else from its header.

    ``summary`` is :func:`_summary` of the file's header, ``stat`` the file's, taken
    before its header was read (None: it vanished).  More than :data:`UNINDEXED_WARN`
    files without a current entry warn once, before their headers are read.
    """
    known = dirindex.read_index(directory) if paths and dirindex.ENABLED else None
    found = [(path, *_entry(known, path)) for path in paths]
    unindexed = sum(text is None for _, _, text, _ in found)
    if dirindex.ENABLED and unindexed > UNINDEXED_WARN:
        why = ("it has no header index" if known is None
               else "they have no current entry in its header index (added or copied by other "
                    "tools, or written by an older version)")
        warnings.warn(
            f"{unindexed} of the {len(paths)} files of archive {directory} are opened from their "
            f"headers because {why}: about {unindexed * HEADER_SECONDS:.0f} s now, and at every "
            f"open. Write the index once with `lcmr-xr archive index {directory}` (or "
            "lcmr_xr.scaleout.index_archive(directory); it reads those headers once, needs write "
            "access to the directory); the open then takes about "
            f"{max(len(paths) * INDEXED_SECONDS, 0.1):.1f} s.", RuntimeWarning, stacklevel=4)
    load = dirindex.loader()
    for path, st, text, _ in found:
        summary = None
        if text is not None:
            try:
                summary = load(text)
            except (ValueError, TypeError, KeyError, RecursionError):  # damaged: read the header
                summary = None
            if not _usable(summary):  # valid JSON, but not a summary (a damaged byte)
                summary = None
        if summary is None:  # st None: gone (read_header says so)
            summary = _summary(dirx.read_header(path, directory))
        yield path, st, summary


_SHAPE_KEYS = {"N", "factor", "Th", "inputs", "outputs"}


def _usable(summary) -> bool:
    """Whether a stored summary holds what the open uses, of the types :func:`_summary`
    gives (a damaged entry decodes to something else: its header is read instead)."""
    if (type(summary) is not dict or type(summary.get("attrs")) is not dict
            or type(summary.get("scalars")) is not dict
            or not isinstance(summary.get("experiment"), (bool, np.bool_))):
        return False
    if not summary["experiment"]:
        return True
    shape = summary.get("shape")
    return (type(shape) is dict and _SHAPE_KEYS <= shape.keys()
            and type(shape["inputs"]) is list and type(shape["outputs"]) is list
            and type(summary.get("structure")) is str and type(summary.get("var_attrs")) is str)


def _summary(header: dict) -> dict:
    """What opening and appending need of one file's header (stored in the index).

    ``attrs`` and ``scalars`` as read; ``experiment`` (an lcmr-xr-1 experiment file);
    for experiments also ``shape`` (:func:`_header_shape`), ``structure`` (a digest of
    the variables' names, shapes and types other than the scalar coordinates, of the
    time coordinates and channel labels) and ``var_attrs`` (a digest of the attributes
    of those variables).
    """
    out = {"attrs": header["attrs"], "scalars": header["scalars"], "experiment": _is_experiment(header)}
    if out["experiment"]:
        out["shape"] = _header_shape(header)
        scalars = [n for n in header["scalars"] if n != cv.EXPERIMENT]  # metadata coordinates
        variables = sorted((n, list(shape) if shape is not None else None, str(dtype))
                           for n, (shape, dtype) in header["variables"].items()
                           if n not in scalars and n != cv.EXPERIMENT)
        slow = header[cv.SLOW_TIME]
        out["structure"] = dirindex.digest([
            variables, dirindex.bytes_digest(header[cv.TIME]),
            None if slow is None else dirindex.bytes_digest(slow), header["inputs"], header["outputs"]])
        out["var_attrs"] = dirindex.digest(
            sorted([n, sorted(a.items())] for n, a in header["var_attrs"].items() if n not in scalars))
    return out


def _header_shape(header: dict) -> dict:
    """:func:`_shape` of a file from its header (:func:`lcmr_xr.scaleout.directory.read_header`)."""
    time = header[cv.TIME]
    n = len(time)
    return {
        "N": n,
        "factor": int(np.asarray(header["attrs"].get(cv.FACTOR, -1)).item()),
        "Th": even_spacing(time, cv.TIME)[1] if n > 1 else float("nan"),
        "inputs": list(header["inputs"]),
        "outputs": list(header["outputs"]),
    }


def _is_experiment(header: dict) -> bool:
    return (header["attrs"].get("conventions") == cv.CONVENTIONS
            and all(v in header["variables"] for v in ("r", "u", "y"))
            and all(header[k] is not None for k in (cv.TIME, "inputs", "outputs")))


LAYOUTS = ("consolidated", "files")


def _refuse_inside_directory_archive(path: Path) -> None:
    """Refuse a consolidated archive file directly inside a directory archive.

    :func:`open_archive` of the directory reads every NetCDF file in it (``.nc``,
    ``.nc4``, ``.netcdf``, any case) as one
    experiment: a file of another structure makes it refuse the whole directory.  A
    directory archive is recognised by its header index (written by every write of this
    library into it); a directory of plain experiment files without one is not.
    """
    parent = path.parent
    if not any((parent / name).exists() for name in (dirindex.INDEX_NAME, dirindex.JOURNAL_NAME)):
        return
    raise ValueError(
        f"refusing to write the consolidated archive {path}: {parent} is a directory archive "
        f"(it has the header index {dirindex.INDEX_NAME}), and open_archive({str(parent)!r}) "
        "would refuse the whole directory for a file of another structure. Write the archive "
        f"file outside it (e.g. {parent.parent / (parent.name + SUFFIX)}), or add the "
        f"experiments to the directory archive itself: save_archive(experiments, {str(parent)!r})."
    )


def _check_archive_name(path: Path, directory_hint: str = "") -> None:
    """Refuse a new consolidated archive whose name does not end in a NetCDF suffix
    (:data:`lcmr_xr.io._guards.NETCDF_SUFFIXES`, any case), as :func:`lcmr_xr.io.save`
    refuses such a name: ``campaign.h5`` or ``runs`` would hold NetCDF-4 under a name that
    says otherwise.  The message names the accepted endings, then ``directory_hint`` (how
    the caller writes a directory archive instead, whose name is free)."""
    from lcmr_xr.io._guards import NETCDF_SUFFIXES, check_suffix

    try:
        check_suffix(path, NETCDF_SUFFIXES, "cannot write the consolidated archive")
    except ValueError as err:
        raise ValueError(f"{err}{' ' + directory_hint if directory_hint else ''}") from None


def _layout(path: Path, layout) -> str:
    """``layout`` checked; by default a directory that exists is a files archive."""
    if layout is None:
        return "files" if path.is_dir() else "consolidated"
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS} (or None: 'files' for an existing "
                         f"directory, else 'consolidated'), got {layout!r}.")
    if layout == "consolidated" and path.is_dir():
        raise ValueError(f"{path} is a directory; a consolidated archive is one file: give a file "
                         "path such as archive.nc, or layout='files' to add files to the directory.")
    if layout == "files" and path.is_file():
        raise ValueError(f"{path} is a file; an archive of layout='files' is a directory: give a "
                         "directory path, or leave layout=None to append to the consolidated archive.")
    return layout


def _validated(experiments):
    """``[(label, ds)]`` and their shapes, every experiment valid and of one shape."""
    from lcmr_xr.experiment import validate_experiment

    items = _split(experiments)
    if not items:
        raise ValueError("experiments is empty: nothing to archive.")
    shapes = []
    for label, ds in items:
        try:
            validate_experiment(ds)
        except ValueError as err:
            raise ValueError(f"experiment {label!r}: {err}") from err
        shapes.append(_shape(ds))
    first = shapes[0]
    lengths = {}
    for (label, _), shape in zip(items, shapes):
        lengths.setdefault(shape["N"], []).append(str(label))
        if not _same_shape(shape, first) and shape["N"] == first["N"]:
            raise ValueError(
                f"experiment {label!r} ({_describe(shape)}) does not match the first one "
                f"({_describe(first)}); an archive holds experiments of one shape. Save it to "
                "another archive."
            )
    if len(lengths) > 1:
        raise ValueError(_length_message(lengths, "the experiments to archive"))
    _check_label_kinds([(label, f"experiment {i}") for i, (label, _) in enumerate(items)],
                       "the experiments to archive")
    return items, first


def save_archive(experiments, path, *, overwrite: bool = False, layout: str | None = None) -> list[Path]:
    """Write experiments to an archive: one consolidated NetCDF file, or one file each.

    Parameters
    ----------
    experiments : xarray.Dataset or sequence of xarray.Dataset
        A stacked experiment dataset with an ``experiment`` dim, or single experiments.
        Every one is validated (:func:`lcmr_xr.experiment.validate_experiment`).
    path : str or os.PathLike
        The archive: a file (consolidated) or a directory (files; created if missing).
        A new consolidated file's name ends in ``.nc``, ``.nc4`` or ``.netcdf`` (any case),
        as :func:`lcmr_xr.io.save` requires of NetCDF files: other names (``campaign.h5``,
        ``runs``) are refused, with the remedy, and so is appending to an existing archive
        file under such a name (one written before the rule came in: it still opens; the
        message names the rename to ``.nc``).  A directory's name is free.  A consolidated
        file is refused directly inside a directory archive (one with the header index):
        the directory's open would refuse a file of another structure.
    overwrite : bool, default False
        Consolidated: replace an existing archive file instead of appending to it.
        Files: replace existing files even when their content has a different shape.
        True or False only (a string such as ``"no"`` is refused, not read as True).
        Without it an existing file is only replaced by an experiment of the same shape
        (length, factor, sample time, channel labels), e.g. a re-measurement.
    layout : {"consolidated", "files"}, optional
        Default: ``"files"`` when ``path`` is an existing directory, else
        ``"consolidated"`` (see the module notes).

    Returns
    -------
    list of pathlib.Path
        Consolidated: ``[path]``.  Files: the files written, in order.

    Notes
    -----
    Consolidated: a new archive is written to a temporary file and renamed into place; an
    existing consolidated archive gets the experiments appended (labels must be new, shape
    and metadata must agree) without rewriting the ones it holds.  The experiments'
    metadata (:data:`lcmr_xr.scaleout.consolidated.METADATA` attributes and scalar
    coordinates) become coordinates along ``experiment``; attributes that differ between
    experiments are dropped.

    Files: file names come from the ``experiment`` coordinate (its position when there is
    none), with every character other than letters, digits, ``.``, ``_``, ``-`` replaced by
    ``_``: ``LABEL.nc``.  A label whose name the directory holds with another NetCDF ending
    (``LABEL.NC``, ``LABEL.nc4``, ...) is refused before anything is written (its open would
    refuse a label carried by two files).  Each file is written atomically with
    :func:`lcmr_xr.io.save`.  The position of each experiment is recorded in the file
    attribute ``lcmr_archive_index`` so :func:`open_archive` returns them in the order given
    (new files are appended after those already in the directory).  The new files' entries
    are added to the directory's header index (:mod:`lcmr_xr.scaleout.dirindex`: one journal
    file, folded into the base ``.lcmr_archive_index.nc`` by a compaction now and then), so
    that :func:`open_archive` reads no file's header.  Two processes writing at once keep
    each other's experiments and entries: a writer holds the directory's write lock
    (:func:`lcmr_xr.scaleout.dirindex.write_lock`) from reading the next order index to
    writing its journal file, so they never take the same order (nor, appending without
    labels, the same label and file).  A directory without an index (of this version) gets
    one first, as :func:`index_archive` writes it (every header read once).

    All experiments of an archive must agree as its open requires: the same shape and
    metadata names, the same variables, channel labels and time coordinates bit for
    bit in the files (a time coordinate that differs by rounding is refused, with the
    remedy), and the same units and long_name of ``r``, ``u``, ``y`` (the open drops
    conflicting ones, and signals without them are no experiment).  The directory is checked against ONE of its files (the first its index
    lists; its open refuses the directory unless every file agrees with it) and the
    files replaced, so a write costs the same whatever the directory holds; a mismatch
    is refused before anything is moved into place.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from lcmr_xr.experiment import experiment
    >>> ds = experiment(np.ones((2, 8, 1)), np.ones((2, 8, 1)), np.ones((2, 4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     [p.name for p in save_archive(ds, os.path.join(d, "arc.nc"))]
    ...     os.mkdir(os.path.join(d, "runs"))
    ...     [p.name for p in save_archive(ds, os.path.join(d, "runs"))]  # a directory: one file each
    ['arc.nc']
    ['0.nc', '1.nc']
    """
    path = Path(path)
    overwrite = as_bool(overwrite, "overwrite")  # "no" must not replace an archive
    layout = _layout(path, layout)
    if layout == "consolidated":
        if overwrite or not path.exists():  # a new file; an existing archive is appended to
            _check_archive_name(path, "For an archive directory (one file per experiment) pass "
                                f"layout='files': save_archive(experiments, {str(path)!r}, "
                                "layout='files').")
        _refuse_inside_directory_archive(path)
    items, first = _validated(experiments)
    if layout == "files":
        return _save_files(items, first, path, overwrite)
    return [_save_consolidated(items, first, path, overwrite)]


def _save_consolidated(items, first, path: Path, overwrite: bool) -> Path:
    from lcmr_xr.io._atomic import atomic_write

    labels = [str(label) for label, _ in items]
    dupes = sorted({lab for lab in labels if labels.count(lab) > 1})
    if dupes:
        raise ValueError(f"experiment labels {dupes} occur more than once; give the experiments "
                         "unique labels, e.g. ds.assign_coords(experiment=[f'run{i}' for i in range(n)]).")
    if path.exists() and not overwrite:
        _append_consolidated(items, first, path)
        return path
    attrs = con.common_attrs([ds for _, ds in items])
    return atomic_write(path, lambda tmp: con.write_consolidated(items, tmp, attrs))


def _header(path: Path) -> dict:
    try:
        return con.read_header(path)
    except OSError as err:
        raise ValueError(f"{path} exists but is not a readable NetCDF-4 archive ({err}); pass "
                         "overwrite=True to replace it, or choose another path.") from err


def _append_consolidated(items, first, path: Path) -> None:
    header = _header(path)
    if not _same_shape(header, first):
        raise ValueError(
            f"{path} holds experiments of another shape ({_describe(header)}) than the new ones "
            f"({_describe(first)}); an archive holds experiments of one shape: write them to "
            "another archive, or pass overwrite=True to replace the file."
        )
    existing = set(map(str, header["labels"]))
    taken = [str(label) for label, _ in items if str(label) in existing]
    if taken:
        raise ValueError(f"experiment(s) {taken[:5]} are already in {path}; give new labels, or "
                         "write a new archive with overwrite=True.")
    if header["labels"]:
        _check_label_kinds([(header["labels"][0], path.name)]
                           + [(label, "new") for label, _ in items], f"{path} and the new experiments")
    metas = [con.metadata_of(label, ds) for label, ds in items]
    con.check_metadata([(label, m) for (label, _), m in zip(items, metas)], header["metadata"])
    count = header["count"]
    for start in range(0, len(items), con.BATCH):
        count = con.append_rows(path, items[start:start + con.BATCH], metas[start:start + con.BATCH],
                                expected_count=count)


def append_to_archive(experiment, path) -> Path:
    """Add one experiment to an archive without rewriting the experiments it holds.

    Parameters
    ----------
    experiment : xarray.Dataset
        One experiment (``lcmr-xr-1``, validated), labelled by a scalar ``experiment``
        coordinate (default: its position in the archive, the number of experiments
        before it in a consolidated archive, its order index in a directory; as text in
        an archive of text labels).  Several stacked along
        ``experiment`` are appended in order.
    path : str or os.PathLike
        A consolidated archive file (created when missing; a new one's name ends in
        ``.nc``, ``.nc4`` or ``.netcdf``, any case, as :func:`save_archive` requires) or an
        archive directory.

    Returns
    -------
    pathlib.Path
        The archive file (consolidated) or the file written (directory).

    Raises
    ------
    ValueError
        The experiment is invalid, of another shape than the archive, carries other
        metadata, or its label is taken or of another kind than the archive's (integer
        vs text); ``path`` is a consolidated archive file directly inside a directory
        archive (its open would refuse the file; see :func:`save_archive`); ``path``'s
        name does not end in a NetCDF suffix (a new file, or an existing archive written
        under another name before the rule: it still opens, and grows once renamed to
        ``.nc``); or, in a directory, the experiment's file ``LABEL.nc`` would go beside
        a file of the same name with another NetCDF ending (``LABEL.NC``, ``LABEL.nc4``,
        ...), which the open would read as a second file of that label.
    FileExistsError
        Directory, where the write lock is not available (some network file systems):
        another append took the same file name while this one was writing (nothing was
        replaced; an append without a label gets the next one when it is appended again).

    Notes
    -----
    Consolidated: the new rows are written after the complete experiments and the
    archive's count is raised last, so an interrupted append leaves the archive as it was
    (the partial row is ignored and overwritten by the next append).  Cost: one open of
    the file and the new experiment's data, not a pass over the archive.

    Directory: an experiment whose file exists is refused (:func:`save_archive` replaces
    it), as is one whose file name exists with another NetCDF ending; the experiment's
    file is written atomically (checked against one file of the directory before it is
    moved into place, see :func:`save_archive`), then its index entry as one journal
    file; an interrupted append leaves the directory without the experiment, or with it
    and (without its entry) read from its header at open.
    Writers into one directory take turns (an exclusive ``flock`` on it, from the label
    position and the order to the journal file): two appends at once get different
    orders and, without labels, different labels; neither replaces the other's file.
    Cost: the same whatever the directory holds (measured 37-71 ms into 10 000 files,
    load 4-6), plus, once per 128 appends or a sixteenth of the directory, a compaction
    of the index (10 000 files: 1.8-2.6 s, once per 625 appends).

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from lcmr_xr.experiment import experiment
    >>> one = experiment(np.ones((8, 1)), np.ones((8, 1)), np.ones((4, 1)), factor=2,
    ...                  sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = os.path.join(d, "arc.nc")
    ...     _ = append_to_archive(one.assign_coords(experiment="a"), p)
    ...     _ = append_to_archive(one.assign_coords(experiment="b"), p)
    ...     open_archive(p).experiment.values.tolist()
    ['a', 'b']
    """
    path = Path(path)
    unlabelled = isinstance(experiment, xr.Dataset) and cv.EXPERIMENT not in experiment.coords
    if path.is_dir():
        with dirindex.write_lock(path):  # the position, the file and its entry: one writer at a time
            if unlabelled:
                experiment = _positions(experiment, *_next_position(path))
            items, first = _validated(experiment)
            written = _save_files(items, first, path, overwrite=False, add_only=True, locked=True)
        _compact_if_due(path, written.due)
        return written[-1]
    if not path.exists():  # a new consolidated archive: named as save names NetCDF files
        _check_archive_name(path, "To append to an archive directory instead, create the "
                            f"directory first (os.makedirs({str(path)!r})) or write it with "
                            f"save_archive(experiment, {str(path)!r}, layout='files').")
        return save_archive(experiment, path, layout="consolidated")[0]
    _refuse_inside_directory_archive(path)
    if unlabelled:
        header = _header(path)  # the default labels, their positions, of the archive's kind
        text = bool(header["labels"]) and _label_kind(header["labels"][0]) == "text"
        experiment = _positions(experiment, header["count"], text)
    items, first = _validated(experiment)
    _append_consolidated(items, first, path)
    return path


def consolidate_archive(directory, path, *, overwrite: bool = False, progress=None) -> Path:
    """Copy a directory archive (one file per experiment) into one consolidated archive file.

    Parameters
    ----------
    directory : str or os.PathLike
        Archive directory (experiment files named ``*.nc``, ``*.nc4`` or ``*.netcdf``, any case).
    path : str or os.PathLike
        The consolidated archive to write (atomically: temporary file, then rename), its
        name ending in ``.nc``, ``.nc4`` or ``.netcdf`` (any case; other names refused, as
        :func:`lcmr_xr.io.save` refuses them); not
        ``directory`` itself nor inside it (refused, even with ``overwrite``: the file
        would break the directory archive or replace one of its experiments).
    overwrite : bool, default False
        Replace ``path`` if it exists (otherwise an existing ``path`` is refused).  True or
        False only.
    progress : callable, optional
        Called as ``progress(done, total)`` after each batch of experiments.

    Returns
    -------
    pathlib.Path
        ``path``.

    Notes
    -----
    The files are checked as :func:`open_archive` checks them (their headers) before
    anything is written, then read one batch at a time in archive order (memory: one
    batch), each file opened once and its values read directly, as the tasks of
    :func:`open_archive` read them.  The directory is left as it was.  The result opens
    identical to the directory (attributes, metadata coordinates, values).  The values
    are copied as they are: NaN in an experiment is reported by the sweep that identifies
    it.  Files with data variables besides ``r``, ``u``, ``y`` are refused (the
    consolidated form holds those three only).

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from lcmr_xr.experiment import experiment
    >>> ds = experiment(np.ones((3, 8, 1)), np.ones((3, 8, 1)), np.ones((3, 4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     _ = save_archive(ds, os.path.join(d, "runs"), layout="files")
    ...     p = consolidate_archive(os.path.join(d, "runs"), os.path.join(d, "runs.nc"))
    ...     open_archive(p).sizes["experiment"]
    3
    """
    from lcmr_xr.io._atomic import atomic_write

    from lcmr_xr.io._guards import same_or_inside

    directory, path = Path(directory), Path(path)
    overwrite = as_bool(overwrite, "overwrite")  # "no" must not replace a file
    if progress is not None and not callable(progress):  # else "'bool' object is not callable" mid-copy
        raise TypeError(f"progress must be None or a callable progress(done, total), got "
                        f"{progress!r} ({type(progress).__name__}).")
    if directory.is_dir() and same_or_inside(path, directory):
        # inside, the file breaks the directory archive (a file of another structure);
        # over one of its files, that experiment is lost: even with overwrite
        where = "the archive directory" if same_or_inside(directory, path) else \
            "inside the archive directory"
        raise ValueError(f"refusing to write {path}: it is {where} {directory}, which "
                         "consolidate_archive reads; choose another path, outside it.")
    _check_archive_name(path)  # a new file: named as save names NetCDF files
    _refuse_inside_directory_archive(path)  # nor inside another directory archive
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path} exists; pass overwrite=True (--overwrite) to replace it, "
                              "or choose another path.")
    # checks every file's header (reads no data); its tasks read con.BATCH files each
    lazy = open_archive(directory, chunks={cv.EXPERIMENT: con.BATCH})
    extra = sorted(name for name in lazy.data_vars if name not in ("r", "u", "y"))
    if extra:  # the consolidated form holds r, u, y only: refuse rather than drop them
        raise ValueError(
            f"the experiments of {directory} hold the data variables {extra} besides r, u, y; "
            "a consolidated archive keeps only r, u, y and would lose them. Keep the directory "
            f"archive, or save the experiments without them first (ds.drop_vars({extra}))."
        )
    attrs = dict(lazy.attrs)
    total = lazy.sizes[cv.EXPERIMENT]

    def write(tmp):
        for start in range(0, total, con.BATCH):
            block = lazy.isel({cv.EXPERIMENT: slice(start, start + con.BATCH)}).compute(
                scheduler="synchronous")  # the files' values, read directly (h5py)
            rows = [(label, block.isel({cv.EXPERIMENT: i}))
                    for i, label in enumerate(block[cv.EXPERIMENT].values.tolist())]
            if start == 0:
                con.write_consolidated(rows, tmp, attrs)
            else:
                metas = [con.metadata_of(label, ds) for label, ds in rows]
                con.append_rows(tmp, rows, metas, expected_count=start)
            if progress is not None:
                progress(min(start + con.BATCH, total), total)

    return atomic_write(path, write)


class _Written(list):
    """The files written (:func:`_save_files`) and whether a compaction of the index is due."""

    due = False


def _save_files(items, first, directory: Path, overwrite: bool, add_only: bool = False,
                locked: bool = False) -> list[Path]:
    """Write experiment files into an archive directory (see :func:`save_archive`).

    The directory's write lock (:func:`lcmr_xr.scaleout.dirindex.write_lock`) is held
    from the check that the new names are free to the journal file that lists the new
    files (``locked``: the caller holds it already), so concurrent writers never take
    the same order or replace each other's new file; a compaction then runs outside it.

    The cost does not grow with the directory (no listing, no pass over the entries):
    the new experiments are checked against ONE file of it (the first that the index's
    base lists, else the first by name, not one being replaced; its header read: the
    directory's open refuses the archive unless every file agrees with it), the files
    replaced are checked themselves, and the next order index comes from the index
    (:mod:`lcmr_xr.scaleout.dirindex`: the base's order column and the journal's file
    names), whose journal gets one file for the new ones; only when the directory changed
    after the newest journal file (a writer died between its file and its journal file,
    or its journal file was not written; the first write after a compaction) are its
    names listed, for the orders of the files the index does not list
    (:func:`_unindexed_orders`).
    Without an index (or with one of an older version) the index is built first, as
    :func:`index_archive` does (reading the headers of the files it does not list).
    """
    names = [_file_stem(label) + SUFFIX for label, _ in items]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ValueError(
            f"experiment labels map to the same file names {dupes} (after replacing unsafe "
            "characters); give the experiments unique labels, e.g. "
            "ds.assign_coords(experiment=[f'run{i}' for i in range(n)])."
        )
    directory.mkdir(parents=True, exist_ok=True)
    if not locked:
        with dirindex.write_lock(directory):
            written = _save_files(items, first, directory, overwrite, add_only, locked=True)
        _compact_if_due(directory, written.due)
        return written
    if add_only:  # append_to_archive: never a file of the archive replaced
        taken = [(label, n) for (label, _), n in zip(items, names) if (directory / n).exists()]
        if taken:
            label, name = taken[0]
            raise ValueError(
                f"experiment {label!r} is already in {directory} ({name}); give it a new label "
                "(its file name comes from it), or replace that experiment (a re-measurement "
                f"of the same shape) with save_archive(experiment, {str(directory)!r}, "
                "layout='files')."
            )
    _refuse_other_endings(items, names, directory, add_only)
    journal, facts = _index_facts(directory)
    targets = set(names)
    # one file of the archive, not replaced: the base's first (no listing of the directory)
    if facts.first is not None and facts.first not in targets and (directory / facts.first).is_file():
        reference = directory / facts.first
    else:
        reference = next((directory / n for n in _nc_names(directory) if n not in targets), None)
    checked = ([reference] if reference else []) + (
        [] if overwrite else [directory / n for n in names if (directory / n).is_file()])
    conflicts, headers = [], {}
    for path in checked:
        headers[path] = header = dirx.read_header(path, directory)
        shape = _header_shape(header) if _is_experiment(header) else None
        if shape is None or not _same_shape(shape, first):
            conflicts.append(f"{path.name} ({_describe(shape) if shape else 'not an lcmr-xr-1 experiment'})")
    if conflicts:
        raise ValueError(
            f"{directory} already holds experiments of another shape than the new ones "
            f"({_describe(first)}): {conflicts[:5]}{' ...' if len(conflicts) > 5 else ''}. "
            "An archive holds experiments of one shape: use a new directory, remove those "
            "files, or pass overwrite=True to replace files of the same name."
        )
    ref = None if reference is None else (reference, headers[reference])
    metas = [con.metadata_of(label, ds) for label, ds in items]
    if ref is not None:
        scalars, attrs = ref[1]["scalars"], ref[1]["attrs"]
        expected = [(scalars.get(cv.EXPERIMENT, reference.stem), con.checked_metadata(
            reference.stem, {n: v for n, v in scalars.items() if n != cv.EXPERIMENT}, attrs))]
    else:
        expected = []
    try:
        con.check_metadata(expected + [(label, m) for (label, _), m in zip(items, metas)])
    except ValueError as err:
        raise ValueError(f"archive {directory}: {err}") from err
    if expected:
        _check_label_kinds([(expected[0][0], reference.name)] + [(label, n) for (label, _), n
                                                                 in zip(items, names)],
                           f"archive {directory} and the new experiments")
    start = _next_order(journal, facts, directory)
    written, rows, unsettled = _Written(), [], set()
    wait = True  # for the clock to pass each file's tick; not again once it did not in time
    for i, ((label, ds), name) in enumerate(zip(items, names)):
        out = ds.copy(deep=False)
        if cv.EXPERIMENT not in out.coords:
            out = out.assign_coords({cv.EXPERIMENT: label})
        if not out[cv.EXPERIMENT].attrs:
            out[cv.EXPERIMENT].attrs.update(cv.label_attrs("experiment"))
        out.attrs = {**out.attrs, ORDER_ATTR: start + i}
        # an append never replaces a file, not even one another writer put there meanwhile
        # (where the write lock is not available)
        path, header, ident, settled = _write_checked(out, directory / name, ref, label,
                                                      replace=not add_only, wait=wait)
        wait = wait and settled  # a coarse clock (1-2 s ticks): one wait per write, not per file
        written.append(path)
        if ref is None:  # the next ones must agree with the first one written
            ref = (path, header)
        try:
            st = os.stat(path)
        except OSError:  # removed by someone else already: no entry
            continue
        if (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns) != ident:  # replaced or edited
            continue  # by someone else already: no entry (read from its header)
        rows.append((name, dirindex.stamp(st), dirindex.summary_text(_summary(header)), start + i))
        if not settled:
            unsettled.add(name)
    written.due = _index_new_files(directory, rows, facts, dirindex.journal_count(journal, facts),
                                   unsettled)
    return written


def _refuse_other_endings(items, names, directory: Path, add_only: bool) -> None:
    """Refuse an experiment whose file ``LABEL.nc`` would go beside a file of the same
    name with another NetCDF ending (``LABEL.NC``, ``LABEL.nc4``, ``LABEL.netcdf``, any
    case): the directory's open reads both (:func:`lcmr_xr.scaleout.dirindex.plain_name`),
    and refuses a label carried by two files.  Looks up those names only
    (:func:`lcmr_xr.scaleout.dirindex.plain_names`), not the whole directory; before
    anything is written."""
    folder = os.fspath(directory)
    for (label, _), name in zip(items, names):
        target = directory / name
        for other in dirindex.plain_names(name[:-len(SUFFIX)]):
            path = os.path.join(folder, other)  # strings: 72 lookups in 0.3 ms
            if other == name or not os.path.lexists(path):
                continue
            try:  # a file system that ignores case finds LABEL.nc itself under LABEL.NC
                if target.exists() and os.path.samefile(path, target):
                    continue
            except OSError:
                pass
            replace = "" if add_only else (
                f", or, to replace that experiment (a re-measurement of the same shape), rename "
                f"{other} to {name} first")
            raise ValueError(
                f"cannot write experiment {label!r} to {target}: {directory} already holds "
                f"{other}, the same name with another NetCDF ending (.nc, .nc4 or .netcdf, any "
                f"case): a file of the archive, most likely experiment {label!r} itself (a "
                f"file's label is its name unless it carries one), and {name} beside it would "
                "give that label two files, which open_archive refuses. Give the experiment "
                f"another label (its file name comes from it){replace}; nothing was written."
            )


def _index_facts(directory: Path):
    """The journal files and the base facts of a directory's index (built first, as
    :func:`index_archive` does, when there is none of this version; a base of a newer
    version is left as it is, with a warning)."""
    journal = dirindex.journal_files(directory)
    facts = dirindex.base_facts(directory)
    if facts.newer is not None:
        _warn_newer(directory, facts.newer)
    elif not (facts.base and facts.ordered) and _nc_names(directory):
        _compact(directory, blocking=True)  # no index (of this version): build it now, once
        journal, facts = dirindex.journal_files(directory), dirindex.base_facts(directory)
    return journal, facts


def _warn_newer(directory: Path, version) -> None:
    warnings.warn(dirindex.newer_message(
        directory / dirindex.INDEX_NAME, version,
        "left as it is (rewriting it would drop what this version cannot read): the new files' "
        "entries go to its journal, and this version's opens read the headers of the files "
        "that its journal does not list"),
        RuntimeWarning, stacklevel=5)


def _next_order(journal, facts, directory: Path) -> int:
    """The order index of the next experiment written into the directory: after the
    largest of the base's and the journal's (read under the directory's write lock), and
    of the files the index does not list when the directory changed after the index was
    last written (:func:`_unindexed_orders`)."""
    orders = [o for o in (facts.top, dirindex.journal_max_order(journal)) if o is not None]
    if facts.newer is not None and not facts.ordered:  # a newer base without orders we know
        orders += [o for o in (dirx.order_index(directory / n, directory)
                               for n in _nc_names(directory)) if o is not None]
    else:
        orders += _unindexed_orders(directory, journal)
    return max(orders) + 1 if orders else 0


def _unindexed_orders(directory: Path, journal: list[str]) -> list[int]:
    """The orders of the directory's files that its index does not list: a writer that
    died after moving its file into place and before writing its journal file left one,
    as does one whose journal file could not be written (disk full; the warning says the
    next write reads their orders), and may another tool (the next write must not take
    such an order again).

    Looked for unless the newest journal file (``journal``: the one of the largest order,
    which the last complete write wrote after moving its files in) is newer than the
    directory's last change (a file moved in or removed, the index's base rewritten): an
    append after a complete one then costs two ``stat`` calls; otherwise (no journal
    file, e.g. after a compaction; a write that ended before its journal file) the names
    are listed, the index read and the order attribute of the files it does not list
    read.  The journal DIRECTORY's time does not tell: a journal write that failed, or a
    writer killed during it, changed it (its temporary) without a journal file.  A file
    whose order cannot be read is left to the checks of the write and of the open."""
    newest = max((n for n in journal if n.split("-", 1)[0].isdigit()), default=None)
    try:
        if newest is not None and (os.stat(directory).st_mtime_ns
                                   < os.stat(directory / dirindex.JOURNAL_NAME / newest).st_mtime_ns):
            return []
    except OSError:
        pass
    index = dirindex.read_index(directory, warn=False) or {}
    orders = []
    for name in _nc_names(directory):
        if name in index:
            continue
        try:
            order = dirx.order_index(directory / name, directory)
        except (OSError, ValueError):
            continue
        if order is not None:
            orders.append(order)
    return orders


def _next_position(directory: Path) -> tuple[int, bool]:
    """The position of an experiment appended to a directory (the order index it gets,
    from the index: no listing), and whether the archive's labels are text (those of the
    base's first file)."""
    journal, facts = _index_facts(directory)
    position = _next_order(journal, facts, directory)
    text = False
    if facts.first is not None and (directory / facts.first).is_file():
        header = dirx.read_header(directory / facts.first, directory)
        text = _label_kind(header["scalars"].get(cv.EXPERIMENT, Path(facts.first).stem)) == "text"
    return position, text


def _positions(experiment: xr.Dataset, start: int, text: bool) -> xr.Dataset:
    """An unlabelled experiment (or several stacked along ``experiment``) labelled by its
    positions in the archive from ``start`` on, as text when ``text``."""
    n = experiment.sizes.get(cv.EXPERIMENT)
    labels = [start] if n is None else list(range(start, start + n))
    labels = [str(lab) for lab in labels] if text else labels
    return experiment.assign_coords({cv.EXPERIMENT: labels[0] if n is None else labels})


def _write_checked(ds: xr.Dataset, path: Path, ref, label,
                   replace: bool = True, wait: bool = True) -> tuple[Path, dict, tuple, bool]:
    """Write ``ds`` to ``path`` atomically as :func:`lcmr_xr.io.save` does, unless the
    header of what was written (read back before it is moved into place) fails the test
    the directory's open applies against ``ref`` (``(path, header)`` of a file of the
    archive; see :func:`_check_structure`).  Returns the path, the header, the
    file's ``(st_dev, st_ino, st_size, st_mtime_ns)`` (which the rename keeps: the entry
    is the header's only if the file at ``path`` still has them) and whether the file
    system's clock had passed that modification time before the rename (so that any
    later change of the file changes it; :func:`lcmr_xr.scaleout.dirindex.wait_past`,
    at most one tick of coarse file times: without it the entry is written "racy"; not
    waited for without ``wait``: False).
    Without ``replace`` an existing ``path`` is never replaced (``FileExistsError``)."""
    from lcmr_xr.io._atomic import atomic_write
    from lcmr_xr.io._guards import check_not_own_source
    from lcmr_xr.io.netcdf import _ENGINE, _checksummed, _flatten_attrs, _map_attrs

    check_not_own_source(ds, path)
    flat = _checksummed(_map_attrs(ds, _flatten_attrs))  # the layout save writes
    got = []

    def write(tmp):
        flat.to_netcdf(tmp, engine=_ENGINE, auto_complex=True)
        header = dirx.read_header(Path(tmp), path.parent)
        if ref is not None:
            _check_structure(header, ref, label, path.parent)
            _check_units(header, ref, label)
        st = os.stat(tmp)
        got.extend([header, (st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns),
                     wait and dirindex.wait_past(path.parent, st.st_mtime_ns)])

    return atomic_write(path, write, overwrite=replace), *got


def _check_structure(header: dict, ref, label, directory: Path) -> None:
    """Refuse an experiment whose file differs from the archive's file ``ref`` where the
    directory's open requires them equal (the ``structure`` of :func:`_summary`): the
    variables' names, shapes and types, the time coordinates bit for bit, the channel
    labels.  The message says what differs and what to do."""
    if _summary(header)["structure"] == _summary(ref[1])["structure"]:
        return
    name = ref[0].name
    for coord in (cv.TIME, cv.SLOW_TIME):
        new, old = header[coord], ref[1][coord]
        if dirindex.bytes_digest(np.asarray(new)) == dirindex.bytes_digest(np.asarray(old)):
            continue
        if new is not None and old is not None and new.shape == old.shape and new.dtype.kind == "f":
            with np.errstate(divide="ignore", invalid="ignore"):
                rel = float(np.nanmax(np.abs(new - old) / np.maximum(np.abs(old), np.finfo(float).tiny)))
            what = (f"its {coord} coordinate differs from that of {name} by up to {rel:.2g} "
                    "relative (rounding)")
        else:
            what = f"its {coord} coordinate differs from that of {name} in type or length"
        raise ValueError(
            f"experiment {label!r}: {what}; the files of an archive directory must have the same "
            f"time coordinates bit for bit (the directory's open refuses them otherwise). Give it "
            f"the archive's coordinates, e.g. ref = lcmr_xr.open_experiment('{ref[0]}'); "
            f"exp.assign_coords(time=ref.time.variable, slow_time=ref.slow_time.variable), or use a consolidated "
            "archive, which keeps one time coordinate "
            "for all experiments and accepts sample times equal to 1e-9 relative."
        )
    raise ValueError(
        f"experiment {label!r} differs from {name} of archive {directory} in its variables "
        "(names, shapes, types) or channel labels; an archive holds experiments of one "
        "structure. Save it to another archive (compare them with lcmr_xr.open_dataset)."
    )


def _check_units(header: dict, ref, label) -> None:
    """Refuse an experiment whose ``r``, ``u`` or ``y`` has other units or long_name than in
    the archive's file ``ref``: the directory's open combines the variables' attributes
    with ``drop_conflicts``, and signals without them are no experiment (it refuses the
    directory)."""
    for name in ("r", "u", "y"):
        new, old = header["var_attrs"].get(name, {}), ref[1]["var_attrs"].get(name, {})
        for attr in ("units", "long_name"):
            if attr in new and attr in old and not dirx._equivalent(new[attr], old[attr]):
                raise ValueError(
                    f"experiment {label!r}: its variable {name!r} has {attr} {new[attr]!r} where "
                    f"{ref[0].name} has {old[attr]!r}; the directory's open would drop the "
                    f"conflicting {attr} and refuse the archive. Convert the experiment or set it "
                    f"(exp[{name!r}].attrs[{attr!r}] = {old[attr]!r}), or save it to another archive."
                )


def _index_new_files(directory: Path, rows: list, known, journal: int, unsettled=()) -> bool:
    """Add the new files' entries to the directory's index (one journal file); returns
    whether a compaction is due (:func:`_compact_if_due`, run outside the write lock).
    A failure only warns (the index is a shortcut)."""
    try:
        dirindex.append_journal(directory, rows, unsettled)
    except (OSError, ValueError) as err:
        _index_not_written(directory, err)
        return False
    return dirindex.compaction_due(known, journal + 1, len(rows))


def _index_not_written(directory: Path, err) -> None:
    warnings.warn(f"the archive index of {directory} was not written ({err}); the archive "
                  "is complete but opens from the headers of the new files, and the next "
                  "write reads their archive order from them (slower), until "
                  "lcmr_xr.scaleout.index_archive(directory) writes it.", RuntimeWarning,
                  stacklevel=5)


def _compact_if_due(directory: Path, due: bool) -> None:
    """The compaction a write found due (unless another process runs one)."""
    if not due:
        return
    try:
        _compact(directory, blocking=False)
    except (OSError, ValueError) as err:
        _index_not_written(directory, err)


def _compact(directory: Path, blocking: bool, verify: bool = False,
             refuse_newer: bool = False) -> Path | None:
    """Write the base of the directory's index from its current entries (base and
    journal) that match their files and the headers of the other files, then remove the
    journal files it folded in (a damaged one is set aside, one of a newer version left).
    ``verify``: decode every entry kept (a damaged one makes its header read).  Returns
    None when another process holds the compaction lock and ``blocking`` is False (that
    process compacts), and when the base is of a newer version (left as it is, with a
    warning; ``refuse_newer``: raise ValueError instead)."""
    with dirindex.compaction_lock(directory, blocking) as locked:
        if not locked:
            return None
        version = dirindex.base_version(directory)
        if dirindex.newer(version):
            if refuse_newer:
                raise ValueError(dirindex.newer_message(
                    directory / dirindex.INDEX_NAME, version,
                    "not rebuilt: this version would drop what it cannot read"))
            _warn_newer(directory, version)
            return None
        try:
            clock = dirindex.fs_clock(directory)  # before any file is stat-ed or read
        except OSError:  # no clock to read: every header read is unsettled
            clock = None
        journal = dirindex.journal_files(directory)
        report: dict = {}
        known = dirindex.read_index(directory, warn=False, journal=journal, report=report)
        load = dirindex.loader()
        rows, root, hot = [], os.fspath(directory), []
        for name in _nc_names(directory):  # strings: a Path per file costs more than its stat
            try:
                st = os.stat(os.path.join(root, name))
            except OSError:  # gone
                continue
            text, order = dirindex.trusted(known, name, st) or (None, None)
            if text is not None and (verify or order is None):
                try:
                    summary = load(text)
                    order = summary["attrs"].get(ORDER_ATTR, -1) if order is None else order
                except (ValueError, TypeError, KeyError, AttributeError):
                    text = None
            if text is None:
                summary = _summary(dirx.read_header(directory / name, directory))
                text, order = dirindex.summary_text(summary), summary["attrs"].get(ORDER_ATTR, -1)
                if clock is None or max(st.st_mtime_ns, st.st_ctime_ns) >= clock:
                    hot.append(len(rows))  # changed in the tick of its read: read again
            rows.append((name, dirindex.stamp(st), text, dirx.order_value(order, directory / name)))
        unsettled = _settle(directory, rows, hot)
        left = set(journal) - set(report["folded"]) - set(report["damaged"])
        out = dirindex.write_index(directory, rows, unsettled, kept=left)
        dirindex.remove_journal(directory, report["folded"])
        dirindex.set_aside(directory, report["damaged"])
        return out


def _settle(directory: Path, rows: list, hot: list) -> set:
    """Read again, once the file system's clock has passed their tick, the headers of the
    files ``rows[hot]`` that changed in the tick in which the compaction read them (a
    change after the read, in that tick, leaves their stamp as it was); a row is
    replaced by what is read then if its file's stamp is still the same.  Returns the
    names whose entries cannot be trusted (the clock did not pass in time, or the file
    changed again): written "racy" (:func:`lcmr_xr.scaleout.dirindex.write_index`)."""
    if not hot:
        return set()
    unsettled = set()
    passed = dirindex.wait_past(directory, max(max(rows[i][1][1], rows[i][1][2]) for i in hot))
    for i in hot:
        name, stamp = rows[i][:2]
        if passed:
            try:
                summary = _summary(dirx.read_header(directory / name, directory))
                now = dirindex.stamp(os.stat(directory / name))
            except (OSError, ValueError):
                now = None
            if now == stamp:
                rows[i] = (name, stamp, dirindex.summary_text(summary),
                           dirx.order_value(summary["attrs"].get(ORDER_ATTR, -1), directory / name))
                continue
        unsettled.add(name)
    return unsettled


def index_archive(directory) -> Path:
    """Write (or bring up to date) the header index of an archive directory.

    The library's writers of a directory archive keep the index current; this builds it
    for a directory written by an older version or by other tools, so that
    :func:`open_archive` takes each file's header facts from it instead of reading every
    file (see :mod:`lcmr_xr.scaleout.dirindex`).

    Parameters
    ----------
    directory : str or os.PathLike
        Archive directory (experiment files named ``*.nc``, ``*.nc4`` or ``*.netcdf``, any case).

    Returns
    -------
    pathlib.Path
        The index file, ``directory / ".lcmr_archive_index.nc"`` (written atomically).

    Raises
    ------
    FileNotFoundError, NotADirectoryError
        ``directory`` does not exist or is a file.
    ValueError
        A file of the directory is not a readable NetCDF file (named), or the index is
        of a newer version than this library writes (named, with the remedies: upgrade
        lcmr_xr, or delete the index file to rebuild it as this version).

    Notes
    -----
    Entries of the current index (its base and its journal) that still match their files
    (name, size, times, inode) are kept; every other file's header is read (about 4.6 ms
    a file).  The journal files it read are folded into the new base and removed; one
    of a newer version is left as it is, a damaged one set aside (renamed
    ``NAME.json.unreadable``, with a warning).  Waits for a compaction that another
    process is running.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from lcmr_xr.experiment import experiment
    >>> ds = experiment(np.ones((2, 8, 1)), np.ones((2, 8, 1)), np.ones((2, 4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     _ = save_archive(ds, d, layout="files")
    ...     index_archive(d).name
    '.lcmr_archive_index.nc'
    """
    directory = Path(directory)
    _nc_files(directory)  # refuse a path that is no directory
    return _compact(directory, blocking=True, verify=True, refuse_newer=True)


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


#: Experiments per dask chunk of a consolidated archive opened with ``chunks=None``:
#: 16 x 170 kB (N = 3600) is a few MB per chunk, read in one task.
EXPERIMENTS_PER_CHUNK = 16


def open_archive(path, chunks=None) -> xr.Dataset:
    """Open an archive (consolidated file or directory) as one lazy experiment dataset.

    Parameters
    ----------
    path : str or os.PathLike
        A consolidated archive file or an archive directory (experiment files named
        ``*.nc``, ``*.nc4`` or ``*.netcdf``, any case; hidden names are never read),
        as written by :func:`save_archive`.
    chunks : dict, optional
        Dask chunks, the same for both layouts.  Default ``None``:
        :data:`EXPERIMENTS_PER_CHUNK` experiments (files of a directory) per chunk, whole
        records along ``time``, which :func:`lcmr_xr.identify` needs (it rechunks the
        core dims to one chunk itself).  ``chunks["experiment"]``: a whole number >= 1 of
        experiments per chunk, -1 or None (one chunk) or ``"auto"`` (the default); every
        other entry is checked as :func:`lcmr_xr.io.open_dataset` checks chunks (a whole
        number >= 1, -1 or None for the whole dim, ``"auto"``, a size in bytes such as
        ``"64MiB"``, or a tuple of sizes adding up to the dim's length) and applied to the
        dims the archive has (``time``, ``slow_time``, ``input``, ``output``); entries for
        other dims are ignored, as ``open_dataset`` ignores them, and a malformed one
        (``{"time": "x"}``, ``{"time": 100.5}``, whatever the dim) is refused.  Sizes follow
        the library's integer rule, as ``open_dataset``'s (``64.0`` and a 0-d array
        ``np.array(64)`` are 64, ``1.5`` is refused, never rounded).

    Returns
    -------
    xarray.Dataset
        Dask-backed experiment dataset (``lcmr-xr-1``), ``experiment`` coordinate (the
        labels) in archive order, the experiments' metadata as coordinates along
        ``experiment``; ``encoding["source"]`` is the archive's path.  Checked with
        :func:`lcmr_xr.experiment.validate_experiment` on metadata only.

    Raises
    ------
    FileNotFoundError
        The path does not exist, or the directory holds no such file.
    ValueError
        ``path`` is a file but not a consolidated archive (not NetCDF-4, or without the
        file attribute ``lcmr_archive = "consolidated-1"``), a file of the directory is not
        a readable experiment file (the message names it), the experiments differ in
        length, factor, sample time or channel labels (the message lists them and says
        what to do), a file of the directory differs from the first in its variables,
        their shapes or types, or its time coordinates (named), or an entry of ``chunks``
        is malformed (refused before anything is read) or does not fit its dim.
    TypeError
        ``chunks`` is not None or a dict.

    Notes
    -----
    Nothing but metadata (and the small label and metadata coordinates) is read: the
    NaN/inf check of the data runs inside the tasks that identify them
    (:func:`lcmr_xr.scaleout.sweep` flags a bad experiment with ``experiment_error``;
    :func:`lcmr_xr.identify` on the lazy data raises when computed).

    A directory archive gives the dataset that concatenating the files along
    ``experiment`` gives (attributes that differ between files dropped).  The header
    facts of each file come from the directory's header index when its entry matches the
    file (name, size, modification and change times, inode; written by
    :func:`save_archive`, :func:`append_to_archive`, :func:`index_archive`), else from
    one pass over the file's header with h5py (:mod:`lcmr_xr.scaleout.directory`; no
    file is kept open); an unreadable index or one of another version is ignored with a
    warning, and more than :data:`UNINDEXED_WARN` files read from their headers warn once
    with the remedy (:func:`index_archive`).  Opening never writes (a read-only directory
    opens).  The tasks read their
    files' values directly, and a file that changed after the open is refused by its
    task with a :class:`lcmr_xr.scaleout.directory.StructureError` naming it.  Measured
    (N = 3600, fresh process, warm page cache, load 1.2-2.4): from the index, 100 /
    1 600 / 10 000 files in 0.08 s / 0.20 s / 0.60 s, +2.0 / +10 / +42 MB (10 000:
    1.34 s at load 1.7-3.5); from every file's header 0.74 s / 9.1 s / 60 s, +1.9 /
    +4.5 / +22 MB (the header reads, HDF5 object and attribute opens, ~0.1 ms each,
    about 40 per file, bound this): write the index of a directory written by other
    tools once (:func:`index_archive`).

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from lcmr_xr.experiment import experiment
    >>> ds = experiment(np.ones((3, 8, 1)), np.ones((3, 8, 1)), np.ones((3, 4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     _ = save_archive(ds, os.path.join(d, "arc.nc"))
    ...     arc = open_archive(os.path.join(d, "arc.nc"))
    ...     dict(arc.r.sizes), arc.r.chunks is not None
    ({'experiment': 3, 'time': 8, 'input': 1}, True)
    """
    from lcmr_xr.experiment import validate_experiment

    path = Path(path)
    if chunks is not None and not isinstance(chunks, dict):  # [1] failed inside: 'list' has no .get
        raise TypeError(f"chunks must be None or a dict such as {{'experiment': "
                        f"{EXPERIMENTS_PER_CHUNK}}}, got {chunks!r} ({type(chunks).__name__}).")
    other = _other_chunks(chunks)  # before any read: a bad argument is not a bad archive
    if path.is_file():
        _check_consolidated(path)
        # checked as for a directory (0 passed, 1.5 failed inside dask); -1: one chunk
        per_chunk = _files_per_chunk(chunks, -1)
        try:
            ds = con.open_consolidated(path, per_chunk)
        except (OSError, KeyError) as err:
            raise ValueError(f"{path} is not a readable consolidated archive ({err}); write one "
                             "with lcmr_xr.scaleout.save_archive.") from err
        ds = _chunk_other_dims(ds, other)
        ds.encoding["source"] = str(path)
        try:
            return validate_experiment(ds, check_values=False)
        except ValueError as err:
            raise ValueError(f"archive {path}: {err}") from err
    return _open_directory(path, chunks, other)


def _other_chunks(chunks) -> dict:
    """The entries of ``chunks`` other than ``experiment``, checked and read as
    :func:`lcmr_xr.io.open_dataset` reads chunks (its words for a malformed one, whatever
    the dim: ``{'time': 'x'}``, ``{'time': 100.5}``; whole floats and 0-d arrays as ints)."""
    rest = {d: c for d, c in (chunks or {}).items() if d != cv.EXPERIMENT}
    if not rest:
        return {}
    from lcmr_xr.io.netcdf import _check_chunks

    return _check_chunks(rest)


def _chunk_other_dims(ds: xr.Dataset, other: dict) -> xr.Dataset:
    """``ds`` rechunked by the entries of ``other`` (:func:`_other_chunks`) for the dims it
    has; the others are ignored, as :func:`lcmr_xr.io.open_dataset` ignores them.  Sizes
    that do not fit a dim (a tuple that does not add up to its length) are refused here,
    naming the dim and its length."""
    rest = {d: c for d, c in other.items() if d in ds.dims}
    if not rest:
        return ds
    try:
        return ds.chunk(rest)
    except ValueError as err:
        sizes = {d: ds.sizes[d] for d in rest}
        raise ValueError(f"chunks {rest!r} do not fit the archive's dims {sizes} ({err}); pass "
                         "sizes that add up to each dim's length, or one size per dim, e.g. "
                         f"{{{next(iter(rest))!r}: 100}}.") from err


#: What an archive is, for the messages that refuse something else.
ARCHIVE_KINDS = ("an archive is one NetCDF file written by lcmr_xr.scaleout.save_archive (file "
                 f"attribute {con.KIND_ATTR}={con.KIND!r}) or a directory of experiment .nc (.nc4, .netcdf) files")


def _check_consolidated(path: Path) -> None:
    """Refuse a file that is not a consolidated archive: name it, say why and what an archive is."""
    if con.is_consolidated(path):
        return
    import h5py

    try:
        with h5py.File(path, "r"):
            reason = f"a NetCDF-4 file without the archive attribute {con.KIND_ATTR}={con.KIND!r}"
    except OSError:
        reason = "not a NetCDF-4 file"
    raise ValueError(
        f"archive {path} is a file but not a consolidated archive ({reason}); {ARCHIVE_KINDS}. "
        "Open a single experiment file with lcmr_xr.open_experiment, or turn a directory into "
        "an archive file with lcmr-xr archive consolidate."
    )


def _open_directory(directory: Path, chunks, other: dict) -> xr.Dataset:
    """A directory archive as one lazy dataset, from one header pass over its files.

    The result is what concatenating every file's lazy xarray open along ``experiment``
    gives (file attributes and variable attributes combined with ``drop_conflicts``, the
    coordinates of the first file, the metadata as coordinates), without keeping a
    handle or a lazy array per file: see :mod:`lcmr_xr.scaleout.directory`.
    """
    from lcmr_xr.experiment import validate_experiment
    from lcmr_xr.io import open_dataset

    paths = _nc_files(directory)
    if not paths:
        raise FileNotFoundError(
            f"archive directory {directory} holds no .nc, .nc4 or .netcdf files (any case; "
            "hidden names are not read); write experiments into it with "
            "lcmr_xr.scaleout.save_archive."
        )
    # one pass in name order; only small summaries are kept per file (not the headers)
    files, foreign = [], []
    merged = dirx.DropConflicts()
    signatures: dict = {}  # variable attributes / structure -> (id, first file with them)
    for path, st, summary in _summaries(directory, paths):
        attrs = summary["attrs"]
        index = dirx.order_value(attrs.get(ORDER_ATTR), path)
        row = {"path": path, "key": (0 if index is not None else 1,
                                     index if index is not None else 0, path.name),
               "stamp": None if st is None else dirindex.stamp(st)}
        files.append(row)
        if not summary["experiment"]:
            foreign.append(row)
            continue
        row["shape"] = summary["shape"]
        scalars = summary["scalars"]
        label = scalars.get(cv.EXPERIMENT, path.stem)
        row["label"] = label
        row["meta"] = con.checked_metadata(  # as con.metadata_of of the file's dataset
            label, {n: v for n, v in scalars.items() if n != cv.EXPERIMENT}, attrs)
        merged.add({k: v for k, v in attrs.items() if k != ORDER_ATTR and k not in con.METADATA})
        for kind, sig in (("structure", summary["structure"]), ("attrs", summary["var_attrs"])):
            row[kind] = signatures.setdefault((kind, sig), (len(signatures), path))[0]
        del summary
    files.sort(key=lambda row: row["key"])
    if foreign:
        _refuse_foreign(min(foreign, key=lambda row: row["key"])["path"])
    lengths = {}
    for row in files:
        lengths.setdefault(row["shape"]["N"], []).append(row["path"].name)
    if len(lengths) > 1:
        raise ValueError(_length_message(lengths, f"the files of {directory}"))
    first = files[0]
    for row in files:
        if row["shape"] != first["shape"] and not _same_shape(row["shape"], first["shape"]):
            raise ValueError(
                f"{row['path'].name} ({_describe(row['shape'])}) does not match "
                f"{first['path'].name} ({_describe(first['shape'])}); an archive holds "
                "experiments of one shape. Move it to another directory."
            )
    for row in files:
        if row["structure"] != first["structure"]:
            raise ValueError(
                f"{row['path'].name} differs from {first['path'].name} in its variables (names, "
                "shapes, types) or in its time and channel coordinates; an archive holds "
                f"experiments of one structure. Move it to another directory (compare them with "
                f"lcmr_xr.open_dataset)."
            )
    _check_label_kinds([(row["label"], row["path"].name) for row in files],
                       f"the files of archive {directory}",
                       "Move the files of one kind to another directory, or save them again "
                       "relabelled: save_archive(lcmr_xr.open_experiment(path).assign_coords("
                       "experiment=str(label)), directory, layout='files'), then remove the old file.")
    owners: dict = {}
    for row in files:
        owners.setdefault(row["label"], []).append(row["path"].name)
    twice = {label: names for label, names in owners.items() if len(names) > 1}
    if twice:
        label, names = next(iter(twice.items()))
        raise ValueError(
            f"archive {directory}: experiment label {label!r} is carried by {len(names)} files "
            f"({', '.join(names[:4])}){f' and {len(twice) - 1} more labels likewise' if len(twice) > 1 else ''}"
            "; a label names one experiment (a file copied or renamed by hand keeps the label it "
            "holds). Move the copies out of the directory; to keep one as another experiment, "
            "save it back under a new label: save_archive(lcmr_xr.open_experiment(path)"
            ".assign_coords(experiment=new_label), directory, layout='files')."
        )
    metas = [(row["label"], row["meta"]) for row in files]
    try:
        con.check_metadata(metas, _metadata_kinds(metas))
    except ValueError as err:
        raise ValueError(f"archive {directory}: {err}") from err

    template = _template(first["path"])
    # variable attributes: drop_conflicts over the files, from one file per distinct set
    by_id = {ident: path for ident, path in signatures.values()}
    decoded = {first["attrs"]: _variable_attrs(template)}
    merged_vars: dict = {}
    seen = set()
    for row in files:  # in archive order; merging one set again would change nothing
        ident = row["attrs"]
        if ident in seen:
            continue
        seen.add(ident)
        if ident not in decoded:
            with open_dataset(by_id[ident], chunks={}) as other:
                decoded[ident] = _variable_attrs(_as_part(other, by_id[ident]))
        for name, attrs in decoded[ident].items():
            merged_vars.setdefault(name, dirx.DropConflicts()).add(attrs)
    ordered = [row["path"] for row in files]
    signals = dirx.lazy_signals(ordered, template, _files_per_chunk(chunks, len(ordered)),
                                stamps=[row["stamp"] for row in files])
    labels = np.asarray([row["label"] for row in files],
                        dtype=template[cv.EXPERIMENT].dtype if template[cv.EXPERIMENT].dtype == object else None)
    data_vars = {
        name: xr.Variable((cv.EXPERIMENT, *var.dims), signals[name], merged_vars[name].result,
                          encoding=dict(var.encoding))
        for name, var in template.data_vars.items()
    }
    coords = {name: var.variable for name, var in template.coords.items() if name != cv.EXPERIMENT}
    coords[cv.EXPERIMENT] = xr.Variable(cv.EXPERIMENT, labels, merged_vars[cv.EXPERIMENT].result)
    for name in metas[0][1]:
        coords[name] = (cv.EXPERIMENT, np.asarray([m[name] for _, m in metas]),
                        {"long_name": name.replace("_", " ")})
    attrs = {k: merged.result[k] for k in template.attrs if k in merged.result}
    attrs.update({k: v for k, v in merged.result.items() if k not in attrs})
    combined = xr.Dataset(data_vars, coords, attrs)
    combined.encoding["source"] = str(directory)
    combined = _chunk_other_dims(combined, other)  # as a consolidated archive's
    try:
        return validate_experiment(combined, check_values=False)
    except ValueError as err:
        raise ValueError(f"archive {directory}: {err}") from err


def _metadata_kinds(metas: list) -> dict:
    """The metadata kinds a directory's files are held to: the first file's, an integer
    made float where any file has a float (the coordinate is then float), so that the
    verdict does not depend on which file comes first: an append, which checks ONE file,
    puts its file before the files without an order (written by other tools)."""
    want = con.check_metadata(metas[:1])
    floats = {name for _, meta in metas for name, value in meta.items() if isinstance(value, float)}
    return {name: "f" if kind == "i" and name in floats else kind for name, kind in want.items()}


def _files_per_chunk(chunks, n_files: int) -> int:
    """Files per dask chunk (task) of a directory archive from ``chunks["experiment"]``, as
    dask reads it: -1 or None one chunk, "auto" the default; a number by the library's
    integer rule, as :func:`lcmr_xr.io.open_dataset` reads chunks (``16.0``, ``np.array(16)``
    are 16; ``1.5`` is refused, never rounded)."""
    from lcmr_xr.io.netcdf import _whole

    value = _whole((chunks or {}).get(cv.EXPERIMENT, EXPERIMENTS_PER_CHUNK))
    if value is None or (isinstance(value, (int, np.integer)) and value == -1):
        return max(1, n_files) if n_files >= 0 else -1  # -1: dask's "one chunk" (consolidated)
    if isinstance(value, str) and value == "auto":
        return EXPERIMENTS_PER_CHUNK
    if isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value > 0:
        return int(value)
    raise ValueError(
        f"chunks['experiment'] = {value!r} is no positive number of experiments per chunk; "
        f"pass e.g. {{'experiment': {EXPERIMENTS_PER_CHUNK}}} (-1: one chunk, 'auto': the default)."
    )


def _as_part(ds: xr.Dataset, path: Path) -> xr.Dataset:
    """One file as the directory archive combines it: order and metadata attributes and
    scalar coordinates dropped, an ``experiment`` coordinate (the file name) if it has none."""
    ds.attrs.pop(ORDER_ATTR, None)
    if cv.EXPERIMENT not in ds.coords:  # a file written by another tool
        ds = ds.assign_coords({cv.EXPERIMENT: ((), path.stem, cv.label_attrs("experiment"))})
    scalars = [c for c in ds.coords if ds[c].ndim == 0 and c != cv.EXPERIMENT]
    ds = ds.drop_vars(scalars)
    ds.attrs = {k: v for k, v in ds.attrs.items() if k not in con.METADATA}
    return ds


def _template(path: Path) -> xr.Dataset:
    """The first file of the archive, read whole (it is small) and closed."""
    from lcmr_xr.io.netcdf import _LAZY_ENGINE, _map_attrs, _restore_attrs

    # the engine of lcmr_xr.io.open_dataset's lazy reads, so the encodings are the same
    with xr.open_dataset(path, engine=_LAZY_ENGINE, decode_timedelta=False) as raw:
        try:
            loaded = _map_attrs(raw.load(), lambda owner, attrs: _restore_attrs(attrs))
        except OSError as err:  # its header read, its values not: damaged (checksum) or cut
            raise ValueError(
                f"{path}: its stored values cannot be read ({err}): the file is damaged (a "
                "checksum failed) or truncated; move it out of the archive directory, or "
                "restore it, and open the archive again.") from err
    return _as_part(loaded, path)


def _variable_attrs(ds: xr.Dataset) -> dict:
    return {name: dict(ds[name].attrs) for name in [*ds.data_vars, cv.EXPERIMENT]}


def _refuse_foreign(path: Path) -> None:
    from lcmr_xr.io import open_dataset

    try:
        with open_dataset(path, chunks={}) as ds:
            conventions, names = ds.attrs.get("conventions"), sorted(ds.data_vars)
    except ValueError:
        conventions, names = None, []
    raise ValueError(
        f"{path} is not an lcmr-xr-1 experiment file (conventions {conventions!r}, variables "
        f"{names}); move it out of the archive directory."
    )
