"""Directory archives opened from one header pass: identical to concatenating every file's
lazy xarray open (the way they were opened before; kept here as the oracle)."""

from __future__ import annotations

import dask
import numpy as np
import pytest
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.experiment import validate_experiment
from lcmr_xr.io import open_dataset, save
from lcmr_xr.scaleout import consolidate_archive, open_archive, save_archive
from lcmr_xr.scaleout import consolidated as con
from lcmr_xr.scaleout.archive import ORDER_ATTR, archive_files
from lcmr_xr.scaleout.directory import StructureError
from test_scaleout import _experiment, _forbid


def _oracle_open(directory):
    """The directory open before the header pass: every file opened lazily with xarray
    (h5netcdf) and the parts combined with ``combine_nested``."""
    parts, metas = [], []
    for path in archive_files(directory):
        ds = open_dataset(path, chunks={})
        ds.attrs.pop(ORDER_ATTR, None)
        if cv.EXPERIMENT not in ds.coords:
            ds = ds.assign_coords({cv.EXPERIMENT: ((), path.stem, cv.label_attrs("experiment"))})
        label = ds.coords[cv.EXPERIMENT].item()
        metas.append((label, con.metadata_of(label, ds)))
        ds = ds.drop_vars([c for c in ds.coords if ds[c].ndim == 0 and c != cv.EXPERIMENT])
        ds.attrs = {k: v for k, v in ds.attrs.items() if k not in con.METADATA}
        parts.append(ds)
    combined = xr.combine_nested(parts, concat_dim=cv.EXPERIMENT, data_vars="all", coords="minimal",
                                 compat="override", join="exact", combine_attrs="drop_conflicts")
    coords = {name: (cv.EXPERIMENT, np.asarray([m[name] for _, m in metas]),
                     {"long_name": name.replace("_", " ")}) for name in metas[0][1]}
    return combined.assign_coords(coords), parts


def _assert_same_as_oracle(directory, **open_kw):
    want, parts = _oracle_open(directory)
    with dask.config.set(scheduler=_forbid):  # the open reads no signal data
        got = open_archive(directory, **open_kw)
    xr.testing.assert_identical(got, want)
    for name in got.variables:
        assert got[name].dtype == want[name].dtype, name
    xr.testing.assert_identical(got.compute(), want.compute())
    for part in parts:
        part.close()
    return got


def _labelled(i, **attrs):
    return _experiment(i).assign_coords(experiment=f"run{i}").assign_attrs(seed=i, case=2, **attrs)


def test_directory_open_is_the_concatenation_of_the_files(tmp_path):
    # metadata attributes and coordinates, attributes shared, differing, in some files only,
    # of the types save restores (tuple, bool, list, None)
    items = [_labelled(i, drive_id=f"D{i % 2}", degrees=(3, 3, 3), noise=True, tags=["a", "b"],
                       note=None, operator="x" if i < 2 else "y").assign_coords(temperature=20.5 + i)
             for i in range(4)]
    items[2] = items[2].assign_attrs(only_here=1.5)
    save_archive(items[:3], tmp_path / "d", layout="files")
    save_archive(items[3:], tmp_path / "d", layout="files")  # appended: order index 3
    got = _assert_same_as_oracle(tmp_path / "d")
    assert got.experiment.values.tolist() == ["run0", "run1", "run2", "run3"]
    assert got.temperature.values.tolist() == [20.5, 21.5, 22.5, 23.5]
    assert "operator" not in got.attrs and got.attrs["only_here"] == 1.5
    assert got.attrs["degrees"] == (3, 3, 3) and got.attrs["noise"] is True
    assert got.r.chunks[0] == (4,)  # EXPERIMENTS_PER_CHUNK files per task
    assert open_archive(tmp_path / "d", chunks={"experiment": 3}).r.chunks[0] == (3, 1)
    for i, exp in enumerate(items):
        np.testing.assert_array_equal(got.y.values[i], exp.y.values)


