"""The consolidated archive: one NetCDF-4/HDF5 file, every experiment along an unlimited dim.

Why one file and not a directory of per-experiment files: opening a file costs tens of
milliseconds of HDF5 metadata lookups, so 10 000 files take minutes to open, while one
file with an ``experiment`` dim opens in well under a second whatever it holds.  Why
NetCDF-4 and not Zarr: it is the format the rest of the library writes, every tool our
users have reads it (``ncdump``, MATLAB's ``ncread``, xarray, netCDF4), a campaign is one
file to copy, and it needs no new dependency; one file on a shared file system is what a
cluster reads (object storage would be the reason for Zarr; nobody needs it yet).

Layout (``lcmr_archive = "consolidated-1"``):

- ``r`` (experiment, time, input), ``u`` (experiment, time, input), ``y`` (experiment,
  slow_time, output): HDF5 chunks of one experiment each, so one experiment is one read
  and an append writes new chunks only.  ``experiment`` is the netCDF unlimited dim.
- ``experiment`` (labels) and the per-experiment metadata :data:`METADATA` (taken from the
  experiments' attributes or scalar coordinates) are coordinates along ``experiment``:
  ``arc.sel(experiment=arc.case == 2)``.
- The file attribute ``lcmr_archive_count`` is the number of complete experiments.  An
  append writes the new rows first and raises the count last, so an append that was
  interrupted leaves rows past the count, which :func:`open_consolidated` ignores and the
  next append overwrites.  (HDF5 itself is not journalled: a machine that loses power in
  the middle of an append can still damage the file; the first write is atomic, temp file
  then rename.)
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv

# The functions below serve lcmr_xr.scaleout.archive (the public API); only these are public.
__all__ = ["METADATA", "KIND", "is_consolidated"]

#: Value of the file attribute ``lcmr_archive`` that marks a consolidated archive.
KIND = cv.ARCHIVE_KIND
KIND_ATTR = cv.ARCHIVE_KIND_ATTR
COUNT_ATTR = cv.ARCHIVE_COUNT_ATTR
#: Experiment attributes that become coordinates along ``experiment`` (with every scalar
#: coordinate of the experiments): what users select experiments by.
METADATA = cv.ARCHIVE_METADATA
_SIGNALS = {"r": (cv.TIME, cv.INPUT), "u": (cv.TIME, cv.INPUT), "y": (cv.SLOW_TIME, cv.OUTPUT)}
#: Experiments written per netCDF4 call when a whole archive is written (bounds memory).
BATCH = 64


def is_consolidated(path) -> bool:
    """Whether ``path`` is a file carrying the consolidated-archive marker (reads metadata only).

    Parameters
    ----------
    path : str or os.PathLike

    Returns
    -------
    bool
    """
    import h5py

    path = Path(path)
    if not path.is_file():
        return False
    try:
        with h5py.File(path, "r") as f:
            kind = f.attrs.get(KIND_ATTR)
    except OSError:
        return False
    return (kind.decode() if isinstance(kind, bytes) else kind) == KIND


# ------------------------------------------------------------------ metadata of one experiment
def metadata_of(label, ds: xr.Dataset) -> dict:
    """``{name: python scalar}``: the experiment's metadata (scalar coords, :data:`METADATA` attrs)."""
    out = {}
    for name, var in ds.coords.items():
        if var.ndim == 0 and name != cv.EXPERIMENT:
            out[name] = var.values.item()
    return checked_metadata(label, out, ds.attrs)


def checked_metadata(label, scalars: dict, attrs: dict) -> dict:
    """:func:`metadata_of` from the scalar coordinates' values and the attributes."""
    out = dict(scalars)
    for name in METADATA:
        if name in attrs and name not in out:
            value = attrs[name]
            out[name] = value.item() if isinstance(value, np.generic) else value
    for name, value in out.items():
        if not isinstance(value, (str, bool, int, float)):
            raise ValueError(
                f"experiment {label!r}: metadata {name!r} = {value!r} is a {type(value).__name__}; "
                "archive metadata must be a string, integer, float or bool (write dates as ISO "
                "strings, e.g. '2026-11-23T10:00')."
            )
    return out


def check_metadata(rows: list[tuple[object, dict]], expected: dict | None = None) -> dict:
    """Names and kinds of the metadata shared by every experiment; refuse a mismatch.

    ``expected`` maps name to numpy dtype kind (an existing archive's coords).
    """
    def kinds(meta):
        return {k: ("U" if isinstance(v, str) else "b" if isinstance(v, bool)
                    else "i" if isinstance(v, int) else "f") for k, v in meta.items()}

    want = expected if expected is not None else kinds(rows[0][1])
    for label, meta in rows:
        got = kinds(meta)
        if set(got) != set(want):
            missing, extra = sorted(set(want) - set(got)), sorted(set(got) - set(want))
            raise ValueError(
                f"experiment {label!r} has the metadata {sorted(got)}, the archive "
                f"{sorted(want)} (missing {missing}, extra {extra}); every experiment of an "
                "archive carries the same metadata: set them, e.g. "
                f"exp.assign_attrs({', '.join(f'{m}=...' for m in missing) or 'name=...'}), or "
                "drop the extra ones."
            )
        bad = [k for k in got if got[k] != want[k] and not (got[k] == "i" and want[k] == "f")]
        if bad:
            raise ValueError(
                f"experiment {label!r}: metadata {bad} have types {[got[k] for k in bad]} but the "
                f"archive stores {[want[k] for k in bad]} (U string, i integer, f float, b bool); "
                "convert them."
            )
    return want


