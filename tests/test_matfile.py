"""MATLAB files: experiments written the way MATLAB writes them, FRFs that MATLAB's frd takes."""

from __future__ import annotations

import os

import h5py
import numpy as np
import pytest
import scipy.io
import xarray as xr

import lcmr_xr
from lcmr_xr import hdd

TH = hdd.FAST_PERIOD


@pytest.fixture(scope="module")
def exp():
    return hdd.simulate(n_samples=240, noise=True, seed=3)


def _same_signals(ds, exp):
    for name in ("r", "u", "y"):
        xr.testing.assert_identical(ds[name], exp[name])
    assert ds.attrs["factor"] == exp.attrs["factor"] and isinstance(ds.attrs["factor"], int)


def test_reads_matlab_rows_columns_and_1x1_scalars(exp, tmp_path):
    path = tmp_path / "hdd.mat"
    # MATLAB users store channels as rows or as columns, a single output as a row vector,
    # and every number as a 1 x 1 double
    scipy.io.savemat(path, {
        "ref": exp.r.values.T,                    # 2 x N: one channel per row
        "u": exp.u.values,                        # N x 2
        "pos": exp.y.values[:, 0][None, :],       # 1 x M row vector
        "Ts": np.array([[TH]]), "F": np.array([[2.0]]),
    })
    raw = scipy.io.loadmat(path)
    assert raw["Ts"].shape == (1, 1) and raw["pos"].shape == (1, exp.sizes["slow_time"])
    ds = lcmr_xr.open_experiment(path, r="ref", y="pos", inputs=["vcm", "pzt"],
                                 outputs=["position"], output_units="m")
    _same_signals(ds, exp)
    # numbers may also be given directly, and a column vector works as well as a row
    scipy.io.savemat(path, {"r": exp.r.values, "u": exp.u.values.T, "y": exp.y.values})
    ds = lcmr_xr.open_experiment(path, factor=2, sampling_period=TH, inputs=["vcm", "pzt"],
                                 outputs=["position"], output_units="m")
    _same_signals(ds, exp)


def test_reads_v73_hdf5_files(exp, tmp_path):
    """MATLAB -v7.3 stores column-major matrices: h5py sees them transposed."""
    path = tmp_path / "hdd73.mat"
    with h5py.File(path, "w", userblock_size=512) as fh:
        fh["r"], fh["u"], fh["y"] = exp.r.values.T, exp.u.values.T, exp.y.values.T
        fh["Ts"], fh["F"] = np.array([[TH]]), np.array([[2.0]])
        fh["output_units"] = np.frombuffer(b"m", dtype=np.uint8).astype(np.uint16)[:, None]
        fh["output_units"].attrs["MATLAB_class"] = np.bytes_(b"char")
    with open(path, "r+b") as fh:  # MATLAB's 128-byte header in the HDF5 user block
        text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Nov 23 04:00:00 2026 HDF5 schema 1.00 ."
        fh.write(text.ljust(116) + b"\x00" * 8 + b"\x00\x02" + b"IM")
    ds = lcmr_xr.open_experiment(path, inputs=["vcm", "pzt"], outputs=["position"])
    _same_signals(ds, exp)


def test_experiment_round_trip_through_mat(exp, tmp_path):
    path = lcmr_xr.save(exp, tmp_path / "e.mat")
    raw = scipy.io.loadmat(path)
    assert raw["r"].shape == (240, 2) and raw["y"].shape == (120, 1)
    assert raw["F"].item() == 2.0 and raw["Ts"].item() == TH
    ds = lcmr_xr.open_experiment(path)  # names, units, F and Ts come from the file
    _same_signals(ds, exp)
    assert os.listdir(tmp_path) == ["e.mat"]  # no temporary file left


def test_frf_for_matlab_frd(tmp_path):
    exp = hdd.simulate(n_samples=240, noise=False, seed=0)
    frf = lcmr_xr.identify(exp, window=6, degrees=(1, 1, 1))
    path = lcmr_xr.save(frf, tmp_path / "frf.mat")
    m = scipy.io.loadmat(path)
    # frd(S.P, S.frequency, S.Ts, "FrequencyUnit", "Hz", "InputName", ..., "OutputName", ...)
    assert m["P"].shape == (1, 2, frf.sizes["frequency"])
    np.testing.assert_array_equal(m["P"], frf.P.transpose("output", "input", "frequency").values)
    np.testing.assert_array_equal(m["P_std"], frf.P_std.transpose("output", "input", "frequency").values)
    np.testing.assert_array_equal(m["frequency"][:, 0], frf.frequency.values)
    assert m["frequency"].shape == (frf.sizes["frequency"], 1)
    assert m["Ts"].item() == frf.attrs["sampling_period"]
    assert m["FrequencyUnit"].item() == "Hz" and m["P_units"].item() == "m"
    assert [c.item() for c in m["InputName"].ravel()] == ["vcm", "pzt"]
    assert [c.item() for c in m["OutputName"].ravel()] == ["position"]
    with pytest.raises(ValueError, match="is a MATLAB file.*ending in .nc"):
        lcmr_xr.open_frf(path)
    with pytest.raises(ValueError, match="sampling_period"):
        lcmr_xr.save(frf.drop_attrs(), tmp_path / "bare.mat")
    with pytest.raises(ValueError, match=r"isel\(experiment=0\)"):
        lcmr_xr.save(xr.concat([frf, frf], dim="experiment"), tmp_path / "two.mat")
    assert sorted(os.listdir(tmp_path)) == ["frf.mat"]


