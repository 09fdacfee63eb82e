"""Consolidated archives, append, consolidation, flagged experiments, streamed sweeps, clusters."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import dask
import netCDF4
import numpy as np
import pytest
import xarray as xr

from lcmr_xr.cli import main as cli_main
from lcmr_xr.identification import identify
from lcmr_xr.io import open_dataset, save
from lcmr_xr.scaleout import (append_to_archive, consolidate_archive, local_cluster, open_archive,
                              save_archive, sweep, sweep_to_disk)
from lcmr_xr.scaleout.consolidated import COUNT_ATTR, append_rows, metadata_of
from lcmr_xr.scaleout.stream import parts_directory
from test_scaleout import _experiment, _forbid, _stack

ROOT = Path(__file__).resolve().parents[1]


def _labelled(i, **attrs):
    return _experiment(i).assign_coords(experiment=f"run{i}").assign_attrs(seed=i, case=2, **attrs)


# ------------------------------------------------------------------------------- archive
def test_consolidated_round_trip_is_lazy_and_selectable(tmp_path):
    items = [_labelled(i, drive_id=f"D{i % 2}") for i in range(3)]
    assert save_archive(items, tmp_path / "a.nc") == [tmp_path / "a.nc"]
    with dask.config.set(scheduler=_forbid):  # opening (and building a sweep) reads no data
        arc = open_archive(tmp_path / "a.nc")
        assert sweep(arc, window=[12]).P.chunks[3] == (3,)  # metadata coords chunked alike
    assert arc.r.chunks is not None and arc.encoding["source"] == str(tmp_path / "a.nc")
    assert arc.experiment.values.tolist() == ["run0", "run1", "run2"]
    assert arc.seed.values.tolist() == [0, 1, 2] and arc.case.values.tolist() == [2, 2, 2]
    assert "seed" not in arc.attrs and arc.attrs["factor"] == 2
    on_d1 = arc.sel(experiment=arc.drive_id == "D1")
    np.testing.assert_array_equal(on_d1.r.values[0], items[1].r.values)
    for i, exp in enumerate(items):
        for name in ("r", "u", "y"):
            np.testing.assert_array_equal(arc[name].values[i], exp[name].values)
    # the directory form of the same experiments opens to the same dataset
    save_archive(items, tmp_path / "dir", layout="files")
    xr.testing.assert_identical(open_archive(tmp_path / "dir").compute(), arc.compute())
    arc.close()


def test_new_consolidated_archives_are_named_as_netcdf_files_existing_ones_still_grow(tmp_path):
    """A new consolidated archive's name ends in .nc, .nc4 or .netcdf (any case), as save
    requires (campaign.h5 was written as NetCDF-4); an archive file written under another
    name before the rule is still opened and appended to (refusing it would strand it),
    but not replaced under that name; a directory archive's name is free."""
    a, b = _labelled(0), _labelled(1)
    for name in ("a.NC", "b.nc4", "c.NetCDF"):
        save_archive(a, tmp_path / name)
        assert open_archive(tmp_path / name).experiment.values.tolist() == ["run0"]
    save_archive(a, tmp_path / "old.nc")
    (tmp_path / "old.nc").rename(tmp_path / "old.h5")  # as an earlier version wrote it
    append_to_archive(b, tmp_path / "old.h5")
    save_archive(_labelled(2), tmp_path / "old.h5")
    assert open_archive(tmp_path / "old.h5").experiment.values.tolist() == ["run0", "run1", "run2"]
    with pytest.raises(ValueError, match=r"consolidated archive .*old\.h5: unsupported file type '\.h5'"):
        save_archive(a, tmp_path / "old.h5", overwrite=True)
    assert open_archive(tmp_path / "old.h5").sizes["experiment"] == 3
    assert save_archive([a, b], tmp_path / "runs.h5", layout="files")[0] == tmp_path / "runs.h5" / "run0.nc"
    assert sorted(os.listdir(tmp_path)) == sorted(["a.NC", "b.nc4", "c.NetCDF", "old.h5", "runs.h5"])


