"""Directory archives (one NetCDF file per experiment): one cheap header pass per file.

An xarray open of a NetCDF-4 file resolves every dimension scale and decodes every
variable (about a hundred HDF5 lookups); done for each of 10 000 files it took 21 minutes
and kept 1.2 GB of handles and lazy arrays.  :func:`read_header` reads instead, with
h5py's low-level calls, only what opening an archive needs: the file attributes (order
index, conventions, factor, metadata, and the rest for ``drop_conflicts``), the names,
shapes and on-disk types of the variables, the attributes of the variables that are not
dimensions, the ``time`` coordinate and the channel labels, the ``experiment`` label and
other scalar coordinates.  Nothing is kept open.

:func:`lazy_signals` then builds each data variable as a dask array whose tasks read
their files' values directly (:func:`read_files`; several files per task, each opened once
for all its variables), decoded like
xarray decodes them.  The first file (opened once with xarray) is the template of names,
coordinates, attributes and encodings; the header pass refuses a file that differs from
it in variables, shapes or on-disk types, and a task refuses, naming the file, one that
changed after the archive was opened (another variable, shape, type, dims or encoding),
and one whose values HDF5 cannot read (:class:`DamagedFile`: a checksum or filter fails;
the header pass reads only headers).  A sweep reads instead NaN for such a file
(:func:`reading_damaged_as_nan`) and flags its experiment, saying why (:func:`damage`).

Attribute values are converted as h5netcdf and xarray convert them (fixed-length strings
decoded, one-element arrays unwrapped, bytes decoded) and then restored as
:func:`lcmr_xr.io.open_dataset` restores them; a file whose variable attributes differ
from the template's is opened with xarray to take its attributes exactly (rare: the
attributes of ``r``, ``u``, ``y`` are the same in the files of one archive).
"""

from __future__ import annotations

import operator
import os
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv

# The functions below serve lcmr_xr.scaleout.archive (the public API); only these are public.
__all__ = ["StructureError", "DamagedFile", "read_header", "read_files", "damage"]

#: Attributes that the netCDF library keeps for itself (h5netcdf hides them too).
_HIDDEN = frozenset(["REFERENCE_LIST", "CLASS", "DIMENSION_LIST", "NAME", "_Netcdf4Dimid",
                     "_Netcdf4Coordinates", "_nc3_strict", "_NCProperties"])
#: Variable attributes that decide how xarray decodes the stored values.
_DECODING = ("_FillValue", "missing_value", "scale_factor", "add_offset", "dtype", "_Unsigned",
             "units", "calendar")
#: Dimension variables of an experiment file (their values: time read, labels read, rest not).
_DIMS = (cv.TIME, cv.SLOW_TIME, cv.INPUT, cv.OUTPUT)


class StructureError(ValueError):
    """A file of a directory archive differs in structure from the archive's first file."""


class DamagedFile(ValueError):
    """The stored values of a file of a directory archive cannot be read (its header can)."""


def _damaged_message(path, err) -> str:
    return (f"{path} is damaged: its stored values cannot be read (HDF5: {err}; a bad sector, "
            "a bit flip, an incomplete copy). Restore it from a copy, or move it out of the "
            "archive directory and reopen the archive (a sweep flags its experiment in "
            "experiment_error and goes on).")


def damage(path) -> str | None:
    """Why the stored values of a file cannot be read: what a sweep says of an experiment
    whose file a task could not read.

    Parameters
    ----------
    path : pathlib.Path or str
        A file of an archive directory.

    Returns
    -------
    str or None
        The message (the file, HDF5's reason, what to do), or None when every variable
        of the file reads.
    """
    import h5py

    try:
        with _open(path) as f:
            for obj in f.values():
                if isinstance(obj, h5py.Dataset):
                    _read(obj.id)
    except OSError as err:
        return _damaged_message(path, err)
    return None


# ------------------------------------------------------------------ low-level reads
def _open(path):
    """An h5py file (read-only) opened as :func:`_open_id` opens it."""
    import h5py

    return h5py.File(_open_id(path))


_FAPLS = []