def _v73(path, exp):
    """A MATLAB -v7.3 file of ``exp`` at ``path`` (HDF5 with MATLAB's 128-byte header)."""
    with h5py.File(path, "w", userblock_size=512) as fh:
        fh["r"], fh["u"], fh["y"] = exp.r.values.T, exp.u.values.T, exp.y.values.T
        fh["Ts"], fh["F"] = np.array([[TH]]), np.array([[2.0]])
    with open(path, "r+b") as fh:
        text = b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Nov 23 04:00:00 2026 HDF5 schema 1.00 ."
        fh.write(text.ljust(116) + b"\x00" * 8 + b"\x00\x02" + b"IM")
    return path


def _v73_text(fh, name, text):
    fh[name] = np.frombuffer(text.encode(), dtype=np.uint8).astype(np.uint16)[:, None]
    fh[name].attrs["MATLAB_class"] = np.bytes_(b"char")
    return fh[name]


def _v73_cell(fh, name, items, prefix=""):
    """A MATLAB -v7.3 cell array: object references to datasets in #refs#."""
    refs = fh.require_group("#refs#")
    targets = []
    for k, item in enumerate(items):
        key = f"{name}{prefix}{k}"
        if isinstance(item, str):
            targets.append(_v73_text(refs, key, item).ref)
        else:
            refs[key] = np.asarray(item, dtype=float)
            refs[key].attrs["MATLAB_class"] = np.bytes_(b"double")
            targets.append(refs[key].ref)
    fh.create_dataset(name, data=np.array([targets], dtype=h5py.ref_dtype))
    fh[name].attrs["MATLAB_class"] = np.bytes_(b"cell")


def test_v73_channel_names_and_logical(exp, tmp_path):
    """A -v7.3 file's InputName/OutputName cell arrays were skipped (the channels came back
    as u0, u1 silently); its logical arrays were read as 0.0/1.0."""
    path = _v73(tmp_path / "names.mat", exp)
    with h5py.File(path, "r+") as fh:
        _v73_cell(fh, "InputName", ["vcm", "pzt"])
        _v73_cell(fh, "OutputName", ["position"])
    ds = lcmr_xr.open_experiment(path)
    assert ds.input.values.tolist() == ["vcm", "pzt"] and ds.output.values.tolist() == ["position"]
    with h5py.File(path, "r+") as fh:  # char(['vcm'; 'pz ']): a 2 x 3 char matrix, seen 3 x 2
        del fh["InputName"]
        fh["InputName"] = np.array([[ord(c) for c in "vcm"], [ord(c) for c in "pz "]], np.uint16).T
        fh["InputName"].attrs["MATLAB_class"] = np.bytes_(b"char")
    assert lcmr_xr.open_experiment(path).input.values.tolist() == ["vcm", "pz"]
    with h5py.File(path, "r+") as fh:
        del fh["InputName"]
        _v73_cell(fh, "InputName", [[[1.0]], [[2.0]]], prefix="n")  # {1, 2}
    with pytest.raises(ValueError, match=r"'InputName' \(the input names\) holds numbers.*inputs="):
        lcmr_xr.open_experiment(path)
    assert lcmr_xr.open_experiment(path, inputs=["1", "2"]).input.values.tolist() == ["1", "2"]
    with h5py.File(path, "r+") as fh:
        fh["mask"] = (exp.r.values.T > 0).astype(np.uint8)
        fh["mask"].attrs["MATLAB_class"] = np.bytes_(b"logical")
    with pytest.raises(ValueError, match=r"'mask' \(r, the fast excitation\) is a MATLAB logical.*double\(mask\)"):
        lcmr_xr.open_experiment(path, r="mask", inputs=["vcm", "pzt"])


