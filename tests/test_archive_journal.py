"""Appending into a directory archive costs the same whatever the directory holds: the new
experiment is checked against one file, its index entry goes to a journal file, and the
base of the index is rewritten only by a compaction.  The open is unchanged (identical to
concatenating the files, with or without the index), crashes and concurrent appenders
cost at most header reads."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import re
import time
import warnings

import h5netcdf
import h5py
import numpy as np
import pytest

from lcmr_xr.io import open_experiment, save
from lcmr_xr.scaleout import append_to_archive, index_archive, open_archive, save_archive
from lcmr_xr.scaleout import archive as arc
from lcmr_xr.scaleout import dirindex
from lcmr_xr.scaleout import directory as dirx
from test_archive_directory import _assert_same_as_oracle, _labelled

INDEX, JOURNAL = dirindex.INDEX_NAME, dirindex.JOURNAL_NAME


def _calls(monkeypatch, module, name):
    """The calls of ``module.name`` from now on (their first arguments)."""
    seen = []
    real = getattr(module, name)

    def spy(*args, **kwargs):
        seen.append(args[0] if args else None)
        return real(*args, **kwargs)

    monkeypatch.setattr(module, name, spy)
    return seen


def _files(d):
    return [p for p in d.glob("*.nc") if not p.name.startswith(".")]


def _archive(d, n):
    save_archive([_labelled(i) for i in range(n)], d, layout="files")
    time.sleep(0.01)


def test_an_append_reads_one_header_and_does_not_rewrite_the_index(tmp_path, monkeypatch):
    for n in (2, 12):
        d = tmp_path / f"d{n}"
        _archive(d, n)
        base = (d / INDEX).stat()
        headers = _calls(monkeypatch, dirx, "read_header")
        writes = _calls(monkeypatch, dirindex, "write_index")
        loads = _calls(monkeypatch, dirindex, "loader")
        append_to_archive(_labelled(100), d)
        # one file of the archive (the first by name) and the new one, before it is moved in
        assert [p.name[:8] for p in headers] == ["run0.nc", ".run100."], headers
        assert writes == [] and loads == []
        assert (d / INDEX).stat().st_mtime_ns == base.st_mtime_ns
        assert len(dirindex.journal_files(d)) == 1
        monkeypatch.undo()
        headers = _calls(monkeypatch, dirx, "read_header")
        got = _assert_same_as_oracle(d)
        assert headers == []  # every file from the index (base and journal)
        assert got.experiment.values.tolist()[-1] == "run100"
        monkeypatch.undo()


def test_the_journal_is_compacted_and_keeps_the_order(tmp_path, monkeypatch):
    d = tmp_path / "d"
    _archive(d, 2)
    monkeypatch.setattr(dirindex, "JOURNAL_FILES", 3)
    for i in (9, 3, 7):  # labels out of name order: the archive keeps the order of the appends
        append_to_archive(_labelled(i), d)
    assert len(dirindex.journal_files(d)) == 3
    writes = _calls(monkeypatch, dirindex, "write_index")
    append_to_archive(_labelled(5), d)  # the fourth journal file: compacted
    assert len(writes) == 1 and dirindex.journal_files(d) == []
    index = dirindex.read_index(d)
    assert index.ordered and index.base_rows == 6
    assert {n: e[0][3] for n, e in index.items()} == {"run0.nc": 0, "run1.nc": 1, "run9.nc": 2,
                                                      "run3.nc": 3, "run7.nc": 4, "run5.nc": 5}
    time.sleep(0.01)
    headers = _calls(monkeypatch, dirx, "read_header")
    got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run9", "run3", "run7", "run5"]
    assert headers == []
    assert [p.name for p in arc.archive_files(d)] == [f"run{i}.nc" for i in (0, 1, 9, 3, 7, 5)]


def test_a_bulk_save_compacts_at_once(tmp_path, monkeypatch):
    d = tmp_path / "d"
    _archive(d, 1)
    monkeypatch.setattr(dirindex, "BULK_ROWS", 3)
    save_archive([_labelled(i) for i in range(1, 4)], d, layout="files")
    assert dirindex.journal_files(d) == [] and dirindex.read_index(d).base_rows == 4


def _old_index(d):
    """The base as the library wrote it before it kept the orders (version 3, no ``order``)."""
    rows = [(name, entries[-1][0], entries[-1][1]) for name, entries in dirindex.read_index(d).items()]
    (d / INDEX).unlink()
    for name in dirindex.journal_files(d):
        (d / JOURNAL / name).unlink()
    text = h5py.string_dtype("utf-8")
    with h5netcdf.File(d / INDEX, "w") as f:
        f.attrs[dirindex.INDEX_ATTR] = np.int64(3)
        f.dimensions = {"file": len(rows)}
        for name, values in (("name", [r[0] for r in rows]), ("summary", [r[2] for r in rows])):
            f.create_variable(name, ("file",), dtype=text)[:] = np.array(values, dtype=object)
        for i, column in enumerate(("size", "mtime_ns", "ctime_ns", "inode")):
            f.create_variable(column, ("file",), dtype=np.int64)[:] = [r[1][i] for r in rows]


def test_an_index_of_the_previous_version_is_read_and_upgraded(tmp_path, monkeypatch):
    d = tmp_path / "d"
    _archive(d, 3)
    for i in (8, 4):
        append_to_archive(_labelled(i), d)
    _old_index(d)
    time.sleep(0.01)
    index = dirindex.read_index(d)
    assert index.base and not index.ordered
    headers = _calls(monkeypatch, dirx, "read_header")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # read as it is: no warning
        _assert_same_as_oracle(d)
        assert [p.name for p in arc.archive_files(d)] == [f"run{i}.nc" for i in (0, 1, 2, 8, 4)]
    assert headers == []
    # the first write rewrites it with the orders (from its entries: no header read)
    append_to_archive(_labelled(6), d)
    assert [p.name[:8] for p in headers] == ["run0.nc", ".run6.nc"]  # the check, the new file
    index = dirindex.read_index(d)
    assert index.ordered and index["run6.nc"][0][3] == 5 and index["run4.nc"][-1][3] == 4
    time.sleep(0.01)
    headers.clear()
    got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2", "run8", "run4", "run6"]
    assert headers == []


def test_a_crash_mid_append_leaves_an_archive_that_opens(tmp_path, monkeypatch):
    class Killed(BaseException):
        """The process dies here (nothing after runs)."""

    def die(*args, **kwargs):
        raise Killed

    d = tmp_path / "d"
    _archive(d, 2)
    want = open_archive(d).compute()
    # while the experiment's file is written: nothing of it appears
    monkeypatch.setattr(arc, "_check_structure", die)
    with pytest.raises(Killed):
        append_to_archive(_labelled(2), d)
    monkeypatch.undo()
    assert sorted(p.name for p in _files(d)) == ["run0.nc", "run1.nc"]
    assert open_archive(d).identical(want)
    # after the file, before its journal entry: the file is read from its header
    monkeypatch.setattr(dirindex, "append_journal", die)
    with pytest.raises(Killed):
        append_to_archive(_labelled(2), d)
    monkeypatch.undo()
    headers = _calls(monkeypatch, dirx, "read_header")
    assert _assert_same_as_oracle(d).experiment.values.tolist() == ["run0", "run1", "run2"]
    assert [p.name for p in headers] == ["run2.nc"]
    monkeypatch.undo()
    # a compaction that wrote the base but did not remove the journal files it folded in
    monkeypatch.setattr(dirindex, "JOURNAL_FILES", 0)
    monkeypatch.setattr(dirindex, "remove_journal", die)
    with pytest.raises(Killed):
        append_to_archive(_labelled(3), d)
    monkeypatch.undo()
    assert len(dirindex.journal_files(d)) == 1
    time.sleep(0.01)
    headers = _calls(monkeypatch, dirx, "read_header")
    got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2", "run3"] and headers == []
    monkeypatch.undo()
    index_archive(d)  # folds the left-over journal file in
    assert dirindex.journal_files(d) == [] and sorted(dirindex.read_index(d)) == [
        "run0.nc", "run1.nc", "run2.nc", "run3.nc"]


def test_a_corrupt_journal_file_is_ignored_with_a_warning(tmp_path, monkeypatch):
    d = tmp_path / "d"
    _archive(d, 2)
    append_to_archive(_labelled(2), d)
    append_to_archive(_labelled(3), d)
    first = dirindex.journal_files(d)[0]
    (d / JOURNAL / first).write_text('{"lcmr_archive_index_journal": 1, "rows": [["run2.nc"')
    headers = _calls(monkeypatch, dirx, "read_header")
    with pytest.warns(RuntimeWarning, match=r"archive index .*\.json ignored \(unreadable.*index_archive"):
        got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2", "run3"]
    assert "run2.nc" in [p.name for p in headers] and "run3.nc" not in [p.name for p in headers]
    monkeypatch.undo()
    with pytest.warns(RuntimeWarning, match=rf"{first} is unreadable \(damaged\); set aside as .*"
                                           rf"{first}\.unreadable"):
        index_archive(d)  # kept, never read again (its file's entry: from the header)
    assert dirindex.journal_files(d) == []
    assert (d / JOURNAL / (first + ".unreadable")).read_text().endswith('[["run2.nc"')
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _assert_same_as_oracle(d)


def test_a_lost_base_update_costs_only_header_reads(tmp_path, monkeypatch):
    d = tmp_path / "d"
    _archive(d, 2)
    older = (d / INDEX).read_bytes()
    monkeypatch.setattr(dirindex, "JOURNAL_FILES", 0)  # compacts: the base lists run2
    append_to_archive(_labelled(2), d)
    monkeypatch.undo()
    assert dirindex.journal_files(d) == []
    (d / INDEX).write_bytes(older)  # another writer's base (without locks) replaced this one's
    time.sleep(0.01)
    headers = _calls(monkeypatch, dirx, "read_header")
    got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2"]
    assert [p.name for p in headers] == ["run2.nc"]


def _append_many(directory, start, journal_files):
    dirindex.JOURNAL_FILES = journal_files
    for i in range(start, start + 6):
        append_to_archive(_labelled(i), directory)


@pytest.mark.parametrize("journal_files", [128, 1])  # 1: (nearly) every append compacts
def test_two_processes_appending_at_once_keep_each_others_entries(tmp_path, monkeypatch, journal_files):
    d = tmp_path / "d"
    _archive(d, 1)
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_append_many, args=(d, start, journal_files)) for start in (10, 20)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=300)
    assert [p.exitcode for p in procs] == [0, 0]
    time.sleep(0.01)
    headers = _calls(monkeypatch, dirx, "read_header")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing ignored
        got = _assert_same_as_oracle(d)
    assert sorted(got.experiment.values.tolist()) == sorted(
        [f"run{i}" for i in [0, *range(10, 16), *range(20, 26)]])
    assert headers == []  # no entry lost
    assert sorted(dirindex.read_index(d)) == sorted(p.name for p in _files(d))
    monkeypatch.undo()
    # and no order taken twice (the directory's write lock; the threaded test below forces
    # the interleaving that took one twice)
    assert sorted(dirx.order_index(p, d) for p in _files(d)) == list(range(13))


def test_an_append_applies_the_structure_test_of_the_open(tmp_path):
    # The sample times of a directory's files must agree bit for bit (its open compares the
    # time coordinates' bytes): an experiment sampled 1e-12 relative slower was appended
    # (the append compared to 1e-9 relative) and the open then refused the directory.
    from lcmr_xr.experiment import experiment

    def sampled(th, label):
        return experiment(np.ones((8, 1)), np.ones((8, 1)), np.ones((4, 1)), factor=2,
                          sampling_period=th).assign_coords(experiment=label)

    d = tmp_path / "arc"
    save_archive(sampled(1e-5, "a"), d, layout="files")
    rounded = sampled(1e-5 * (1 + 1e-12), "b")
    assert not np.array_equal(rounded.time.values, open_archive(d).time.values)
    with pytest.raises(ValueError, match=r"experiment 'b': its time coordinate differs from that of "
                                         r"a\.nc by up to 1e-12 relative \(rounding\).*bit for bit"
                                         r".*assign_coords\(time=ref\.time\.variable, slow_time=ref\.slow_time\.variable\)"):
        append_to_archive(rounded, d)
    assert sorted(p.name for p in d.iterdir() if not p.name.startswith(".")) == ["a.nc"]
    assert open_archive(d).sizes["experiment"] == 1
    # the remedy of the message
    ref = open_experiment(d / "a.nc")
    append_to_archive(rounded.assign_coords(time=ref.time.variable, slow_time=ref.slow_time.variable), d)
    assert open_archive(d).experiment.values.tolist() == ["a", "b"]
    # other variables: refused as the open refuses them
    with pytest.raises(ValueError, match=r"experiment 'c' differs from a\.nc .* in its variables"):
        append_to_archive(sampled(1e-5, "c").assign(extra=lambda ds: ds.r * 2), d)
    # and two new experiments of one save are held to the same test
    with pytest.raises(ValueError, match=r"experiment 'e': its time coordinate"):
        save_archive([sampled(1e-5, "d"), sampled(1e-5 * (1 + 1e-12), "e")], tmp_path / "new",
                     layout="files")


def test_an_append_applies_the_metadata_test_of_the_open(tmp_path):
    d = tmp_path / "d"
    _archive(d, 2)
    odd = _labelled(2)
    odd.attrs = {k: v for k, v in odd.attrs.items() if k != "case"}
    with pytest.raises(ValueError, match=r"experiment 'run2' has the metadata \['seed'\]"):
        append_to_archive(odd, d)
    assert sorted(p.name for p in _files(d)) == ["run0.nc", "run1.nc"]


def test_an_open_of_many_files_without_entries_warns_once_with_the_remedy(tmp_path, monkeypatch):
    d = tmp_path / "d"
    _archive(d, 4)
    monkeypatch.setattr(arc, "UNINDEXED_WARN", 2)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        open_archive(d)  # indexed: no warning
    (d / INDEX).unlink()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _assert_same_as_oracle(d)
    caught = [w for w in caught if issubclass(w.category, RuntimeWarning)]
    assert len(caught) == 1, [str(w.message) for w in caught]
    message = str(caught[0].message)
    assert f"4 of the 4 files of archive {d}" in message and "it has no header index" in message
    assert f"lcmr-xr archive index {d}" in message and "index_archive(directory)" in message
    assert "about 0 s now" in message and "then takes about 0.1 s" in message
    monkeypatch.setattr(dirindex, "ENABLED", False)  # deliberately without the index: no warning
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        open_archive(d)
    monkeypatch.setattr(dirindex, "ENABLED", True)
    index_archive(d)
    time.sleep(0.01)
    save(_labelled(5), d / "by_hand.nc")  # two files: below the threshold
    save(_labelled(6), d / "by_hand2.nc")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        open_archive(d)
    save(_labelled(7), d / "by_hand3.nc")
    with pytest.warns(RuntimeWarning, match=r"3 of the 7 files .* no current entry in its header index"):
        open_archive(d)


# ------------------------------------------------------------------ review (session 9)
def test_an_append_before_files_without_an_order_keeps_the_archive_openable(tmp_path):
    # Files written by another tool carry no order: a new file goes before them, so the
    # open's metadata test (kinds held to the first file's) must not depend on which file
    # is first.  A float seed in the old files and an integer one in the new file: the
    # append (which compares with one old file) accepted it, the open then refused.
    from test_scaleout import _experiment

    d = tmp_path / "d"
    d.mkdir()
    for i in range(2):
        save(_experiment(i).assign_coords(experiment=f"run{i}").assign_attrs(seed=i + 0.5, case=2),
             d / f"run{i}.nc")
    index_archive(d)
    append_to_archive(_experiment(5).assign_coords(experiment="run5").assign_attrs(seed=5, case=2), d)
    got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run5", "run0", "run1"]
    assert got.seed.values.tolist() == [5.0, 0.5, 1.5]


@pytest.mark.parametrize("attr", ["units", "long_name"])
def test_an_append_refuses_units_the_open_would_drop(tmp_path, attr):
    # The open combines the variables' attributes with drop_conflicts; r, u, y without
    # units or long_name are no experiment: the open refused the whole directory.
    d = tmp_path / "d"
    _archive(d, 2)
    odd = _labelled(2)
    odd["r"].attrs[attr] = "something else"
    with pytest.raises(ValueError, match=rf"experiment 'run2': its variable 'r' has {attr} "
                                         r"'something else' where run0\.nc has .*drop.*set it"):
        append_to_archive(odd, d)
    assert sorted(p.name for p in _files(d)) == ["run0.nc", "run1.nc"]
    _assert_same_as_oracle(d)


def test_an_append_never_reads_a_file_outside_the_directory_that_the_index_names(tmp_path, monkeypatch):
    d = tmp_path / "d"
    _archive(d, 2)
    save(_labelled(9), tmp_path / "outside.nc")
    rows = [(n, e[-1][0], e[-1][1], e[-1][3]) for n, e in dirindex.read_index(d).items()]
    for bad in ("../outside.nc", str(tmp_path / "outside.nc")):
        dirindex.write_index(d, [(bad, *rows[0][1:])] + rows)  # its first entry names it
        headers = _calls(monkeypatch, dirx, "read_header")
        append_to_archive(_labelled(len(_files(d))), d)
        assert [p.parent for p in headers] == [d, d], headers  # a file of d, the new one
        monkeypatch.undo()
    _assert_same_as_oracle(d)


def test_journal_entries_of_another_summary_version_are_not_trusted(tmp_path, monkeypatch):
    # A summary's content is versioned by dirindex.VERSION (the base's attribute); journal
    # files carried only their own format number, so a library with other summaries took
    # them as its own.
    d = tmp_path / "d"
    _archive(d, 2)
    append_to_archive(_labelled(2), d)
    time.sleep(0.01)
    assert "run2.nc" in dirindex.read_index(d)
    # a journal file that does not say (written before they did) holds version 3
    path = d / JOURNAL / dirindex.journal_files(d)[0]
    data = json.loads(path.read_text())
    assert data.pop(dirindex.INDEX_ATTR) == dirindex.VERSION == 3
    path.write_text(json.dumps(data))
    assert dirindex.trusted(dirindex.read_index(d), "run2.nc", (d / "run2.nc").stat()) is not None
    monkeypatch.setattr(dirindex, "VERSION", dirindex.VERSION + 1)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert dirindex.read_index(d) is None
    messages = [str(w.message) for w in caught]  # the base's and the journal file's
    assert len(messages) == 2 and "index.nc ignored (version 3, this library reads version 4)" in messages[1]
    assert re.search(r"\.json ignored \(summaries of version 3, this library reads version 4\)"
                     r".*index_archive", messages[0]), messages
    # and it writes and reads its own
    index_archive(d)
    append_to_archive(_labelled(3), d)
    time.sleep(0.01)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert sorted(dirindex.read_index(d)) == ["run0.nc", "run1.nc", "run2.nc", "run3.nc"]


def test_an_append_whose_file_another_writer_replaced_writes_no_entry_for_it(tmp_path, monkeypatch):
    # Another process re-measures the same experiment between this write's rename and its
    # stat: the entry then held this write's summary under the other file's stamp.
    d = tmp_path / "d"
    _archive(d, 2)
    real = arc._write_checked

    def raced(ds, path, ref, label, **kwargs):
        out = real(ds, path, ref, label, **kwargs)
        save(_labelled(2).assign_attrs(seed=99), tmp_path / "other.nc")  # (save takes .nc names)
        os.replace(tmp_path / "other.nc", path)
        return out

    monkeypatch.setattr(arc, "_write_checked", raced)
    append_to_archive(_labelled(2), d)
    monkeypatch.undo()
    time.sleep(0.01)
    got = _assert_same_as_oracle(d)
    assert got.seed.values.tolist() == [0, 1, 99]


def test_an_append_into_a_directory_never_replaces_an_experiment(tmp_path):
    # append_to_archive adds experiments ("its label is taken" raises, as for a consolidated
    # archive); into a directory it replaced the file of the same name without a word.
    d = tmp_path / "d"
    _archive(d, 2)
    before = (d / "run1.nc").read_bytes()
    for label in ("run1", "run1."):  # the same file name
        with pytest.raises(ValueError, match=rf"experiment '{label}' is already in .*d \(run1\.nc\); "
                                             r"give it a new label.*save_archive\(experiment, "):
            append_to_archive(_labelled(1).assign_coords(experiment=label), d)
    assert (d / "run1.nc").read_bytes() == before
    assert _assert_same_as_oracle(d).experiment.values.tolist() == ["run0", "run1"]
    save_archive(_labelled(1).assign_attrs(seed=11), d, layout="files")  # the remedy: replaced
    assert open_archive(d).seed.values.tolist() == [0, 11]


@pytest.mark.parametrize("damage", [('"attrs"', '"attrz"'), ('{"d":[["attrs"', '{"l":[["attrs"'),
                                    ('["shape",{"d":', '["shape",{"l":')])
def test_a_damaged_summary_in_a_current_entry_is_read_from_the_header(tmp_path, monkeypatch, damage):
    # A summary that is valid JSON but not what the open uses (a damaged byte in a key or
    # a tag) failed the open with a KeyError / TypeError from deep inside.
    d = tmp_path / "d"
    _archive(d, 2)
    append_to_archive(_labelled(2), d)
    path = d / JOURNAL / dirindex.journal_files(d)[0]
    data = json.loads(path.read_text())
    assert data["rows"][0][3].count(damage[0]) == 1
    data["rows"][0][3] = data["rows"][0][3].replace(*damage)
    path.write_text(json.dumps(data))
    time.sleep(0.01)
    headers = _calls(monkeypatch, dirx, "read_header")
    got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2"]
    assert [p.name for p in headers] == ["run2.nc"]


def test_a_journal_file_nested_too_deep_is_ignored_with_a_warning(tmp_path):
    # json's parser raises RecursionError (no ValueError) on deep nesting: the open failed.
    d = tmp_path / "d"
    _archive(d, 2)
    append_to_archive(_labelled(2), d)
    (d / JOURNAL / "000000000009-1-junk.json").write_text("[" * 200_000)
    time.sleep(0.01)
    with pytest.warns(RuntimeWarning, match=r"000000000009-1-junk\.json ignored \(unreadable.*index_archive"):
        got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == ["run0", "run1", "run2"]


def test_of_two_current_journal_entries_of_a_file_the_newest_is_taken(tmp_path, monkeypatch):
    # "newest entry first" (dirindex.Index) sorted the journal's entries by summary text.
    d = tmp_path / "d"
    _archive(d, 2)
    append_to_archive(_labelled(2), d)
    newer = d / JOURNAL / dirindex.journal_files(d)[0]
    data = json.loads(newer.read_text())
    text = data["rows"][0][3]
    assert text.count('["seed",2]') == 1
    data["rows"][0][3] = text.replace('["seed",2]', '["seed",99]')  # sorts after the right one
    older = d / JOURNAL / "000000000001-1-older.json"
    older.write_text(json.dumps(data))
    st = (d / "run2.nc").stat()
    tick = max(st.st_mtime_ns, st.st_ctime_ns)
    os.utime(older, ns=(tick + 1000, tick + 1000))
    os.utime(newer, ns=(tick + 2000, tick + 2000))
    headers = _calls(monkeypatch, dirx, "read_header")
    got = _assert_same_as_oracle(d)
    assert got.seed.values.tolist() == [0, 1, 2] and headers == []


def test_an_append_whose_file_another_process_edited_writes_no_entry_for_it(tmp_path, monkeypatch):
    # The same, the file edited in place (same inode) between the rename and the stat.
    d = tmp_path / "d"
    _archive(d, 2)
    real = arc._write_checked

    def raced(ds, path, ref, label, **kwargs):
        out = real(ds, path, ref, label, **kwargs)
        time.sleep(0.01)  # a later clock tick
        with h5py.File(path, "r+") as f:
            f.attrs["seed"] = np.int64(99)
        return out

    monkeypatch.setattr(arc, "_write_checked", raced)
    append_to_archive(_labelled(2), d)
    monkeypatch.undo()
    time.sleep(0.01)
    got = _assert_same_as_oracle(d)
    assert got.seed.values.tolist() == [0, 1, 99]


@pytest.mark.parametrize("value", ["b", 2.5, np.array([1, 2])])
def test_an_order_attribute_that_is_no_integer_is_refused_by_name(tmp_path, value):
    """Another tool's order attribute ``2.5`` (or text, or a list) is refused at open and
    by archive_files, naming the file and the attribute, instead of a bare int() error or
    a silent 2."""
    _archive(tmp_path, 3)
    victim = sorted(_files(tmp_path))[1]
    with h5py.File(victim, "r+") as f:
        f.attrs[arc.ORDER_ATTR] = value
    for call in (open_archive, arc.archive_files):
        with pytest.raises(ValueError, match=rf"{victim.name}.*{arc.ORDER_ATTR}=.*not an "
                                             "integer archive order.*Remove the attribute"):
            call(tmp_path)


def test_an_integral_float_order_is_that_integer(tmp_path):
    """An order written as a float that is an integer (3.0, as some tools write numbers)
    sorts as that integer."""
    _archive(tmp_path, 3)
    first = min(_files(tmp_path), key=lambda p: dirx.order_index(p, tmp_path))
    with h5py.File(first, "r+") as f:
        f.attrs[arc.ORDER_ATTR] = 7.0  # after the others (1, 2)
    assert dirx.order_index(first, tmp_path) == 7
    assert arc.archive_files(tmp_path)[-1] == first


@pytest.mark.parametrize("column", ["order", "size"])
def test_a_base_whose_integer_column_is_not_integers_is_ignored_and_rebuilt(tmp_path, column):
    """A base index whose ``order`` (or stamp) column another tool rewrote as text is
    ignored with the usual warning at open (the headers are read), and an append treats
    the directory as unindexed (no TypeError from inside the writer); the archive still
    opens with every experiment in order."""
    _archive(tmp_path, 3)
    index_archive(tmp_path)
    with h5py.File(tmp_path / INDEX, "r+") as f:
        n = f[column].shape[0]
        attrs = dict(f[column].attrs)
        dims = f[column].dims[0][0] if len(f[column].dims[0]) else None
        del f[column]
        f.create_dataset(column, data=np.array([b"x"] * n))
        for k, v in attrs.items():
            if k not in ("DIMENSION_LIST", "REFERENCE_LIST"):
                f[column].attrs[k] = v
        if dims is not None:
            f[column].dims[0].attach_scale(dims)
    with pytest.warns(RuntimeWarning, match=rf"ignored.*column '{column}' holds"):
        assert dirindex.read_index(tmp_path) is None  # no journal after index_archive
    append_to_archive(_labelled(3), tmp_path)
    got = open_archive(tmp_path)
    assert got.seed.values.tolist() == [0, 1, 2, 3]


# ------------------------------------------------------------------ data safety (session 11)
@pytest.mark.parametrize("labelled", [False, True])
def test_two_appends_at_once_get_different_orders_and_lose_nothing(tmp_path, monkeypatch, labelled):
    """Two appenders that read the index at the same time took the same next order (each
    the largest order + 1): unlabelled, both got the same label and file name, and the
    second rename replaced the first experiment; labelled, both files got one order.  The
    second appender here computes its order while the first holds its own (the first
    waits until the second reaches the order, or the lock that keeps it out)."""
    import threading

    d = tmp_path / "d"
    save_archive([_labelled(i).assign_coords(experiment=i if not labelled else f"run{i}")
                  for i in range(2)], d, layout="files")
    news = [_labelled(i) for i in (2, 3)]
    news = news if labelled else [ds.drop_vars("experiment") for ds in news]
    arrived, errors = threading.Event(), []

    def second():
        try:
            append_to_archive(news[1], d)
        except BaseException as err:  # noqa: BLE001 - reported below
            errors.append(err)
            arrived.set()

    other = threading.Thread(target=second)
    real_order, real_lock = arc._next_order, getattr(dirindex, "write_lock", None)

    def next_order(*args):
        value = real_order(*args)
        if threading.current_thread() is other:
            arrived.set()
        elif not other.is_alive() and not arrived.is_set():
            other.start()  # the first appender has its order: the second runs now
            assert arrived.wait(120)
        return value

    def write_lock(*args, **kwargs):
        if threading.current_thread() is other:
            arrived.set()  # about to wait for the first appender's lock
        return real_lock(*args, **kwargs)

    monkeypatch.setattr(arc, "_next_order", next_order)
    monkeypatch.setattr(dirindex, "write_lock", write_lock, raising=False)
    try:
        append_to_archive(news[0], d)
    except ValueError as err:
        errors.append(err)
    other.join(120)
    monkeypatch.undo()
    assert errors == []
    files = arc.archive_files(d)
    orders = [dirx.order_index(p, d) for p in files]
    assert orders == [0, 1, 2, 3], [p.name for p in files]
    got = _assert_same_as_oracle(d)
    assert got.seed.values.tolist() == [0, 1, 2, 3]
    assert got.experiment.values.tolist() == ([f"run{i}" for i in range(4)] if labelled else [0, 1, 2, 3])


def test_without_locks_an_append_never_replaces_the_file_another_wrote_meanwhile(
        tmp_path, monkeypatch):
    """Where the write lock is not available (some network file systems) two unlabelled
    appends at once take one label and file name.  The later rename used to replace the
    other's experiment without a word; now the file is put in place by a hard link, which
    fails on an existing name: the late append raises and the other's data stay."""
    import contextlib
    import threading

    d = tmp_path / "d"
    save_archive([_labelled(i).assign_coords(experiment=i) for i in range(2)], d, layout="files")
    mine, theirs = (_labelled(i).drop_vars("experiment") for i in (2, 3))
    monkeypatch.setattr(dirindex, "write_lock", lambda *a, **k: contextlib.nullcontext())
    real_write, done = arc._write_checked, []

    def write_checked(*args, **kwargs):
        if not done:  # this append checked that its name is free; the other runs to its end
            done.append(True)
            other = threading.Thread(target=append_to_archive, args=(theirs, d))
            other.start()
            other.join(120)
        return real_write(*args, **kwargs)

    monkeypatch.setattr(arc, "_write_checked", write_checked)
    with pytest.raises(FileExistsError, match=r"the file exists \(another process wrote it"):
        append_to_archive(mine, d)
    monkeypatch.undo()
    files = arc.archive_files(d)
    assert len(files) == 3 and not [p for p in d.iterdir() if p.name.endswith(".tmp")]
    got = open_archive(d)
    assert got.seed.values.tolist() == [0, 1, 3]  # the other's experiment, not replaced