# ------------------------------------------------------------------ writing
def _stacked(rows, labels, metas) -> xr.Dataset:
    """The first experiments as one dataset with an ``experiment`` dim (what xarray writes)."""
    parts = []
    for (label, ds), meta in zip(rows, metas):
        one = ds[list(_SIGNALS)].drop_vars([c for c in ds.coords if ds[c].ndim == 0])
        one = one.transpose(*(d for d in (cv.TIME, cv.SLOW_TIME, cv.INPUT, cv.OUTPUT) if d in one.dims))
        parts.append(one.expand_dims(cv.EXPERIMENT))
    out = xr.concat(parts, cv.EXPERIMENT, coords="minimal", compat="override", join="exact",
                    combine_attrs="drop")
    for name, var in out.data_vars.items():
        var.attrs = dict(rows[0][1][name].attrs)
    coords = {cv.EXPERIMENT: (cv.EXPERIMENT, np.asarray(labels), cv.label_attrs("experiment"))}
    for name in metas[0]:
        coords[name] = (cv.EXPERIMENT, np.asarray([m[name] for m in metas]),
                        {"long_name": name.replace("_", " ")})
    return out.assign_coords(coords)


def common_attrs(datasets) -> dict:
    """Attributes equal in every experiment (as xarray's ``drop_conflicts``), less the metadata."""
    first = dict(datasets[0].attrs)
    keep = {}
    for key, value in first.items():
        if key in METADATA:
            continue
        same = True
        for ds in datasets[1:]:
            other = ds.attrs.get(key, None)
            try:
                same = key in ds.attrs and bool(np.array_equal(np.asarray(value), np.asarray(other)))
            except Exception:  # noqa: BLE001 - incomparable values differ
                same = False
            if not same:
                break
        if same:
            keep[key] = value
    return keep


def write_consolidated(rows: list[tuple[object, xr.Dataset]], tmp: str, attrs: dict) -> None:
    """Write validated, same-shape experiments ``[(label, ds), ...]`` to the new file ``tmp``."""
    from lcmr_xr.io.netcdf import _flatten_attrs, _map_attrs

    metas = [metadata_of(label, ds) for label, ds in rows]
    check_metadata(list(zip([lab for lab, _ in rows], metas)))
    first = _stacked(rows[:1], [rows[0][0]], metas[:1])
    first.attrs = {**attrs, KIND_ATTR: KIND, COUNT_ATTR: 0}
    encoding = {}
    for name, dims in _SIGNALS.items():
        encoding[name] = {"chunksizes": (1,) + tuple(first.sizes[d] for d in dims),
                          "_FillValue": np.nan}
    for name in [cv.EXPERIMENT, *metas[0]]:
        encoding[name] = {"chunksizes": (4096,)}
    flat = _map_attrs(first, _flatten_attrs)
    flat.isel({cv.EXPERIMENT: slice(0, 0)}).to_netcdf(
        tmp, engine="netcdf4", unlimited_dims=[cv.EXPERIMENT], encoding=encoding)
    for start in range(0, len(rows), BATCH):
        batch = rows[start:start + BATCH]
        append_rows(tmp, batch, metas[start:start + BATCH], expected_count=start)


def _open_for_append(path):
    """netCDF4 handle on ``path`` in append mode; a clear error when another handle holds it."""
    import netCDF4

    try:
        return netCDF4.Dataset(path, "a")
    except OSError as err:
        raise OSError(
            f"cannot open {path} for appending ({err}): the archive is open elsewhere (HDF5 "
            "locks a file that is being read, e.g. by a dataset from open_archive in this or "
            "another process). Close it first (arc.close()), or wait for the sweep reading it."
        ) from err


def _drop_conflicting_attrs(nc, datasets) -> None:
    """Delete the archive's attributes that the new experiments do not share (``drop_conflicts``)."""
    from lcmr_xr.io.netcdf import _flatten_attrs

    flat = _flatten_attrs("the experiment", common_attrs(list(datasets)))
    for key in nc.ncattrs():
        if key in (KIND_ATTR, COUNT_ATTR, "lcmr_attr_types"):
            continue
        value = nc.getncattr(key)
        try:
            same = key in flat and bool(np.array_equal(np.asarray(value), np.asarray(flat[key])))
        except Exception:  # noqa: BLE001 - incomparable values differ
            same = False
        if not same:
            nc.delncattr(key)


