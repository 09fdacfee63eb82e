"""NetCDF files of experiments and FRF results: atomic writes, exact complex round trips.

NetCDF attributes must be flat (strings, numbers, 1-d arrays).  Python values that are not
(``bool``, ``tuple``, ``list``, ``None``) are converted on :func:`save` and their original
types recorded in a JSON attribute ``lcmr_attr_types`` on the same object, so that
:func:`open_dataset` restores them and a saved dataset opens ``assert_identical``.
"""

from __future__ import annotations

import json
import numbers
import warnings
from numbers import Number
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr.conventions import CONVENTIONS, FREQUENCY, INPUT, OUTPUT
from lcmr_xr.io._atomic import atomic_write
from lcmr_xr.io.matfile import is_mat_path, open_mat_experiment, save_mat
from lcmr_xr.io._atomic import check_writable_target
from lcmr_xr.io._guards import MAT_SUFFIX, NETCDF_SUFFIXES, check_not_own_source, check_suffix
from lcmr_xr.experiment.dataset import validate_experiment
from lcmr_xr.settings import as_integer

__all__ = ["open_dataset", "open_experiment", "open_frf", "save"]

_LAZY_ENGINE = "h5netcdf"
_ENGINE = "netcdf4"
_TYPES_ATTR = "lcmr_attr_types"


# --- attribute flattening -------------------------------------------------------------


def _is_complex(value) -> bool:
    if isinstance(value, (tuple, list)):
        return any(_is_complex(v) for v in value)
    return isinstance(value, (complex, np.complexfloating)) or (
        isinstance(value, np.ndarray) and value.dtype.kind == "c")


def _flatten_value(owner: str, key: str, value):
    """``(flat_value, type_tag or None)`` for one attribute value."""
    if _is_complex(value):  # netCDF4 refused it mid-write: "illegal data type for attribute b'c'"
        raise TypeError(
            f"attribute {key!r} of {owner} is complex ({value!r}), which NetCDF attributes cannot "
            "store; keep it as a (complex) variable instead, or as two attributes of its real "
            "and imaginary parts."
        )
    if isinstance(value, (bool, np.bool_)):
        return int(value), "bool"
    if value is None:
        return "", "none"
    if isinstance(value, (tuple, list)):
        if len(value) == 0:
            return "", f"empty_{type(value).__name__}"
        items = list(value)
        if all(isinstance(v, str) for v in items):
            return items, type(value).__name__
        if all(isinstance(v, (Number, np.number)) and not isinstance(v, (bool, np.bool_)) for v in items):
            return np.asarray(items), type(value).__name__
        if all(isinstance(v, (bool, np.bool_)) for v in items):
            return np.asarray(items, dtype=np.int8), f"bool_{type(value).__name__}"
        raise TypeError(
            f"attribute {key!r} of {owner} is a {type(value).__name__} of mixed types {value!r}, "
            "which NetCDF cannot store; make it all numbers or all strings, or a JSON string."
        )
    if isinstance(value, np.ndarray) and value.dtype == bool:
        return value.astype(np.int8), "bool_array"
    if isinstance(value, np.ndarray) and value.ndim > 1:
        raise TypeError(
            f"attribute {key!r} of {owner} is a {value.ndim}-d array; NetCDF attributes are "
            "1-d. Store it as a variable instead, or flatten it."
        )
    if isinstance(value, (str, bytes, Number, np.number, np.ndarray)):
        return value, None
    raise TypeError(
        f"attribute {key!r} of {owner} has type {type(value).__name__}, which NetCDF cannot "
        "store; use a string, number, or 1-d sequence (e.g. json.dumps for a dict)."
    )


def _flatten_attrs(owner: str, attrs: dict) -> dict:
    if _TYPES_ATTR in attrs:
        raise ValueError(f"{owner} already has the reserved attribute {_TYPES_ATTR!r}; remove it.")
    out, types = {}, {}
    for key, value in attrs.items():
        flat, tag = _flatten_value(owner, key, value)
        out[key] = flat
        if tag is not None:
            types[key] = tag
    if types:
        out[_TYPES_ATTR] = json.dumps(types, sort_keys=True)
    return out


