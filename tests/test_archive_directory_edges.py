"""Directory archives: inputs the header pass must read as a lazy xarray open of every file
does (the oracle of tests/test_archive_directory.py): 0-d data variables (not metadata
coordinates) and the dask spellings of one chunk along ``experiment``."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lcmr_xr.scaleout import open_archive, save_archive
from test_archive_directory import _assert_same_as_oracle, _labelled, _oracle_open


def test_scalar_data_variables_stay_data_variables(tmp_path):
    # a 0-d data variable is no scalar coordinate (no metadata): xarray keeps it a data
    # variable of every file, so the archive has it along experiment, like r, u, y
    items = [_labelled(i).assign(gain=xr.DataArray(1.5 + i, attrs={"units": "1"}))
             for i in range(3)]
    save_archive(items, tmp_path, layout="files")
    got = _assert_same_as_oracle(tmp_path)
    assert "gain" in got.data_vars and "gain" not in got.coords
    assert got.gain.values.tolist() == [1.5, 2.5, 3.5]
    assert got.seed.values.tolist() == [0, 1, 2]  # the metadata coordinate is still one


def test_string_data_variables_read_whole(tmp_path):
    # strings (0-d and along time) of other lengths in other files: read as str objects,
    # none cut to the first file's width; the values those of the oracle
    notes = ["Kanal ä", "Kanal ä, längerer Text", "k"]
    items = [_labelled(i).assign(note=xr.DataArray(notes[i]),
                                 tag=("time", np.array([f"t{j * 10 ** i}" for j in range(480)])))
             for i in range(3)]
    save_archive(items, tmp_path, layout="files")
    want, parts = _oracle_open(tmp_path)
    got = open_archive(tmp_path).compute()
    assert got.note.values.tolist() == notes == want.note.values.tolist()
    assert got.tag.values.tolist() == want.tag.values.tolist()
    assert got.tag.values[2, 479] == "t47900"
    xr.testing.assert_identical(got.drop_vars(["note", "tag"]),
                                want.drop_vars(["note", "tag"]).compute())
    for part in parts:
        part.close()


@pytest.mark.parametrize("whole", [-1, None, "auto"])
def test_one_chunk_spellings_of_dask(tmp_path, whole):
    save_archive([_labelled(i) for i in range(5)], tmp_path, layout="files")
    got = open_archive(tmp_path, chunks={"experiment": whole})
    want = (5,) if whole in (-1, None) else got.r.chunks[0]
    assert got.r.chunks[0] == want and sum(got.r.chunks[0]) == 5
    np.testing.assert_array_equal(got.y.values[4], _labelled(4).y.values)


def test_chunks_along_experiment_refused_with_the_remedy(tmp_path):
    save_archive([_labelled(i) for i in range(2)], tmp_path, layout="files")
    for bad in (0, -2, 2.5, "many"):
        with pytest.raises(ValueError, match=r"chunks\['experiment'\] .* positive number of "
                                             r"experiments per chunk"):
            open_archive(tmp_path, chunks={"experiment": bad})


def test_consolidating_refuses_to_drop_other_data_variables(tmp_path):
    # the consolidated form holds r, u, y only: extra data variables of the files are
    # refused by name (they were dropped without a word), and nothing is written
    from lcmr_xr.scaleout import consolidate_archive

    items = [_labelled(i).assign(gain=xr.DataArray(1.5 + i),
                                 temp=("time", np.full(_labelled(i).sizes["time"], 20.0 + i)))
             for i in range(3)]
    save_archive(items, tmp_path / "d", layout="files")
    with pytest.raises(ValueError, match=r"data variables \['gain', 'temp'\] besides r, u, y.*"
                                         r"drop_vars"):
        consolidate_archive(tmp_path / "d", tmp_path / "c.nc")
    assert not (tmp_path / "c.nc").exists()
    save_archive([ds.drop_vars(["gain", "temp"]) for ds in items], tmp_path / "d", overwrite=True,
                 layout="files")
    consolidate_archive(tmp_path / "d", tmp_path / "c.nc")
    xr.testing.assert_identical(open_archive(tmp_path / "c.nc").compute(),
                                open_archive(tmp_path / "d").compute())


def test_labels_of_two_kinds_are_refused_where_they_would_meet(tmp_path):
    """An integer label next to text labels used to be appended to a directory and read
    back as text (``7`` became ``"7"``, the int lost without a word); now the append, the
    save of a mixed list and the consolidated append refuse it, naming both kinds."""
    from lcmr_xr.scaleout import append_to_archive

    save_archive([_labelled(0)], tmp_path / "d", layout="files")
    with pytest.raises(ValueError, match=r"mix experiment labels of different kinds: "
                                         r"text 'run0' \(run0.nc\), integer 7 \(7.nc\)"):
        append_to_archive(_labelled(1).assign_coords(experiment=7), tmp_path / "d")
    assert sorted(p.name for p in (tmp_path / "d").glob("[!.]*.nc")) == ["run0.nc"]
    assert open_archive(tmp_path / "d").experiment.values.tolist() == ["run0"]
    mixed = [_labelled(1), _labelled(2).assign_coords(experiment=5)]
    for layout, path in (("files", tmp_path / "e"), ("consolidated", tmp_path / "c.nc")):
        with pytest.raises(ValueError, match="integer 5 .experiment 1."):
            save_archive(mixed, path, layout=layout)
        assert not path.exists()
    save_archive([_labelled(0).assign_coords(experiment=3)], tmp_path / "c.nc")
    with pytest.raises(ValueError, match="integer 3 .c.nc., text 'run1'"):
        append_to_archive(_labelled(1), tmp_path / "c.nc")
    assert open_archive(tmp_path / "c.nc").experiment.values.tolist() == [3]
    # one kind is fine, integers included
    append_to_archive(_labelled(1).assign_coords(experiment=4), tmp_path / "c.nc")
    assert open_archive(tmp_path / "c.nc").experiment.values.tolist() == [3, 4]


def test_a_directory_whose_files_mix_label_kinds_is_refused_at_open(tmp_path):
    """Files written by another tool (or renamed by hand) with integer and text labels:
    the open names them instead of turning the integers into text."""
    save_archive([_labelled(0), _labelled(1)], tmp_path / "d", layout="files")
    save_archive([_labelled(2).assign_coords(experiment=9)], tmp_path / "other", layout="files")
    (tmp_path / "other" / "9.nc").rename(tmp_path / "d" / "9.nc")
    with pytest.raises(ValueError, match=r"files of archive .* mix experiment labels of different "
                                         r"kinds: integer 9 \(9.nc\), text 'run0' \(run0.nc\)"):
        open_archive(tmp_path / "d")


def test_a_label_carried_by_two_files_is_refused_at_open(tmp_path):
    """A file copied by hand keeps its label: two experiments with one label made an
    archive whose ``sel(experiment=...)`` returned both; the open names the files."""
    import shutil

    save_archive([_labelled(0), _labelled(1)], tmp_path / "d", layout="files")
    shutil.copy(tmp_path / "d" / "run1.nc", tmp_path / "d" / "copy.nc")
    with pytest.raises(ValueError, match=r"label 'run1' is carried by 2 files \((copy.nc, run1.nc|"
                                         r"run1.nc, copy.nc)\).*Move the copies out"):
        open_archive(tmp_path / "d")
    (tmp_path / "d" / "copy.nc").unlink()
    assert open_archive(tmp_path / "d").experiment.values.tolist() == ["run0", "run1"]


def test_an_unlabelled_append_to_a_text_labelled_archive_gets_its_position_as_text(tmp_path):
    """append_to_archive labels an experiment without a label by its position in the
    archive; in an archive of text labels that position is text (``"2"``), not an
    integer that the one-kind rule then refuses; in one of integers it stays an integer."""
    from lcmr_xr.scaleout import append_to_archive

    save_archive([_labelled(0), _labelled(1)], tmp_path / "t.nc")
    append_to_archive(_labelled(2).drop_vars("experiment"), tmp_path / "t.nc")
    assert open_archive(tmp_path / "t.nc").experiment.values.tolist() == ["run0", "run1", "2"]
    save_archive([_labelled(0).assign_coords(experiment=5)], tmp_path / "i.nc")
    append_to_archive(_labelled(1).drop_vars("experiment"), tmp_path / "i.nc")
    assert open_archive(tmp_path / "i.nc").experiment.values.tolist() == [5, 1]


def test_an_unlabelled_append_to_a_directory_gets_its_order_index(tmp_path):
    """In a directory the position is the order index the file gets (from the index,
    without listing the directory); before, the label was 0 (the position in the list
    passed in), so an integer-labelled directory refused every unlabelled append as
    "experiment 0 is already in ..." and a text-labelled one got the integer 0."""
    from lcmr_xr.scaleout import append_to_archive

    save_archive([_labelled(0).assign_coords(experiment=0),
                  _labelled(1).assign_coords(experiment=1)], tmp_path / "i", layout="files")
    written = append_to_archive(_labelled(2).drop_vars("experiment"), tmp_path / "i")
    assert written.name == "2.nc"
    assert open_archive(tmp_path / "i").experiment.values.tolist() == [0, 1, 2]
    save_archive([_labelled(0), _labelled(1)], tmp_path / "t", layout="files")
    append_to_archive(_labelled(2).drop_vars("experiment"), tmp_path / "t")
    assert open_archive(tmp_path / "t").experiment.values.tolist() == ["run0", "run1", "2"]
    fresh = append_to_archive(_labelled(0).drop_vars("experiment"), tmp_path / "new.nc")
    assert open_archive(fresh).experiment.values.tolist() == [0]  # new path: consolidated
    (tmp_path / "e").mkdir()  # an empty directory: the first experiment is 0
    assert append_to_archive(_labelled(0).drop_vars("experiment"), tmp_path / "e").name == "0.nc"


@pytest.mark.parametrize("layout", ["files", "consolidated"])
def test_unlabelled_stacked_experiments_are_appended_at_their_positions(tmp_path, layout):
    """Several unlabelled experiments stacked along ``experiment`` get the positions after
    the archive's last one (they got 0, 1, ..: the positions in the stack, already taken)."""
    from lcmr_xr.scaleout import append_to_archive

    path = tmp_path / ("d" if layout == "files" else "c.nc")
    save_archive([_labelled(i).assign_coords(experiment=i) for i in range(2)], path, layout=layout)
    stack = xr.concat([_labelled(2), _labelled(3)], dim="experiment").drop_vars("experiment")
    append_to_archive(stack, path)
    assert open_archive(path).experiment.values.tolist() == [0, 1, 2, 3]