def _signal_block(rows, name):
    dims = _SIGNALS[name]
    return np.stack([np.asarray(ds[name].transpose(*dims).values, dtype=float) for _, ds in rows])


def append_rows(path, rows, metas, *, expected_count=None) -> int:
    """Write ``rows`` after the complete experiments of ``path``, then raise the count.

    The caller has validated the experiments and checked them against the archive.  Returns
    the new count.
    """
    with _open_for_append(path) as nc:
        count = int(nc.getncattr(COUNT_ATTR))
        if expected_count is not None and count != expected_count:
            raise RuntimeError(f"{path} changed while it was written (count {count}, expected "
                               f"{expected_count}); is another process appending to it?")
        stop = count + len(rows)
        if count:  # the first rows of a new archive set its attributes
            _drop_conflicting_attrs(nc, [ds for _, ds in rows])
        for name in _SIGNALS:
            nc[name][count:stop] = _signal_block(rows, name)
        labels = [label for label, _ in rows]
        names = {cv.EXPERIMENT: labels}
        for key in (metas[0] if metas else {}):
            names[key] = [m[key] for m in metas]
        for key, values in names.items():
            var = nc[key]
            if var.dtype is str:
                for i, v in enumerate(values):  # vlen strings are written one at a time
                    var[count + i] = str(v)
            else:
                var[count:stop] = np.asarray(values).astype(var.dtype)
        nc.sync()  # the rows are on disk before the count says they exist
        nc.setncattr(COUNT_ATTR, np.int64(stop))
    return stop


# ------------------------------------------------------------------ reading
def read_header(path) -> dict:
    """Shape, channel labels, count, and the ``experiment`` coordinates (values, attributes).

    Reads no signal data: only the small 1-d variables along ``experiment``.
    """
    import netCDF4

    with netCDF4.Dataset(path, "r") as nc:
        if KIND_ATTR not in nc.ncattrs() or nc.getncattr(KIND_ATTR) != KIND:
            raise ValueError(f"{path} is not a consolidated lcmr_xr archive (no attribute "
                             f"{KIND_ATTR}={KIND!r}); open a directory archive with open_archive "
                             "or write one with save_archive.")
        count = int(nc.getncattr(COUNT_ATTR))
        time = nc[cv.TIME][:2]
        coords, kinds = {}, {}
        for name, var in nc.variables.items():
            if var.dimensions != (cv.EXPERIMENT,):
                continue
            var.set_auto_mask(False)
            values = var[:count]
            attrs = {k: var.getncattr(k) for k in var.ncattrs() if not k.startswith("_")}
            if attrs.pop("dtype", None) == "bool":  # xarray stores bools as int8 marked so
                values = np.asarray(values).astype(bool)
            elif var.dtype is str:
                values = np.asarray([str(v) for v in values], dtype=str) if count else np.array([], str)
            coords[name] = (np.asarray(values), attrs)
            if name != cv.EXPERIMENT:
                kinds[name] = coords[name][0].dtype.kind
        labels = coords[cv.EXPERIMENT][0]
        return {
            "N": len(nc.dimensions[cv.TIME]),
            "factor": int(np.asarray(nc.getncattr(cv.FACTOR)).item()) if cv.FACTOR in nc.ncattrs() else -1,
            "Th": float(time[1] - time[0]) if len(time) > 1 else float("nan"),
            "inputs": [str(v) for v in nc[cv.INPUT][:]],
            "outputs": [str(v) for v in nc[cv.OUTPUT][:]],
            "count": count,
            "labels": labels.tolist(),
            "metadata": kinds,
            "coords": coords,
        }


def open_consolidated(path, experiments_per_chunk: int) -> xr.Dataset:
    """Open a consolidated archive lazily: labels and metadata in memory, signals as dask."""
    from lcmr_xr.io.netcdf import _map_attrs, _restore_attrs

    header = read_header(path)
    raw = xr.open_dataset(path, engine="h5netcdf", chunks={cv.EXPERIMENT: experiments_per_chunk},
                          decode_timedelta=False, drop_variables=list(header["coords"]))
    ds = _map_attrs(raw, lambda owner, attrs: _restore_attrs(attrs))
    count = int(ds.attrs.pop(COUNT_ATTR))
    ds.attrs.pop(KIND_ATTR)
    if ds.sizes[cv.EXPERIMENT] > count:  # rows of an interrupted append
        ds = ds.isel({cv.EXPERIMENT: slice(0, count)})
    # labels and metadata are small, read directly (as dask arrays they would cost a
    # compute here and tasks in every sweep)
    out = ds.assign_coords({name: (cv.EXPERIMENT, values, attrs)
                            for name, (values, attrs) in header["coords"].items()})
    out.set_close(raw.close)  # close() releases the file (HDF5 locks it against appends)
    return out