def _newer_base(d, order=True):
    """The base as a newer library might write it: another version, a column this one does
    not know (and, with ``order=False``, without the order column)."""
    with h5py.File(d / INDEX, "r+") as f:
        f.attrs[dirindex.INDEX_ATTR] = np.int64(dirindex.VERSION + 1)
        f.create_dataset("future", data=np.arange(f["name"].shape[0]))
        if not order:
            del f["order"]
    return (d / INDEX).read_bytes()


@pytest.mark.parametrize("order", [True, False])
def test_a_base_of_a_newer_version_is_never_rewritten_by_this_one(tmp_path, monkeypatch, order):
    """A base of a newer index version was taken for no index: the next write rebuilt it
    as this version (every header read; what the newer version kept lost) and every later
    write compacted again.  Now it is left as it is, with a warning naming the version and
    the remedy; orders continue after the newer base's, and index_archive refuses."""
    d = tmp_path / "d"
    _archive(d, 3)
    before = _newer_base(d, order)
    newer = dirindex.VERSION + 1
    for i in (3, 4):
        with pytest.warns(RuntimeWarning, match=rf"archive index .*{INDEX} is of version {newer}, "
                                               r"written by a newer lcmr_xr.*left as it is.*[Uu]pgrade"):
            append_to_archive(_labelled(i), d)
        assert (d / INDEX).read_bytes() == before
    with pytest.warns(RuntimeWarning, match=rf"ignored \(version {newer}, written by a newer"):
        files = arc.archive_files(d)
    assert [dirx.order_index(p, d) for p in files] == [0, 1, 2, 3, 4]
    with pytest.raises(ValueError, match=rf"{INDEX} is of version {newer}, written by a newer "
                                         r"lcmr_xr.*[Uu]pgrade.*or delete"):
        index_archive(d)
    assert (d / INDEX).read_bytes() == before
    with pytest.warns(RuntimeWarning, match=rf"ignored \(version {newer}, written by a newer lcmr_xr"):
        got = _assert_same_as_oracle(d)
    assert got.experiment.values.tolist() == [f"run{i}" for i in range(5)]
    (d / INDEX).unlink()  # the remedy: this version rebuilds it
    index_archive(d)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert sorted(dirindex.read_index(d)) == [f"run{i}.nc" for i in range(5)]