def _open_id(path):
    """A low-level read-only file id (the file closes once it and the ids opened in it are gone).

    Without HDF5's file locks when it can (a little faster): archive files are written
    whole and renamed into place (:func:`lcmr_xr.io.save`), so a reader never meets a file
    being written.  A file that this process holds open already with locks (e.g. a lazy
    dataset of it) must be opened with the same flags, so that is tried second.
    """
    from h5py import h5f, h5p

    if not _FAPLS:
        for locking in (False, True):
            fapl = h5p.create(h5p.FILE_ACCESS)  # close degree: HDF5's default, as h5py's
            if not locking:
                try:
                    fapl.set_file_locking(False, True)
                except (AttributeError, RuntimeError):  # HDF5 older than 1.12.1
                    continue
            _FAPLS.append(fapl)
    name = os.fsencode(path)
    for i, fapl in enumerate(_FAPLS):
        try:
            return h5f.open(name, h5f.ACC_RDONLY, fapl=fapl)
        except OSError:
            if i == len(_FAPLS) - 1:
                raise


def _archive_file_id(path, directory):
    """:func:`_open_id` of a file of archive ``directory``; one that HDF5 cannot open is
    named, with what to do."""
    try:
        return _open_id(path)
    except OSError as err:
        raise ValueError(
            f"{path} in archive {directory} is not a readable NetCDF file (truncated, corrupt, "
            f"or another format: {err}); move it out of the archive directory."
        ) from err


#: Per on-disk attribute type: its numpy dtype, h5py's memory type and string info
#: (the conversions cost more than the read).
_ATTR_TYPES: dict = {}


def _attr_type(attr):
    import h5py
    from h5py import h5t

    dtype = attr.dtype
    key = dtype if dtype.metadata is None else (dtype, tuple(sorted(dtype.metadata.items(), key=str)))
    known = _ATTR_TYPES.get(key)
    if known is None:
        known = _ATTR_TYPES[key] = (dtype, h5t.py_create(dtype), h5py.check_string_dtype(dtype))
    return known


def _attr_value(attr):
    """One attribute as h5netcdf returns it (strings decoded, one-element arrays unwrapped)."""
    from h5py import h5s

    dtype, mtype, info = _attr_type(attr)
    shape = attr.shape
    if not shape and attr.get_space().get_simple_extent_type() == h5s.NULL:  # h5py.Empty
        return b"" if info and info.length == 1 else np.array([], dtype=dtype)
    out = np.empty(shape, dtype=dtype)
    attr.read(out, mtype=mtype)
    value = out[()] if out.ndim == 0 else out
    if info is not None:
        if info.length is not None and info.length > 1:
            value = (value.decode(info.encoding, "surrogateescape") if np.isscalar(value)
                     else [b.decode(info.encoding, "surrogateescape") for b in value.flat])
        else:  # variable-length: h5py hands attributes back decoded
            value = (value.decode(info.encoding, "surrogateescape") if isinstance(value, bytes)
                     else [v.decode(info.encoding, "surrogateescape") if isinstance(v, bytes) else v
                           for v in value.flat] if info.length is None else value.tolist())
    if not np.isscalar(value) and len(value) == 1:
        value = value[0]
    return value


def raw_attributes(oid) -> dict:
    """``{name: value}`` of an HDF5 object's attributes, netCDF's own hidden, as h5netcdf reads them."""
    from h5py import h5a

    names = []
    h5a.iterate(oid, lambda name, *_: names.append(name))
    out = {}
    for name in names:
        key = name.decode("utf-8", "surrogateescape")
        if key not in _HIDDEN:
            out[key] = _attr_value(h5a.open(oid, name))
    return out


def _xarray_attrs(raw: dict) -> dict:
    """Attributes as xarray's h5netcdf backend hands them on (bytes decoded to str)."""
    out = {}
    for key, value in raw.items():
        if isinstance(value, bytes) and key not in ("_FillValue", "missing_value"):
            try:
                value = value.decode("utf-8")
            except UnicodeDecodeError:
                pass
        out[key] = value
    return out


def restored(raw: dict) -> dict:
    """File attributes as :func:`lcmr_xr.io.open_dataset` returns them."""
    from lcmr_xr.io.netcdf import _restore_attrs

    return _restore_attrs(_xarray_attrs(raw))


def _read(dset) -> np.ndarray:
    """The whole of a dataset (a low-level ``DatasetID``; strings as ``bytes`` objects)."""
    from h5py import h5s

    out = np.empty(dset.shape, dtype=dset.dtype)
    if out.size:
        dset.read(h5s.ALL, h5s.ALL, out)
    return out


def _labels(values) -> list[str]:
    return [v.decode("utf-8") if isinstance(v, bytes) else str(v) for v in np.ravel(values)]