def test_append_adds_one_experiment_and_an_interrupted_append_is_ignored(tmp_path):
    path = tmp_path / "a.nc"
    append_to_archive(_labelled(0), path)  # creates the archive
    append_to_archive(_labelled(1), path)
    # an append that died after writing its rows but before raising the count
    exp = _labelled(2)
    append_rows(path, [("half", exp)], [metadata_of("half", exp)])
    with netCDF4.Dataset(path, "a") as nc:
        nc.setncattr(COUNT_ATTR, np.int64(2))
    arc = open_archive(path)
    assert arc.experiment.values.tolist() == ["run0", "run1"]
    arc.close()
    append_to_archive(_labelled(3), path)  # overwrites the partial row
    arc = open_archive(path)
    assert arc.experiment.values.tolist() == ["run0", "run1", "run3"]
    np.testing.assert_array_equal(arc.u.values[2], _labelled(3).u.values)
    assert arc.seed.values.tolist() == [0, 1, 3]
    # refused: a label already there, another length, other metadata, while open
    with pytest.raises(OSError, match="open elsewhere.*arc.close"):
        append_to_archive(_labelled(4), path)
    arc.close()
    with pytest.raises(ValueError, match=r"\['run1'\] are already in"):
        append_to_archive(_labelled(1), path)
    longer = _experiment(5, n=960).assign_coords(experiment="x").assign_attrs(seed=5, case=2)
    with pytest.raises(ValueError, match="another shape.*N=480.*N=960"):
        append_to_archive(longer, path)
    with pytest.raises(ValueError, match=r"missing \['case'\].*assign_attrs\(case=\.\.\.\)"):
        append_to_archive(_experiment(6).assign_coords(experiment="y").assign_attrs(seed=6), path)
    assert open_archive(path).sizes["experiment"] == 3  # nothing was added by the refusals


def test_save_archive_layouts_and_overwrite(tmp_path):
    save_archive([_labelled(0)], tmp_path / "a.nc")
    save_archive([_labelled(1)], tmp_path / "a.nc")  # an existing archive: appended
    assert open_archive(tmp_path / "a.nc").experiment.values.tolist() == ["run0", "run1"]
    save_archive([_labelled(2)], tmp_path / "a.nc", overwrite=True)  # replaced
    assert open_archive(tmp_path / "a.nc").experiment.values.tolist() == ["run2"]
    (tmp_path / "junk.nc").write_text("not netcdf")
    with pytest.raises(ValueError, match="not a readable NetCDF-4 archive.*overwrite=True"):
        save_archive([_labelled(0)], tmp_path / "junk.nc")
    with pytest.raises(ValueError, match="is a directory.*layout='files'"):
        save_archive([_labelled(0)], tmp_path, layout="consolidated")
    with pytest.raises(ValueError, match="layout must be one of"):
        save_archive([_labelled(0)], tmp_path / "b.nc", layout="zarr")
    with pytest.raises(ValueError, match=r"labels \['run0'\] occur more than once"):
        save_archive([_labelled(0), _labelled(0)], tmp_path / "c.nc")


def test_consolidate_directory_command(tmp_path, capsys):
    items = [_labelled(i) for i in range(3)]
    save_archive(items, tmp_path / "dir", layout="files")
    before = sorted(p.name for p in (tmp_path / "dir").iterdir())
    assert cli_main(["archive", "consolidate", str(tmp_path / "dir"), "-o", str(tmp_path / "a.nc")]) == 0
    assert sorted(p.name for p in (tmp_path / "dir").iterdir()) == before  # input untouched
    xr.testing.assert_identical(open_archive(tmp_path / "a.nc").compute(),
                                open_archive(tmp_path / "dir").compute())
    assert cli_main(["archive", "consolidate", str(tmp_path / "dir"), "-o", str(tmp_path / "a.nc")]) == 2
    assert "already exists; pass --overwrite" in capsys.readouterr().err
    with pytest.raises(FileExistsError):
        consolidate_archive(tmp_path / "dir", tmp_path / "a.nc")