def test_a_compaction_removes_only_the_journal_files_it_folded_in(tmp_path):
    """A compaction removed every journal file it listed, also those it could not read: a
    newer version's entries were lost, and a damaged file's bytes with them.  Now a
    newer version's file stays as it is and a damaged one is set aside (renamed, never
    read again), named in a warning."""
    d = tmp_path / "d"
    _archive(d, 2)
    append_to_archive(_labelled(2), d)
    journal = d / JOURNAL
    ours = dirindex.journal_files(d)
    data = json.loads((journal / ours[0]).read_text())
    newer = {**data, dirindex.INDEX_ATTR: dirindex.VERSION + 1}
    (journal / "000000000002-1-newer.json").write_text(json.dumps(newer))
    newer_format = {**data, dirindex.JOURNAL_KEY: dirindex.JOURNAL_VERSION + 1}
    (journal / "000000000002-2-format.json").write_text(json.dumps(newer_format))
    damaged = b'{"lcmr_archive_index_journal": 1, "rows": [["run2.nc"'
    (journal / "000000000002-3-damaged.json").write_bytes(damaged)
    with pytest.warns(RuntimeWarning, match=r"000000000002-3-damaged\.json .*unreadable.*set aside as "
                                           r".*000000000002-3-damaged\.json\.unreadable"):
        index_archive(d)
    assert dirindex.journal_files(d) == ["000000000002-1-newer.json", "000000000002-2-format.json"]
    assert json.loads((journal / "000000000002-1-newer.json").read_text()) == newer
    assert json.loads((journal / "000000000002-2-format.json").read_text()) == newer_format
    assert (journal / "000000000002-3-damaged.json.unreadable").read_bytes() == damaged
    assert sorted(dirindex.read_index(d, warn=False)) == ["run0.nc", "run1.nc", "run2.nc"]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        _assert_same_as_oracle(d)
    ignored = {re.search(r"journal/(\S+) ignored", str(w.message)).group(1) for w in caught}
    assert ignored == {"000000000002-1-newer.json", "000000000002-2-format.json"}