def _decoded_scalar(name, value, raw_attrs):
    """A 0-d variable's value as xarray decodes it, as a Python scalar."""
    if isinstance(value, bytes):
        return value.decode("utf-8")
    var = xr.conventions.decode_cf_variable(name, xr.Variable((), value, _xarray_attrs(raw_attrs)),
                                            decode_timedelta=False)
    out = var.values[()]
    return out.item() if isinstance(out, np.generic) else out


# ------------------------------------------------------------------ one file's header
def read_header(path: Path, directory: Path) -> dict:
    """What opening an archive needs of one file, read in one pass (see the module notes).

    Parameters
    ----------
    path : pathlib.Path
        An experiment file of the archive.
    directory : pathlib.Path
        The archive directory (for the message about an unreadable file).

    Returns
    -------
    dict
        ``attrs`` (file attributes as :func:`lcmr_xr.io.open_dataset` restores them),
        ``variables`` (``{name: (shape, on-disk dtype)}`` of every variable),
        ``var_attrs`` (``{name: attributes as stored}`` of the variables that are not
        dimensions), ``scalars`` (``{name: value}`` of the 0-d variables, decoded),
        ``time`` and ``slow_time`` (values), ``inputs``, ``outputs`` (channel labels),
        ``path``.

    Raises
    ------
    ValueError
        The file is not a readable NetCDF-4/HDF5 file (named, with what to do).
    """
    from h5py import h5d, h5g

    fid = _archive_file_id(path, directory)
    try:
        header = {"path": path, "attrs": restored(raw_attributes(fid)), "variables": {},
                  "var_attrs": {}, "scalars": {}, cv.TIME: None, cv.SLOW_TIME: None, "inputs": None,
                  "outputs": None}
        root = h5g.open(fid, b"/")
        for link in list(root):
            name = link.decode("utf-8", "surrogateescape")
            try:
                dset = h5d.open(fid, link)
            except (KeyError, ValueError, OSError, TypeError):  # a group: not an experiment file
                header["variables"][name] = (None, None)
                continue
            shape = dset.shape
            header["variables"][name] = (shape, dset.dtype)
            if name in (cv.TIME, cv.SLOW_TIME):
                header[name] = _read(dset)
            elif name in (cv.INPUT, cv.OUTPUT):
                header["inputs" if name == cv.INPUT else "outputs"] = _labels(_read(dset))
            elif name not in _DIMS:
                raw = raw_attributes(dset)
                header["var_attrs"][name] = raw
                if len(shape) == 0:
                    header["scalars"][name] = _decoded_scalar(name, _read(dset)[()], raw)
        # a 0-d variable is a (metadata) coordinate only if a ``coordinates`` attribute
        # names it, as xarray decodes it; the others are data variables
        named = set()
        for raw in (header["attrs"], *header["var_attrs"].values()):
            if isinstance(raw.get("coordinates"), str):
                named.update(raw["coordinates"].split())
        header["scalars"] = {n: v for n, v in header["scalars"].items() if n in named}
        return header
    finally:
        fid.close()


def order_index(path: Path, directory: Path):
    """The archive order attribute of a file (None without it): one attribute read."""
    from h5py import h5a

    from lcmr_xr.scaleout.archive import ORDER_ATTR

    fid = _archive_file_id(path, directory)
    try:
        if not h5a.exists(fid, ORDER_ATTR.encode()):
            return None
        value = _attr_value(h5a.open(fid, ORDER_ATTR.encode()))
    finally:
        fid.close()
    return order_value(value, path)


def order_value(value, path):
    """The archive order that a file's order attribute ``value`` holds, as an int (None:
    no attribute).  Refuses anything but an integer (a float only if it is one): another
    tool's ``2.5`` or ``"b"`` is no order to guess from."""
    if value is None:
        return None
    from lcmr_xr.scaleout.archive import ORDER_ATTR

    v = np.asarray(value)
    if v.ndim == 0 and (v.dtype.kind in "iu" or (v.dtype.kind == "f" and float(v).is_integer())):
        return int(v)
    raise ValueError(
        f"{path}: its attribute {ORDER_ATTR}={value!r} is not an integer archive order. "
        f"Remove the attribute (the file then comes after the ordered ones, by name) or set "
        f"it to an integer, e.g. with h5py: h5py.File(path, 'r+').attrs[{ORDER_ATTR!r}] = 7.")