def _tree(root):
    """Every file and directory under ``root`` (hidden ones too: the index, its journal,
    temporaries): size and modification time."""
    import os

    out = {}
    for base, dirs, files in os.walk(root):
        for name in dirs + files:
            st = os.stat(os.path.join(base, name))
            out[os.path.relpath(os.path.join(base, name), root)] = (st.st_size, st.st_mtime_ns)
    return out


@pytest.mark.parametrize("name", ["run5.NC", "run5.nc4", "run5.NetCDF"])
def test_a_label_whose_file_exists_under_another_netcdf_ending_is_refused_before_writing(tmp_path, name):
    """The directory holds every NetCDF name (run5.NC, run5.nc4, run5.NetCDF); an append
    (or a save) labelled run5 checked only run5.nc, wrote it beside run5.NC, and the
    archive then no longer opened (the label carried by two files).  Now refused up
    front, naming the file and the remedy; nothing written, not even the index."""
    from lcmr_xr.io import save
    from lcmr_xr.scaleout import append_to_archive

    d = tmp_path / "d"
    save_archive([_labelled(0), _labelled(1)], d, layout="files")
    save(_labelled(5), d / name)  # as another tool (or a rename by hand) put it there
    before = _tree(d)
    for write in (lambda: append_to_archive(_labelled(5), d),
                  lambda: save_archive([_labelled(6), _labelled(5)], d, layout="files")):
        with pytest.raises(ValueError, match=rf"run5.*{name}.*another NetCDF ending.*another label"):
            write()
        assert _tree(d) == before  # no file, no temporary, no journal entry
    assert open_archive(d).experiment.values.tolist() == ["run0", "run1", "run5"]
    # another label goes in; the file names compare exactly but for the ending's case
    append_to_archive(_labelled(6), d)
    append_to_archive(_labelled(7).assign_coords(experiment="Run5"), d)
    assert open_archive(d).experiment.values.tolist() == ["run0", "run1", "run6", "Run5", "run5"]