# ------------------------------------------------------------------------------- flagged data
def test_a_bad_experiment_is_flagged_not_fatal(tmp_path):
    save_archive([_labelled(i) for i in range(3)], tmp_path / "dir", layout="files")
    with netCDF4.Dataset(tmp_path / "dir" / "run1.nc", "a") as nc:  # a sample lost on disk
        nc["y"][7, 0] = np.nan
    arc = open_archive(tmp_path / "dir")  # opens: the values are checked in the tasks
    res = sweep(arc, window=[12], experiments_per_task=2).compute(scheduler="synchronous")
    errors = res.experiment_error.isel(method=0, degrees=0, window=0).values.tolist()
    assert errors[0] == errors[2] == ""
    assert "run1.nc" in errors[1] and "NaN or inf" in errors[1]
    bad = res.isel(method=0, degrees=0, window=0, experiment=1)
    assert bool(np.isnan(bad.P).all()) and bool(bad.P_flag.all())
    good = identify(arc.isel(experiment=[2]).compute(), window=12, errors="ignore")
    np.testing.assert_allclose(res.P.isel(method=0, degrees=0, window=0, experiment=[2]).values,
                               good.P.values, rtol=1e-12)


# ------------------------------------------------------------------------------- streaming
class _Crash(Exception):
    pass


def test_sweep_to_disk_survives_a_crash_and_resumes(tmp_path):
    exps = _stack([f"e{i}" for i in range(4)])
    out = tmp_path / "sweep.nc"
    settings = dict(window=[12, 20], experiments_per_task=2)

    def crash(done, total, rate):
        raise _Crash

    with pytest.raises(_Crash):
        sweep_to_disk(exps, out, **settings, workers=1, progress=crash)
    kept = sorted(p.name for p in parts_directory(out).glob("*.nc"))
    assert kept and not out.exists()
    seen = []
    sweep_to_disk(exps, out, **settings, progress=lambda d, t, r: seen.append((d, t, r)))
    assert seen[0][1] == 8 and seen[0][0] == 2 * len(kept) + 2  # the kept parts were skipped
    assert seen[-1][0] == 8 and seen[-1][2] > 0
    assert not parts_directory(out).exists()
    want = sweep(exps, **settings).compute(scheduler="synchronous")
    xr.testing.assert_identical(open_dataset(out), want)
    with pytest.raises(FileExistsError):
        sweep_to_disk(exps, out, **settings)
    # parts of another sweep in the way are refused, not mixed in
    with pytest.raises(_Crash):
        sweep_to_disk(exps, tmp_path / "b.nc", window=[12], workers=1, progress=crash)
    with pytest.raises(ValueError, match=r"another sweep \(different \['window'\]\)"):
        sweep_to_disk(exps, tmp_path / "b.nc", window=[20])


def test_sweep_to_disk_never_adopts_a_directory_it_did_not_make(tmp_path):
    """A directory ``.OUTPUT.parts`` that a sweep did not make (no manifest) was taken as
    the parts directory and removed with everything in it when the sweep was done: the
    user's files in it were lost.  It is refused now (nothing run, nothing removed), as is
    a file of that name; an empty one, or one left by an interrupted start (only the
    manifest's temporary), is still used."""
    exps = _stack(["e0", "e1"])
    out = tmp_path / "sweep.nc"
    parts = parts_directory(out)
    parts.mkdir()
    (parts / "notes.txt").write_text("mine")
    with pytest.raises(FileExistsError, match=r"holds files of no sweep \(notes.txt\)"):
        sweep_to_disk(exps, out, window=[12], progress=False)
    assert (parts / "notes.txt").read_text() == "mine" and not out.exists()
    (parts / "notes.txt").unlink()
    parts.rmdir()
    parts.write_text("a file")
    with pytest.raises(FileExistsError, match="exists and is a file"):
        sweep_to_disk(exps, out, window=[12], progress=False)
    assert parts.read_text() == "a file"
    parts.unlink()
    parts.mkdir()
    (parts / ".manifest.json.0badf00d-1.abcd1234.tmp").write_text("{")  # an interrupted start
    sweep_to_disk(exps, out, window=[12], progress=False)
    assert out.exists() and not parts.exists()