def _restore_value(value, tag: str):
    if tag == "bool":
        return bool(value)
    if tag == "none":
        return None
    if tag.startswith("empty_"):
        return () if tag == "empty_tuple" else []
    if tag == "bool_array":
        return np.asarray(value).astype(bool)
    seq = np.atleast_1d(value) if not isinstance(value, (list, str)) else value
    if isinstance(seq, str):
        seq = [seq]
    items = [v.item() if isinstance(v, np.generic) else v for v in list(seq)]
    if tag.startswith("bool_"):
        items = [bool(v) for v in items]
        tag = tag[len("bool_"):]
    return tuple(items) if tag == "tuple" else items


def _restore_attrs(attrs: dict) -> dict:
    # netCDF4 hands back numpy scalars; plain Python numbers are what users wrote.
    out = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in attrs.items()}
    if _TYPES_ATTR not in out:
        return out
    types = json.loads(out.pop(_TYPES_ATTR))
    for key, tag in types.items():
        if key in out:
            out[key] = _restore_value(out[key], tag)
    return out


def _map_attrs(ds: xr.Dataset, func) -> xr.Dataset:
    out = ds.copy(deep=False)
    out.attrs = func("the dataset", dict(ds.attrs))
    for name, var in out.variables.items():
        # shallow copy: new Variable objects, so the caller's attrs are never touched
        var.attrs = func(f"variable {name!r}", dict(ds.variables[name].attrs))
    return out


# --- public API ---------------------------------------------------------------------


def save(ds: xr.Dataset, path) -> Path:
    """Write a dataset to NetCDF-4 (or a MATLAB ``.mat`` file) atomically, complex values included.

    Parameters
    ----------
    ds : xarray.Dataset
        Any dataset (experiment, FRF, spectra).  Attribute values that NetCDF cannot hold
        (bool, tuple, list, None) are converted and restored by :func:`open_dataset`;
        complex attribute values are refused (TypeError: NetCDF has no complex attributes).
    path : str or os.PathLike
        Target file; its directory must exist.  An existing file is replaced.  Its name
        ends in ``.nc``, ``.nc4`` or ``.netcdf`` (NetCDF-4; any case), or ``.mat``: a path
        ending in ``.mat`` writes an FRF or experiment dataset for MATLAB instead
        (:func:`lcmr_xr.io.matfile.save_mat`: ``P`` as ``ny x nu x nf``, frequency in Hz,
        ``Ts``, channel names, so that ``frd`` takes it in one line).  The file a lazy
        (dask-backed) ``ds`` was opened from and still reads is refused.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ValueError
        If ``path`` ends in another suffix (``x.txt``, or none): the accepted ones are
        named; or it is the file a lazy ``ds`` still reads.
    IsADirectoryError, PermissionError
        If ``path`` is a directory or lies in one that cannot be written.
    TypeError
        If ``ds`` is not a Dataset.

    Notes
    -----
    Every array is stored with HDF5's Fletcher-32 checksum, so that a file whose stored
    bytes were damaged later is refused when read (:func:`open_dataset`) instead of
    returning other numbers.
    The data are written to a temporary file in the same directory, flushed to disk, and
    moved over ``path`` with :func:`os.replace` (atomic on POSIX), so a failure mid-write
    never leaves a half-written file and never destroys an existing one.  The temporary is
    the hidden ``.NAME.HOST-PID.XXXXXXXX.tmp`` next to ``path``; when a process is killed
    mid-write it stays behind, and the next ``save`` to the same ``path`` removes it (the
    temporaries of writers that no longer run).  Complex arrays use the netCDF4
    ``auto_complex`` compound type and read back bit for bit.

    Examples
    --------
    >>> import numpy as np, xarray as xr, tempfile, os
    >>> ds = xr.Dataset({"P": ("frequency", np.array([1 + 2j, 3 - 1j]))},
    ...                 attrs={"degrees": (3, 3, 3), "noise": True})
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = save(ds, os.path.join(d, "frf.nc"))
    ...     xr.testing.assert_identical(open_dataset(p), ds)
    """
    if not isinstance(ds, xr.Dataset):
        raise TypeError(
            f"save writes an xarray.Dataset, got {type(ds).__name__}; for a DataArray use "
            "x.to_dataset(name='...')."
        )
    check_not_own_source(ds, path)
    check_writable_target(path)  # (a directory is named as one, not as a wrong file type)
    # the name says the format: x.txt or x (no suffix) held NetCDF-4 and nothing said so
    check_suffix(path, NETCDF_SUFFIXES + (MAT_SUFFIX,))
    if is_mat_path(path):
        return save_mat(ds, path)
    flat = _checksummed(_map_attrs(ds, _flatten_attrs))
    return atomic_write(path, lambda tmp: flat.to_netcdf(tmp, engine=_ENGINE, auto_complex=True))