class _CoarseClock:
    """A file system whose times tick only when told: every ``os.stat`` / ``os.fstat``
    time is floored to the last tick (a real time: what ``os.utime`` writes back stays in
    its tick), a tick being where :meth:`tick` touched a file.  The index's waits for
    the next tick (``time.sleep`` in ``dirindex``) tick it.  Models the file systems
    whose times advance in ticks (4 ms on older Linux kernels, 1-2 s on FAT, some
    network file systems), deterministically."""

    def __init__(self, monkeypatch, scratch):
        self.real_stat, self.real_fstat, self.scratch = os.stat, os.fstat, scratch
        self.ticks = [0]
        scratch.touch()
        self.tick()
        monkeypatch.setattr(os, "stat", lambda *a, **k: self._floored(self.real_stat(*a, **k)))
        monkeypatch.setattr(os, "fstat", lambda *a, **k: self._floored(self.real_fstat(*a, **k)))

        class _Time:
            monotonic = staticmethod(time.monotonic)

            @staticmethod
            def sleep(seconds):
                self.tick()

        monkeypatch.setattr(dirindex, "time", _Time)

    def tick(self):
        os.utime(self.scratch)
        self.ticks.append(self.real_stat(self.scratch).st_mtime_ns)

    def _floor(self, ns):
        return max(t for t in self.ticks if t <= ns)

    def _floored(self, st):
        m, c = self._floor(st.st_mtime_ns), self._floor(st.st_ctime_ns)
        return os.stat_result(list(st)[:8] + [m // 10**9, c // 10**9], {
            "st_atime": st.st_atime, "st_mtime": m / 1e9, "st_ctime": c / 1e9,
            "st_atime_ns": st.st_atime_ns, "st_mtime_ns": m, "st_ctime_ns": c,
            "st_blksize": st.st_blksize, "st_blocks": st.st_blocks, "st_rdev": st.st_rdev})