def test_directory_open_of_files_from_other_tools_and_other_variable_attributes(tmp_path):
    save_archive([_labelled(0), _labelled(1)], tmp_path, layout="files")
    # written by another tool: no experiment coordinate, no order index; other attributes of y
    other = _experiment(2).assign_attrs(seed=2, case=2)
    other["y"].attrs["long_name"] = "position"
    other["r"].attrs["comment"] = "only here"
    save(other, tmp_path / "zz_other.nc")
    with pytest.raises(ValueError, match="'y' lacks the 'units' or 'long_name'"):
        validate_experiment(_oracle_open(tmp_path)[0], check_values=False)
    with pytest.raises(ValueError, match="'y' lacks the 'units' or 'long_name'"):
        open_archive(tmp_path)  # the concatenation drops the long_name that differs
    other["y"].attrs["long_name"] = _experiment(0).y.attrs["long_name"]
    other["y"].attrs["sensor"] = "LDV"
    save(other, tmp_path / "zz_other.nc")
    got = _assert_same_as_oracle(tmp_path)
    assert got.experiment.values.tolist() == ["run0", "run1", "zz_other"]
    assert got.y.attrs["sensor"] == "LDV" and got.r.attrs["comment"] == "only here"
    # integer labels
    ints = tmp_path / "ints"
    save_archive([_experiment(i).assign_attrs(seed=i) for i in range(3)], ints, layout="files")
    got = _assert_same_as_oracle(ints)
    assert got.experiment.values.tolist() == [0, 1, 2]


def test_directory_open_refuses_what_it_refused_and_a_file_of_another_structure(tmp_path):
    save_archive([_labelled(0), _labelled(1)], tmp_path, layout="files")
    # another metadata set: the same message as before
    bad = _labelled(3)
    bad.attrs.pop("case")
    save(bad, tmp_path / "run2.nc")
    with pytest.raises(ValueError, match=r"archive .*: experiment 'run3' has the metadata \['seed'\]"):
        open_archive(tmp_path)
    # r stored as float32: named at open
    odd = _labelled(3).assign(r=lambda d: d.r.astype(np.float32))
    save(odd, tmp_path / "run2.nc")
    with pytest.raises(ValueError, match=r"run2\.nc differs from run0\.nc in its variables"):
        open_archive(tmp_path)
    (tmp_path / "run2.nc").unlink()
    # a file replaced after the open with another structure: the task names it
    arc = open_archive(tmp_path, chunks={"experiment": 1})
    save(_labelled(1).assign(r=lambda d: d.r.astype(np.float32)), tmp_path / "run1.nc")
    np.testing.assert_array_equal(arc.r.isel(experiment=0).values, _labelled(0).r.values)
    with pytest.raises(StructureError, match=r"run1\.nc: variable 'r' is float32.*reopen"):
        arc.r.isel(experiment=1).values
    save(_labelled(1).drop_vars("u"), tmp_path / "run1.nc")
    with pytest.raises(StructureError, match=r"run1\.nc: has no variable 'u'"):
        arc.u.values


def test_consolidating_a_directory_reads_each_file_once_directly(tmp_path, monkeypatch):
    items = [_labelled(i, drive_id=f"D{i % 2}") for i in range(5)]
    save_archive(items, tmp_path / "d", layout="files")
    opened = []
    real = xr.open_dataset
    monkeypatch.setattr(xr, "open_dataset", lambda *a, **k: opened.append(a[0]) or real(*a, **k))
    monkeypatch.setattr(con, "BATCH", 2)  # several batches
    consolidate_archive(tmp_path / "d", tmp_path / "c.nc")
    monkeypatch.undo()
    assert len(opened) <= 1  # the template, not every file
    want, parts = _oracle_open(tmp_path / "d")
    xr.testing.assert_identical(open_archive(tmp_path / "c.nc").compute(), want.compute())
    for part in parts:
        part.close()