def test_sweep_to_disk_identifies_each_experiment_once(tmp_path, monkeypatch):
    """Assembling the result from the parts must not run the identify tasks again (the
    archive's metadata coordinates once came back through them)."""
    import importlib

    identify_module = importlib.import_module("lcmr_xr.identification.identify")
    save_archive([_labelled(i) for i in range(3)], tmp_path / "a.nc")
    arc = open_archive(tmp_path / "a.nc")
    assert "seed" in arc.coords  # metadata along experiment: what pulled the tasks back
    calls = []
    real = identify_module.record_kernel

    def counted(*args, **kwargs):  # the kernel of every identify, whichever path calls it
        kernel = real(*args, **kwargs)

        def counting(r, u, y, *rest):
            calls.append(float(np.asarray(r)[..., 0, 0].ravel()[0]))  # which experiment
            return kernel(r, u, y, *rest)
        return counting

    monkeypatch.setattr(identify_module, "record_kernel", counted)
    out = sweep_to_disk(arc, tmp_path / "r.nc", window=[12, 20], experiments_per_task=2,
                        scheduler="synchronous", progress=False)
    first = [float(v) for v in arc.r.isel(time=0, input=0).values]
    assert len(set(first)) == 3 and sorted(calls) == sorted(2 * first)
    res = open_dataset(out)
    np.testing.assert_array_equal(res.seed.values, arc.seed.values)
    arc.close()


def test_sweep_to_disk_tasks_write_their_parts_or_hand_them_back(tmp_path, monkeypatch):
    """Tasks that see the parts directory write their parts and return only the name; a
    worker that does not (a remote cluster without the file system) returns the arrays
    and the caller writes them: the same file either way, bad experiment flagged in both."""
    import importlib

    stream = importlib.import_module("lcmr_xr.scaleout.stream")
    save_archive([_labelled(i) for i in range(3)], tmp_path / "dir", layout="files")
    with netCDF4.Dataset(tmp_path / "dir" / "run2.nc", "a") as nc:  # a sample lost on disk
        nc["y"][5, 0] = np.nan
    arc = open_archive(tmp_path / "dir")
    settings = dict(window=[12], degrees=["2-2-2", "3-3-3"], experiments_per_task=2)
    returned = []
    real = stream._identify_to_part

    def recorded(*args, **kwargs):
        out = real(*args, **kwargs)
        returned.append(out)
        return out

    monkeypatch.setattr(stream, "_identify_to_part", recorded)
    a = sweep_to_disk(arc, tmp_path / "a.nc", **settings, progress=False)
    assert len(returned) == 4 and all(isinstance(r, str) for r in returned)  # names only
    returned.clear()
    monkeypatch.setattr(stream, "_sees_parts", lambda parts, run_id: False)
    b = sweep_to_disk(arc, tmp_path / "b.nc", **settings, progress=False)
    assert len(returned) == 4 and all(isinstance(r, dict) for r in returned)
    want = sweep(arc, **settings).compute(scheduler="synchronous")  # chunks of 2 and 1
    for out in (a, b):
        got = open_dataset(out)
        xr.testing.assert_identical(got, want)
        errors = got.experiment_error.values
        assert (errors[..., 2] != "").all() and (np.delete(errors, 2, axis=-1) == "").all()
        assert "run2.nc" in str(errors[0, 1, 0, 2]) and "NaN or inf" in str(errors[0, 1, 0, 2])
    arc.close()