def _edit_seed(path, seed):
    """Another tool's edit of a file's header in place (same size once the attribute has
    been rewritten once: ``modify`` keeps its storage)."""
    with h5py.File(path, "r+") as f:
        f.attrs.modify("seed", np.int64(seed))


def test_an_entry_read_in_the_tick_of_its_files_change_is_trusted_only_if_checked_after_it(
        tmp_path, monkeypatch):
    """The "racy" rule trusts an entry when its file's times are older than the index
    file's.  The writers waited for the next tick and then stamped the index file with
    it: a file changed again in place, in the same tick, after its header was read (same
    size, times and inode) kept the old summary, trusted.  Now a header read in the tick
    of its file's change is read again once that tick is over (and kept only if the
    file's stamp did not change)."""
    d = tmp_path / "d"
    _archive(d, 2)
    victim = d / "run1.nc"
    _edit_seed(victim, 50)  # the first edit grows the file; later ones keep its size
    clock = _CoarseClock(monkeypatch, tmp_path / "clock")
    _edit_seed(victim, 51)  # in this tick: the compaction below reads it in the same tick
    size = victim.stat().st_size
    real = dirx.read_header

    def read_header(path, directory):
        header = real(path, directory)
        if path == victim and header["attrs"]["seed"] == 51:
            _edit_seed(victim, 99)  # the same tick: the same stamp
            assert victim.stat().st_size == size
        return header

    monkeypatch.setattr(dirx, "read_header", read_header)
    index_archive(d)
    monkeypatch.setattr(dirx, "read_header", real)
    clock.tick()
    assert open_archive(d).seed.values.tolist() == [0, 99]
    _assert_same_as_oracle(d)