def _checksummed(ds: xr.Dataset) -> xr.Dataset:
    """``ds`` (a shallow copy of the caller's) with a Fletcher-32 checksum on every array.

    HDF5 checks no data by default: bytes flipped in a stored array read back as other
    numbers without a word.  With the checksum such a file is refused when read (HDF5
    verifies each chunk), as a truncated one is.  The filter needs chunked storage, so
    a ``contiguous`` layout carried over from a file read earlier is dropped.
    """
    for var in ds.variables.values():
        if var.ndim:
            encoding = {k: v for k, v in var.encoding.items() if k != "contiguous"}
            var.encoding = {**encoding, "fletcher32": True}
    return ds


def open_dataset(path, chunks=None) -> xr.Dataset:
    """Open a NetCDF file written by :func:`save`, restoring attribute types.

    Parameters
    ----------
    path : str or os.PathLike
        File to read.
    chunks : dict or "auto", optional
        Dask chunks.  Default ``None``: the data are loaded into memory and the file is
        closed (experiment and FRF files are small); with chunks the data stay lazy.
        Sizes follow the library's integer rule (:func:`lcmr_xr.settings.as_integer`):
        ``100.0`` and a 0-d array ``np.array(100)`` are 100, ``100.5`` is refused.

    Returns
    -------
    xarray.Dataset
        The stored dataset with its original attribute types.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If it is not a readable NetCDF file (truncated, corrupt or another format; a
        MATLAB ``.mat`` file is pointed to :func:`open_experiment`), or a chunk size is not a whole number >= 1, -1 (the whole dim), ``"auto"`` or None,
        or a tuple of chunk lengths (``{"time": (100, 100)}``) does not add up to its dim's
        length in the file (checked after the header is read: an argument, not the file, is wrong).
    TypeError
        If ``chunks`` is neither None, ``"auto"``, an int nor a dict.

    Examples
    --------
    >>> import numpy as np, xarray as xr, tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = save(xr.Dataset({"a": ("x", [1.0, 2.0])}), os.path.join(d, "a.nc"))
    ...     open_dataset(p)["a"].values.tolist()
    [1.0, 2.0]
    """
    path = Path(path)
    chunks = _check_chunks(chunks)  # before the read: a bad argument is not a corrupt file
    if path.is_dir():
        raise IsADirectoryError(
            f"{path} is a directory, not a NetCDF file; for an archive directory use "
            "lcmr_xr.scaleout.open_archive (or lcmr-xr sweep)."
        )
    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}; check the path.")
    if is_mat_path(path):  # a v7.3 file is HDF5 underneath: it must not open as a NetCDF
        raise ValueError(
            f"{path} is a MATLAB file; open_dataset reads NetCDF files. Read an experiment "
            "with lcmr_xr.open_experiment(path) (its r=, u=, y=, factor=, sampling_period= "
            "name the file's variables), or any .mat file with scipy.io.loadmat."
        )
    tuples = _chunk_tuples(chunks)
    if tuples:  # their sums against the file's dims, before dask sees them (its error was
        # reported as a corrupt file): the dims alone, read by the lazy open's library
        # (2 ms; through xarray, decode_cf=False, 26 ms: the whole open's time again)
        try:
            import h5netcdf

            with h5netcdf.File(path, "r") as head:
                sizes = {name: dim.size for name, dim in head.dimensions.items()}
        except (OSError, ValueError, RuntimeError, KeyError, IndexError) as err:
            raise _unreadable(path, err) from err
        _check_chunk_sums(tuples, sizes, path)
    try:
        # Lazy files stay open; a second netCDF4 handle on a file that another netCDF4 handle
        # holds can crash HDF5 (xarray issue 8289), so lazy reads go through h5netcdf, which
        # reads the same NetCDF-4 files (complex values included) and has no such problem.
        if chunks is None:
            options = {"engine": _ENGINE, "auto_complex": True}
        else:
            options = {"engine": _LAZY_ENGINE}
        with warnings.catch_warnings():
            # save stores each array in checksummed chunks (netCDF's default sizes, often the
            # whole array): dask chunks across them read a chunk more than once, which is
            # cheap at these sizes and no reason to warn on every lazy open
            warnings.filterwarnings("ignore", message="The specified chunks separate the stored",
                                    category=UserWarning)
            ds = xr.open_dataset(
                path,
                chunks=chunks,
                decode_timedelta=False,  # 's' time coordinates are plain floats in seconds
                **options,
            )
        if chunks is None:
            ds.load()
            ds.close()
    except (OSError, ValueError, RuntimeError, KeyError, IndexError) as err:
        raise _unreadable(path, err) from err
    out = _map_attrs(ds, lambda owner, attrs: _restore_attrs(attrs))
    if chunks is not None:
        out = _named_reads(out, path)
    out.set_close(ds.close)  # the copy's close() releases the file (lazy reads keep it open)
    return out