def test_sweep_to_disk_resumes_parts_of_a_manifest_without_run_id(tmp_path):
    """Parts directories written before the run id (the manifest of an earlier version)
    are resumed, not refused."""
    import json

    exps = _stack(["a", "b", "c"])
    out = tmp_path / "s.nc"

    def crash(done, total, rate):
        raise _Crash

    with pytest.raises(_Crash):
        sweep_to_disk(exps, out, window=[12], experiments_per_task=1, workers=1, progress=crash)
    manifest = parts_directory(out) / "manifest.json"
    found = json.loads(manifest.read_text())
    assert len(found.pop("id")) == 32
    manifest.write_text(json.dumps(found))
    kept = len(list(parts_directory(out).glob("*.nc")))
    seen = []
    sweep_to_disk(exps, out, window=[12], experiments_per_task=1,
                  progress=lambda d, t, r: seen.append(d))
    assert seen[0] == kept + 1 and seen[-1] == 3
    xr.testing.assert_identical(open_dataset(out), sweep(exps, window=[12], experiments_per_task=1)
                                .compute(scheduler="synchronous"))


def test_sweep_interrupted_under_a_name_now_refused_can_be_resumed(tmp_path, capsys):
    """A sweep started under a name ``save`` now refuses (``r.h5``, before the rule) left
    its parts in ``.r.h5.parts/``; the refusal of ``r.h5`` only named the endings, and the
    parts were stranded.  It now names the parts directory and the rename that resumes the
    sweep (API and command line), and doing what it says runs only the missing tasks and
    gives the full sweep's result."""
    exps = _stack(["a", "b", "c"])
    settings = dict(window=[12], experiments_per_task=1)

    def crash(done, total, rate):
        raise _Crash

    old = tmp_path / "r.h5"  # the parts as the earlier version left them under that name
    with pytest.raises(_Crash):
        sweep_to_disk(exps, tmp_path / "r.nc", **settings, workers=1, progress=crash)
    parts_directory(tmp_path / "r.nc").rename(parts_directory(old))
    kept = len(list(parts_directory(old).glob("*.nc")))
    assert kept >= 1
    words = ("'.h5'", f"{parts_directory(old)} holds the finished parts of a sweep to r.h5",
             f"rename that directory to {parts_directory(tmp_path / 'r.nc')}",
             f"with the output {tmp_path / 'r.nc'}")
    with pytest.raises(ValueError) as info:
        sweep_to_disk(exps, old, **settings, progress=False)
    assert all(w in str(info.value) for w in words), str(info.value)
    save_archive(exps, tmp_path / "arc.nc")
    assert cli_main(["sweep", str(tmp_path / "arc.nc"), "-o", str(old), "--window", "12"]) == 2
    err = capsys.readouterr().err
    assert all(w in err for w in words[1:]) and "-o " in err, err
    assert parts_directory(old).is_dir() and not old.exists()  # nothing touched
    # without a parts directory the refusal is the plain one
    with pytest.raises(ValueError) as info:
        sweep_to_disk(exps, tmp_path / "other.h5", **settings, progress=False)
    assert "parts" not in str(info.value)
    parts_directory(old).rename(parts_directory(tmp_path / "r.nc"))  # what the message says
    seen = []
    sweep_to_disk(exps, tmp_path / "r.nc", **settings, progress=lambda d, t, r: seen.append(d))
    assert seen[0] == kept + 1 and seen[-1] == 3  # resumed: only the missing tasks ran
    xr.testing.assert_identical(open_dataset(tmp_path / "r.nc"),
                                sweep(exps, **settings).compute(scheduler="synchronous"))


