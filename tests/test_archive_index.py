"""The header index of a directory archive: opening from it gives exactly what opening
from every file's header gives (and so what concatenating the files gives), whatever
happened to the files or the index since it was written."""

from __future__ import annotations

import multiprocessing as mp
import os
import time
import warnings

import h5py
import netCDF4
import numpy as np
import pytest
import xarray as xr

from lcmr_xr.io import save
from lcmr_xr.scaleout import append_to_archive, index_archive, open_archive, save_archive
from lcmr_xr.scaleout import dirindex
from lcmr_xr.scaleout import directory as dirx
from lcmr_xr.scaleout.archive import archive_files
from test_archive_directory import _assert_same_as_oracle, _labelled
from test_scaleout import _experiment

INDEX = dirindex.INDEX_NAME


def _headers_read(monkeypatch):
    """The names of the files whose headers are read from now on."""
    read = []
    real = dirx.read_header
    monkeypatch.setattr(dirx, "read_header", lambda path, d: read.append(path.name) or real(path, d))
    return read


def _fresh_index(directory):
    """Index written a clock tick after the files (entries of files modified in the tick of
    the index are not trusted: the 'racy' rule)."""
    time.sleep(0.05)
    return index_archive(directory)


def _open_both_ways(directory, monkeypatch):
    """open_archive with and without the index: identical to each other and to the oracle."""
    got = _assert_same_as_oracle(directory)
    monkeypatch.setattr(dirindex, "ENABLED", False)
    xr.testing.assert_identical(open_archive(directory).compute(), got.compute())
    monkeypatch.setattr(dirindex, "ENABLED", True)
    return got


def _items():
    items = [_labelled(i, drive_id=f"D{i % 2}", degrees=(3, 3, 3), noise=True, tags=["a", "b"],
                       note=None, rms=np.array([1e-3, np.nan]), gain=np.float32(0.1),
                       operator="x" if i < 2 else "y").assign_coords(temperature=20.5 + i)
             for i in range(4)]
    items[2] = items[2].assign_attrs(only_here=1.5)
    return items


def test_writers_keep_the_index_and_the_open_reads_no_header(tmp_path, monkeypatch):
    d = tmp_path / "d"
    items = _items()
    save_archive(items[:3], d, layout="files")
    assert (d / INDEX).is_file()
    append_to_archive(items[3], d)  # appended: in the index too
    entries = dirindex.read_index(d)
    assert sorted(entries) == ["run0.nc", "run1.nc", "run2.nc", "run3.nc"]
    _fresh_index(d)
    read = _headers_read(monkeypatch)
    got = _open_both_ways(d, monkeypatch)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2", "run3"]
    assert read.count("run0.nc") == 1  # only the open without the index read headers
    read.clear()
    open_archive(d)
    assert read == []
    assert [p.name for p in archive_files(d)] == ["run0.nc", "run1.nc", "run2.nc", "run3.nc"]
    # the index is a hidden NetCDF file, not an experiment of the archive
    with netCDF4.Dataset(d / INDEX) as nc:
        assert nc.dimensions["file"].size == 4 and nc.getncattr(dirindex.INDEX_ATTR) == dirindex.VERSION


def test_stale_removed_added_files_and_no_index(tmp_path, monkeypatch):
    d = tmp_path / "d"
    save_archive([_labelled(i, drive_id="A") for i in range(4)], d, layout="files")
    _fresh_index(d)
    # rewritten after the index with other values and metadata (same size: same structure)
    size = (d / "run1.nc").stat().st_size
    save(_labelled(7, drive_id="B").assign_coords(experiment="run1")
         .assign_attrs(lcmr_archive_index=1), d / "run1.nc")
    assert (d / "run1.nc").stat().st_size == size
    # changed in place with its modification time put back: the change time tells
    st = (d / "run2.nc").stat()
    with netCDF4.Dataset(d / "run2.nc", "a") as nc:
        nc.setncattr("seed", np.int64(99))
    os.utime(d / "run2.nc", ns=(st.st_atime_ns, st.st_mtime_ns))
    (d / "run3.nc").unlink()  # removed
    save(_labelled(5, drive_id="A"), d / "zz_by_hand.nc")  # added by another tool
    read = _headers_read(monkeypatch)
    got = _open_both_ways(d, monkeypatch)
    assert set(read[:3]) == {"run1.nc", "run2.nc", "zz_by_hand.nc"} and "run0.nc" not in read[:3]
    assert got.experiment.values.tolist() == ["run0", "run1", "run2", "run5"]
    assert got.seed.values.tolist() == [0, 7, 99, 5]
    assert got.drive_id.values.tolist() == ["A", "B", "A", "A"]
    np.testing.assert_array_equal(got.y.values[1], _labelled(7).y.values)
    # no index (a directory of an older version): the same dataset
    (d / INDEX).unlink()
    xr.testing.assert_identical(_assert_same_as_oracle(d).compute(), got.compute())
    # a write brings every file into the index again
    append_to_archive(_labelled(9, drive_id="A"), d)
    _fresh_index(d)
    read.clear()
    _assert_same_as_oracle(d)
    assert "run1.nc" not in read[:5] and "zz_by_hand.nc" not in read[:5]