# ------------------------------------------------------------------ attributes across files
def _equivalent(a, b) -> bool:
    """xarray's ``equivalent`` for attribute values (arrays, lists, NaN)."""
    if a is b:
        return True
    try:
        if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
            a, b = np.asarray(a), np.asarray(b)
            if a.shape != b.shape and a.size != 1 and b.size != 1:
                try:
                    np.broadcast_shapes(a.shape, b.shape)
                except ValueError:
                    return False
            with np.errstate(invalid="ignore"):
                same = (a == b)
                if a.dtype.kind in "fc" or b.dtype.kind in "fc":
                    same = same | (_isnull(a) & _isnull(b))
            return bool(np.all(same))
        if isinstance(a, list) or isinstance(b, list):
            return (isinstance(a, list) and isinstance(b, list) and len(a) == len(b)
                    and all(_equivalent(x, y) for x, y in zip(a, b)))
        if _scalar_null(a) and _scalar_null(b):
            return True
        same = a == b
        return bool(same) if isinstance(same, (bool, np.bool_)) else False
    except (ValueError, TypeError):
        return False


def _isnull(a):
    return np.isnan(a) if a.dtype.kind in "fc" else np.zeros(a.shape, bool)


def _scalar_null(a) -> bool:
    try:
        return a is None or (isinstance(a, (float, np.floating)) and np.isnan(a))
    except TypeError:
        return False


class DropConflicts:
    """xarray's ``combine_attrs="drop_conflicts"`` fed one attribute dict at a time."""

    def __init__(self):
        self.result, self.dropped = {}, set()

    def add(self, attrs: dict) -> None:
        for key, value in attrs.items():
            if key in self.dropped:
                continue
            if key not in self.result:
                self.result[key] = value
            elif not _equivalent(self.result[key], value):
                del self.result[key]
                self.dropped.add(key)


# ------------------------------------------------------------------ reading the data in tasks
def _dim_names(dset) -> tuple:
    """Names of the dimension scales attached to an h5py dataset (None where none is)."""
    names = []
    for dim in dset.dims:
        scales = list(dim.values())
        names.append(scales[0].name.lstrip("/") if scales else None)
    return tuple(names)


def _refuse(path, spec: dict, what: str):
    raise StructureError(
        f"{path}: {what}, unlike the archive's first file {spec['first']} that the archive "
        f"was opened with; an archive holds experiments of one structure (was the file "
        f"replaced after open_archive?). Move {Path(path).name} to another directory, or "
        "reopen the archive."
    )


def _open_for_reading(path):
    """The file's low-level id; a file that cannot be opened any more is refused naming it
    (never read as damaged: it may be gone, moved out, or not readable for this user)."""
    try:
        return _open_id(path)
    except OSError as err:
        if not os.path.lexists(path):
            raise StructureError(
                f"{path} was removed or moved after the archive was opened ({err}); reopen the "
                "archive (open_archive) to read the files it holds now.") from err
        if not os.access(path, os.R_OK):
            raise StructureError(
                f"{path} cannot be opened for reading ({err}); give this user read permission "
                "on it, or move it out of the archive directory and reopen the archive.") from err
        raise StructureError(f"{path}: not a readable NetCDF file any more ({err}); move it out "
                             "of the archive directory and reopen the archive.") from err


def _encoding_of(dset) -> dict:
    """The attributes of a dataset (low-level id) that decide how xarray decodes it."""
    from h5py import h5a

    return {k: _attr_value(h5a.open(dset, k.encode())) for k in _DECODING
            if h5a.exists(dset, k.encode())}


def _dimids(dset):
    """netCDF's dimension ids of a dataset (the ``_Netcdf4Coordinates`` attribute), or None."""
    from h5py import h5a

    if not h5a.exists(dset, b"_Netcdf4Coordinates"):
        return None
    return tuple(int(v) for v in np.ravel(_attr_value(h5a.open(dset, b"_Netcdf4Coordinates"))))