def test_part_reader_decodes_like_xarray(tmp_path):
    """The assembly reads parts with netCDF4 directly; values must be xarray's decoded
    ones, also for an encoding a sweep result does not use (then xarray decodes)."""
    from lcmr_xr.scaleout.stream import _read_part

    ds = xr.Dataset({"c": (("experiment", "f"), np.array([[1 + 2j, np.nan], [3j, 4]])),
                     "x": (("experiment", "f"), np.array([[np.nan, 1.5], [2.0, -1.0]])),
                     "b": (("f", "experiment"), np.array([[True, False], [False, True]])),
                     "s": (("experiment",), np.array(["", "bad: NaN"], dtype=object)),
                     "i": (("experiment", "f"), np.array([[1, -7], [3, 4]]))})
    ds["i"].encoding["_FillValue"] = -7  # masked on read: xarray decodes it to NaN
    path = save(ds, tmp_path / "p.nc")
    want = open_dataset(path)
    dims = {"c": ("window", "experiment", "f"), "x": ("window", "experiment", "f"),
            "b": ("window", "experiment", "f"), "s": ("window", "experiment"),
            "i": ("window", "experiment", "f")}
    for names in (["c", "x", "b", "s"], ["c", "i"]):  # plain, then one needing xarray
        dtypes = {n: want[n].dtype for n in names}
        got = _read_part(path, names, dims, dtypes)
        for n in names:
            expected = want[n].expand_dims("window").transpose(*dims[n]).values
            assert got[n].dtype == expected.dtype and got[n].shape == expected.shape
            np.testing.assert_array_equal(got[n], expected)
    assert np.isnan(got["i"][0, 0, 1])


def test_part_writer_writes_what_xarray_and_the_part_reader_read_alike(tmp_path, monkeypatch):
    """Tasks write their parts with netCDF4 directly (values only): xarray decodes them to
    the very values and types, and the part reader takes its direct path (not xarray's)."""
    from lcmr_xr.scaleout import stream

    arrays = {"c": (("experiment", "f"), np.array([[1 + 2j, np.nan], [3j, 4]])),
              "x": (("f", "experiment"), np.array([[np.nan, 1.5], [2.0, -1.0]]).T.copy().T),
              "b": (("f", "experiment"), np.array([[True, False], [False, True]])),
              "s": (("experiment",), np.array(["", "bad: NaN"], dtype=object)),
              "k": (("experiment",), np.array([3, -1]))}
    path = tmp_path / "p.nc"
    stream._write_part(path, arrays)
    # what xarray reads is what it reads from the same values written by save
    xr.testing.assert_identical(open_dataset(path),
                                open_dataset(save(xr.Dataset(arrays), tmp_path / "saved.nc")))
    monkeypatch.setattr(stream, "_read_part_xarray", None)  # the direct path only
    dims = {name: ("window",) + d for name, (d, _) in arrays.items()}
    read = stream._read_part(path, list(arrays), dims, {n: v.dtype for n, (_, v) in arrays.items()})
    for name, (_, values) in arrays.items():
        assert read[name].dtype == values.dtype
        np.testing.assert_array_equal(read[name], values[None])


def test_sweep_to_disk_never_writes_into_or_over_its_archive(tmp_path):
    save_archive([_labelled(i) for i in range(2)], tmp_path / "dir", layout="files")
    save_archive([_labelled(i) for i in range(2)], tmp_path / "a.nc")
    before = sorted(p.name for p in tmp_path.rglob("*"))
    with pytest.raises(ValueError, match="inside the input directory"):
        sweep_to_disk(open_archive(tmp_path / "dir"), tmp_path / "dir" / "r.nc", window=[12])
    with pytest.raises(ValueError, match="the input file"):
        sweep_to_disk(open_archive(tmp_path / "a.nc"), tmp_path / "a.nc", window=[12], overwrite=True)
    assert sorted(p.name for p in tmp_path.rglob("*")) == before  # no parts directory either


def test_sweep_to_disk_keeps_only_the_variables_asked_for(tmp_path):
    exps = _stack(["a", "b", "c"])
    exps["y"][1, 5, 0] = np.nan  # a flagged experiment: its kept variables only, too
    out = sweep_to_disk(exps, tmp_path / "s.nc", window=[12, 15], variables=["P_flag", "P"],
                        experiments_per_task=2, scheduler="synchronous", progress=False)
    got = open_dataset(out)
    assert list(got.data_vars) == ["P", "P_flag", "experiment_error"]  # the sweep's order
    want = sweep(exps, window=[12, 15]).compute(scheduler="synchronous")
    xr.testing.assert_identical(got, want[["P", "P_flag", "experiment_error"]])
    assert (got.experiment_error.values[..., 1] != "").all() and got.P_flag[..., 1, :].all()
    with pytest.raises(ValueError, match=r"\['Q'\] are not in this sweep's result; choose from"):
        sweep_to_disk(exps, tmp_path / "t.nc", window=[12], variables=["P", "Q"])
    with pytest.raises(ValueError, match="variables must be names"):
        sweep_to_disk(exps, tmp_path / "t.nc", window=[12], variables=[])
    assert not (tmp_path / "t.nc").exists() and not parts_directory(tmp_path / "t.nc").exists()