def _unreadable(path, err) -> ValueError:
    """The error for a file that xarray cannot open (names the file and the remedy)."""
    return ValueError(f"cannot read {path}: not a valid NetCDF-4 file (truncated, corrupt, or "
                      f"another format): {err}. Re-create it with lcmr_xr.save.")


def _chunk_tuples(chunks) -> dict:
    """The entries of a checked ``chunks`` dict that list every chunk's length (tuples)."""
    if not isinstance(chunks, dict):
        return {}
    return {dim: value for dim, value in chunks.items() if isinstance(value, tuple)}


def _check_chunk_sums(tuples: dict, sizes: dict, path) -> None:
    """Refuse a tuple of chunk lengths (``{'time': (3, 3)}``) that does not add up to its
    dim's length in the file ``path`` (``sizes``), naming the dim, its length and the sum;
    dims the file lacks are ignored, as xarray ignores any size for them."""
    for dim, value in tuples.items():
        if dim not in sizes or sum(value) == sizes[dim]:
            continue
        n = sizes[dim]
        example = (n // 2, n - n // 2) if n > 1 else (n,)
        raise ValueError(
            f"chunks {{{dim!r}: {value!r}}}: a tuple lists the length of every chunk along "
            f"{dim!r}, so it must add up to the dim's length, {n} in {path}, but it adds up to "
            f"{sum(value)}. Pass lengths that add up to {n}, e.g. {{{dim!r}: {example!r}}}, or a "
            f"single size for chunks of equal length, e.g. {{{dim!r}: {min(value)}}}."
        )


class _Corrupt(ValueError):
    """Stored values of a file that cannot be read (the message names the file)."""


class _NamedRead:
    """The array a lazy variable's dask tasks read (``array[key]``), whose read errors name
    the file: HDF5's own message (a failed checksum) does not."""

    __slots__ = ("array", "path")

    def __init__(self, array, path):
        self.array, self.path = array, path

    shape = property(lambda self: self.array.shape)
    dtype = property(lambda self: self.array.dtype)
    ndim = property(lambda self: self.array.ndim)

    def __getitem__(self, key):
        try:
            return np.asarray(self.array[key])
        except OSError as err:
            raise _Corrupt(
                f"cannot read {self.path}: its stored values are corrupt (HDF5: {err}; a bad sector, "
                "a bit flip, an incomplete copy). Restore it from a copy, or re-create it with "
                "lcmr_xr.save.") from err


def _named_reads(ds: xr.Dataset, path) -> xr.Dataset:
    """``ds`` (lazy) whose reads of ``path`` name the file when they fail: the array each
    variable's graph reads from (dask's ``original-`` layer of ``from_array``) wrapped in
    :class:`_NamedRead`; the keys and values are the same."""
    from dask.highlevelgraph import HighLevelGraph, MaterializedLayer

    out = {}
    for name, var in ds.variables.items():
        if var.chunks is None:
            continue
        graph = var.data.__dask_graph__()
        layers = dict(graph.layers)
        for key, layer in graph.layers.items():
            if key.startswith("original-") and len(layer) == 1:
                (k, array), = layer.items()
                if hasattr(array, "shape") and hasattr(array, "__getitem__"):
                    layers[key] = MaterializedLayer({k: _NamedRead(array, path)})
        if layers != dict(graph.layers):
            import dask.array as da

            data = da.Array(HighLevelGraph(layers, graph.dependencies), var.data.name,
                            var.data.chunks, meta=var.data._meta)
            out[name] = var.copy(data=data)
    return ds.assign(out) if out else ds


def _is_chunk_size(value) -> bool:
    if isinstance(value, str):  # "auto" or a size in bytes as dask reads it ("64MiB")
        if value == "auto":
            return True
        from dask.utils import parse_bytes

        try:
            parse_bytes(value)
        except (ValueError, TypeError):
            return False
        return True
    # a number of elements (>= 1) or -1 (the whole dim); -2 was reported as a corrupt file
    # by xarray's error, 0 silently meant the whole dim
    return (isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))
            and (value >= 1 or value == -1))