def test_names_and_units_must_be_text(exp, tmp_path):
    """MATLAB's InputName is text (frd refuses numbers): a numeric InputName became the
    labels "1.0", "2.0"; numeric units became "1.0".  A char matrix is one name per row,
    its blank padding removed (as MATLAB's cellstr does)."""
    path = tmp_path / "x.mat"
    signals = {"r": exp.r.values, "u": exp.u.values, "y": exp.y.values, "Ts": TH, "F": 2.0}
    numbers = np.empty((2, 1), dtype=object)
    numbers[0, 0], numbers[1, 0] = 1.0, 2.0
    for bad in (np.array([[1.0, 2.0]]), numbers):
        scipy.io.savemat(path, {**signals, "InputName": bad})
        with pytest.raises(ValueError, match=r"x.mat: variable 'InputName' \(the input names\) holds "
                                             r"numbers, not text.*cellstr\(string\(InputName\)\).*inputs="):
            lcmr_xr.open_experiment(path)
    scipy.io.savemat(path, {**signals, "output_units": 1.0})
    with pytest.raises(ValueError, match=r"'output_units' \(a unit string\) holds numbers.*output_units="):
        lcmr_xr.open_experiment(path)
    scipy.io.savemat(path, {**signals, "InputName": np.array(["vcm", "pz "]), "OutputName": "position"})
    ds = lcmr_xr.open_experiment(path)
    assert ds.input.values.tolist() == ["vcm", "pz"] and ds.output.values.tolist() == ["position"]


def test_units_in_a_cell_are_read_several_refused(exp, tmp_path):
    """A unit kept as MATLAB keeps iddata's InputUnit, a cell {'V'}, was refused as 'holds no
    text (a object array) ... a number is not read as one' (it is text, no number); before
    that it became the unit "['V']".  One unit in a cell or a char matrix is that unit;
    several different ones are refused naming them (one unit for r and u), not 'no text'."""
    path = tmp_path / "x.mat"
    signals = {"r": exp.r.values, "u": exp.u.values, "y": exp.y.values, "Ts": TH, "F": 2.0}
    one = np.empty((1, 1), dtype=object)
    one[0, 0] = "V"
    two = np.empty((1, 2), dtype=object)
    two[0, 0], two[0, 1] = "V", "V"
    for units in (one, two, np.array(["V ", "V "])):
        scipy.io.savemat(path, {**signals, "input_units": units, "output_units": one})
        ds = lcmr_xr.open_experiment(path)
        assert ds.r.attrs["units"] == "V" and ds.u.attrs["units"] == "V" and ds.y.attrs["units"] == "V"
    mixed = np.empty((1, 2), dtype=object)
    mixed[0, 0], mixed[0, 1] = "V", "mA"
    for units in (mixed, np.array(["V ", "mA"])):
        scipy.io.savemat(path, {**signals, "input_units": units})
        with pytest.raises(ValueError, match=r"x.mat: variable 'input_units' holds 2 units \('V', 'mA'\); "
                                             r"it is one unit for r and u.*input_units="):
            lcmr_xr.open_experiment(path)
    numbers = np.empty((1, 1), dtype=object)
    numbers[0, 0] = 1.0
    scipy.io.savemat(path, {**signals, "input_units": numbers})
    with pytest.raises(ValueError, match=r"'input_units' \(a unit string\) holds numbers"):
        lcmr_xr.open_experiment(path)


def test_logical_signals_are_refused_integers_read(exp, tmp_path):
    """A MATLAB logical array was cast to 0.0/1.0 and identified as a signal."""
    path = tmp_path / "x.mat"
    scipy.io.savemat(path, {"r": exp.r.values > 0, "u": exp.u.values, "y": exp.y.values,
                            "Ts": TH, "F": 2.0, "counts": (exp.r.values * 1e9).astype(np.int16),
                            "flag": np.array([[True]])})
    assert dict((n, c) for n, _, c in scipy.io.whosmat(path))["r"] == "logical"
    with pytest.raises(ValueError, match=r"'r' \(r, the fast excitation\) is a MATLAB logical array.*"
                                         r"2\*double\(r\) - 1"):
        lcmr_xr.open_experiment(path)
    with pytest.raises(ValueError, match="'flag'.*one real number"):
        lcmr_xr.open_experiment(path, r="counts", factor="flag")
    ds = lcmr_xr.open_experiment(path, r="counts")  # an ADC's int16 counts: numbers
    np.testing.assert_array_equal(ds.r.values, (exp.r.values * 1e9).astype(np.int16).astype(float))