def test_sweep_to_disk_of_experiments_without_labels(tmp_path):
    """No coordinate along experiment (a plain xr.concat): the tasks cut nothing but data."""
    exps = xr.concat([_experiment(i) for i in range(3)], "experiment")
    out = sweep_to_disk(exps, tmp_path / "s.nc", window=[12], experiments_per_task=2,
                        scheduler="synchronous", progress=False)
    want = sweep(exps, window=[12]).compute(scheduler="synchronous")
    xr.testing.assert_identical(open_dataset(out), want)


def test_sweep_to_disk_prints_experiments_per_second(tmp_path, capsys):
    sweep_to_disk(_stack(["a", "b"]), tmp_path / "s.nc", window=[12], scheduler="synchronous")
    err = capsys.readouterr().err
    assert "100% Completed | 2/2 experiment-settings" in err and "experiments/s" in err
    assert "\r" not in err  # stderr is no terminal here: plain lines


# ------------------------------------------------------------------------------- clusters
def test_local_cluster_workers_get_the_allocator_settings():
    from distributed import Client

    from lcmr_xr.scaleout.cluster import _CALLBACK

    def inspect(dask_worker):
        return (dict(os.environ), dask_worker.memory_manager.memory_pause_fraction,
                _CALLBACK in dask_worker.periodic_callbacks,
                dask_worker.memory_manager.memory_spill_fraction,
                sorted(k for k in dask_worker.periodic_callbacks if k.startswith("profile")),
                __import__("dask").config.get("distributed.admin.tick.interval"))

    # a cluster with distributed's defaults leaves MALLOC_TRIM_THRESHOLD_=65536 in this
    # process's environment (its nanny writes it there), which nannies prefer to their config
    before = os.environ.get("MALLOC_TRIM_THRESHOLD_")
    os.environ["MALLOC_TRIM_THRESHOLD_"] = "65536"
    try:
        with local_cluster(1, memory_limit="2GB", silence_logs=50) as cluster, \
                Client(cluster) as client:
            env, pause, trims, spill, profiler, tick = next(iter(client.run(inspect).values()))
        assert os.environ["MALLOC_TRIM_THRESHOLD_"] == "65536"  # this process's is restored
    finally:
        if before is None:
            os.environ.pop("MALLOC_TRIM_THRESHOLD_")
        else:
            os.environ["MALLOC_TRIM_THRESHOLD_"] = before
    assert env["MALLOC_TRIM_THRESHOLD_"] == str(64 * 2**20)
    assert env["MALLOC_MMAP_THRESHOLD_"] == str(32 * 2**20)
    assert env["OPENBLAS_NUM_THREADS"] == "1"  # distributed's own defaults are kept
    assert pause == 0.9  # PAUSE_FRACTION, set by the preload
    assert spill == 0.85  # SPILL_FRACTION: above the libraries' share of a small worker
    assert trims == (sys.platform == "linux")  # the preload's heap trimming (glibc)
    # distributed's statistical profiler is off: its call trees grew the workers' memory
    assert profiler == []
    assert tick == "1s"  # CLUSTER_CONFIG: an idle cluster's CPU