def test_an_appended_file_changed_in_the_tick_of_its_write_gets_no_trusted_entry(tmp_path, monkeypatch):
    """The same for an append: its file was renamed into place in the tick of its write,
    so another tool's edit right after it (same size) left its stamp unchanged and the
    entry (of the file as written) was trusted.  Now the append waits for the tick of its
    file's write to end before the rename: any later change is seen in its stamp."""
    d = tmp_path / "d"
    _archive(d, 2)
    _CoarseClock(monkeypatch, tmp_path / "clock")
    real = arc._write_checked

    def edited(ds, path, ref, label, **kwargs):
        out = real(ds, path, ref, label, **kwargs)
        size = path.stat().st_size
        _edit_seed(path, 99)
        assert path.stat().st_size == size
        return out

    monkeypatch.setattr(arc, "_write_checked", edited)
    append_to_archive(_labelled(2), d)
    monkeypatch.setattr(arc, "_write_checked", real)
    assert open_archive(d).seed.values.tolist() == [0, 1, 99]
    _assert_same_as_oracle(d)


def test_where_no_lock_can_be_taken_the_errors_of_a_write_are_not_chained_to_that(
        tmp_path, monkeypatch):
    """Where a directory cannot be opened to lock it (Windows; no permission), the write and
    compaction locks proceed without one, but they did so inside the ``except OSError``
    handler: every error of the write raised under them (a taken label, a file that is no
    NetCDF) was reported "during handling of" that PermissionError, as if it were its
    cause.  Now such errors carry no trace of the lock that could not be taken."""
    d = tmp_path / "d"
    _archive(d, 2)
    real_open = os.open

    def no_directories(path, *args, **kwargs):
        if os.path.isdir(path):
            raise PermissionError(13, "Permission denied", os.fspath(path))
        return real_open(path, *args, **kwargs)

    monkeypatch.setattr(dirindex.os, "open", no_directories)
    with pytest.raises(ValueError, match="is already in") as taken:
        append_to_archive(_labelled(1), d)  # under the write lock (none taken)
    (d / "zz_not_netcdf.nc").write_bytes(b"not a NetCDF file")
    with pytest.raises(ValueError, match="zz_not_netcdf") as foreign:
        index_archive(d)  # under the compaction lock (none taken)
    for err in (taken.value, foreign.value):
        chain, seen = [], err
        while seen is not None:
            chain.append(seen)
            seen = seen.__cause__ or seen.__context__
        assert not any(isinstance(e, PermissionError) for e in chain), chain
    monkeypatch.undo()
    append_to_archive(_labelled(2), d)  # and the write itself goes on without the lock
    (d / "zz_not_netcdf.nc").unlink()
    assert open_archive(d).seed.values.tolist() == [0, 1, 2]


def test_a_write_of_many_files_waits_for_a_coarse_clock_once_not_per_file(tmp_path, monkeypatch):
    """Each file written waits (at most TICK_WAIT) for the file system's clock to pass the
    tick of its write, so that its entry can be trusted.  Where the clock does not pass
    in time (file times of 1-2 s: ext3, HFS+, FAT) every file waited the whole TICK_WAIT:
    a bulk write of N files took N x 50 ms more (modelled 60 files: 1.3 s -> 4.4 s) for
    entries that end up "racy" anyway.  Now, once one file's wait fails, the write's
    later files do not wait (their entries are written racy: not trusted)."""
    d = tmp_path / "d"
    _archive(d, 2)  # indexed (a fine clock)
    monkeypatch.setattr(dirindex, "TICK_WAIT", 0.005)
    monkeypatch.setattr(dirindex, "fs_clock", lambda directory: 0)  # never passes in time
    waits = _calls(monkeypatch, dirindex, "wait_past")
    save_archive([_labelled(i) for i in range(2, 7)], d, layout="files")  # no compaction due
    assert len(waits) == 1
    monkeypatch.undo()
    headers = _calls(monkeypatch, dirx, "read_header")
    _assert_same_as_oracle(d)  # right: the new files from their headers (no entry trusted)
    assert sorted(p.name for p in headers) == [f"run{i}.nc" for i in range(2, 7)]