def _whole(value):
    """A whole number as the int dask needs, by the settings' integer rule
    (:func:`lcmr_xr.settings.as_integer`: ``100.0``, ``np.int64(100)`` and a 0-d array
    ``np.array(100)`` are 100); a 0-d array of anything else is read as what it holds, and
    anything else is returned unchanged (for :func:`_check_chunks` to judge and word)."""
    if (isinstance(value, np.ndarray) or type(value).__name__ == "DataArray") and value.ndim == 0:
        value = value.item()
    if isinstance(value, numbers.Real) and not isinstance(value, (bool, np.bool_)):
        try:
            return as_integer(value, "chunks")
        except ValueError:  # a fraction, NaN or inf: _check_chunks's message names the remedy
            return value
    return value


def _check_chunks(chunks):
    """``chunks`` as dask takes it: None, ``"auto"``, an int, or a dict of dim -> size
    (int, ``"auto"``, a byte size such as ``"64MiB"``, None, or a tuple of ints); anything
    else is refused here, before xarray's own ValueError would be reported as an
    unreadable file.  Returns ``chunks`` with whole floats (``100.0``) as ints."""
    chunks = _whole(chunks)
    if isinstance(chunks, dict):
        chunks = {k: tuple(_whole(c) for c in v) if isinstance(v, tuple) else _whole(v)
                  for k, v in chunks.items()}
    if chunks is None or (isinstance(chunks, str) and chunks == "auto") or (
            _is_chunk_size(chunks) and not isinstance(chunks, str)):
        return chunks
    if isinstance(chunks, dict):
        bad = {k: v for k, v in chunks.items()
               if not (v is None or _is_chunk_size(v)
                       or (isinstance(v, tuple) and v and all(_is_chunk_size(c) and not isinstance(c, str)
                                                              for c in v)))}
        if not bad:
            whole = {k: v for k, v in chunks.items() if isinstance(v, tuple) and -1 in v}
            if whole:
                dim, value = next(iter(whole.items()))
                raise ValueError(
                    f"chunks {{{dim!r}: {value!r}}}: -1 (the whole dim) is a chunk size on its "
                    f"own, not a chunk's length in a tuple (the lengths of every chunk, each >= 1, "
                    f"adding up to the dim's length); pass {{{dim!r}: -1}} for one chunk, or "
                    "the lengths themselves."
                )
            return chunks
        raise ValueError(
            f"chunks {bad!r}: a chunk size must be a whole number (>= 1) of elements, 'auto', a size "
            "in bytes ('64MiB'), -1 (the whole dim) or None; pass e.g. "
            "chunks={'frequency': 100} or chunks={}."
        )
    if isinstance(chunks, (float, np.floating)) and np.isfinite(chunks):
        raise ValueError(f"chunks={chunks!r}: a chunk size is a whole number of elements, it is "
                         f"not rounded; pass chunks={int(np.floor(chunks))} or chunks={{}} (one "
                         "chunk per variable).")
    if isinstance(chunks, (int, np.integer)) and not isinstance(chunks, (bool, np.bool_)):
        raise ValueError(f"chunks={chunks!r}: a chunk size must be a whole number (>= 1) of "
                         "elements, or -1 (the whole dim); pass e.g. chunks={} (one chunk per "
                         "variable) or chunks={'frequency': 100}.")
    raise TypeError(
        f"chunks must be None (load into memory), 'auto', an int or a dict of dim -> size, got "
        f"{chunks!r} ({type(chunks).__name__}); pass e.g. chunks={{}} (one chunk per variable)."
    )


def _check_conventions(ds: xr.Dataset, path, kind: str) -> None:
    conv = ds.attrs.get("conventions")
    if conv != CONVENTIONS:
        raise ValueError(
            f"{path} is not an lcmr_xr {kind} file: its 'conventions' attribute is {conv!r}, "
            f"expected {CONVENTIONS!r}. Build an experiment from its arrays "
            "with lcmr_xr.experiment(r, u, y, factor=F, sampling_period=Th) (read them with "
            "lcmr_xr.open_dataset), or open it as it is with lcmr_xr.open_dataset."
        )