def test_a_corrupt_or_foreign_index_is_ignored_with_a_warning(tmp_path, monkeypatch):
    d = tmp_path / "d"
    save_archive([_labelled(i) for i in range(3)], d, layout="files")
    _fresh_index(d)
    want = open_archive(d).compute()
    (d / INDEX).write_bytes(b"\x89HDF\r\n garbage")
    with pytest.warns(RuntimeWarning, match=r"archive index .* ignored \(unreadable.*index_archive"):
        got = _assert_same_as_oracle(d)
    xr.testing.assert_identical(got.compute(), want)
    _fresh_index(d)
    with h5py.File(d / INDEX, "a") as f:  # another version
        f.attrs[dirindex.INDEX_ATTR] = np.int64(dirindex.VERSION + 1)
    newer = (rf"ignored \(version {dirindex.VERSION + 1}, written by a newer lcmr_xr; this library "
             rf"reads version {dirindex.VERSION}\).*Upgrade lcmr_xr")
    with pytest.warns(RuntimeWarning, match=newer):
        _assert_same_as_oracle(d)
    older = dirindex.VERSION - 1
    with h5py.File(d / INDEX, "a") as f:  # an older version: rebuilt by index_archive
        f.attrs[dirindex.INDEX_ATTR] = np.int64(older)
    with pytest.warns(RuntimeWarning, match=rf"ignored \(version {older}, this library reads "
                                           rf"version {dirindex.VERSION}\).*index_archive"):
        _assert_same_as_oracle(d)
    # one damaged entry (its mtime kept: not racy): that file is read from its header
    _fresh_index(d)
    st = (d / INDEX).stat()
    with h5py.File(d / INDEX, "a") as f:
        f["summary"][1] = "{not json"
    os.utime(d / INDEX, ns=(st.st_atime_ns, st.st_mtime_ns))
    read = _headers_read(monkeypatch)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        xr.testing.assert_identical(open_archive(d).compute(), want)
    assert read == ["run1.nc"]


def test_the_checks_of_the_open_hold_for_files_served_from_the_index(tmp_path, monkeypatch):
    cases = {
        "length": (_experiment(5, n=240).assign_coords(experiment="run5").assign_attrs(seed=5, case=2),
                   r"have different lengths \(N=240: 1 \(run5\.nc\); N=480: 2"),
        "metadata": (_labelled(5).drop_attrs().assign_attrs(
            {k: v for k, v in _labelled(5).attrs.items() if k != "case"}),
            r"experiment 'run5' has the metadata \['seed'\]"),
        "structure": (_labelled(5).assign(r=lambda ds: ds.r.astype(np.float32)),
                      r"run5\.nc differs from run0\.nc in its variables"),
        "foreign": (xr.Dataset({"a": ("x", [1.0, 2.0])}), r"run5\.nc is not an lcmr-xr-1 experiment"),
    }
    for name, (odd, message) in cases.items():
        d = tmp_path / name
        save_archive([_labelled(0), _labelled(1)], d, layout="files")
        save(odd, d / "run5.nc")
        _fresh_index(d)
        entries = dirindex.read_index(d)
        assert "run5.nc" in entries, name
        read = _headers_read(monkeypatch)
        with pytest.raises(ValueError, match=message):
            open_archive(d)
        assert "run5.nc" not in read, name
        monkeypatch.setattr(dirindex, "ENABLED", False)
        with pytest.raises(ValueError, match=message):
            open_archive(d)
        monkeypatch.undo()