def _read_from(fid, path, name: str, spec: dict) -> np.ndarray:
    """Variable ``name`` of the open file ``fid`` decoded as xarray decodes it, checked
    against ``spec`` (see :func:`read_files`)."""
    import h5py
    from h5py import h5d

    try:
        dset = h5d.open(fid, name.encode())
    except (KeyError, ValueError, OSError, TypeError):
        _refuse(path, spec, f"has no variable {name!r}")
    if dset.shape != spec["shape"] or dset.dtype != spec["raw_dtype"]:
        _refuse(path, spec, f"variable {name!r} is {dset.dtype} of shape {dset.shape}, not "
                            f"{spec['raw_dtype']} of shape {spec['shape']}")
    if spec["dimids"] is None or _dimids(dset) != spec["dimids"]:  # resolve the dims' names
        dims = _dim_names(h5py.Dataset(dset))
        if dims != spec["dims"]:
            _refuse(path, spec, f"variable {name!r} has the dims {dims}, not {spec['dims']}")
    encoding = _encoding_of(dset)
    if set(encoding) != set(spec["encoding"]) or not all(
            _equivalent(encoding[k], spec["encoding"][k]) for k in encoding):
        _refuse(path, spec, f"variable {name!r} is stored with the encoding {encoding}, not "
                            f"{spec['encoding']}")
    values = _read(dset)
    var = xr.conventions.decode_cf_variable(
        name, xr.Variable(spec["dims"], values, _xarray_attrs(encoding)), decode_timedelta=False)
    out = np.asarray(var.values)
    if h5py.check_string_dtype(dset.dtype) is not None:  # str objects, as xarray decodes them
        out = np.array([v.decode("utf-8") if isinstance(v, bytes) else v for v in out.flat],
                       dtype=object).reshape(out.shape)
    if out.dtype != spec["dtype"]:
        _refuse(path, spec, f"variable {name!r} decodes to {out.dtype}, not {spec['dtype']}")
    return out


#: Name prefix of the dask layer whose tasks call :func:`read_files` (see :func:`lazy_signals`).
READ_LAYER = "archive-read-"


def read_files(paths: tuple, specs: dict, damaged: str = "raise") -> dict:
    """The variables of several files, each stacked along a new leading axis (one dask task).

    Each file is opened once for all its variables.

    Parameters
    ----------
    paths : tuple of str
        The files, in archive order.
    specs : dict
        ``{name: spec}``: what each variable must be like (from the archive's first file,
        see :func:`lazy_signals`): ``shape``, ``raw_dtype``, ``dims``, ``encoding`` (the
        attributes that decide the decoding), ``dtype`` (decoded), ``first`` (its path).
    damaged : {"raise", "nan"}, default "raise"
        A file that opens but whose values cannot be read (damaged: HDF5's checksum or
        filter fails): :class:`DamagedFile` naming it, or (``"nan"``, the sweep's reads)
        its floating-point variables NaN, for the sweep to flag its experiment
        (:func:`damage` says why).  A file that does not open (removed or moved out after
        the open, no permission) is refused either way (:class:`StructureError`).

    Returns
    -------
    dict
        ``{name: numpy.ndarray}`` of shape ``(len(paths), *spec["shape"])``, decoded as
        xarray decodes the variable.

    Raises
    ------
    StructureError
        A file lacks a variable or stores it otherwise (type, shape, dims, encoding) than
        the first file did when the archive was opened, or does not open (removed, moved
        out, no permission, not HDF5 any more); the message names the file.
    DamagedFile
        A file's values cannot be read (with ``damaged="nan"``: only a variable that is not
        floating point); the message names the file and what to do.
    """
    out = {name: np.empty((len(paths),) + tuple(spec["shape"]), dtype=spec["dtype"])
           for name, spec in specs.items()}

    def unreadable(name, i, path, err):
        if damaged == "raise" or out[name].dtype.kind not in "fc":
            raise DamagedFile(_damaged_message(path, err)) from err
        out[name][i] = np.nan

    for i, path in enumerate(paths):
        fid = _open_for_reading(path)  # a file that does not open (gone, no permission): raised
        try:
            for name, spec in specs.items():
                try:
                    out[name][i] = _read_from(fid, path, name, spec)
                except OSError as err:  # HDF5 cannot read the stored values (checksum, filter)
                    unreadable(name, i, path, err)
        finally:
            fid.close()
    return out