def open_experiment(path, chunks=None, **mat_options) -> xr.Dataset:
    """Open and validate an experiment file (``lcmr-xr-1``), NetCDF or MATLAB ``.mat``.

    Parameters
    ----------
    path : str or os.PathLike
        NetCDF file written by :func:`save` from an experiment dataset, or a MATLAB
        ``.mat`` file (v5, v7, v7.3; rows or columns, ``(1, 1)`` scalars).
    chunks : dict, optional
        Dask chunks (default: load into memory); NetCDF only.
    **mat_options
        For a ``.mat`` file only: ``r``, ``u``, ``y`` (variable names, default ``"r"``,
        ``"u"``, ``"y"``), ``factor`` and ``sampling_period`` (numbers or names of
        ``(1, 1)`` variables, default ``"F"`` and ``"Ts"``), ``inputs``, ``outputs``,
        ``input_units``, ``output_units``; see
        :func:`lcmr_xr.io.matfile.open_mat_experiment`.  Refused for NetCDF files.

    Returns
    -------
    xarray.Dataset
        Validated by :func:`lcmr_xr.experiment.validate_experiment`.

    Raises
    ------
    FileNotFoundError, ValueError
        Missing, unreadable, foreign (not ``lcmr-xr-1``) or invalid file; the message names
        the file and the problem.

    Examples
    --------
    >>> import numpy as np, tempfile, os
    >>> from lcmr_xr.experiment import experiment
    >>> ds = experiment(np.ones((8, 1)), np.ones((8, 1)), np.ones((4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = save(ds, os.path.join(d, "e.nc"))
    ...     open_experiment(p).attrs["factor"]
    2
    """
    if is_mat_path(path):
        if chunks is not None:
            raise ValueError(f"chunks applies to NetCDF files; {path} is a MATLAB file, read whole.")
        return open_mat_experiment(path, **mat_options)
    if mat_options:
        raise TypeError(
            f"{sorted(mat_options)} apply to MATLAB .mat files only; {path} is read as NetCDF, "
            "whose variables and attributes are fixed by the conventions."
        )
    ds = open_dataset(path, chunks=chunks)
    _check_conventions(ds, path, "experiment")
    try:
        return validate_experiment(ds)
    except _Corrupt:  # lazy data read by the check: named already
        raise
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from err


def open_frf(path, chunks=None) -> xr.Dataset:
    """Open an FRF result file and check its structure (``P``, ``frequency``, conventions).

    Parameters
    ----------
    path : str or os.PathLike
        NetCDF file written by :func:`save` from an FRF dataset.
    chunks : dict, optional
        Dask chunks (default: load into memory).

    Returns
    -------
    xarray.Dataset
        The FRF dataset (``P``, usually ``P_std``, settings in attributes).

    Raises
    ------
    FileNotFoundError, ValueError
        Missing, unreadable or foreign file, or ``P`` missing, not complex, or lacking the
        ``frequency``/``output``/``input`` dims.

    Examples
    --------
    >>> import numpy as np, xarray as xr, tempfile, os
    >>> frf = xr.Dataset({"P": (("frequency", "output", "input"), np.ones((3, 1, 1), complex))},
    ...                  coords={"frequency": [0.0, 1.0, 2.0], "output": ["y0"], "input": ["u0"]},
    ...                  attrs={"conventions": "lcmr-xr-1"})
    >>> with tempfile.TemporaryDirectory() as d:
    ...     open_frf(save(frf, os.path.join(d, "f.nc"))).sizes["frequency"]
    3
    """
    if is_mat_path(path):
        raise ValueError(
            f"{path} is a MATLAB file: FRFs are written to .mat for MATLAB's frd "
            "(scipy.io.loadmat reads it); open_frf reads the NetCDF file that lcmr_xr.save "
            "writes to a path ending in .nc."
        )
    ds = open_dataset(path, chunks=chunks)
    _check_conventions(ds, path, "FRF")
    if "P" not in ds.data_vars:
        raise ValueError(f"{path} has no variable 'P' (the FRF); is it an experiment file? Use open_experiment.")
    missing = [d for d in (FREQUENCY, OUTPUT, INPUT) if d not in ds["P"].dims]
    if missing:
        raise ValueError(f"{path}: 'P' has dims {ds['P'].dims}, missing {missing}; it is not an FRF file.")
    if FREQUENCY not in ds.coords:
        raise ValueError(f"{path}: the 'frequency' coordinate (Hz) is missing; the FRF cannot be placed.")
    if not np.issubdtype(ds["P"].dtype, np.complexfloating):
        raise ValueError(f"{path}: 'P' is {ds['P'].dtype}, expected complex; the file is not an FRF result.")
    return ds