def test_an_index_not_written_warns_and_the_next_write_reads_the_order_from_the_file(
        tmp_path, monkeypatch):
    """Where the journal cannot be written, the append itself is complete; the next writer
    did not see its order (an unlabelled append was refused as 'already in').  Now it reads
    the orders of the files the index does not list (the directory changed after the
    journal did), and the warning names index_archive, which restores the index."""
    d = tmp_path / "d"
    save_archive([_labelled(i).assign_coords(experiment=i) for i in range(2)], d, layout="files")

    def fail(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(dirindex, "append_journal", fail)
    with pytest.warns(RuntimeWarning, match=r"not written .*Permission denied.*reads their archive "
                                            r"order from them.*index_archive\(directory\)"):
        append_to_archive(_labelled(2).drop_vars("experiment"), d)
    monkeypatch.undo()
    append_to_archive(_labelled(3).drop_vars("experiment"), d)
    got = open_archive(d)
    assert got.experiment.values.tolist() == [0, 1, 2, 3] and got.seed.values.tolist() == [0, 1, 2, 3]
    assert [dirx.order_index(p, d) for p in arc.archive_files(d)] == [0, 1, 2, 3]


class _Killed(BaseException):
    """The process dies here (nothing after runs)."""


def _die(*args, **kwargs):
    raise _Killed


@pytest.mark.parametrize("labelled", [True, False])
def test_after_a_crash_between_a_file_and_its_journal_file_the_next_append_skips_its_order(
        tmp_path, monkeypatch, labelled):
    """A writer that died after moving its file into place and before writing its journal
    file left a file whose order the index does not know: the next append took it again
    (labelled: two files of one order, ordered by name; unlabelled: refused as 'already
    in', the label being the position).  Now the order allocation reads the orders of the
    files the index does not list (only when the directory changed after the journal)."""
    d = tmp_path / "d"
    label = (lambda i: f"run{9 - i}") if labelled else (lambda i: i)  # names against the order
    save_archive([_labelled(i).assign_coords(experiment=label(i)) for i in range(2)], d, layout="files")
    new = [_labelled(i) if not labelled else _labelled(i).assign_coords(experiment=label(i))
           for i in (2, 3, 4)]
    new = new if labelled else [ds.drop_vars("experiment") for ds in new]
    monkeypatch.setattr(dirindex, "append_journal", _die)
    with pytest.raises(_Killed):
        append_to_archive(new[0], d)
    monkeypatch.undo()
    scans = _calls(monkeypatch, dirindex, "read_index")
    append_to_archive(new[1], d)
    listed = len(scans)
    assert listed >= 1  # the directory changed after the journal: its files are listed
    append_to_archive(new[2], d)
    assert len(scans) == listed  # after a complete append: two stat calls, no listing
    files = arc.archive_files(d)
    assert [p.stem for p in files] == [str(label(i)) for i in range(5)]
    assert [dirx.order_index(p, d) for p in files] == [0, 1, 2, 3, 4]
    monkeypatch.undo()
    got = _assert_same_as_oracle(d)
    assert got.seed.values.tolist() == [0, 1, 2, 3, 4]


@pytest.mark.parametrize("how", ["disk full", "killed"])
@pytest.mark.parametrize("labelled", [True, False])
def test_a_journal_write_failing_inside_its_atomic_write_does_not_hide_the_order(
        tmp_path, monkeypatch, labelled, how):
    """A journal write that failed after atomic_write created its temporary in the journal
    directory (ENOSPC, EIO while writing the JSON; a writer killed then) changed the journal
    directory's time, which the order allocation compared with the archive directory's: the
    next append skipped the files the index does not list and took their order again
    (labelled: two files of order 2; unlabelled: refused as 'already in').  Now the newest
    journal FILE's time counts, and the warning ('the next write reads their archive order
    from them') holds."""
    import errno

    d = tmp_path / "d"
    label = (lambda i: f"run{i}") if labelled else (lambda i: i)
    save_archive([_labelled(i).assign_coords(experiment=label(i)) for i in range(2)], d, layout="files")
    append_to_archive(_labelled(2).assign_coords(experiment=label(2)), d)  # one journal file
    new = [_labelled(i).assign_coords(experiment=label(i)) for i in (3, 4, 5)]
    new = new if labelled else [ds.drop_vars("experiment") for ds in new]
    time.sleep(0.02)
    temporaries = []

    def dump(obj, fh, **kwargs):  # inside atomic_write: its temporary exists
        temporaries.append(fh.name)
        assert os.path.exists(fh.name) and os.path.dirname(fh.name) == str(d / JOURNAL)
        time.sleep(0.05)  # the write takes a moment, then fails
        if how == "killed":
            raise _Killed
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(dirindex.json, "dump", dump)
    if how == "killed":
        with pytest.raises(_Killed):
            append_to_archive(new[0], d)
    else:
        with pytest.warns(RuntimeWarning, match=r"not written .*No space left.*reads their "
                                                r"archive order from them"):
            append_to_archive(new[0], d)
    monkeypatch.undo()
    assert len(temporaries) == 1
    assert (d / JOURNAL).stat().st_mtime_ns > d.stat().st_mtime_ns  # what misled the check
    scans = _calls(monkeypatch, dirindex, "read_index")
    append_to_archive(new[1], d)
    listed = len(scans)
    assert listed >= 1  # the directory changed after the newest journal file: listed
    append_to_archive(new[2], d)
    assert len(scans) == listed  # after a complete append: two stat calls, no listing
    files = arc.archive_files(d)
    assert [p.stem for p in files] == [str(label(i)) for i in range(6)]
    assert [dirx.order_index(p, d) for p in files] == list(range(6))
    monkeypatch.undo()
    got = _assert_same_as_oracle(d)
    assert got.seed.values.tolist() == list(range(6))


def test_journal_files_a_compaction_keeps_do_not_make_every_append_compact(tmp_path, monkeypatch):
    """A compaction leaves the journal files of a newer version; they counted towards the
    next one, so with more than JOURNAL_FILES of them every append compacted (a rewrite of
    the base per append).  Now the base names them (KEPT_ATTR) and they do not count.  A
    damaged file set aside (NAME.json.unreadable) is no journal file and never counted."""
    d = tmp_path / "d"
    _archive(d, 2)
    monkeypatch.setattr(dirindex, "JOURNAL_FILES", 3)
    append_to_archive(_labelled(2), d)
    journal = d / JOURNAL
    data = json.loads((journal / dirindex.journal_files(d)[0]).read_text())
    newer = {**data, dirindex.INDEX_ATTR: dirindex.VERSION + 1}
    for k in range(5):
        (journal / f"000000000002-{k}-newer.json").write_text(json.dumps(newer))
    (journal / "000000000002-9-damaged.json").write_bytes(b'{"lcmr_archive_index_journal": 1, "ro')
    with pytest.warns(RuntimeWarning):
        index_archive(d)
    assert len(dirindex.journal_files(d)) == 5
    assert (journal / "000000000002-9-damaged.json.unreadable").exists()
    writes = _calls(monkeypatch, dirindex, "write_index")
    for i in (3, 4, 5):
        append_to_archive(_labelled(i), d)
    assert writes == []  # three journal files of this version: not past JOURNAL_FILES
    append_to_archive(_labelled(6), d)  # the fourth: compacted, the newer ones kept
    assert len(writes) == 1 and len(dirindex.journal_files(d)) == 5
    append_to_archive(_labelled(7), d)
    assert len(writes) == 1
    monkeypatch.undo()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the newer journal files are named in warnings
        assert _assert_same_as_oracle(d).seed.values.tolist() == list(range(8))


def test_the_write_lock_is_reentrant_within_a_thread(tmp_path):
    """A tool holding the write lock that called save_archive (which takes it too) waited
    for itself forever: flock on a second descriptor of the same process conflicts.  Now
    a thread that holds it takes it again (any spelling of the directory); other threads
    still wait for it."""
    import threading

    d = tmp_path / "d"
    _archive(d, 2)
    done, entered, errors = threading.Event(), threading.Event(), []

    def tool():
        try:
            with dirindex.write_lock(d):
                save_archive(_labelled(2), d, layout="files")
                with dirindex.write_lock(tmp_path / "." / "d"):
                    append_to_archive(_labelled(3), d)
                other = threading.Thread(target=lambda: _enter(d, entered))
                other.start()
                assert not entered.wait(0.5)  # another thread waits for the lock
            other.join(60)
            assert entered.is_set()
        except BaseException as err:  # noqa: BLE001 - reported below
            errors.append(err)
        done.set()

    threading.Thread(target=tool, daemon=True).start()
    assert done.wait(120), "the writer waited for its own lock"
    assert errors == []
    assert _assert_same_as_oracle(d).seed.values.tolist() == [0, 1, 2, 3]


def _enter(d, entered):
    with dirindex.write_lock(d):
        entered.set()


def _forked(job, n):
    """The pids of ``n`` children forked now (os.fork), each running ``job(i)`` (exit code 0
    if it returned; :func:`_reap`)."""
    pids = []
    for i in range(n):
        pid = os.fork()
        if pid == 0:  # the child: never back into pytest
            code = 1
            try:
                job(i)
                code = 0
            except BaseException:  # noqa: BLE001 - the exit code reports it
                import traceback

                traceback.print_exc()
            finally:
                os._exit(code)
        pids.append(pid)
    return pids


def _reap(pids, timeout=120):
    """The exit codes of the children ``pids`` (killed after ``timeout`` s: -9)."""
    deadline, codes = time.monotonic() + timeout, {}
    while len(codes) < len(pids):
        for pid in pids:
            if pid not in codes:
                got, status = os.waitpid(pid, os.WNOHANG)
                if got:
                    codes[pid] = os.waitstatus_to_exitcode(status)
        if time.monotonic() > deadline:
            for pid in pids:
                if pid not in codes:
                    os.kill(pid, 9)
                    os.waitpid(pid, 0)
                    codes[pid] = -9
        time.sleep(0.01)
    return [codes[p] for p in pids]


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_processes_forked_while_the_write_lock_is_held_wait_for_it(tmp_path):
    """A process forked while it held the write lock (a tool running save_archive in a
    fork-based pool inside ``write_lock``) passed the held-state to its children, which
    then took the re-entrant path without flock: they held the lock at once, before the
    parent released it, and two unlabelled appends took one order (FileExistsError; two
    labelled ones: two files of one order).  Now each child waits for the parent and for
    the other child; the parent's release is not kept back by the children's copies."""
    d = tmp_path / "d"
    _archive(d, 2)
    log = tmp_path / "log"

    def hold(i):
        with dirindex.write_lock(d):
            start = time.time()
            time.sleep(0.3)
            end = time.time()
        with open(log, "a") as fh:
            fh.write(f"{start!r} {end!r}\n")

    with dirindex.write_lock(d):
        pids = _forked(hold, 2)
        time.sleep(0.3)
        released = time.time()
    assert _reap(pids) == [0, 0]
    spans = sorted(tuple(map(float, line.split())) for line in log.read_text().splitlines())
    assert len(spans) == 2
    assert spans[0][0] >= released  # waited for the parent
    assert spans[1][0] >= spans[0][1]  # and for the other child
    # the appends of two children forked inside the lock: one order each
    with dirindex.write_lock(d):
        pids = _forked(lambda i: append_to_archive(_labelled(10 + i).drop_vars("experiment"), d), 2)
        time.sleep(0.1)
    assert _reap(pids) == [0, 0]
    with dirindex.write_lock(d):
        pids = _forked(lambda i: append_to_archive(_labelled(20 + i).assign_coords(
            experiment=f"new{i}"), d), 2)
        time.sleep(0.1)
    assert _reap(pids) == [0, 0]
    orders = sorted(dirx.order_index(p, d) for p in _files(d))
    assert orders == list(range(6))
    got = _assert_same_as_oracle(d)
    assert sorted(got.seed.values.tolist()) == [0, 1, 10, 11, 20, 21]


@pytest.mark.skipif(not hasattr(os, "fork"), reason="needs os.fork")
def test_a_fork_between_opening_and_registering_the_lock_descriptor(tmp_path, monkeypatch):
    """Another thread forking between ``os.open`` of the lock descriptor and its
    registration left the child an unregistered copy, which the child's fork handler did
    not close: the child kept the parent's ``flock`` alive after the parent released it
    (writers then waited for a process that never wrote).  The fork now waits for the
    registration; the child closes its copy, and the lock is free once the parent
    releases it while the child still runs."""
    import fcntl
    import threading as th

    d = tmp_path / "d"
    _archive(d, 1)
    real_open = os.open
    opened, forked = th.Event(), th.Event()

    def slow_open(path, flags, *args, **kwargs):
        fd = real_open(path, flags, *args, **kwargs)
        if os.fspath(path) == os.fspath(d):  # the write lock's descriptor: hold the window open
            opened.set()
            forked.wait(1.0)
        return fd

    monkeypatch.setattr(dirindex.os, "open", slow_open)
    child = {}
    go, ready = tmp_path / "go", tmp_path / "ready"

    def fork_in_the_window():
        opened.wait(10)
        pid = os.fork()
        if pid == 0:  # keep running (holding whatever it inherited) until told to stop
            ready.touch()  # the fork handlers have run
            deadline = time.monotonic() + 30
            while not go.exists() and time.monotonic() < deadline:
                time.sleep(0.01)
            os._exit(0)
        child["pid"] = pid
        forked.set()

    thread = th.Thread(target=fork_in_the_window)
    thread.start()
    try:
        with dirindex.write_lock(d):
            pass
        thread.join()
        monkeypatch.undo()
        deadline = time.monotonic() + 30
        while not ready.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        probe = os.open(d, os.O_RDONLY)
        try:  # the parent released it: free, though the child still runs
            fcntl.flock(probe, fcntl.LOCK_EX | fcntl.LOCK_NB)
        finally:
            os.close(probe)
    finally:
        go.touch()
        thread.join()
        if "pid" in child:
            assert _reap([child["pid"]], timeout=60) == [0]