@pytest.mark.parametrize("damage", ["truncated", "header only"])
def test_damaged_v73_file_is_named(exp, tmp_path, damage):
    """A -v7.3 file that HDF5 cannot open (an incomplete copy) raised h5py's OSError
    ("Unable to synchronously open file (truncated file ...)"), naming no file and no
    remedy; now a ValueError names the file, as for a damaged v5 file."""
    path = _v73(tmp_path / "run.mat", exp)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2] if damage == "truncated" else data[:512] + b"junk" * 64)
    with pytest.raises(ValueError, match=r"cannot read .*run.mat as a MATLAB -v7.3 file.*save it again"):
        lcmr_xr.open_experiment(path)


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_open_dataset_points_to_open_experiment(exp, tmp_path, version):
    """open_dataset on a .mat file called it "not a valid NetCDF-4 file ... Re-create it
    with lcmr_xr.save" (v5), or opened a -v7.3 file (HDF5) as a NetCDF dataset of its raw
    variables; now it names the reader of .mat files."""
    path = lcmr_xr.save(exp, tmp_path / "e.mat") if version == "v5" else _v73(tmp_path / "e.mat", exp)
    for chunks in (None, {}):
        with pytest.raises(ValueError, match=r"e.mat is a MATLAB file; open_dataset reads NetCDF.*"
                                             r"lcmr_xr.open_experiment\(path\)"):
            lcmr_xr.open_dataset(path, chunks=chunks)
    _same_signals(lcmr_xr.open_experiment(path, inputs=["vcm", "pzt"], outputs=["position"],
                                          output_units="m"), exp)


def test_errors_name_the_file_once(exp, tmp_path):
    """A bad (1, 1) variable was reported as 'x.mat: x.mat: variable ...'."""
    path = tmp_path / "x.mat"
    scipy.io.savemat(path, {"r": exp.r.values, "u": exp.u.values, "y": exp.y.values,
                            "Ts": np.array([TH, TH]), "F": 2.0})
    for kwargs in ({}, {"sampling_period": "missing"}):
        with pytest.raises(ValueError) as info:
            lcmr_xr.open_experiment(path, **kwargs)
        assert str(info.value).count("x.mat") == 1, str(info.value)


def test_clear_errors(exp, tmp_path):
    path = tmp_path / "x.mat"
    scipy.io.savemat(path, {"r": exp.r.values, "u": exp.u.values, "y": exp.y.values,
                            "Ts": TH, "F": 2.5, "sq": np.ones((3, 3)), "names": ["a", "b"],
                            "s": {"a": 1.0}})
    with pytest.raises(ValueError, match=r"no variable 'yy'.*variables are: F, Ts, names, r, s, sq, u, y"):
        lcmr_xr.open_experiment(path, y="yy")
    with pytest.raises(ValueError, match="factor"):
        lcmr_xr.open_experiment(path)  # F = 2.5: not a whole number, refused by experiment()
    with pytest.raises(ValueError, match="cannot tell samples from channels"):
        lcmr_xr.open_experiment(path, r="sq", factor=2)
    with pytest.raises(ValueError, match="real numeric"):
        lcmr_xr.open_experiment(path, u="s", factor=2)
    with pytest.raises(ValueError, match="one real number"):
        lcmr_xr.open_experiment(path, factor="r")
    with pytest.raises(ValueError, match="no variable 'Tsample'"):
        lcmr_xr.open_experiment(path, factor=2, sampling_period="Tsample")
    with pytest.raises(TypeError, match="number or a variable name"):
        lcmr_xr.open_experiment(path, factor=[2])
    with pytest.raises(ValueError, match=r"x.mat: .*N = M \* F"):
        lcmr_xr.open_experiment(path, factor=3)
    with pytest.raises(ValueError, match="chunks applies to NetCDF"):
        lcmr_xr.open_experiment(path, chunks={"time": 10}, factor=2)
    with pytest.raises(TypeError, match="MATLAB .mat files only"):
        lcmr_xr.open_experiment(tmp_path / "x.nc", factor=2)
    with pytest.raises(TypeError, match="unexpected keyword"):
        lcmr_xr.open_experiment(path, bogus=1)
    garbage = tmp_path / "garbage.mat"
    garbage.write_bytes(b"not a MAT-file at all" * 20)
    with pytest.raises(ValueError, match="cannot read .*garbage.mat"):
        lcmr_xr.open_experiment(garbage, factor=2)
    with pytest.raises(FileNotFoundError, match="no such file"):
        lcmr_xr.open_experiment(tmp_path / "missing.mat")


def test_save_mat_refuses_and_leaves_nothing(exp, tmp_path, monkeypatch):
    with pytest.raises(ValueError, match="FRF dataset .* or an experiment dataset"):
        lcmr_xr.save(xr.Dataset({"a": ("x", [1.0])}), tmp_path / "a.mat")
    with pytest.raises(FileNotFoundError, match="create it first"):
        lcmr_xr.save(exp, tmp_path / "missing" / "e.mat")

    def disk_full(*args, **kwargs):
        raise OSError("disk full")

    target = lcmr_xr.save(exp, tmp_path / "e.mat")
    before = target.read_bytes()
    monkeypatch.setattr(scipy.io, "savemat", disk_full)
    with pytest.raises(OSError, match="disk full"):
        lcmr_xr.save(exp, target)
    assert target.read_bytes() == before and os.listdir(tmp_path) == ["e.mat"]