def test_open_never_writes(tmp_path, monkeypatch):
    d = tmp_path / "d"
    save_archive([_labelled(i) for i in range(3)], d, layout="files")
    save(_labelled(3), d / "run3.nc")  # not in the index
    before = {p.name: p.stat().st_mtime_ns for p in d.iterdir()}

    def refuse(*args, **kwargs):
        raise AssertionError("the open wrote something")

    monkeypatch.setattr(dirindex, "write_index", refuse)
    monkeypatch.setattr("lcmr_xr.io._atomic.atomic_write", refuse)
    os.chmod(d, 0o555)
    try:
        _assert_same_as_oracle(d)
    finally:
        os.chmod(d, 0o755)
    assert {p.name: p.stat().st_mtime_ns for p in d.iterdir()} == before


def test_a_lost_index_update_only_costs_header_reads(tmp_path, monkeypatch):
    d = tmp_path / "d"
    save_archive([_labelled(i) for i in range(2)], d, layout="files")
    older = (d / INDEX).read_bytes()
    append_to_archive(_labelled(2), d)
    (d / INDEX).write_bytes(older)  # another writer's base replaced this one's: the journal lists run2
    time.sleep(0.05)
    read = _headers_read(monkeypatch)
    _assert_same_as_oracle(d)
    assert read == []
    for name in dirindex.journal_files(d):  # the journal lost too
        (d / dirindex.JOURNAL_NAME / name).unlink()
    got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2"] and read == ["run2.nc"]


def _append_many(directory, start):
    for i in range(start, start + 6):
        append_to_archive(_labelled(i), directory)


def test_two_processes_appending_at_once(tmp_path):
    d = tmp_path / "d"
    save_archive([_labelled(100)], d, layout="files")
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_append_many, args=(d, start)) for start in (0, 10)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=300)
    assert [p.exitcode for p in procs] == [0, 0]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # the index is whole (read, not ignored)
        entries = dirindex.read_index(d)
        got = _assert_same_as_oracle(d)
    assert set(entries) == {p.name for p in d.glob("*.nc") if not p.name.startswith(".")}
    assert sorted(got.experiment.values.tolist()) == sorted(
        [f"run{i}" for i in [*range(6), *range(10, 16), 100]])


def test_index_values_round_trip_exactly():
    values = {"nan": float("nan"), "neg0": -0.0, "inf": float("-inf"), "f32": np.float32(0.1),
              "i64": np.int64(-2**62), "u64": np.uint64(2**64 - 1), "b": True, "none": None,
              "tuple": (1, "a", (2.5,)), "empty": (), "list": [1, [2, 3]], "bytes": b"\x00\xff",
              "text": "caf\u00e9 \udcff", "arr": np.array([[1.5, np.nan]], dtype=">f8"),
              "bools": np.array([True, False]), "big": 10**30}
    text = dirindex.summary_text(values)
    assert text is not None
    for got in (dirindex.loads(text), dirindex.decode(__import__("json").loads(text))):
        assert dirindex.same(got, values)
        assert list(got) == list(values) and type(got["tuple"][2]) is tuple
        assert got["arr"].dtype == np.dtype(">f8") and type(got["f32"]) is np.float32
    assert not dirindex.same(np.float32(0.1), np.float64(np.float32(0.1)))
    assert not dirindex.same((1,), [1]) and not dirindex.same(1, True)
    assert dirindex.summary_text({"c": 1j}) is None  # not kept: its file is read from its header
    with pytest.raises(dirindex.Unindexable):
        dirindex.encode(np.array([1j]))


def test_index_command(tmp_path, capsys):
    from lcmr_xr.cli import main as cli_main

    save_archive([_labelled(i) for i in range(2)], tmp_path, layout="files")
    (tmp_path / INDEX).unlink()
    assert cli_main(["archive", "index", str(tmp_path)]) == 0
    assert f"wrote {tmp_path / INDEX}" in capsys.readouterr().out
    assert sorted(dirindex.read_index(tmp_path)) == ["run0.nc", "run1.nc"]
    assert cli_main(["archive", "index", str(tmp_path / "missing")]) == 2
    assert "does not exist" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["archive", "index", "--help"])
    assert "header index" in capsys.readouterr().out


