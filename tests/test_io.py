"""NetCDF save/open: exact round trips (complex too), atomic writes, clear errors."""

from __future__ import annotations

import os

import dask
import numpy as np
import pytest
import xarray as xr

from lcmr_xr.experiment import experiment
from lcmr_xr.io import open_dataset, open_experiment, open_frf, save
from lcmr_xr.transforms import dft, lift


def _experiment(seed=0, lead=()):
    rng = np.random.default_rng(seed)
    n, f = 24, 3
    return experiment(
        rng.standard_normal(lead + (n, 2)), rng.standard_normal(lead + (n, 2)),
        rng.standard_normal(lead + (n // f, 1)), factor=f, sampling_period=1 / 100800,
        inputs=["vcm", "pzt"], outputs=["position"], input_units="A", output_units="m",
        attrs={"case": 2, "rms": (8.0e-8, 3.6e-9), "noise": True, "tags": ["a", "b"],
               "note": None, "benchmark": "hdd"},
    )


def _frf(seed=0):
    rng = np.random.default_rng(seed)
    shape = (5, 1, 2)
    p = rng.standard_normal(shape) + 1j * rng.standard_normal(shape)
    return xr.Dataset(
        {
            "P": (("frequency", "output", "input"), p, {"units": "m/A", "long_name": "FRF"}),
            "P_std": (("frequency", "output", "input"), np.abs(p) / 10, {"units": "m/A", "long_name": "std"}),
        },
        coords={
            "frequency": ("frequency", np.arange(5) * 10.0, {"units": "Hz", "long_name": "frequency"}),
            "output": ("output", ["position"], {"units": "1", "long_name": "output"}),
            "input": ("input", ["vcm", "pzt"], {"units": "1", "long_name": "input"}),
        },
        attrs={"conventions": "lcmr-xr-1", "method": "lrm", "window": 30, "degrees": (3, 3, 3),
               "factor": 3},
    )


def test_experiment_round_trip_identical(tmp_path):
    ds = _experiment(lead=(2,))
    path = save(ds, tmp_path / "exp.nc")
    back = open_experiment(path)
    xr.testing.assert_identical(back, ds)
    assert back.attrs["rms"] == (8.0e-8, 3.6e-9) and back.attrs["noise"] is True
    assert back.attrs["tags"] == ["a", "b"] and back.attrs["note"] is None
    assert isinstance(back.attrs["factor"], int)
    assert "noise" in ds.attrs and ds.attrs["noise"] is True  # the caller's dataset is untouched
    assert "lcmr_attr_types" not in ds.attrs


def test_complex_frf_round_trip_exact(tmp_path):
    frf = _frf()
    back = open_frf(save(frf, tmp_path / "frf.nc"))
    xr.testing.assert_identical(back, frf)
    np.testing.assert_array_equal(back["P"].values, frf["P"].values)  # bit for bit
    assert back.attrs["degrees"] == (3, 3, 3)


def test_every_array_is_checksummed_and_a_damaged_value_is_refused(tmp_path):
    """HDF5 checks no stored values by default: a flipped byte read back as another number.
    save stores a Fletcher-32 checksum per chunk; damage anywhere in the values is refused."""
    import h5py

    frf = _frf()
    path = save(frf, tmp_path / "frf.nc")
    with h5py.File(path, "r") as f:
        arrays = [n for n, d in f.items() if isinstance(d, h5py.Dataset) and d.ndim]
        assert arrays and all(f[n].fletcher32 for n in arrays), [n for n in arrays if not f[n].fletcher32]
        offset = f["P"].id.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[offset + 8] ^= 0x01  # one bit of P's first value
    (tmp_path / "bad.nc").write_bytes(bytes(data))
    with pytest.raises(ValueError, match="bad.nc.*corrupt"):
        open_frf(tmp_path / "bad.nc")
    # lazily, when read: h5py's words without the file; now the file, h5py's reason, the remedy
    with pytest.raises(ValueError, match=r"cannot read .*bad\.nc: its stored values are corrupt "
                                         r"\(HDF5: .*filter returned failure.*Restore it from a copy"):
        open_dataset(tmp_path / "bad.nc", chunks={})["P"].values


def test_file_without_checksums_opens_and_saves_with_them(tmp_path):
    """Files written before the checksums (contiguous layout) still open, and saving what
    was read from them drops the layout the checksum cannot use."""
    frf = _frf()
    frf.to_netcdf(tmp_path / "old.nc", engine="netcdf4", auto_complex=True,
                  encoding={"P": {"contiguous": True}})
    old = open_frf(tmp_path / "old.nc")
    assert old["P"].encoding["contiguous"] is True
    for lazy in (False, True):
        src = open_dataset(tmp_path / "old.nc", chunks={}) if lazy else old
        back = open_frf(save(src, tmp_path / f"new{lazy}.nc"))
        xr.testing.assert_identical(back.drop_attrs(deep=False), frf.drop_attrs(deep=False))
        np.testing.assert_array_equal(back["P"].values, frf["P"].values)


def test_spectra_of_lifted_experiment_round_trip(tmp_path):
    spec = dft(lift(_experiment()), dim="slow_time")
    xr.testing.assert_identical(open_dataset(save(spec, tmp_path / "spec.nc")), spec)


def test_open_with_chunks_is_lazy(tmp_path):
    path = save(_experiment(lead=(3,)), tmp_path / "exp.nc")
    lazy = open_dataset(path, chunks={"experiment": 1})
    assert dask.is_dask_collection(lazy["r"].data)
    xr.testing.assert_identical(lazy.compute(), open_dataset(path))


def test_failed_write_keeps_old_file_and_leaves_no_temp(tmp_path, monkeypatch):
    path = tmp_path / "exp.nc"
    old = _experiment(seed=1)
    save(old, path)
    before = path.read_bytes()

    real_to_netcdf = xr.Dataset.to_netcdf

    def half_then_fail(self, target, *args, **kwargs):
        real_to_netcdf(self, target, *args, **kwargs)
        with open(target, "r+b") as fh:  # leave a truncated, broken file behind
            fh.truncate(os.path.getsize(target) // 2)
        raise OSError("disk full (simulated)")

    monkeypatch.setattr(xr.Dataset, "to_netcdf", half_then_fail)
    with pytest.raises(OSError, match="simulated"):
        save(_experiment(seed=2), path)
    monkeypatch.undo()
    assert path.read_bytes() == before
    assert sorted(os.listdir(tmp_path)) == ["exp.nc"]
    xr.testing.assert_identical(open_experiment(path), old)


def test_save_replaces_existing_file(tmp_path):
    path = tmp_path / "exp.nc"
    save(_experiment(seed=1), path)
    new = _experiment(seed=2)
    save(new, path)
    xr.testing.assert_identical(open_experiment(path), new)
    assert sorted(os.listdir(tmp_path)) == ["exp.nc"]


def test_truncated_file_error_names_file(tmp_path):
    path = save(_experiment(), tmp_path / "exp.nc")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])
    with pytest.raises(ValueError, match=r"exp\.nc.*truncated"):
        open_experiment(path)


def test_not_netcdf_and_missing_file(tmp_path):
    text = tmp_path / "notes.nc"
    text.write_text("hello, not a netCDF file\n")
    with pytest.raises(ValueError, match=r"notes\.nc.*not a valid NetCDF"):
        open_dataset(text)
    with pytest.raises(FileNotFoundError, match="nothing.nc"):
        open_experiment(tmp_path / "nothing.nc")


def test_foreign_files_refused(tmp_path):
    foreign = xr.Dataset({"r": ("time", np.ones(4))}, attrs={"conventions": "CF-1.8"})
    path = save(foreign, tmp_path / "cf.nc")
    with pytest.raises(ValueError, match=r"cf\.nc is not an lcmr_xr experiment file.*'CF-1.8'"):
        open_experiment(path)
    with pytest.raises(ValueError, match=r"cf\.nc is not an lcmr_xr FRF file"):
        open_frf(path)
    # an experiment file is not an FRF file, and vice versa
    exp_path = save(_experiment(), tmp_path / "exp.nc")
    with pytest.raises(ValueError, match="no variable 'P'"):
        open_frf(exp_path)
    frf_path = save(_frf(), tmp_path / "frf.nc")
    with pytest.raises(ValueError, match=r"frf\.nc: invalid experiment dataset"):
        open_experiment(frf_path)


def test_invalid_experiment_file_names_file_and_problem(tmp_path):
    ds = _experiment()
    ds.attrs["factor"] = 4
    path = save(ds, tmp_path / "bad.nc")
    with pytest.raises(ValueError, match=r"bad\.nc: invalid experiment dataset: N=24"):
        open_experiment(path)


def test_frf_checks(tmp_path):
    real_p = _frf().assign(P=lambda d: abs(d["P"]))
    with pytest.raises(ValueError, match="expected complex"):
        open_frf(save(real_p, tmp_path / "a.nc"))
    no_freq = _frf().drop_vars("frequency")
    with pytest.raises(ValueError, match="'frequency' coordinate"):
        open_frf(save(no_freq, tmp_path / "b.nc"))


def test_save_refuses_unstorable_attributes(tmp_path):
    ds = _experiment()
    ds.attrs["settings"] = {"a": 1}
    with pytest.raises(TypeError, match="'settings'.*json.dumps"):
        save(ds, tmp_path / "x.nc")
    ds.attrs["settings"] = (1, "a")
    with pytest.raises(TypeError, match="mixed types"):
        save(ds, tmp_path / "x.nc")
    # complex values (a scalar, in a list, an array) failed inside netCDF4 ("illegal data
    # type for attribute b'gain', must be one of dict_keys([...]), got c16")
    for value in (1 + 2j, np.complex64(1j), [1.0, 2j], np.array([1j])):
        ds.attrs["settings"] = value
        with pytest.raises(TypeError, match="'settings' of the dataset is complex.*real and imaginary"):
            save(ds, tmp_path / "x.nc")
    ds.attrs.pop("settings")
    ds["r"].attrs["gain"] = 2j  # on a variable as well
    with pytest.raises(TypeError, match="'gain' of variable 'r' is complex"):
        save(ds, tmp_path / "x.nc")
    assert os.listdir(tmp_path) == []
    with pytest.raises(TypeError, match="to_dataset"):
        save(ds["r"], tmp_path / "x.nc")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        save(_experiment(), tmp_path / "missing_dir" / "x.nc")


def test_lazy_reopen_of_held_files_does_not_crash(tmp_path):
    """Regression: reopening files that a lazy dataset still holds, after a threaded compute.

    With netCDF4 handles on both sides this crashed HDF5 (segmentation fault, xarray
    issue 8289); lazy reads now use h5netcdf.  Run in a subprocess so a crash fails the
    test instead of killing the test session.
    """
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent(f"""
        import xarray as xr
        from lcmr_xr import hdd
        from lcmr_xr.scaleout import open_archive, save_archive
        exps = xr.concat([hdd.simulate(400, seed=s) for s in range(4)], dim="experiment")
        save_archive(exps, r"{tmp_path}")
        held = []
        for _ in range(4):
            held.append(open_archive(r"{tmp_path}"))
            held[-1].r.mean().compute(scheduler="threads")
        print("ok")
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert run.stdout.strip() == "ok"


def test_atomic_writes_list_their_directory_o1_times_and_still_clean_dead_writers(tmp_path, monkeypatch):
    """A sweep writes thousands of files into one directory: a write must not list it each
    time (that was O(files) per write), and a killed writer's temporary is still removed."""
    import subprocess
    import sys

    from lcmr_xr.io import _atomic

    for i in range(200):
        (tmp_path / f"part{i}.nc").write_bytes(b"")
    dead = int(subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                              capture_output=True, text=True, check=True).stdout)
    host = _atomic._host_tag()
    before = tmp_path / f".a.nc.{host}-{dead}.before00.tmp"  # left before our first write
    before.write_bytes(b"x")
    listings = []
    real = os.scandir
    monkeypatch.setattr(_atomic.os, "scandir", lambda d: listings.append(d) or real(d))

    def write(name):
        _atomic.atomic_write(tmp_path / name, lambda tmp: open(tmp, "wb").close())

    write("a.nc")
    assert not before.exists() and len(listings) == 1  # the first write lists and cleans
    during = tmp_path / f".a.nc.{host}-{dead}.during00.tmp"  # a writer killed meanwhile
    during.write_bytes(b"x")
    other = tmp_path / f".b.nc.{host}-{dead}.during00.tmp"  # another name's: not a.nc's to remove
    other.write_bytes(b"x")
    for i in range(600):
        write("a.nc" if i % 2 else f"new{i}.nc")
    # about one listing per directory size (>= 200 + new files) of writes, not one per write
    assert 2 <= len(listings) <= 1 + 600 // 200
    assert not during.exists() and other.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".") and "during00" not in p.name]