def reading_damaged_as_nan(array):
    """``array`` (dask) whose reads of archive files (:func:`read_files`) give NaN for a
    damaged file instead of failing: for a computation that treats NaN as a failed
    experiment and says why (the sweep, :func:`damage`).

    The keys are the same (a renamed read layer would need every layer above it renamed):
    computed in ONE ``dask.compute`` with other uses of the same lazy data, a damaged file
    may be read either way for both (an error naming it, or NaN).  Undamaged files read
    the same values either way.
    """
    from dask.highlevelgraph import HighLevelGraph, MaterializedLayer

    graph = array.__dask_graph__()
    layers, changed = dict(graph.layers), False
    for name, layer in graph.layers.items():
        if not name.startswith(READ_LAYER):
            continue
        tasks = dict(layer)
        for key, task in tasks.items():
            if type(task) is tuple and len(task) == 3 and task[0] is read_files:
                tasks[key] = (read_files, task[1], task[2], "nan")
                changed = True
        layers[name] = MaterializedLayer(tasks)
    if not changed:
        return array
    import dask.array as da

    return da.Array(HighLevelGraph(layers, graph.dependencies), array.name, array.chunks,
                    meta=array._meta)


def directories_read(array) -> tuple[str, ...]:
    """The directories of the archive files that the dask ``array`` reads (its
    :func:`read_files` tasks; ``()`` for other data): where a sweep looks for the file of
    an experiment whose values are NaN (:func:`damage`), whatever became of the dataset's
    ``encoding`` (``astype`` and most operations drop it)."""
    graph = getattr(array, "__dask_graph__", lambda: None)()
    if graph is None:
        return ()
    found = {}
    for name, layer in graph.layers.items():
        if not name.startswith(READ_LAYER):
            continue
        for task in layer.values():
            if type(task) is tuple and len(task) >= 3 and task[0] is read_files and task[1]:
                found.update(dict.fromkeys(os.path.dirname(os.fspath(p)) for p in task[1]))
    return tuple(found)


def variable_spec(first: Path, name: str, template: xr.Variable) -> dict:
    """What a file's variable must be like to be read as ``template`` (the first file's)."""
    with _open(first) as f:
        dset = f[name]
        spec = {"shape": dset.shape, "raw_dtype": dset.dtype, "dims": _dim_names(dset),
                "dimids": _dimids(dset.id), "encoding": _encoding_of(dset.id)}
    # strings as objects: a fixed width (the first file's) would truncate longer ones
    spec.update(dtype=np.dtype(object) if template.dtype.kind in "SU" else template.dtype,
                first=str(first))
    if spec["dims"] != template.dims:
        raise StructureError(f"{first}: variable {name!r} has the dims {spec['dims']} on disk but "
                             f"{template.dims} when xarray reads it; rewrite it with lcmr_xr.save.")
    return spec


def lazy_signals(files: list[Path], template: xr.Dataset, per_chunk: int, stamps=None) -> dict:
    """``{name: dask array}`` of every data variable of ``template`` over ``files`` (leading
    ``experiment`` axis, ``per_chunk`` files per task).

    The arrays' dask names digest every file's ``stamps`` (size, times, inode, as the
    caller took them; stat-ed here when not given): a file rewritten in place gives new
    names, so a cluster that still holds the old chunks (``persist``) never serves them
    for the new contents.
    """
    import dask.array as da
    from dask.base import tokenize
    from dask.highlevelgraph import HighLevelGraph

    groups = [tuple(str(p) for p in files[i:i + per_chunk]) for i in range(0, len(files), per_chunk)]
    if stamps is None:
        from lcmr_xr.scaleout.dirindex import stamp

        stamps = [stamp(os.stat(p)) for p in files]
    specs = {name: variable_spec(files[0], name, var.variable) for name, var in template.data_vars.items()}
    token = tokenize(groups, sorted((n, s["shape"], str(s["dtype"])) for n, s in specs.items()), stamps)
    load = f"{READ_LAYER}{token}"  # one task per group of files reads all their variables
    loads = {(load, g): (read_files, paths, specs) for g, paths in enumerate(groups)}
    out = {}
    for name, var in template.data_vars.items():
        key = f"archive-{name}-{token}"
        zeros = (0,) * var.ndim
        graph = {(key, g, *zeros): (operator.getitem, (load, g), name) for g in range(len(groups))}
        chunks = (tuple(len(p) for p in groups),) + tuple((n,) for n in var.shape)
        layers = HighLevelGraph({load: loads, key: graph}, {load: set(), key: {load}})
        out[name] = da.Array(layers, key, chunks, dtype=specs[name]["dtype"],
                             meta=np.empty((0,) * (var.ndim + 1), dtype=specs[name]["dtype"]))
    return out