def test_the_names_a_writer_looks_up_for_a_label_are_the_listing_rule_s():
    """plain_names(stem), which a writer stats before adding STEM.nc, is exactly the set of
    names the directory's listing (plain_name) reads as STEM and a NetCDF ending, any case."""
    from itertools import product

    from lcmr_xr.io._guards import NETCDF_SUFFIXES

    got = dirindex.plain_names("run5")
    assert len(got) == len(set(got)) == 4 + 4 + 64  # .nc, .nc4, .netcdf in every case
    spellings = {"".join(cs) for s in NETCDF_SUFFIXES + (".h5", ".nc.tmp", ".ncx", ".n")
                 for cs in product(*({c.lower(), c.upper()} for c in s))}
    candidates = {"run5" + s for s in spellings} | {"Run5.nc", "run50.nc", "run.nc", ".run5.nc"}
    assert set(got) == {n for n in candidates if dirindex.plain_name(n) and n.startswith("run5.")}
    assert dirindex.plain_names(".hidden") == [] and dirindex.plain_names("a/b") == []


def test_a_directory_archive_holds_every_netcdf_name_that_save_writes(tmp_path, monkeypatch):
    # save writes NetCDF-4 to x.nc, x.NC, x.nc4, x.netcdf (any case); the directory's listing
    # took only names ending exactly in ".nc", so x.NC and x.nc4 put there were silently
    # not part of the archive (its open, index, consolidation and sweep)
    from lcmr_xr.io._atomic import temporary_prefix
    from lcmr_xr.scaleout import consolidate_archive, sweep

    d = tmp_path / "d"
    items = [_labelled(i) for i in range(6)]
    save_archive(items[:2], d, layout="files")  # run0.nc, run1.nc (orders 0, 1)
    for i, name in ((2, "run2.NC"), (3, "run3.nc4"), (4, "run4.NetCDF")):
        save(items[i], d / name)  # by save, as another tool would: no archive order
    # never experiment files: other endings, hidden names (temporaries of atomic writes)
    for name in ("notes.txt", "run9.nc.tmp", "run7.h5", ".hidden.NC",
                 temporary_prefix(d / "run8.nc") + "abcdefgh.tmp"):
        (d / name).write_bytes(b"\x89HDF\r\n\x1a\n not an experiment")
    want = ["run0.nc", "run1.nc", "run2.NC", "run3.nc4", "run4.NetCDF"]
    assert [p.name for p in archive_files(d)] == want  # ordered ones first, then by name
    got = _open_both_ways(d, monkeypatch)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2", "run3", "run4"]
    for i in range(5):
        np.testing.assert_array_equal(got.y.values[i], items[i].y.values)
    # the index lists them, and the open then reads no header
    _fresh_index(d)
    assert sorted(dirindex.read_index(d)) == sorted(want)
    read = _headers_read(monkeypatch)
    xr.testing.assert_identical(open_archive(d).compute(), got.compute())
    assert read == []
    monkeypatch.undo()
    # an append takes the next order after the indexed ones and keeps naming LABEL.nc
    append_to_archive(items[5], d)
    assert [p.name for p in archive_files(d)] == ["run0.nc", "run1.nc", "run5.nc", *want[2:]]
    assert sorted(dirindex.read_index(d)) == sorted(want + ["run5.nc"])
    full = _open_both_ways(d, monkeypatch)
    labels = ["run0", "run1", "run5", "run2", "run3", "run4"]
    assert full.experiment.values.tolist() == labels
    # consolidated: the same six experiments, in the same order
    one = open_archive(consolidate_archive(d, tmp_path / "all.nc")).compute()
    assert one.experiment.values.tolist() == labels
    for name in ("r", "u", "y"):
        np.testing.assert_array_equal(one[name].values, full[name].values)
    # the sweep over the directory: every experiment, none flagged
    res = sweep(open_archive(d), window=[12], degrees=["2-2-2"]).compute()
    assert res.experiment.values.tolist() == labels
    assert res.experiment_error.values.ravel().tolist() == [""] * 6
    want_p = sweep(one, window=[12], degrees=["2-2-2"]).compute().P
    np.testing.assert_array_equal(res.P.values, want_p.values)