@pytest.mark.parametrize("links", [True, False])
def test_atomic_write_without_overwrite_never_replaces_an_existing_file(tmp_path, monkeypatch, links):
    """``overwrite=False`` puts the complete file in place only under a free name: by a hard
    link (refused atomically by the file system), or where links are not supported, by a
    check just before the rename.  Nothing is replaced and no temporary stays behind."""
    from pathlib import Path

    from lcmr_xr.io import _atomic

    if not links:
        def no_link(src, dst):
            raise PermissionError(1, "Operation not permitted")
        monkeypatch.setattr(_atomic.os, "link", no_link)
    target = tmp_path / "a.txt"
    _atomic.atomic_write(target, lambda tmp: Path(tmp).write_text("first"), overwrite=False)
    assert target.read_text() == "first"
    with pytest.raises(FileExistsError, match="a.txt: the file exists"):
        _atomic.atomic_write(target, lambda tmp: Path(tmp).write_text("second"), overwrite=False)
    assert target.read_text() == "first"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["a.txt"]
    _atomic.atomic_write(target, lambda tmp: Path(tmp).write_text("third"))  # the default replaces
    assert target.read_text() == "third"


@pytest.mark.parametrize("name", ["x.nc", "x.NC", "x.nc4", "x.netcdf", "x.mat", "x.txt", "x.h5", "x"])
def test_save_writes_the_format_its_name_says(tmp_path, name):
    """save wrote NetCDF-4 under any name (x.txt, x.h5, no suffix).  Now a NetCDF ending
    (any case) writes NetCDF-4, .mat a MATLAB file, and any other name is refused before
    anything is written, naming the accepted endings."""
    exp = _experiment(seed=3)
    target = tmp_path / name
    if name.lower().endswith((".nc", ".nc4", ".netcdf")):
        xr.testing.assert_identical(open_dataset(save(exp, target)), exp)
        assert target.read_bytes()[:4] == b"\x89HDF"
    elif name.endswith(".mat"):
        import scipy.io

        assert set(scipy.io.loadmat(save(exp, target))) >= {"r", "u", "y", "Ts", "F"}
    else:
        with pytest.raises(ValueError, match=r"unsupported file type .*must end in \.nc, \.nc4, "
                                             r"\.netcdf or \.mat, e\.g\. .*x\.nc"):
            save(exp, target)
    assert sorted(p.name for p in tmp_path.iterdir()) == ([name] if target.exists() else [])