def test_task_reader_checks_the_dims_by_name_when_the_dimension_ids_differ(tmp_path):
    from lcmr_xr.scaleout.directory import read_files, variable_spec

    save_archive([_labelled(0)], tmp_path, layout="files")
    path = tmp_path / "run0.nc"
    spec = variable_spec(path, "r", open_archive(tmp_path).r.isel(experiment=0).variable)
    assert spec["dims"] == ("time", "input") and spec["dimids"] is not None
    other_ids = {**spec, "dimids": (7, 8)}  # as a file whose writer numbered its dims otherwise
    np.testing.assert_array_equal(read_files((str(path),), {"r": other_ids})["r"][0],
                                  _labelled(0).r.values)
    with pytest.raises(StructureError, match=r"'r' has the dims \('time', 'input'\), not"):
        read_files((str(path),), {"r": {**other_ids, "dims": ("input", "time")}})


def test_a_file_rewritten_in_place_gives_new_dask_names(tmp_path):
    # The names digest every file's stamp: a middle file re-saved with other values must not
    # share its chunks' keys with the earlier open (a cluster holding persisted chunks of
    # that open would otherwise serve the old values for the new file).
    exps = [_labelled(i) for i in range(5)]
    save_archive(xr.concat(exps, dim="experiment"), tmp_path / "arc", layout="files")
    before = open_archive(tmp_path / "arc", chunks={"experiment": 1})
    middle = archive_files(tmp_path / "arc")[2]
    changed = open_dataset(middle).load()
    changed["r"] = changed.r.copy(data=2.0 * changed.r.values)
    save(changed, middle)
    after = open_archive(tmp_path / "arc", chunks={"experiment": 1})
    assert before.r.data.name != after.r.data.name
    np.testing.assert_array_equal(after.r.isel(experiment=2).values, 2.0 * exps[2].r.values)
    # the same files give the same names (dask can still share work between equal opens)
    assert open_archive(tmp_path / "arc").r.data.name == open_archive(tmp_path / "arc").r.data.name


def test_consolidated_file_refused_inside_a_directory_archive_only(tmp_path):
    """save_archive / append_to_archive wrote a consolidated file into a directory archive,
    whose open then refused the whole directory (a file of another structure).  A plain
    directory of experiment files (no header index: not written as an archive) still takes
    an archive file, and the archive directory itself still takes experiments."""
    from lcmr_xr.scaleout import append_to_archive

    exps = xr.concat([_experiment(seed=s) for s in range(2)], cv.EXPERIMENT).assign_coords(
        {cv.EXPERIMENT: ["a", "b"]})
    arc = tmp_path / "arc"
    save_archive(exps, arc, layout="files")
    before = sorted(p.name for p in arc.iterdir())
    for write in (lambda: save_archive(exps, arc / "all.nc"),
                  lambda: save_archive(exps, arc / "all.nc", layout="consolidated", overwrite=True),
                  lambda: append_to_archive(exps.isel({cv.EXPERIMENT: 0}), arc / "one.nc")):
        with pytest.raises(ValueError, match="refusing to write the consolidated archive .* is a "
                                             "directory archive"):
            write()
    assert sorted(p.name for p in arc.iterdir()) == before
    assert open_archive(arc)[cv.EXPERIMENT].values.tolist() == ["a", "b"]  # still opens
    append_to_archive(_experiment(seed=5).assign_coords({cv.EXPERIMENT: "c"}), arc)  # the directory itself
    assert open_archive(arc)[cv.EXPERIMENT].values.tolist() == ["a", "b", "c"]
    plain = tmp_path / "runs"
    plain.mkdir()
    save(exps.isel({cv.EXPERIMENT: 0}), plain / "a.nc")
    save_archive(exps, plain / "all.nc")
    assert open_archive(plain / "all.nc").sizes[cv.EXPERIMENT] == 2