def test_worker_trims_its_heap_only_above_the_fraction_of_its_limit():
    from types import SimpleNamespace

    from lcmr_xr.scaleout.cluster import TRIM_FRACTION, trim_check

    calls = []
    rss = {"bytes": 0}
    worker = SimpleNamespace(memory_manager=SimpleNamespace(memory_limit=1000),
                             monitor=SimpleNamespace(get_process_memory=lambda: rss["bytes"]))
    check = trim_check(worker, calls.append)
    rss["bytes"] = int(TRIM_FRACTION * 1000)  # at the fraction: keep the heap
    check()
    assert calls == []
    rss["bytes"] += 1
    check()
    assert calls == [0]  # malloc_trim(0): give back every free page
    # no limit (memory_limit=0) or no malloc_trim: nothing to check
    assert trim_check(SimpleNamespace(memory_manager=SimpleNamespace(memory_limit=0)), print) is None
    assert trim_check(worker, None) is None


@pytest.mark.slow
def test_sweep_runs_unchanged_on_a_remote_scheduler(tmp_path):
    """Scheduler and worker as separate processes on 127.0.0.1; the same streamed sweep."""
    from distributed import Client

    env = {**os.environ, "PYTHONPATH": f"{ROOT}{os.pathsep}{os.environ.get('PYTHONPATH', '')}"}
    sched_file = tmp_path / "scheduler.json"
    procs = [subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_scheduler",
                               "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
                               "--scheduler-file", str(sched_file)], env=env,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)]
    try:
        deadline = time.monotonic() + 60
        while not sched_file.exists() and time.monotonic() < deadline:
            time.sleep(0.1)
        procs.append(subprocess.Popen([sys.executable, "-m", "distributed.cli.dask_worker",
                                       "--scheduler-file", str(sched_file), "--host", "127.0.0.1",
                                       "--nthreads", "1", "--no-dashboard"], env=env,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL))
        save_archive([_labelled(i) for i in range(3)], tmp_path / "a.nc")
        arc = open_archive(tmp_path / "a.nc")
        with Client(scheduler_file=str(sched_file), timeout="30s") as client:
            client.wait_for_workers(1, timeout=60)
            out = sweep_to_disk(arc, tmp_path / "s.nc", window=[12], client=client, progress=False)
            assert all(pid != os.getpid() for pid in client.run(os.getpid).values())
        want = sweep(arc, window=[12]).compute(scheduler="synchronous")
        xr.testing.assert_identical(open_dataset(out), want)
    finally:
        for proc in reversed(procs):
            proc.terminate()
        for proc in reversed(procs):
            try:
                proc.wait(timeout=20)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()


@pytest.mark.parametrize("layout", ["consolidated", "files"])
def test_an_experiment_sampled_0_05_percent_slower_is_refused(tmp_path, layout):
    # The sample times must agree to rounding: np.isclose's absolute slack (1e-8 s, 0.1 % of
    # a 10 us sample time) once let such an experiment into a consolidated archive, where it
    # took the archive's time coordinate.
    from lcmr_xr.experiment import experiment

    def sampled(th, label):
        ds = experiment(np.ones((8, 1)), np.ones((8, 1)), np.ones((4, 1)), factor=2,
                        sampling_period=th)
        return ds.assign_coords(experiment=label)

    path = tmp_path / ("arc.nc" if layout == "consolidated" else "arc")
    save_archive(sampled(1e-5, "a"), path, layout=layout)
    with pytest.raises(ValueError, match=r"another shape.*Th=1e-05 s.*|another shape.*Th=1\.0005e-05 s"):
        append_to_archive(sampled(1.0005e-5, "b"), path)
    if layout == "consolidated":  # rounding: the same (the archive keeps one time coordinate)
        append_to_archive(sampled(1e-5 * (1 + 1e-12), "c"), path)
    else:  # a directory's open compares the time coordinates bit for bit: so does its append
        with pytest.raises(ValueError, match=r"time coordinate differs .* 1e-12 relative.*bit for bit"):
            append_to_archive(sampled(1e-5 * (1 + 1e-12), "c"), path)
    assert open_archive(path).sizes["experiment"] == (2 if layout == "consolidated" else 1)
