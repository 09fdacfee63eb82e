"""The catalogue of bad inputs (issue 15): every one gets a clear answer, none loses data.

One parametrised case per bad input, across the Python API, the command line and files.
Each case runs in a working directory holding real files (an experiment, an FRF, an
archive, foreign and broken NetCDF files) and asserts

- the exception type and the key words of its message (API), or exit status 2 and one
  line ``lcmr-xr CMD: error: ...`` with the key words (CLI; argparse's own refusals exit 2
  with its ``error:`` line), or, for inputs that must be *accepted* (a MATLAB (1, 1)
  factor, data scaled by 1e300, dask data chunked along time), the right result;
- that no file of the working directory changed: names, sizes and modification times
  are the same before and after (nothing written, nothing overwritten, no temporaries).

The settings-type cases (``window=30.5``, ``covariance="no"``, ...) are answered by the
settings validator of issue 17 (``lcmr_xr.settings``).
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import signal
import socket
import subprocess
import sys
import textwrap
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np
import pytest
import xarray as xr

import lcmr_xr
import lcmr_xr.plot
from lcmr_xr import cli, hdd
from lcmr_xr.demo import band_table, resonance_peaks
from lcmr_xr.experiment import experiment, validate_experiment
from lcmr_xr.io import open_dataset, open_experiment, open_frf, save
from lcmr_xr.io._atomic import stale_temporaries, temporary_prefix
from lcmr_xr.scaleout import (append_to_archive, consolidate_archive, open_archive, save_archive,
                              select_settings, sweep, sweep_to_disk)

TH = 1 / 100800
_needs_control = pytest.mark.skipif(importlib.util.find_spec("control") is None,
                                    reason="python-control (the [control] extra) is not installed")


# ------------------------------------------------------------------------ environment
@pytest.fixture(scope="module")
def small():
    """Noiseless HDD benchmark experiment: N = 400, F = 2, inputs vcm/pzt, one output."""
    return hdd.simulate(n_samples=400, noise=False, seed=1)


@pytest.fixture(scope="module")
def small_frf(small):
    return lcmr_xr.identify(small, window=12, degrees=(2, 2, 2))


@pytest.fixture(scope="module")
def template(tmp_path_factory, small, small_frf):
    """The files every case starts from (copied, with their times, into its working dir)."""
    root = tmp_path_factory.mktemp("template")
    save(small, root / "exp.nc")
    save(small_frf, root / "frf.nc")
    save(experiment(small.r.values[:8], small.u.values[:8], small.y.values[:4], factor=2,
                    sampling_period=TH), root / "short.nc")
    save(xr.Dataset({"r": ("time", np.ones(4))}, attrs={"conventions": "CF-1.8"}), root / "cf.nc")
    (root / "notes.nc").write_text("hello, not a netCDF file\n")
    data = (root / "exp.nc").read_bytes()
    (root / "trunc.nc").write_bytes(data[: len(data) // 3])
    (root / "damaged.nc").write_bytes(_damaged(root / "exp.nc", "r"))
    save_archive(xr.concat([small, hdd.simulate(n_samples=400, noise=False, seed=2)],
                           dim="experiment").assign_coords(experiment=["e0", "e1"]), root / "arc",
                 layout="files")
    save_archive(small, root / "arc1.nc")  # a consolidated archive (one file)
    shutil.copy2(root / "arc1.nc", root / "old.h5")  # one as written before new ones had to be .nc
    shutil.copytree(root / "arc", root / "damagedarc")  # its first file's values damaged
    (root / "damagedarc" / "e0.nc").write_bytes(_damaged(root / "arc" / "e0.nc", "r"))
    shutil.copytree(root / "arc", root / "damagedarc2")  # its second file's values damaged
    (root / "damagedarc2" / "e1.nc").write_bytes(_damaged(root / "arc" / "e1.nc", "r"))
    # its second file renamed e1.NC and damaged: a NetCDF name in another case (was left
    # out of the directory, silently) is read, and a sweep names it
    shutil.copytree(root / "arc", root / "casearc")
    (root / "casearc" / "e1.nc").unlink()
    (root / "casearc" / "e1.NC").write_bytes(_damaged(root / "arc" / "e1.nc", "r"))
    (root / "h5only").mkdir()  # no NetCDF name: no archive
    shutil.copy2(root / "exp.nc", root / "h5only" / "exp.h5")
    (root / "junkarc").mkdir()
    shutil.copy2(root / "exp.nc", root / "junkarc" / "good.nc")
    (root / "junkarc" / "junk.nc").write_bytes(b"\x89HDF\r\n\x1a\n not really")
    (root / "forarc").mkdir()
    shutil.copy2(root / "exp.nc", root / "forarc" / "a.nc")
    shutil.copy2(root / "cf.nc", root / "forarc" / "cf.nc")
    (root / "mixed").mkdir()
    save(small, root / "mixed" / "a.nc")
    save(hdd.simulate(n_samples=800, noise=False, seed=1), root / "mixed" / "b.nc")
    (root / "empty").mkdir()
    (root / "dir.nc").mkdir()
    (root / "demo").mkdir()
    save(small_frf, root / "demo" / "hdd_frf.nc")
    return root


def _damaged(path: Path, name: str) -> bytes:
    """The bytes of ``path`` with 64 bytes of variable ``name``'s stored values changed
    (the header intact: what a bad sector or a bit flip on a disk does)."""
    import h5py

    with h5py.File(path, "r") as f:
        dset = f[name].id
        offset = dset.get_offset() if dset.get_offset() is not None else dset.get_chunk_info(0).byte_offset
    data = bytearray(path.read_bytes())
    data[offset + 64: offset + 128] = bytes(0xA5 ^ b for b in data[offset + 64: offset + 128])
    return bytes(data)


def _toy_loop():
    """(plant, controller, filter) of a one-input loop with Th = 0.5 s and a controller at
    1 s (F = 2, or F = 2.5 truncated)."""
    from lcmr_xr.kernels.lti import static_gain, tf_q_inverse

    return tf_q_inverse([0.0, 0.5], [1.0, -0.9], dt=0.5), static_gain(0.2, dt=1.0), None


def snapshot(root: Path) -> dict:
    """Every file and directory under ``root`` (hidden ones too): size and mtime."""
    out = {}
    for base, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(base) / name
            st = path.stat()
            out[str(path.relative_to(root))] = (st.st_size if path.is_file() else -1, st.st_mtime_ns)
    return out


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class _Server:
    """A TCP service on 127.0.0.1 that is not a dask scheduler: it sends junk, or nothing."""

    def __init__(self, reply: bytes | None):
        self.sock = socket.socket()
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.port = self.sock.getsockname()[1]
        self.reply = reply
        self.conns = []
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self):
        while True:
            try:
                conn, _ = self.sock.accept()
            except OSError:
                return
            self.conns.append(conn)
            if self.reply is not None:
                try:
                    conn.sendall(self.reply)
                except OSError:
                    pass

    def close(self):
        for c in self.conns:
            c.close()
        self.sock.close()


@pytest.fixture(scope="module")
def servers():
    junk = _Server(b"HTTP/1.1 200 OK\r\nContent-Length: 5\r\n\r\nhello" * 4)
    silent = _Server(None)
    yield {"junk": junk.port, "silent": silent.port, "unused": _free_port()}
    junk.close()
    silent.close()


@dataclass
class Env:
    small: xr.Dataset
    frf: xr.Dataset
    servers: dict
    monkeypatch: pytest.MonkeyPatch

    @property
    def r(self):
        return self.small.r.values

    @property
    def u(self):
        return self.small.u.values

    @property
    def y(self):
        return self.small.y.values

    def build(self, **kw):
        args = {"r": self.r, "u": self.u, "y": self.y}
        args.update({k: kw.pop(k) for k in ("r", "u", "y") if k in kw})
        return experiment(args["r"], args["u"], args["y"], **{"factor": 2, "sampling_period": TH, **kw})

    def changed(self, **updates):
        ds = self.small.copy(deep=True)
        for key, value in updates.items():
            ds[key] = value
        return ds


@dataclass
class Case:
    id: str
    call: Callable | None = None           # API: call(env); CLI: argv(env) list
    raises: type | tuple | None = None
    words: tuple = ()
    absent: tuple = ()
    cli: Callable | None = None
    argparse: bool = False                 # refused by argparse itself
    check: Callable | None = None          # for accepted inputs: check(result, env)
    max_seconds: float | None = None
    marks: tuple = field(default_factory=tuple)


def _drop_attr(ds, key):
    ds = ds.copy()
    ds.attrs = {k: v for k, v in ds.attrs.items() if k != key}
    return ds


def _set_attr(ds, **attrs):
    ds = ds.copy()
    ds.attrs = {**ds.attrs, **attrs}
    return ds


def _spectrum(e):
    return lcmr_xr.dft(e.small.r)


def _lifted_slow_output(res, exp, factor):
    """``res`` is ``exp`` lifted by ``factor`` along ``slow_time``: ``y[l F + j]`` at
    ``[l, j]``, ``r`` and ``u`` passed through, the experiment's ``factor`` kept."""
    m = exp.sizes["slow_time"] // factor
    want = exp.y.values.reshape(m, factor, exp.sizes["output"])
    assert res.y.dims == ("slow_slow_time", "lift_phase", "output"), res.y.dims
    np.testing.assert_array_equal(res.y.values, want)
    xr.testing.assert_identical(res.r, exp.r)
    assert res.attrs["factor"] == exp.attrs["factor"]
    assert res.lift_phase.attrs["lift_factor"] == factor


def _lifted_spectrum(e):
    return lcmr_xr.dft(lcmr_xr.lift(e.small.r, 2), dim="slow_time")


def _with_nan(ds, name, index, lazy_chunks=None):
    ds = ds.copy(deep=True)
    ds[name].values[index] = np.nan
    return ds if lazy_chunks is None else ds.chunk(lazy_chunks)


def _flagged_experiment(bad, words):
    """Check a sweep result: experiment ``bad`` is NaN, flagged, and its error has ``words``."""
    def check(result, env):
        errors = result.experiment_error.values.ravel().tolist()
        assert all(w in errors[bad] for w in words), errors[bad]
        assert [m for i, m in enumerate(errors) if i != bad] == [""] * (len(errors) - 1)
        assert bool(result.P_flag.isel(experiment=bad).all())
        assert np.isnan(result.P.isel(experiment=bad).values).all()
        good = result.P.isel(experiment=[i for i in range(len(errors)) if i != bad])
        want = lcmr_xr.identify(env.small, window=12, degrees=(2, 2, 2)).P
        np.testing.assert_allclose(good.values.squeeze(), want.values.squeeze(), rtol=1e-6)
    return check


def _same_p(scale_y=1.0, rtol=1e-6):
    def check(result, env):
        want = lcmr_xr.identify(env.small, window=12, degrees=(2, 2, 2)).P * scale_y
        np.testing.assert_allclose(result.P.values, want.values, rtol=rtol)
    return check


def _identify12(ds, **kw):
    return lcmr_xr.identify(ds, **{"window": 12, "degrees": (2, 2, 2), **kw})


def _periodic3():
    return hdd.simulate(n_samples=400, noise=False, seed=1, periods=3)


def _scaled(env, s_r, s_u, s_y):
    return env.changed(r=env.small.r * s_r, u=env.small.u * s_u, y=env.small.y * s_y)


def _fake_readonly(env):
    import tempfile

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", os.path.join(kwargs.get("dir", "."), ".x.tmp"))

    env.monkeypatch.setattr(tempfile, "mkstemp", refuse)
    return save(env.small, "out.nc")


API = [
    # --- experiment(): building from arrays --------------------------------------------
    Case("factor_1x1_from_loadmat", lambda e: e.build(factor=np.array([[2]])),
         check=lambda ds, e: (ds.attrs["factor"] == 2 and isinstance(ds.attrs["factor"], int)) or pytest.fail()),
    Case("sampling_period_1x1_from_loadmat", lambda e: e.build(sampling_period=np.array([[TH]])),
         check=lambda ds, e: np.testing.assert_allclose(float(ds.time[1]), TH, rtol=1e-12)),
    Case("factor_vector", lambda e: e.build(factor=np.array([2, 2])), TypeError, ("factor", "single", "(2,)")),
    Case("factor_fraction", lambda e: e.build(factor=2.5), ValueError,
         ("factor", "positive integer", "not rounded", "factor=2")),
    Case("factor_zero", lambda e: e.build(factor=0), ValueError, ("factor", "positive integer")),
    Case("factor_bool", lambda e: e.build(factor=True), TypeError, ("factor", "boolean")),
    Case("factor_string", lambda e: e.build(factor="2"), TypeError, ("factor", "number")),
    Case("factor_nan", lambda e: e.build(factor=np.nan), ValueError, ("factor", "positive integer")),
    Case("sampling_period_negative", lambda e: e.build(sampling_period=-TH), ValueError, ("sampling_period", "positive")),
    Case("sampling_period_vector", lambda e: e.build(sampling_period=np.array([TH, TH])), TypeError,
         ("sampling_period", "single")),
    Case("sampling_period_missing", lambda e: experiment(e.r, e.u, e.y, factor=2), ValueError,
         ("sampling_period=Th",)),
    Case("sampling_period_disagrees_with_time", lambda e: experiment(e.small.r, e.small.u, e.small.y, factor=2,
                                                                    sampling_period=2 * TH),
         ValueError, ("disagrees", "spacing")),
    Case("r_transposed", lambda e: e.build(r=e.r.T), ValueError, ("transposed", "r.T")),
    Case("u_transposed", lambda e: e.build(u=e.u.T), ValueError, ("transposed", "u.T")),
    Case("y_matlab_row_vector", lambda e: e.build(y=e.y.T), ValueError, ("transposed", "y.T", "(1, 200)")),
    Case("r_stacked_transposed", lambda e: e.build(r=np.stack([e.r.T, e.r.T]), u=np.stack([e.u, e.u]),
                                                   y=np.stack([e.y, e.y])),
         ValueError, ("transposed", "swapaxes")),
    Case("r_four_dims", lambda e: e.build(r=e.r[None, None]), ValueError, ("4 dims", "DataArrays")),
    Case("r_shorter_than_u", lambda e: e.build(r=e.r[:398]), ValueError, ("do not fit together",)),
    Case("n_not_multiple_of_factor", lambda e: e.build(r=e.r[:399], u=e.u[:399]), ValueError,
         ("not a multiple", "398")),
    Case("too_many_labels", lambda e: e.build(inputs=["vcm"]), ValueError, ("1 labels", "2 channels")),
    Case("labels_of_r_and_u_differ", lambda e: experiment(e.small.r, e.small.u.assign_coords(input=["a", "b"]),
                                                          e.small.y, factor=2),
         ValueError, ("same input labels",)),
    Case("attrs_set_factor", lambda e: e.build(attrs={"factor": 3}), ValueError, ("must not set", "factor")),
    Case("complex_r", lambda e: e.build(r=e.r + 0j), ValueError, ("complex",)),
    Case("nan_in_r", lambda e: e.build(r=np.where(np.arange(400)[:, None] == 7, np.nan, e.r)), ValueError,
         ("NaN",)),
    Case("inf_in_y", lambda e: e.build(y=np.where(np.arange(200)[:, None] == 7, np.inf, e.y)), ValueError,
         ("y contains 1 NaN or inf value(s) (output='y0') at 1 of its 200 slow_time samples",
          "from slow_time = 0.000138889 s", "interpolate_na('slow_time')")),
    # a sweep flags the bad experiment (experiment_error says which and why) and goes on
    Case("nan_in_one_experiment_of_a_sweep", lambda e: sweep(
        _with_nan(xr.concat([e.small, e.small], "experiment"), "u", (1, 30, 0), {"experiment": 1}),
        window=[12], degrees=["2-2-2"]).compute(),
        check=_flagged_experiment(1, ("u contains 1 NaN or inf", "from time = 0.000297619 s",
                                       "interpolate"))),
    Case("r_experiment_dim_but_u_y_not", lambda e: e.build(r=np.stack([e.r, e.r])), ValueError,
         ("leading dims", "r ('experiment',)", "u ()")),
    Case("y_experiment_dim_but_u_not", lambda e: e.build(y=np.stack([e.y, e.y])), ValueError,
         ("leading dims",)),
    Case("r_shared_by_repeated_experiments", lambda e: e.build(u=np.stack([e.u, e.u]), y=np.stack([e.y, e.y])),
         check=lambda ds, e: ds.u.dims == ("experiment", "time", "input") or pytest.fail()),
    Case("dataarray_unnamed_dims", lambda e: experiment(xr.DataArray(e.r, dims=("t", "ch")), e.small.u,
                                                        e.small.y, factor=2),
         ValueError, ("rename", "'time'")),
    Case("string_data", lambda e: e.build(r=e.r.astype(str)), ValueError, ("non-numeric",)),
    Case("labels_as_one_string", lambda e: e.build(inputs="vcm"), TypeError, ("sequence of labels",)),
    Case("uneven_time", lambda e: experiment(e.small.r.assign_coords(time=e.small.time * (1 + np.arange(400) * 1e-4)),
                                             e.small.u.drop_vars("time"), e.small.y.drop_vars("slow_time"), factor=2),
         ValueError, ("not evenly spaced",)),
    Case("units_not_text", lambda e: e.build(output_units=5), TypeError, ("output_units", "unit string", "5")),
    Case("units_list", lambda e: e.build(input_units=["V"]), TypeError, ("input_units", "['V']")),
    Case("units_empty", lambda e: e.build(output_units=""), ValueError, ("output_units", "unit string")),
    Case("arrays_empty", lambda e: e.build(r=e.r[:0], u=e.u[:0], y=e.y[:0]), ValueError, ("r", "no data"),
         absent=("transposed",)),
    # --- validate_experiment(): datasets -------------------------------------------------
    Case("validate_check_values_text", lambda e: validate_experiment(e.small, check_values="no"), TypeError,
         ("check_values", "True or False")),
    Case("validate_dataarray", lambda e: validate_experiment(e.small.r), TypeError,
         ("xarray.Dataset", "lcmr_xr.experiment(r, u, y")),
    Case("conventions_missing", lambda e: validate_experiment(_drop_attr(e.small, "conventions")), ValueError,
         ("conventions", "missing")),
    Case("conventions_foreign", lambda e: validate_experiment(_set_attr(e.small, conventions="CF-1.8")), ValueError,
         ("CF-1.8", "lcmr_xr.experiment(r, u, y"), absent=("experiment.experiment",)),
    Case("factor_attr_missing", lambda e: validate_experiment(_drop_attr(e.small, "factor")), ValueError,
         ("'factor' is missing",)),
    Case("factor_attr_disagrees_with_spacing", lambda e: validate_experiment(_set_attr(e.small, factor=4)),
         ValueError, ("factor=4", "N/M = 400/200 = 2", "spacing / time spacing = 2")),
    Case("factor_attr_not_a_divisor", lambda e: validate_experiment(_set_attr(e.small, factor=3)),
         ValueError, ("not a multiple", "factor=3", "= 2")),
    Case("factor_attr_text", lambda e: validate_experiment(_set_attr(e.small, factor="two")), ValueError,
         ("positive integer",)),
    # the attribute is read by the one reader of a stored factor (settings.recorded_factor):
    # inf failed inside int() with an OverflowError, [True] was read as the factor 1
    Case("factor_attr_inf", lambda e: validate_experiment(_set_attr(e.small, factor=np.inf)), ValueError,
         ("'factor' must be a positive integer", "inf", "set ds.attrs['factor'] = F")),
    Case("factor_attr_bool_array", lambda e: validate_experiment(_set_attr(e.small, factor=np.array([True]))),
         ValueError, ("'factor' must be a positive integer", "True")),
    Case("variable_y_missing", lambda e: validate_experiment(e.small.drop_vars("y")), ValueError,
         ("'y' is missing",)),
    Case("units_missing", lambda e: validate_experiment(e.changed(r=e.small.r.drop_attrs())), ValueError,
         ("'units'",)),
    Case("duplicate_labels", lambda e: validate_experiment(e.small.assign_coords(input=["a", "a"])), ValueError,
         ("duplicates",)),
    Case("slow_time_spacing_wrong", lambda e: validate_experiment(e.small.assign_coords(slow_time=e.small.slow_time * 1.5)),
         ValueError, ("slow_time", "spaced by", "spacing / time spacing = 3")),
    Case("time_not_starting_at_zero", lambda e: validate_experiment(e.small.assign_coords(time=e.small.time + 1.0)),
         ValueError, ("starts at",)),
    # identify drops the first transient_periods by position: periods out of recording
    # order kept the transient and dropped a steady period (P changed by 41 % of its peak)
    Case("periods_reversed", lambda e: _identify12(
        hdd.simulate(n_samples=400, noise=False, seed=1, periods=3).isel(period=[2, 1, 0]),
        transient_periods=1), ValueError, ("'period' coordinate [2, 1, 0]", "sortby")),
    Case("period_coordinate_text", lambda e: validate_experiment(
        hdd.simulate(n_samples=400, noise=False, seed=1, periods=2).assign_coords(period=["a", "b"])),
        ValueError, ("'period' coordinate ['a', 'b']", "increasing integers")),
    Case("units_attribute_not_text", lambda e: validate_experiment(e.changed(y=e.small.y.assign_attrs(units=["m"]))),
         ValueError, ("'y'", "units ['m']", "UDUNITS")),
    # --- the HDD simulation and multisines: whole numbers and flags are not coerced ----------
    Case("simulate_samples_fractional", lambda e: hdd.simulate(n_samples=400.5, noise=False), ValueError,
         ("n_samples", "400.5", "not rounded")),
    Case("simulate_samples_text", lambda e: hdd.simulate(n_samples="400", noise=False), TypeError,
         ("n_samples", "'400'")),
    Case("simulate_noise_text", lambda e: hdd.simulate(n_samples=400, noise="no"), TypeError,
         ("noise", "True or False")),
    Case("simulate_fast_output_text", lambda e: hdd.simulate(n_samples=400, noise=False, fast_output="yes"),
         TypeError, ("fast_output", "True or False")),
    Case("simulate_seed_negative", lambda e: hdd.simulate(n_samples=400, noise=False, seed=-1), ValueError,
         ("seed", ">= 0", "pass e.g. seed=0")),  # the remedy: "seed must be >= 0, got -1." had none
    Case("simulate_seed_fractional", lambda e: hdd.simulate(n_samples=400, noise=False, seed=1.5), ValueError,
         ("seed", "1.5", "not rounded")),
    Case("simulate_seed_none", lambda e: hdd.simulate(n_samples=400, noise=False, seed=None), TypeError,
         ("seed", "None")),
    Case("multisine_samples_fractional", lambda e: lcmr_xr.multisine(400.5, sampling_period=TH, rms=1.0, seed=0),
         ValueError, ("n_samples", "400.5", "not rounded")),
    Case("multisine_periods_bool", lambda e: lcmr_xr.multisine(400, sampling_period=TH, rms=1.0, seed=0,
                                                               periods=True),
         TypeError, ("periods", "True")),
    # --- transforms ------------------------------------------------------------------------
    # the factor follows the settings' integer rule ("2" was a ValueError, as 2.5)
    Case("lift_factor_text", lambda e: lcmr_xr.lift(e.small.r, "2"), TypeError, ("factor", "'2'", "factor=2")),
    Case("lift_factor_fractional", lambda e: lcmr_xr.lift(e.small.r, 2.5), ValueError,
         ("factor", "2.5", "not rounded")),
    Case("lift_factor_whole_float", lambda e: lcmr_xr.lift(e.small.r, 2.0),
         check=lambda res, e: xr.testing.assert_identical(res, lcmr_xr.lift(e.small.r, 2))),
    # an explicit factor other than the one the signal records lifted by it, and the result
    # carried the recorded one on; the same factor (also as 2.0 or a file's [2]) is accepted
    Case("lift_factor_disagrees_with_attribute", lambda e: lcmr_xr.lift(e.small, 4), ValueError,
         ("factor=4", "F = 2", "attrs['factor']", "factor=2", "assign_attrs(factor=4)")),
    Case("lift_factor_disagrees_with_dataarray_attribute",
         lambda e: lcmr_xr.lift(e.small.r.assign_attrs(factor=np.array([2])), 4), ValueError,
         ("factor=4", "F = 2")),
    Case("lift_factor_agrees_with_attribute", lambda e: lcmr_xr.lift(e.small.assign_attrs(factor=np.array([2])), 2.0),
         check=lambda res, e: xr.testing.assert_identical(res, lcmr_xr.lift(e.small.assign_attrs(factor=np.array([2]))))),
    Case("lift_factor_attribute_text", lambda e: lcmr_xr.lift(e.small.r.assign_attrs(factor="two")), ValueError,
         ("x.attrs['factor']", "'two'", "not a lifting factor", "factor=F")),
    # the recorded factor is time's ratio to slow_time: lifting along another dim (the slow
    # output by 4) was refused since the check came in (session 16), and told to set the
    # experiment's factor to 4; a lifting along slow_time is not held to it
    Case("lift_other_dim_not_held_to_recorded_factor", lambda e: lcmr_xr.lift(e.small, 4, dim="slow_time"),
         check=lambda res, e: _lifted_slow_output(res, e.small, 4)),
    Case("unlift_reordered_phases", lambda e: lcmr_xr.unlift(lcmr_xr.lift(e.small.r, 2).sortby("lift_phase", ascending=False)),
         ValueError, ("lift_phase", "[1, 0]", "sortby")),
    Case("unlift_selected_phase", lambda e: lcmr_xr.unlift(lcmr_xr.lift(e.small.r.drop_vars("time"), 2).isel(lift_phase=[1])),
         ValueError, ("lift_phase", "[1]")),
    Case("dft_numpy", lambda e: lcmr_xr.dft(e.r), TypeError, ("dft", "xr.DataArray"), absent=("attribute",)),
    Case("idft_numpy", lambda e: lcmr_xr.idft(np.fft.fft(e.r, axis=0)), TypeError, ("idft", "xr.DataArray"),
         absent=("attribute",)),
    # factor follows the settings' integer rule: "2" and True were told "factor=2 does not
    # match the 2 lifting phases" (a ValueError), 2.5 "does not match" instead of "not rounded"
    Case("fast_spectrum_factor_fractional", lambda e: lcmr_xr.fast_spectrum_from_lifted(
        _lifted_spectrum(e), factor=2.5), ValueError,
        ("factor must be an integer", "2.5", "not rounded", "factor=2"), absent=("does not match",)),
    Case("fast_spectrum_factor_text", lambda e: lcmr_xr.fast_spectrum_from_lifted(_lifted_spectrum(e), factor="2"),
         TypeError, ("factor must be an integer", "'2'", "(str)", "pass e.g. factor=2"), absent=("does not match",)),
    Case("fast_spectrum_factor_bool", lambda e: lcmr_xr.fast_spectrum_from_lifted(_lifted_spectrum(e), factor=True),
         TypeError, ("factor must be an integer", "True", "(bool)"), absent=("does not match",)),
    Case("fast_spectrum_factor_numpy_bool", lambda e: lcmr_xr.fast_spectrum_from_lifted(
        _lifted_spectrum(e), factor=np.True_), TypeError, ("factor must be an integer", "True")),
    Case("fast_spectrum_factor_zero", lambda e: lcmr_xr.fast_spectrum_from_lifted(_lifted_spectrum(e), factor=0),
         ValueError, ("factor must be >= 1", "got 0")),
    Case("fast_spectrum_factor_other", lambda e: lcmr_xr.fast_spectrum_from_lifted(_lifted_spectrum(e), factor=3),
         ValueError, ("factor=3 does not match the 2 lifting phases", "omit factor")),
    Case("fast_spectrum_factor_whole", lambda e: [lcmr_xr.fast_spectrum_from_lifted(_lifted_spectrum(e), factor=f)
                                                  for f in (2.0, np.array(2), np.int64(2))],
         check=lambda res, e: [xr.testing.assert_identical(r, lcmr_xr.fast_spectrum_from_lifted(_lifted_spectrum(e)))
                               for r in res]),
    Case("dft_one_sided_text", lambda e: lcmr_xr.dft(e.small.r, one_sided="no"), TypeError,
         ("one_sided", "True or False")),
    # NaN made every bin of the spectrum NaN, silently
    Case("dft_nan_in_r", lambda e: lcmr_xr.dft(_with_nan(e.small, "r", (7, 1)).r), ValueError,
         ("r contains 1 NaN or inf", "input='pzt'", "time = 6.94444e-05 s", "interpolate_na")),
    Case("dft_inf_in_dataset", lambda e: lcmr_xr.dft(_with_nan(e.small, "y", (20, 0)).assign(
        y=lambda d: d.y.where(d.y.notnull(), np.inf)), dim="slow_time"), ValueError,
         ("y contains 1 NaN or inf", "output='position'", "indices 20..20")),
    Case("dft_nan_lazy", lambda e: lcmr_xr.dft(_with_nan(e.small, "u", (30, 0), {"input": 1}).u).compute(),
         ValueError, ("u contains 1 NaN or inf", "dask block", "indices 30..30", "interpolate_na")),
    # idft and fast_spectrum_from_lifted passed NaN/inf through (every time sample / F fast
    # bins NaN), silently: refused as dft refuses them, eagerly and per lazy block
    Case("idft_nan_in_spectrum", lambda e: lcmr_xr.idft(
        _spectrum(e).where(lambda X: X.frequency != X.frequency[5], np.nan)), ValueError,
         ("r contains 2 NaN or inf", "at 1 of its 400 frequency bins", "frequency = 1260 Hz",
          "indices 5..5", "every time sample", "fillna")),
    Case("idft_inf_lazy", lambda e: lcmr_xr.idft(_spectrum(e).where(
        lambda X: (X.frequency != X.frequency[7]) | (X.input != "pzt"), np.inf).chunk(input=1)).compute(),
         ValueError, ("r contains 1 NaN or inf", "dask block", "indices 7..7", "fillna")),
    Case("fast_spectrum_nan_slow_bin", lambda e: lcmr_xr.fast_spectrum_from_lifted(
        _lifted_spectrum(e).where(lambda X: X.slow_frequency != X.slow_frequency[3], np.nan)),
         ValueError, ("r contains 4 NaN or inf", "at 1 of its 200 slow_frequency bins",
                      "indices 3..3", "2 fast bins", "fillna")),
    Case("fast_spectrum_nan_lazy", lambda e: lcmr_xr.fast_spectrum_from_lifted(
        _lifted_spectrum(e).where(lambda X: X.slow_frequency != X.slow_frequency[3], np.nan)
        .chunk(input=1)).compute(),
         ValueError, ("r contains 2 NaN or inf", "dask block", "indices 3..3", "fillna")),
    # --- simulate_closed_loop: the factor was truncated (2.5 simulated F = 2), flags coerced ---
    Case("simulate_closed_loop_factor_fractional", lambda e: lcmr_xr.simulate_closed_loop(
        *_toy_loop(), 2.5, xr.DataArray(np.ones((8, 1)), dims=("time", "input"))), ValueError,
        ("factor", "2.5", "not rounded")),
    Case("simulate_closed_loop_fast_output_text", lambda e: lcmr_xr.simulate_closed_loop(
        *_toy_loop(), 2, xr.DataArray(np.ones((8, 1)), dims=("time", "input")), fast_output="no"), TypeError,
        ("fast_output", "True or False")),
    Case("simulate_closed_loop_plant_none", lambda e: lcmr_xr.simulate_closed_loop(
        None, _toy_loop()[1], None, 2, xr.DataArray(np.ones((8, 1)), dims=("time", "input"))), TypeError,
        ("plant", "StateSpace"), absent=("attribute",)),
    # --- exact lifted-system tools: labels checked, factors whole ------------------------------
    Case("lifted_frf_factor_fractional", lambda e: lcmr_xr.lifted_frf(e.frf.P, 2.5, n_samples=400), ValueError,
         ("factor", "2.5", "not rounded")),
    Case("lifted_frf_factor_zero", lambda e: lcmr_xr.lifted_frf(e.frf.P, 0, n_samples=400), ValueError,
         ("factor", ">= 1")),
    Case("lifted_frf_n_samples_fractional", lambda e: lcmr_xr.lifted_frf(e.frf.P, 2, n_samples=400.5), ValueError,
         ("n_samples", "400.5", "not rounded")),
    Case("lifted_frf_numpy", lambda e: lcmr_xr.lifted_frf(e.frf.P.values, 2), TypeError,
         ("lifted_frf", "xr.DataArray"), absent=("attribute",)),
    Case("lifted_frf_dim_missing", lambda e: lcmr_xr.lifted_frf(e.frf.P.rename(frequency="f"), 2, n_samples=400),
         ValueError, ("frequency", "rename"), absent=("KeyError",)),
    Case("first_block_row_factor_fractional", lambda e: lcmr_xr.frf_from_first_block_row(e.frf.PS, 2.5), ValueError,
         ("factor", "2.5", "not rounded")),
    Case("first_block_row_numpy", lambda e: lcmr_xr.frf_from_first_block_row(e.frf.PS.values), TypeError,
         ("frf_from_first_block_row", "xr.DataArray"), absent=("attribute",)),
    # --- plots: flags are True or False ----------------------------------------------------
    Case("bode_db_text", lambda e: lcmr_xr.plot.bode(e.frf, db="no"), TypeError, ("db", "True or False")),
    Case("bode_unwrap_text", lambda e: lcmr_xr.plot.bode(e.frf, unwrap="yes"), TypeError, ("unwrap",)),
    Case("bode_ax_text", lambda e: lcmr_xr.plot.bode(e.frf, ax="a"), TypeError, ("matplotlib Axes", "str"),
         absent=("shape",)),
    Case("lifted_db_text", lambda e: lcmr_xr.plot.lifted(e.frf, db="no"), TypeError, ("db", "True or False")),
    # --- FRD export: python-control assumes increasing frequencies ----------------------------
    Case("to_frd_frequencies_reversed", lambda e: lcmr_xr.to_frd(e.frf.isel(frequency=slice(None, None, -1))),
         ValueError, ("increase strictly", "sortby"), marks=(_needs_control,)),
    Case("to_frd_frequency_repeated", lambda e: lcmr_xr.to_frd(e.frf.isel(frequency=[1, 2, 2, 3])),
         ValueError, ("increase strictly", "drop_duplicates"), marks=(_needs_control,)),
    Case("from_frd_units_number", lambda e: lcmr_xr.from_frd(lcmr_xr.to_frd(e.frf.isel(frequency=slice(1, None))),
                                                             units=5),
         TypeError, ("units", "non-empty string", "5"), marks=(_needs_control,)),
    Case("from_frd_long_name_number", lambda e: lcmr_xr.from_frd(lcmr_xr.to_frd(e.frf.isel(frequency=slice(1, None))),
                                                                 long_name=5),
         TypeError, ("long_name", "5"), marks=(_needs_control,)),
    # --- the accuracy table of the README: frf.P - truth aligns by label ----------------------
    Case("band_table_truth_on_other_frequencies", lambda e: band_table(
        e.frf, hdd.true_frf(e.frf.frequency[1:] * (1 + 1e-12)).reindex(frequency=e.frf.frequency * (1 + 1e-12))),
        ValueError, ("truth must be on the FRF's frequencies", "reindex")),
    Case("band_table_band_reversed", lambda e: band_table(
        e.frf, hdd.true_frf(e.frf.frequency[1:]).reindex(frequency=e.frf.frequency), bands=[(5000, 500)]),
        ValueError, ("0 <= f_lo < f_hi",)),
    Case("band_table_experiment", lambda e: band_table(e.small, e.frf.P), TypeError, ("FRF dataset", "without P")),
    # 2.5 peaks failed inside Python's slicing ("slice indices must be integers")
    Case("resonance_peaks_count_fractional", lambda e: resonance_peaks(
        e.frf, hdd.true_frf(e.frf.frequency[1:]).reindex(frequency=e.frf.frequency), count=2.5),
        ValueError, ("count", "2.5", "not rounded")),
    Case("resonance_peaks_search_bins_text", lambda e: resonance_peaks(
        e.frf, hdd.true_frf(e.frf.frequency[1:]).reindex(frequency=e.frf.frequency), search_bins="3"),
        TypeError, ("search_bins", "'3'")),
    Case("true_frf_frequency_nan", lambda e: hdd.true_frf([1000.0, np.nan]), ValueError,
         ("frequency", "NaN or inf", "drop them")),
    # --- identify() ------------------------------------------------------------------------
    Case("identify_dataarray", lambda e: lcmr_xr.identify(e.small.r), TypeError, ("experiment xarray.Dataset",)),
    Case("method_unknown", lambda e: _identify12(e.small, method="lsq"), ValueError, ("method", "'lsq'")),
    Case("degrees_pair_for_lrm", lambda e: _identify12(e.small, degrees=(3, 3)), ValueError, ("degrees", "three non-negative")),
    Case("degrees_negative", lambda e: _identify12(e.small, degrees=(3, -1, 3)), ValueError, ("non-negative",)),
    Case("lpm_with_denominator", lambda e: _identify12(e.small, method="lpm", degrees=(2, 2, 2)), ValueError,
         ("Rd", "(2, 2, 0)")),
    Case("window_zero", lambda e: _identify12(e.small, window=0), ValueError, ("window", ">= 1")),
    # a typo in the switch of the second compiling process must not silently mean on or off
    Case("compile_ahead_setting_typo",
         lambda e: (e.monkeypatch.setenv("LCMR_XR_COMPILE_AHEAD", "yes"), _identify12(e.small, window=10))[1],
         ValueError, ("LCMR_XR_COMPILE_AHEAD", "'yes'", "not 0 or 1", "set it to 0")),
    Case("window_too_small", lambda e: _identify12(e.small, window=3), ValueError, ("Use window >=",)),
    Case("window_too_wide", lambda e: _identify12(e.small, window=150), ValueError,
         ("wider than the spectrum", "window <= 99")),
    Case("experiment_too_short_default_window",
         lambda e: lcmr_xr.identify(experiment(e.r[:8], e.u[:8], e.y[:4], factor=2, sampling_period=TH)),
         ValueError, ("too short", "M = 4", "slow samples"), absent=("window <= 0", "window <= 1")),
    Case("errors_unknown", lambda e: _identify12(e.small, errors="warn"), ValueError, ("errors", "'warn'")),
    Case("errors_none", lambda e: _identify12(e.small, errors=None), ValueError, ("errors", "None")),
    Case("closed_loop_unknown", lambda e: _identify12(e.small, closed_loop="bogus"), ValueError, ("closed_loop",)),
    Case("excitation_held_per_slow_period", lambda e: _identify12(e.changed(r=e.small.r.copy(data=np.repeat(e.r[::2], 2, axis=0)))),
         ValueError, ("rank", "excite")),
    Case("data_scaled_1e300", lambda e: _identify12(_scaled(e, 1e300, 1e300, 1e300)), check=_same_p()),
    Case("data_scaled_1e-300", lambda e: _identify12(_scaled(e, 1e-300, 1e-300, 1e-300)), check=_same_p()),
    Case("output_scaled_1e200", lambda e: _identify12(_scaled(e, 1, 1, 1e200)), check=_same_p(1e200)),
    Case("input_scaled_1e-200_single_rate", lambda e: lcmr_xr.identify_single_rate(_scaled(e, 1e-200, 1e-200, 1), window=12,
                                                                                    degrees=(1, 1, 1)),
         check=lambda res, e: np.testing.assert_allclose(
             res.P.values, lcmr_xr.identify_single_rate(e.small, window=12, degrees=(1, 1, 1)).P.values * 1e200, rtol=1e-6)),
    Case("dask_chunked_along_time", lambda e: _identify12(e.small.chunk(time=100, slow_time=50)).compute(),
         check=_same_p(rtol=1e-12)),
    Case("dask_chunked_along_time_with_nan", lambda e: _identify12(_with_nan(e.small, "r", (50, 0), {"time": 100, "slow_time": 50})).compute(),
         ValueError, ("r contains 1 NaN or inf", "time = 0.000496", "indices 50..50", "interpolate_na"), absent=("R and Z", "bad bins", "Core dimension")),
    Case("dask_nan_in_y", lambda e: _identify12(_with_nan(e.small, "y", (20, 0), {})).compute(),
         ValueError, ("y contains 1 NaN or inf", "slow_time =", "indices 20..20"), absent=("R and Z",)),
    Case("frequency_chunks_below_window", lambda e: _identify12(e.small, frequency_chunks=5), ValueError,
         ("frequency_chunks", ">= 12")),
    Case("frequency_chunks_zero", lambda e: _identify12(e.small, frequency_chunks=0), ValueError, ("frequency_chunks", ">= 1")),
    Case("single_rate_window_too_wide", lambda e: lcmr_xr.identify_single_rate(e.small, window=120), ValueError,
         ("wider than the spectrum",)),
    # settings types (issue 17's validator, lcmr_xr.settings)
    Case("window_fractional", lambda e: _identify12(e.small, window=30.5), (TypeError, ValueError), ("window", "30.5")),
    Case("window_text", lambda e: _identify12(e.small, window="30"), (TypeError, ValueError), ("window",)),
    Case("window_bool", lambda e: _identify12(e.small, window=True), (TypeError, ValueError), ("window", "True")),
    Case("covariance_text", lambda e: _identify12(e.small, covariance="no"), (TypeError, ValueError), ("covariance",)),
    Case("covariance_int", lambda e: _identify12(e.small, covariance=2), (TypeError, ValueError), ("covariance",)),
    Case("method_list", lambda e: _identify12(e.small, method=["lrm"]), (TypeError, ValueError), ("method",)),
    Case("closed_loop_unknown_on_dask", lambda e: _identify12(e.small.chunk(), closed_loop="bogus"), (TypeError, ValueError),
         ("closed_loop",)),
    Case("degrees_fractional", lambda e: _identify12(e.small, degrees=(2.5, 2, 2)), (TypeError, ValueError),
         ("degrees",)),
    # one integer rule for every whole-number setting: 2.0 is 2, 2.5 is refused (never
    # rounded), a string is a TypeError naming the argument (transient_periods=2.0 was
    # refused while window=30.0 was accepted, and "1" got a ValueError)
    Case("transient_periods_whole_float", lambda e: _identify12(_periodic3(), transient_periods=1.0),
         check=lambda res, e: xr.testing.assert_identical(res, _identify12(_periodic3(), transient_periods=1))),
    Case("transient_periods_fractional", lambda e: _identify12(_periodic3(), transient_periods=1.5), ValueError,
         ("transient_periods", "1.5", "not rounded")),
    Case("transient_periods_text", lambda e: _identify12(_periodic3(), transient_periods="1"), TypeError,
         ("transient_periods", "'1'", "transient_periods=1")),
    Case("transient_periods_bool", lambda e: _identify12(_periodic3(), transient_periods=True), TypeError,
         ("transient_periods", "True")),
    Case("simulate_periods_whole_float", lambda e: hdd.simulate(n_samples=400, noise=False, seed=1, periods=3.0),
         check=lambda ds, e: xr.testing.assert_identical(ds, _periodic3())),
    Case("simulate_periods_fractional", lambda e: hdd.simulate(n_samples=400, noise=False, periods=2.5), ValueError,
         ("periods", "2.5", "not rounded")),
    Case("simulate_periods_text", lambda e: hdd.simulate(n_samples=400, noise=False, periods="2"), TypeError,
         ("periods", "'2'")),
    Case("simulate_closed_loop_periods_fractional", lambda e: lcmr_xr.simulate_closed_loop(
        *_toy_loop(), 2, xr.DataArray(np.ones((8, 1)), dims=("time", "input")), periods=2.5), ValueError,
        ("periods", "2.5", "not rounded")),
    Case("simulate_case_whole_float", lambda e: hdd.simulate(n_samples=400, noise=False, seed=1, case=2.0),
         check=lambda ds, e: xr.testing.assert_identical(ds, e.small)),
    Case("simulate_case_text", lambda e: hdd.simulate(n_samples=400, noise=False, case="2"), TypeError,
         ("case", "'2'", "case=2")),
    Case("true_frf_case_fractional", lambda e: hdd.true_frf([1000.0], case=2.5), ValueError,
         ("case", "2.5", "not rounded")),
    Case("simulate_closed_loop_factor_text", lambda e: lcmr_xr.simulate_closed_loop(
        *_toy_loop(), "2", xr.DataArray(np.ones((8, 1)), dims=("time", "input"))), TypeError,
        ("factor", "'2'", "factor=2")),
    # one number in a 0-d array (a sweep choice's .values) is that number; a 1-element list is not
    Case("window_zero_dim_array", lambda e: _identify12(e.small, window=np.array(12)),
         check=lambda res, e: xr.testing.assert_identical(res, e.frf)),
    Case("window_zero_dim_dataarray", lambda e: _identify12(e.small, window=xr.DataArray(12.0)),
         check=lambda res, e: xr.testing.assert_identical(res, e.frf)),
    Case("window_one_element_list", lambda e: _identify12(e.small, window=[12]), TypeError, ("window", "[12]")),
    Case("sweep_experiments_per_task_text", lambda e: sweep(xr.concat([e.small, e.small], "experiment"), window=12,
                                                            experiments_per_task="1"),
         TypeError, ("experiments_per_task", "'1'")),
    Case("sweep_experiments_per_task_fractional", lambda e: sweep(xr.concat([e.small, e.small], "experiment"),
                                                                  window=12, experiments_per_task=1.5),
         ValueError, ("experiments_per_task", "1.5", "not rounded")),
    Case("sweep_experiments_per_task_whole_float", lambda e: sweep(xr.concat([e.small, e.small], "experiment"),
                                                                   window=12, degrees="2-2-2",
                                                                   experiments_per_task=1.0),
         check=lambda res, e: res.P.chunks[res.P.get_axis_num("experiment")] == (1, 1) or pytest.fail(
             str(res.P.chunks))),
    # --- files: save / open --------------------------------------------------------------
    Case("save_dataarray", lambda e: save(e.small.r, "x.nc"), TypeError, ("to_dataset",)),
    Case("save_into_missing_directory", lambda e: save(e.small, "nodir/x.nc"), FileNotFoundError,
         ("nodir", "does not exist")),
    # save wrote NetCDF-4 under any name (x.txt, or none); sweep_to_disk found out only at the
    # end, after every task (save), or never; the accepted endings are named, in any case
    Case("save_text_suffix", lambda e: save(e.small, "x.txt"), ValueError,
         ("x.txt", "'.txt'", ".nc, .nc4, .netcdf or .mat", "e.g. x.nc")),
    Case("save_no_suffix", lambda e: save(e.small, "result"), ValueError,
         ("result", "(no suffix)", ".nc", ".mat", "e.g. result.nc")),
    Case("sweep_to_disk_text_suffix", lambda e: sweep_to_disk(open_archive("arc"), "r.txt", window=[12]), ValueError,
         ("r.txt", "'.txt'", ".nc, .nc4 or .netcdf"), absent=(".mat",)),
    Case("save_onto_a_directory", lambda e: save(e.small, "arc"), IsADirectoryError, ("cannot write arc", "is a directory"),
         absent=(".tmp",)),
    Case("save_where_not_writable", _fake_readonly, PermissionError, ("cannot write out.nc",), absent=(".x.tmp",)),
    Case("save_lazy_over_its_source", lambda e: save(open_dataset("exp.nc", chunks={}), "exp.nc"), ValueError,
         ("exp.nc", "still reads", "load")),
    Case("save_dict_attribute", lambda e: save(_set_attr(e.small, settings={"a": 1}), "x.nc"), TypeError,
         ("'settings'", "json.dumps")),
    Case("save_mixed_tuple_attribute", lambda e: save(_set_attr(e.small, settings=(1, "a")), "x.nc"), TypeError,
         ("mixed types",)),
    Case("open_missing", lambda e: open_experiment("nothing.nc"), FileNotFoundError, ("nothing.nc",)),
    # damaged stored values (header intact) are refused, not read back as other numbers
    Case("open_damaged_values", lambda e: open_experiment("damaged.nc"), ValueError, ("damaged.nc", "corrupt")),
    # lazily: h5py's message at compute time, without the file's name
    Case("open_lazy_damaged_values", lambda e: open_dataset("damaged.nc", chunks={"time": 100}).r.values,
         ValueError, ("cannot read damaged.nc", "corrupt", "Restore it from a copy")),
    Case("open_experiment_lazy_damaged_values", lambda e: open_experiment("damaged.nc", chunks={}), ValueError,
         ("cannot read damaged.nc", "corrupt"), absent=("damaged.nc: cannot",)),
    # a bad chunks argument is not reported as a damaged file
    Case("open_chunks_fractional", lambda e: open_frf("frf.nc", chunks={"frequency": 2.5}), ValueError,
         ("chunks", "2.5", "whole number"), absent=("not a valid NetCDF",)),
    # the integer rule: a whole float is that chunk size ({'frequency': 100.0} was refused
    # as "must be a whole number"; chunks=100.0 a TypeError), a fraction is refused, not rounded
    Case("open_chunks_whole_float", lambda e: open_frf("frf.nc", chunks={"frequency": 100.0, "input": (1.0, 1)}),
         check=lambda res, e: (res.P.chunks == open_frf("frf.nc", chunks={"frequency": 100, "input": (1, 1)}).P.chunks
                               and res.P.chunks[0][0] == 100) or pytest.fail(str(res.P.chunks))),
    Case("open_chunks_whole_float_scalar", lambda e: open_dataset("exp.nc", chunks=100.0),
         check=lambda res, e: res.r.chunks == open_dataset("exp.nc", chunks=100).r.chunks or pytest.fail(
             str(res.r.chunks))),
    Case("open_chunks_fractional_scalar", lambda e: open_dataset("exp.nc", chunks=100.5), ValueError,
         ("chunks", "100.5", "not rounded"), absent=("not a valid NetCDF",)),
    # a 0-d integer array (a value taken from an array, e.g. ds.sizes-derived .values) was a
    # TypeError; the settings' integer rule reads it as the number it holds
    Case("open_chunks_zero_d_array", lambda e: open_dataset("exp.nc", chunks=np.array(100)),
         check=lambda res, e: res.r.chunks == open_dataset("exp.nc", chunks=100).r.chunks or pytest.fail(
             str(res.r.chunks))),
    Case("open_chunks_zero_d_arrays_in_dict", lambda e: open_dataset("exp.nc", chunks={"time": np.array(100.0),
                                                                                       "input": (np.int64(1), 1)}),
         check=lambda res, e: res.r.chunks == open_dataset("exp.nc", chunks={"time": 100, "input": (1, 1)}).r.chunks
         or pytest.fail(str(res.r.chunks))),
    Case("open_chunks_zero_d_array_fractional", lambda e: open_dataset("exp.nc", chunks=np.array(100.5)), ValueError,
         ("chunks", "100.5", "not rounded"), absent=("not a valid NetCDF",)),
    Case("open_chunks_zero_d_array_text", lambda e: open_dataset("exp.nc", chunks=np.array("x")), TypeError,
         ("chunks", "'x'"), absent=("not a valid NetCDF",)),
    # a tuple of chunk lengths that does not add up to its dim (short.nc: 8 samples) was
    # reported as "not a valid NetCDF-4 file (truncated, corrupt...)": the argument is named
    Case("open_chunks_tuple_not_adding_up", lambda e: open_dataset("short.nc", chunks={"time": (3, 3)}),
         ValueError, ("chunks {'time': (3, 3)}", "dim's length, 8 in short.nc", "adds up to 6",
                      "e.g. {'time': (4, 4)}"), absent=("not a valid NetCDF", "corrupt")),
    Case("open_experiment_chunks_tuple_too_long", lambda e: open_experiment("short.nc", chunks={"time": (8, 8)}),
         ValueError, ("'time'", "8 in short.nc", "adds up to 16"), absent=("not a valid NetCDF", "corrupt")),
    Case("open_chunks_tuple_with_whole_dim", lambda e: open_dataset("short.nc", chunks={"time": (3, -1)}),
         ValueError, ("chunks {'time': (3, -1)}", "-1 (the whole dim)", "{'time': -1}"),
         absent=("not a valid NetCDF", "corrupt")),
    # a damaged file is still the file's fault, tuples or not
    Case("open_chunks_tuple_truncated_file", lambda e: open_dataset("trunc.nc", chunks={"time": (3, 3)}),
         ValueError, ("cannot read trunc.nc", "not a valid NetCDF-4 file"), absent=("adds up",)),
    Case("open_chunks_tuple_adding_up", lambda e: open_dataset("short.nc", chunks={"time": (3, 5), "input": (1, 1)}),
         check=lambda res, e: res.r.chunks == ((3, 5), (1, 1)) or pytest.fail(str(res.r.chunks))),
    Case("open_chunks_text", lambda e: open_dataset("frf.nc", chunks="x"), TypeError, ("chunks", "'x'"),
         absent=("not a valid NetCDF",)),
    Case("open_text_file", lambda e: open_dataset("notes.nc"), ValueError, ("notes.nc", "not a valid NetCDF")),
    Case("open_truncated", lambda e: open_experiment("trunc.nc"), ValueError, ("trunc.nc", "truncated")),
    Case("open_foreign_netcdf", lambda e: open_experiment("cf.nc"), ValueError,
         ("cf.nc", "'CF-1.8'", "lcmr_xr.experiment(r, u, y"), absent=("experiment.experiment",)),
    Case("open_frf_on_experiment", lambda e: open_frf("exp.nc"), ValueError, ("no variable 'P'", "open_experiment")),
    # said only "variable 'r' is missing. add 'r' with dims ('time', 'input')"
    Case("open_experiment_on_frf", lambda e: open_experiment("frf.nc"), ValueError,
         ("frf.nc", "invalid experiment", "this is an FRF dataset", "lcmr_xr.open_frf")),
    Case("identify_an_frf", lambda e: lcmr_xr.identify(e.frf), ValueError,
         ("FRF dataset (it holds 'P'", "Pass the experiment (r, u, y)")),
    Case("open_directory_as_file", lambda e: open_experiment("arc"), IsADirectoryError, ("arc", "directory", "open_archive")),
    # --- archives ----------------------------------------------------------------------------
    Case("archive_missing", lambda e: open_archive("nothing"), FileNotFoundError, ("nothing", "does not exist")),
    # a consolidated archive is a file: other files are refused, named, with what an archive is
    Case("archive_path_is_a_file", lambda e: open_archive("exp.nc"), ValueError,
         ("exp.nc", "is a file but not a consolidated archive", "without the archive attribute",
          "an archive is one NetCDF file written by", "or a directory", "open_experiment"),
         absent=("does not exist",)),
    Case("archive_file_not_netcdf", lambda e: open_archive("notes.nc"), ValueError,
         ("notes.nc", "not a consolidated archive", "not a NetCDF-4 file", "an archive is one NetCDF file")),
    Case("archive_file_truncated", lambda e: open_archive("trunc.nc"), ValueError,
         ("trunc.nc", "not a consolidated archive", "not a NetCDF-4 file")),
    Case("archive_consolidated_into_directory_layout", lambda e: save_archive(e.small, "arc1.nc", layout="files"),
         ValueError, ("arc1.nc", "is a file", "layout='files' is a directory")),
    Case("archive_empty", lambda e: open_archive("empty"), FileNotFoundError, ("holds no .nc",)),
    Case("archive_only_other_suffixes", lambda e: open_archive("h5only"), FileNotFoundError,
         ("h5only holds no .nc, .nc4 or .netcdf files", "save_archive")),
    # a directory archive holds every NetCDF name save writes (x.NC, x.nc4), as save does:
    # e1.NC was left out of the open, the consolidation and the sweep without a word
    Case("archive_file_in_other_case_damaged_compute", lambda e: open_archive("casearc").compute(), ValueError,
         ("casearc/e1.NC is damaged", "Restore it from a copy")),
    Case("archive_file_in_other_case_damaged_consolidate", lambda e: consolidate_archive("casearc", "all.nc"),
         ValueError, ("casearc/e1.NC is damaged",)),
    Case("archive_file_in_other_case_damaged_sweep", lambda e: sweep(open_archive("casearc"), window=[12],
                                                                     degrees=["2-2-2"]).compute(),
         check=_flagged_experiment(1, ("experiment 'e1' (file casearc/e1.NC)", "is damaged",
                                       "Restore it from a copy"))),
    Case("archive_first_file_damaged", lambda e: open_archive("damagedarc"), ValueError,
         ("damagedarc/e0.nc", "damaged", "move it out")),
    # a later file's damaged values failed at compute time with h5py's message (no file
    # name), and aborted a sweep: now the file is named with the remedy, a sweep flags it
    Case("archive_second_file_damaged_compute", lambda e: open_archive("damagedarc2").compute(), ValueError,
         ("damagedarc2/e1.nc is damaged", "cannot be read", "Restore it from a copy", "move it out")),
    Case("archive_second_file_damaged_lazy", lambda e: open_archive("damagedarc2", chunks={"experiment": 1}).r.values,
         ValueError, ("damagedarc2/e1.nc is damaged", "Restore it from a copy")),
    Case("archive_second_file_damaged_consolidate", lambda e: consolidate_archive("damagedarc2", "all.nc"),
         ValueError, ("damagedarc2/e1.nc is damaged",)),
    Case("archive_second_file_damaged_sweep", lambda e: sweep(open_archive("damagedarc2"), window=[12],
                                                              degrees=["2-2-2"]).compute(),
         check=_flagged_experiment(1, ("experiment 'e1' (file damagedarc2/e1.nc)", "is damaged",
                                       "Restore it from a copy"))),
    # astype drops encoding["source"]: the damaged file's experiment was reported as
    # holding NaN ('remove or interpolate the bad samples'); the sweep finds the file from
    # its own reads of the archive
    Case("archive_second_file_damaged_sweep_astype",
         lambda e: sweep(open_archive("damagedarc2").astype("float64"), window=[12],
                         degrees=["2-2-2"]).compute(),
         check=_flagged_experiment(1, ("experiment 'e1' (file damagedarc2/e1.nc)", "is damaged",
                                       "Restore it from a copy"))),
    Case("archive_with_junk_file", lambda e: open_archive("junkarc"), ValueError, ("junkarc/junk.nc", "not a readable NetCDF",
                                                                        "move it out")),
    Case("archive_with_foreign_file", lambda e: open_archive("forarc"), ValueError, ("cf.nc", "not an lcmr-xr-1 experiment")),
    Case("archive_mixed_lengths", lambda e: open_archive("mixed"), ValueError, ("different lengths", "N=400", "N=800")),
    Case("save_archive_duplicate_names", lambda e: save_archive(
        xr.concat([e.small, e.small], "experiment").assign_coords(experiment=["a b", "a_b"]), "newarc",
        layout="files"),
        ValueError, ("same file names",)),
    Case("save_archive_empty", lambda e: save_archive([], "newarc.nc"), ValueError, ("empty",)),
    # a new consolidated archive took any name (campaign.h5, runs) while save refused it: NetCDF-4
    # under a name that says otherwise; the endings are named, and the directory layout
    Case("save_archive_h5_name", lambda e: save_archive(e.small, "campaign.h5"), ValueError,
         ("consolidated archive campaign.h5", "'.h5'", ".nc, .nc4 or .netcdf", "e.g. campaign.nc",
          "layout='files'"), absent=(".mat",)),
    Case("save_archive_no_suffix", lambda e: save_archive(e.small, "runs"), ValueError,
         ("consolidated archive runs", "(no suffix)", "e.g. runs.nc", "layout='files'")),
    Case("append_to_archive_new_h5", lambda e: append_to_archive(e.small, "new.h5"), ValueError,
         ("consolidated archive new.h5", "'.h5'", "e.g. new.nc", "create the directory first")),
    # an existing consolidated archive under such a name (written before the rule) still
    # opens, but took appends: NetCDF-4 went on being written under it; the rename is named
    Case("open_archive_old_h5", lambda e: open_archive("old.h5"),
         check=lambda ds, e: (ds.experiment.values.tolist() == [0] and ds.sizes["time"] == 400)
         or pytest.fail(str(ds))),
    # a directory holding e1.NC (any NetCDF ending, any case): an append labelled e1 checked
    # only e1.nc and wrote it beside, a second file for one label, which the open refuses
    Case("append_to_archive_label_under_other_ending",
         lambda e: append_to_archive(e.small.assign_coords(experiment="e1"), "casearc"), ValueError,
         ("experiment 'e1'", "casearc/e1.nc", "casearc already holds e1.NC", "another NetCDF ending",
          "another label")),
    Case("save_archive_label_under_other_ending",
         lambda e: save_archive(e.small.assign_coords(experiment="e1"), "casearc", layout="files"), ValueError,
         ("experiment 'e1'", "casearc already holds e1.NC", "another label", "rename e1.NC to e1.nc")),
    Case("consolidate_archive_h5_name", lambda e: consolidate_archive("arc", "all.h5"), ValueError,
         ("consolidated archive all.h5", "'.h5'", ".nc, .nc4 or .netcdf", "e.g. all.nc"),
         absent=("layout=",)),
    Case("consolidate_archive_h5_overwrite", lambda e: consolidate_archive("arc", "all.h5", overwrite=True),
         ValueError, ("'.h5'", "e.g. all.nc")),
    # overwrite="no" is truthy: it replaced the archive / the file (data lost); the snapshot
    # check of every case proves nothing changed
    Case("save_archive_overwrite_text", lambda e: save_archive(e.small, "arc1.nc", overwrite="no"), TypeError,
         ("overwrite", "True or False")),
    Case("consolidate_overwrite_text", lambda e: consolidate_archive("arc", "exp.nc", overwrite="no"), TypeError,
         ("overwrite", "True or False")),
    Case("sweep_to_disk_overwrite_text", lambda e: sweep_to_disk(open_archive("arc1.nc"), "frf.nc", window=[12],
                                                                 degrees=["2-2-2"], overwrite="no"),
         TypeError, ("overwrite", "True or False")),
    # the API wrote the consolidated file inside the directory it read (the directory then
    # no longer opened: a file of another structure), and with overwrite=True over one of
    # its experiment files (that experiment lost); the command line refused both
    Case("consolidate_output_inside_directory_api", lambda e: consolidate_archive("arc", "arc/all.nc"),
         ValueError, ("refusing to write", "arc/all.nc", "inside the archive directory arc",
                      "another path")),
    Case("consolidate_output_over_own_file_api",
         lambda e: consolidate_archive("arc", "arc/e0.nc", overwrite=True),
         ValueError, ("refusing to write", "arc/e0.nc", "inside the archive directory arc")),
    Case("consolidate_output_is_the_directory_api",
         lambda e: consolidate_archive("arc", "./arc", overwrite=True),
         ValueError, ("refusing to write", "the archive directory arc")),
    # workers=-1 failed inside concurrent.futures ("max_workers must be greater than 0")
    # after the parts directory was made (left behind); 0 ran on every CPU and 2.5 on 2
    # threads without a word; progress="no" (truthy) silently showed nothing
    Case("sweep_to_disk_workers_negative", lambda e: sweep_to_disk(open_archive("arc1.nc"), "out.nc", window=[12],
                                                                   degrees=["2-2-2"], workers=-1),
         ValueError, ("workers must be >= 1", "-1")),
    Case("sweep_to_disk_workers_zero", lambda e: sweep_to_disk(open_archive("arc1.nc"), "out.nc", window=[12],
                                                               degrees=["2-2-2"], workers=0),
         ValueError, ("workers must be >= 1", "0", "workers=")),
    Case("sweep_to_disk_workers_fractional", lambda e: sweep_to_disk(open_archive("arc1.nc"), "out.nc",
                                                                     window=[12], degrees=["2-2-2"], workers=2.5),
         ValueError, ("workers must be an integer", "2.5", "not rounded")),
    Case("sweep_to_disk_progress_text", lambda e: sweep_to_disk(open_archive("arc1.nc"), "out.nc", window=[12],
                                                                degrees=["2-2-2"], progress="no"),
         TypeError, ("progress must be True", "False or a callable", "'no'")),
    # failed after the first batch was copied, with "'bool' object is not callable"
    Case("consolidate_progress_not_callable", lambda e: consolidate_archive("arc", "all.nc", progress=True),
         TypeError, ("progress must be None or a callable", "progress(done, total)", "True")),
    # a time coordinate in ms was read as seconds: frequencies off by 1000 without a word
    # (experiment() even labelled its slow_time 's' with the ms numbers)
    Case("dft_time_in_ms", lambda e: lcmr_xr.dft(e.small.r.assign_coords(time=e.small.time * 1e3).assign_coords(
        time=lambda x: x.time.assign_attrs(units="ms"))), ValueError,
         ("'time' is in 'ms'", "seconds", "factor 1000", "* 0.001")),
    Case("experiment_time_in_ms", lambda e: validate_experiment(e.small.assign_coords(
        time=(e.small.time * 1e3).assign_attrs(units="ms"),
        slow_time=(e.small.slow_time * 1e3).assign_attrs(units="ms"))), ValueError,
         ("invalid experiment dataset", "'time' is in 'ms'", "factor 1000")),
    Case("experiment_built_from_time_in_minutes", lambda e: experiment(
        e.small.r.assign_coords(time=(e.small.time / 60).assign_attrs(units="min")), e.small.u.values,
        e.small.y.values, factor=2, inputs=["vcm", "pzt"]), ValueError, ("'time' is in 'min'", "* 60")),
    # attrs=[1] failed inside dict() ("cannot convert dictionary update sequence element");
    # attrs={"conventions": ...} was told to "pass factor=... instead"
    Case("experiment_attrs_not_a_dict", lambda e: e.build(attrs=[1]), TypeError,
         ("attrs must be a dict", "[1]")),
    Case("experiment_attrs_conventions", lambda e: e.build(attrs={"conventions": "CF-1.8"}), ValueError,
         ("must not set 'conventions'", "always sets 'lcmr-xr-1'"), absent=("factor=",)),
    # chunks=[1] failed inside with "'list' object has no attribute 'get'"; a consolidated
    # archive took {'experiment': 0} without a word and failed inside dask on 1.5 (a
    # directory refused both with the remedy)
    Case("archive_chunks_not_a_dict", lambda e: open_archive("arc1.nc", chunks=[1]), TypeError,
         ("chunks must be None or a dict", "[1]")),
    Case("archive_directory_chunks_not_a_dict", lambda e: open_archive("arc", chunks=[1]), TypeError,
         ("chunks must be None or a dict",)),
    Case("archive_consolidated_chunks_zero", lambda e: open_archive("arc1.nc", chunks={"experiment": 0}),
         ValueError, ("chunks['experiment'] = 0", "positive number of experiments")),
    Case("archive_consolidated_chunks_fractional", lambda e: open_archive("arc1.nc", chunks={"experiment": 1.5}),
         ValueError, ("chunks['experiment'] = 1.5", "positive number of experiments")),
    Case("archive_consolidated_chunks_whole", lambda e: open_archive("arc1.nc", chunks={"experiment": -1}),
         check=lambda ds, e: ds.r.chunks[0] == (1,) or pytest.fail(str(ds.r.chunks))),
    # sizes by the library's integer rule, as open_dataset's chunks: a 0-d array and a whole
    # float were "no positive number of experiments per chunk" (open_dataset takes them), a
    # directory's {'time': np.array(100)} failed inside dask ("chunks can only contain
    # integers") and {'time': 100.5} likewise
    Case("archive_consolidated_chunks_zero_d_array", lambda e: open_archive("arc1.nc", chunks={"experiment": np.array(1)}),
         check=lambda ds, e: ds.r.chunks == open_archive("arc1.nc", chunks={"experiment": 1}).r.chunks
         or pytest.fail(str(ds.r.chunks))),
    Case("archive_directory_chunks_zero_d_array", lambda e: open_archive("arc", chunks={"experiment": np.array(1)}),
         check=lambda ds, e: ds.r.chunks[0] == (1, 1) or pytest.fail(str(ds.r.chunks))),
    Case("archive_directory_chunks_whole_float", lambda e: open_archive("arc", chunks={"experiment": 1.0}),
         check=lambda ds, e: ds.r.chunks[0] == (1, 1) or pytest.fail(str(ds.r.chunks))),
    Case("archive_directory_chunks_time_zero_d_array", lambda e: open_archive("arc", chunks={"time": np.array(100)}),
         check=lambda ds, e: ds.r.chunks == open_archive("arc", chunks={"time": 100}).r.chunks
         and ds.r.chunks[1] == (100,) * 4 or pytest.fail(str(ds.r.chunks))),
    Case("archive_directory_chunks_time_fractional", lambda e: open_archive("arc", chunks={"time": 100.5}),
         ValueError, ("chunks {'time': 100.5}", "whole number (>= 1)"), absent=("can only contain",)),
    Case("archive_directory_chunks_zero_d_fractional", lambda e: open_archive("arc", chunks={"experiment": np.array(1.5)}),
         ValueError, ("chunks['experiment'] = 1.5", "positive number of experiments")),
    # a consolidated archive ignored every entry but 'experiment', malformed ones too, where a
    # directory applied them ({'time': 'x'} refused, {'time': 4} applied); a directory ignored a
    # malformed entry of a dim it lacks, which open_dataset refuses
    Case("archive_consolidated_chunks_time_text", lambda e: open_archive("arc1.nc", chunks={"time": "x"}),
         ValueError, ("chunks {'time': 'x'}", "whole number (>= 1)")),
    Case("archive_consolidated_chunks_time_fractional", lambda e: open_archive("arc1.nc", chunks={"time": 100.5}),
         ValueError, ("chunks {'time': 100.5}", "whole number (>= 1)")),
    Case("archive_consolidated_chunks_time", lambda e: open_archive("arc1.nc", chunks={"time": np.array(100),
                                                                                      "slow_time": 50.0}),
         check=lambda ds, e: (ds.r.chunks == ((1,), (100,) * 4, (2,)) and ds.y.chunks[1] == (50,) * 4
                              and ds.r.chunks[1:] == open_archive("arc", chunks={"time": 100}).r.chunks[1:])
         or pytest.fail(str((ds.r.chunks, ds.y.chunks)))),
    Case("archive_consolidated_chunks_tuple_not_adding_up",
         lambda e: open_archive("arc1.nc", chunks={"time": (100, 100)}), ValueError,
         ("chunks {'time': (100, 100)}", "do not fit", "'time': 400")),
    Case("archive_directory_chunks_tuple_not_adding_up",
         lambda e: open_archive("arc", chunks={"time": (100, 100)}), ValueError,
         ("chunks {'time': (100, 100)}", "do not fit", "'time': 400")),
    Case("archive_consolidated_chunks_other_dim_ignored", lambda e: open_archive("arc1.nc", chunks={"frequency": 4}),
         check=lambda ds, e: ds.r.chunks == open_archive("arc1.nc").r.chunks or pytest.fail(str(ds.r.chunks))),
    Case("archive_directory_chunks_other_dim_malformed", lambda e: open_archive("arc", chunks={"frequency": "x"}),
         ValueError, ("chunks {'frequency': 'x'}", "whole number (>= 1)")),
    Case("archive_consolidated_chunks_zero_d_bool", lambda e: open_archive("arc1.nc", chunks={"experiment": np.array(True)}),
         ValueError, ("chunks['experiment'] = True", "positive number of experiments")),
    # chunks={'time': -2} was reported as "not a valid NetCDF-4 file (truncated, corrupt,
    # ...)" (xarray's refusal of the argument); 0 silently meant the whole dim
    Case("open_chunks_negative", lambda e: open_dataset("exp.nc", chunks={"time": -2}), ValueError,
         ("chunks {'time': -2}", "whole number (>= 1)", "-1 (the whole dim)"), absent=("corrupt",)),
    Case("open_chunks_zero", lambda e: open_experiment("exp.nc", chunks={"time": 0}), ValueError,
         ("chunks {'time': 0}", "whole number (>= 1)")),
    Case("open_chunks_zero_int", lambda e: open_dataset("exp.nc", chunks=0), ValueError,
         ("chunks=0", "whole number (>= 1)")),
    # an address in place of a Client failed inside ("'str' object has no attribute
    # 'compute'") after the parts directory was made (left behind)
    Case("sweep_to_disk_client_address", lambda e: sweep_to_disk(open_archive("arc1.nc"), "out.nc", window=[12],
                                                                  degrees=["2-2-2"], client="tcp://127.0.0.1:8786"),
         TypeError, ("client must be a distributed.Client", "distributed.Client('tcp://")),
    # astype drops encoding["source"]: the sweep wrote its result and parts inside the
    # directory archive it read (which then no longer opened: a file of no experiment)
    Case("sweep_to_disk_output_inside_archive_after_astype",
         lambda e: sweep_to_disk(open_archive("arc").astype("float64"), "arc/out.nc", window=[12],
                                 degrees=["2-2-2"], progress=False),
         ValueError, ("refusing to write output arc/out.nc", "inside the input directory")),
    # a consolidated file inside a directory archive made the directory's open refuse
    # the whole directory ("all.nc differs from e0.nc in its variables ...")
    Case("save_archive_file_inside_directory_archive", lambda e: save_archive(e.small, "arc/all.nc"),
         ValueError, ("refusing to write the consolidated archive arc/all.nc", "arc is a directory archive",
                      "outside it (e.g. arc.nc)", "save_archive(experiments, 'arc')")),
    Case("append_to_archive_file_inside_directory_archive",
         lambda e: append_to_archive(e.small.assign_coords(experiment="x"), "arc/one.nc"),
         ValueError, ("refusing to write the consolidated archive arc/one.nc", "directory archive")),
    Case("consolidate_archive_into_another_directory_archive",
         lambda e: consolidate_archive("arc", "damagedarc/all.nc"),
         ValueError, ("refusing to write the consolidated archive damagedarc/all.nc", "directory archive")),
    Case("save_archive_not_datasets", lambda e: save_archive([e.small.r], "newarc.nc"), TypeError, ("not an experiment Dataset",)),
    # --- sweep / select ------------------------------------------------------------------------
    Case("sweep_window_too_small", lambda e: sweep(e.small, window=[3]), ValueError, ("Use window >=",)),
    # one number is one setting, judged by the settings' check (not "not a sequence")
    Case("sweep_window_fractional_scalar", lambda e: sweep(e.small, window=12.5), ValueError,
         ("window", "12.5", "not rounded")),
    Case("sweep_window_whole_float", lambda e: sweep(e.small, window=12.0, degrees="2-2-2"),
         check=lambda res, e: res.window.values.tolist() == [12] or pytest.fail(str(res.window.values))),
    # one number in a 0-d array (a sweep choice's .values) is that number, as for identify
    # (a 0-d array was iterated: numpy's "iteration over a 0-d array")
    Case("sweep_window_zero_dim_array", lambda e: sweep(e.small, window=np.array(12), degrees="2-2-2"),
         check=lambda res, e: res.window.values.tolist() == [12] or pytest.fail(str(res.window.values))),
    Case("sweep_window_zero_dim_dataarray", lambda e: sweep(e.small, window=xr.DataArray(12.0), degrees="2-2-2"),
         check=lambda res, e: res.window.values.tolist() == [12] or pytest.fail(str(res.window.values))),
    Case("sweep_pool_zero_dim_array", lambda e: sweep(xr.concat([e.small, e.small], "experiment"), window=12,
                                                      degrees="2-2-2", pool=np.array(2)),
         check=lambda res, e: xr.testing.assert_identical(
             res, sweep(xr.concat([e.small, e.small], "experiment"), window=12, degrees="2-2-2", pool=2))),
    Case("sweep_pool_fractional", lambda e: sweep(xr.concat([e.small, e.small], "experiment"), window=12, pool=1.5),
         ValueError, ("pool", "1.5", "not rounded")),
    Case("sweep_degrees_label", lambda e: sweep(e.small, window=[12], degrees=["3-3"]), ValueError,
         ("three non-negative", "'3-3'")),
    Case("sweep_pool_without_experiments", lambda e: sweep(e.small, window=[12], pool=2), ValueError,
         ("pool groups the 'experiment' dim",)),
    Case("select_unknown_criterion", lambda e: select_settings(sweep(e.small, window=[12]), e.small, criterion="aic"),
         ValueError, ("criterion", "'aic'")),
    Case("select_cross_with_one_experiment", lambda e: select_settings(sweep(e.small, window=[12]), e.small,
                                                                      criterion="cross"),
         ValueError, ("at least two", "fpe")),
]


CLI = [
    # identify
    Case("identify_input_missing", cli=lambda e: ["identify", "missing.nc", "-o", "out.nc"], words=("missing.nc",)),
    Case("identify_input_not_netcdf", cli=lambda e: ["identify", "notes.nc", "-o", "out.nc"], words=("notes.nc",)),
    Case("identify_output_is_input", cli=lambda e: ["identify", "exp.nc", "-o", "exp.nc"],
         words=("refusing", "exp.nc", "input")),
    Case("identify_output_is_input_other_spelling", cli=lambda e: ["identify", "exp.nc", "-o", "./arc/../exp.nc"],
         words=("refusing",)),
    Case("identify_output_exists", cli=lambda e: ["identify", "exp.nc", "-o", "frf.nc"],
         words=("frf.nc", "already exists", "--overwrite")),
    Case("identify_plot_bad_format", cli=lambda e: ["identify", "exp.nc", "-o", "out.nc", "--plot", "f.xyz"],
         words=("--plot", "'.xyz'", ".png")),
    Case("identify_plot_over_input", cli=lambda e: ["identify", "exp.nc", "-o", "out.nc", "--plot", "arc"],
         words=("--plot",)),
    Case("identify_output_bad_format", cli=lambda e: ["identify", "exp.nc", "-o", "out.txt"], words=("'.txt'", ".nc")),
    Case("identify_output_directory_missing", cli=lambda e: ["identify", "exp.nc", "-o", "nodir/out.nc"],
         words=("nodir", "does not exist")),
    Case("identify_output_is_a_directory", cli=lambda e: ["identify", "exp.nc", "-o", "dir.nc"],
         words=("dir.nc", "is a directory")),
    Case("identify_window_too_wide", cli=lambda e: ["identify", "exp.nc", "-o", "out.nc", "--window", "200"],
         words=("wider than the spectrum",)),
    Case("identify_foreign_input", cli=lambda e: ["identify", "cf.nc", "-o", "out.nc"],
         words=("cf.nc", "lcmr_xr.experiment(r, u, y"), absent=("experiment.experiment",)),
    Case("identify_frf_as_input", cli=lambda e: ["identify", "frf.nc", "-o", "out.nc"],
         words=("invalid experiment", "this is an FRF dataset")),
    Case("identify_directory_as_input", cli=lambda e: ["identify", "arc", "-o", "out.nc"], words=("arc", "directory")),
    Case("identify_too_short", cli=lambda e: ["identify", "short.nc", "-o", "out.nc"], words=("too short",),
         absent=("window <= 0",)),
    Case("identify_lpm_with_denominator", cli=lambda e: ["identify", "exp.nc", "-o", "out.nc", "--method", "lpm",
                                                         "--degrees", "3-3-3"], words=("Rd",)),
    # --window goes through the settings' validator (it also takes 'auto'): refused, not rounded
    Case("identify_window_fractional", cli=lambda e: ["identify", "exp.nc", "-o", "out.nc", "--window", "30.5"],
         words=("window must be an integer", "30.5", "not rounded")),
    Case("identify_method_unknown", cli=lambda e: ["identify", "exp.nc", "-o", "out.nc", "--method", "lsq"],
         argparse=True, words=("invalid choice", "lsq")),
    # simulate
    Case("simulate_output_exists", cli=lambda e: ["simulate", "-o", "exp.nc", "--samples", "400"],
         words=("exp.nc", "already exists", "--overwrite")),
    Case("simulate_output_bad_format", cli=lambda e: ["simulate", "-o", "sim.png"], words=("'.png'", ".nc")),
    Case("simulate_output_directory_missing", cli=lambda e: ["simulate", "-o", "nodir/x.nc"], words=("does not exist",)),
    Case("simulate_samples_odd", cli=lambda e: ["simulate", "-o", "x.nc", "--samples", "5"],
         words=("--samples", "multiple")),
    Case("cli_simulate_seed_negative", cli=lambda e: ["simulate", "-o", "x.nc", "--seed", "-1"],
         words=("--seed", ">= 0")),
    Case("identify_damaged_input", cli=lambda e: ["identify", "damaged.nc", "-o", "out.nc"],
         words=("damaged.nc", "corrupt")),
    Case("simulate_case_unknown", cli=lambda e: ["simulate", "-o", "x.nc", "--case", "10"], argparse=True,
         words=("invalid choice",)),
    # sweep
    Case("sweep_output_over_archive_member", cli=lambda e: ["sweep", "arc", "-o", "arc/e0.nc", "--window", "12"],
         words=("refusing", "arc/e0.nc", "inside the input directory")),
    Case("sweep_output_new_file_in_archive", cli=lambda e: ["sweep", "arc", "-o", "arc/new.nc", "--window", "12"],
         words=("refusing", "arc/new.nc")),
    Case("sweep_select_in_archive", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--window", "12", "--select",
                                                   "arc/choice.nc"], words=("refusing", "--select")),
    Case("sweep_pool_with_select", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--window", "12", "--pool",
                                                  "2", "--select", "c.nc"], words=("--pool", "--select")),
    Case("sweep_output_equals_select", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--select", "r.nc"],
         words=("same file",)),
    Case("sweep_output_exists", cli=lambda e: ["sweep", "arc", "-o", "frf.nc", "--window", "12"],
         words=("frf.nc", "already exists", "--overwrite")),
    Case("sweep_archive_is_a_file", cli=lambda e: ["sweep", "exp.nc", "-o", "r.nc"], words=("exp.nc", "is a file"),
         absent=("does not exist",)),
    Case("sweep_archive_not_netcdf", cli=lambda e: ["sweep", "notes.nc", "-o", "r.nc"],
         words=("notes.nc", "not a consolidated archive", "not a NetCDF-4 file")),
    Case("sweep_output_is_consolidated_archive", cli=lambda e: ["sweep", "arc1.nc", "-o", "arc1.nc", "--overwrite"],
         words=("refusing", "arc1.nc", "the input file")),
    Case("sweep_archive_missing", cli=lambda e: ["sweep", "nothing", "-o", "r.nc"], words=("nothing", "does not exist")),
    # archive consolidate
    Case("consolidate_output_inside_directory", cli=lambda e: ["archive", "consolidate", "arc", "-o", "arc/all.nc"],
         words=("refusing", "arc/all.nc", "inside the input directory")),
    Case("consolidate_output_exists", cli=lambda e: ["archive", "consolidate", "arc", "-o", "frf.nc"],
         words=("frf.nc", "already exists", "--overwrite")),
    Case("consolidate_output_bad_format", cli=lambda e: ["archive", "consolidate", "arc", "-o", "all.zarr"],
         words=("'.zarr'", ".nc")),
    Case("consolidate_input_is_an_archive_file", cli=lambda e: ["archive", "consolidate", "arc1.nc", "-o", "b.nc"],
         words=("arc1.nc", "consolidated archive file already")),
    Case("consolidate_input_missing", cli=lambda e: ["archive", "consolidate", "nothing", "-o", "b.nc"],
         words=("nothing", "does not exist")),
    Case("consolidate_directory_with_junk", cli=lambda e: ["archive", "consolidate", "junkarc", "-o", "b.nc"],
         words=("junkarc/junk.nc", "not a readable NetCDF")),
    Case("sweep_archive_with_junk", cli=lambda e: ["sweep", "junkarc", "-o", "r.nc", "--window", "12"],
         words=("junk.nc",)),
    Case("cli_sweep_window_too_small", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--window", "3"],
         words=("Use window >=",)),
    Case("cli_sweep_degrees_label", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--degrees", "3-3"],
         words=("three non-negative",)),
    Case("sweep_scheduler_unknown", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--scheduler", "gpu"],
         words=("neither threads",)),
    Case("sweep_scheduler_bad_port", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--scheduler", "tcp://127.0.0.1:port"],
         words=("neither threads",)),
    Case("sweep_scheduler_nothing_listens", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--window", "12",
                                                            "--scheduler", f"tcp://127.0.0.1:{e.servers['unused']}"],
         words=("no dask scheduler answers", f"127.0.0.1"), max_seconds=8.0),
    Case("sweep_scheduler_foreign_service", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--window", "12",
                                                            "--scheduler", f"tcp://127.0.0.1:{e.servers['junk']}",
                                                            "--connect-timeout", "3"],
         words=("not as a dask scheduler",), max_seconds=10.0),
    Case("sweep_scheduler_silent_service", cli=lambda e: ["sweep", "arc", "-o", "r.nc", "--window", "12",
                                                           "--scheduler", f"tcp://127.0.0.1:{e.servers['silent']}",
                                                           "--connect-timeout", "1"],
         words=("not as a dask scheduler", "within 1 s"), max_seconds=10.0),
    # demo
    Case("demo_experiment_missing", cli=lambda e: ["demo", "--experiment", "missing.nc", "--output-dir", "out"],
         words=("missing.nc",)),
    Case("demo_output_dir_is_a_file", cli=lambda e: ["demo", "--experiment", "exp.nc", "--output-dir", "exp.nc"],
         words=("exp.nc", "is a file")),
    Case("demo_output_exists", cli=lambda e: ["demo", "--experiment", "exp.nc", "--output-dir", "demo"],
         words=("hdd_frf.nc", "already exists", "--overwrite")),
    Case("demo_experiment_is_an_output", cli=lambda e: ["demo", "--experiment", "demo/hdd_frf.nc", "--output-dir", "demo",
                                                        "--overwrite"], words=("refusing", "hdd_frf.nc")),
    Case("demo_window_too_small", cli=lambda e: ["demo", "--experiment", "exp.nc", "--output-dir", "newdir",
                                                 "--window", "3", "--no-plot"], words=("Use window >=",)),
]


@pytest.fixture
def workdir(template, tmp_path, monkeypatch):
    work = tmp_path / "work"
    shutil.copytree(template, work, copy_function=shutil.copy2)
    monkeypatch.chdir(work)
    return work


def _params(cases):
    return [pytest.param(c, id=c.id, marks=c.marks) for c in cases]


@pytest.mark.parametrize("case", _params(API))
def test_api_bad_input(case, workdir, small, small_frf, servers, monkeypatch):
    env = Env(small, small_frf, servers, monkeypatch)
    before = snapshot(workdir)
    if case.raises is None:
        case.check(case.call(env), env)
    else:
        with pytest.raises(case.raises) as info:
            case.call(env)
        message = str(info.value)
        for word in case.words:
            assert word in message, f"{word!r} not in: {message}"
        for word in case.absent:
            assert word not in message, f"{word!r} in: {message}"
    monkeypatch.undo()
    assert snapshot(workdir) == before


@pytest.mark.parametrize("case", _params(CLI))
def test_cli_bad_input(case, workdir, small, small_frf, servers, monkeypatch, capsys):
    env = Env(small, small_frf, servers, monkeypatch)
    before = snapshot(workdir)
    start = time.perf_counter()
    if case.argparse:
        with pytest.raises(SystemExit) as info:
            cli.main(case.cli(env))
        status = info.value.code
    else:
        status = cli.main(case.cli(env))
    elapsed = time.perf_counter() - start
    err = capsys.readouterr().err
    assert status == 2
    lines = [line for line in err.splitlines() if "error:" in line]
    assert len(lines) == 1, err
    line = lines[0]
    if not case.argparse:
        assert line.startswith(f"lcmr-xr {case.cli(env)[0]}: error: "), err
    for word in case.words:
        assert word in line, f"{word!r} not in: {line}"
    for word in case.absent:
        assert word not in line, f"{word!r} in: {line}"
    if case.max_seconds is not None:
        assert elapsed < case.max_seconds, f"took {elapsed:.1f} s"
    assert snapshot(workdir) == before


@pytest.mark.parametrize("timeout", ["0", "-1", "nan", "inf"])
@pytest.mark.parametrize("scheduler", ["threads", "tcp"])
def test_cli_sweep_checks_connect_timeout_before_it_starts(timeout, scheduler, workdir, servers, capsys):
    """--connect-timeout was checked only when the client connected: the command had
    already opened the archive, built the sweep and printed "sweeping ..." (and with a
    local scheduler a bad value was never noticed).  Now it is one error line, first."""
    address = "threads" if scheduler == "threads" else f"tcp://127.0.0.1:{servers['unused']}"
    before = snapshot(workdir)
    status = cli.main(["sweep", "arc", "-o", "r.nc", "--window", "12", "--scheduler", address,
                       "--connect-timeout", timeout])
    err = capsys.readouterr().err
    assert status == 2
    assert err.splitlines() == [err.strip()] and err.startswith("lcmr-xr sweep: error: --connect-timeout"), err
    assert "positive number of seconds" in err and "--connect-timeout 10" in err, err
    assert snapshot(workdir) == before


@pytest.mark.parametrize("server", ["unused", "junk"])
def test_cli_sweep_says_sweeping_only_once_connected(server, workdir, servers, capsys):
    """lcmr-xr sweep printed "sweeping {...} on scheduler tcp://..." before it connected, so
    a scheduler that is not there looked like a sweep that started and failed.  Now the
    failed connection is the only line; with a local scheduler the line still comes first."""
    before = snapshot(workdir)
    status = cli.main(["sweep", "arc", "-o", "r.nc", "--window", "12", "--scheduler",
                       f"tcp://127.0.0.1:{servers[server]}", "--connect-timeout", "3"])
    err = capsys.readouterr().err
    assert status == 2
    assert err.splitlines() == [err.strip()] and err.startswith("lcmr-xr sweep: error: "), err
    assert "sweeping" not in err, err
    assert snapshot(workdir) == before


def test_catalogue_size():
    """The catalogue covers the issue's ~90 bad inputs (API, CLI and files)."""
    assert len(API) + len(CLI) >= 90
    assert len({c.id for c in API + CLI}) == len(API) + len(CLI)


def test_sweep_to_disk_flags_a_damaged_file_and_goes_on(workdir, small):
    """A task reading a damaged file failed, and with it ``sweep_to_disk`` (the command
    line's sweep): now that experiment is NaN and flagged, naming the file, the others
    identified; the archive is left as it was."""
    before = snapshot(workdir / "damagedarc2")
    sweep_to_disk(open_archive("damagedarc2"), "out.nc", window=[12], degrees=["2-2-2"],
                  experiments_per_task=2)
    result = open_dataset("out.nc")
    _flagged_experiment(1, ("damagedarc2/e1.nc is damaged", "Restore it from a copy"))(
        result, Env(small, None, {}, None))
    assert snapshot(workdir / "damagedarc2") == before



@pytest.mark.parametrize("how", ["moved out", "replaced by junk"])
def test_a_file_that_no_longer_opens_is_not_read_as_damaged(tmp_path, small, how):
    """The sweep read a file removed or moved out after the archive was opened (the remedy
    the library suggests for a damaged file), or replaced by one that is not HDF5, as NaN
    and reported its experiment as holding NaN ('remove or interpolate the bad samples'):
    a wrong diagnosis.  Only the values of a file that opens read as NaN (damaged); a file
    that does not open is refused, naming it, by the sweep as by a plain compute."""
    arc = tmp_path / "arc"
    save_archive(xr.concat([small, hdd.simulate(n_samples=400, noise=False, seed=2)],
                           dim="experiment").assign_coords(experiment=["e0", "e1"]), arc,
                 layout="files")
    ds = open_archive(arc)
    if how == "moved out":
        (arc / "e1.nc").rename(tmp_path / "e1-moved-out.nc")
        words = ("arc/e1.nc was removed or moved after the archive was opened",
                 "reopen the archive")
    else:
        (arc / "e1.nc").write_bytes(b"\x89HDF\r\n\x1a\n not really")
        words = ("arc/e1.nc: not a readable NetCDF file any more", "move it out")
    for run in (lambda: ds.r.values,
                lambda: sweep(ds, window=[12], degrees=["2-2-2"]).compute(),
                lambda: sweep(ds.astype("float64"), window=[12], degrees=["2-2-2"]).compute(),
                lambda: sweep_to_disk(ds, tmp_path / "out.nc", window=[12], degrees=["2-2-2"],
                                      progress=False)):
        with pytest.raises(ValueError) as info:
            run()
        assert all(w in str(info.value) for w in words), str(info.value)
        assert "NaN" not in str(info.value)


def test_a_file_this_user_cannot_read_is_named_with_the_permission_remedy(tmp_path, small, monkeypatch):
    """The branch of the archive's task reader for a file that exists but cannot be read
    by this user (no read permission after the archive was opened) was never run by a
    test.  It names the file and the remedy (read permission, or move it out), not NaN or
    damage.  As root, whom permissions do not stop, the refusal is simulated where the
    reader meets it (HDF5's open and os.access)."""
    from lcmr_xr.scaleout import directory

    arc = tmp_path / "arc"
    save_archive(xr.concat([small, hdd.simulate(n_samples=400, noise=False, seed=2)],
                           dim="experiment").assign_coords(experiment=["e0", "e1"]), arc,
                 layout="files")
    ds = open_archive(arc)
    locked = arc / "e1.nc"
    os.chmod(locked, 0)
    if os.geteuid() == 0:
        real_open_id, real_access = directory._open_id, os.access

        def open_id(path):
            if os.fspath(path) == os.fspath(locked):
                raise PermissionError(13, "Permission denied", os.fspath(path))
            return real_open_id(path)

        monkeypatch.setattr(directory, "_open_id", open_id)
        monkeypatch.setattr(directory.os, "access", lambda path, mode, *a, **k: (
            False if os.fspath(path) == os.fspath(locked) else real_access(path, mode, *a, **k)))
    try:
        for run in (lambda: ds.r.values,
                    lambda: sweep(ds, window=[12], degrees=["2-2-2"]).compute()):
            with pytest.raises(ValueError) as info:
                run()
            message = str(info.value)
            assert "arc/e1.nc cannot be opened for reading" in message, message
            assert "give this user read permission" in message and "NaN" not in message
    finally:
        os.chmod(locked, 0o644)


# ----------------------------------------------------------- interrupted writes (15.5)
def test_stale_temporary_of_a_dead_writer_is_removed_on_next_save(tmp_path, small):
    target = tmp_path / "exp.nc"
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True,
                          text=True, check=True)
    host = temporary_prefix(target).split(".")[-2].split("-")[0]
    stale = tmp_path / f".exp.nc.{host}-{int(dead.stdout)}.abcd1234.tmp"
    stale.write_bytes(b"x" * 1000)
    live = tmp_path / f"{temporary_prefix(target)}live5678.tmp"  # a writer that still runs: kept
    live.write_bytes(b"y")
    other = tmp_path / f".other.nc.{host}-{int(dead.stdout)}.abcd1234.tmp"  # another target's
    other.write_bytes(b"z")
    remote = tmp_path / f".exp.nc.0badf00d-{int(dead.stdout)}.abcd1234.tmp"  # another host's, recent
    remote.write_bytes(b"w")
    assert stale_temporaries(target) == [stale]
    save(small, target)
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["exp.nc", live.name, other.name,
                                                                 remote.name])


def test_old_untagged_temporary_is_removed_recent_one_kept(tmp_path, small):
    old = tmp_path / ".exp.nc.k2j4h5g6.tmp"  # the name older versions used
    old.write_bytes(b"x")
    os.utime(old, (time.time() - 7200, time.time() - 7200))
    recent = tmp_path / ".exp.nc.a1b2c3d4.tmp"
    recent.write_bytes(b"x")
    save(small, tmp_path / "exp.nc")
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["exp.nc", recent.name])


def test_sigkill_during_save_leaves_a_temporary_that_the_next_save_removes(tmp_path, small):
    """A real process killed with SIGKILL while ``save`` writes; the next save cleans up."""
    target = tmp_path / "exp.nc"
    script = textwrap.dedent(f"""
        import sys, time
        import numpy as np, xarray as xr
        import lcmr_xr
        real = xr.Dataset.to_netcdf
        def slow(self, path, *a, **k):
            real(self, path, *a, **k)
            print("written", flush=True)
            time.sleep(60)  # killed here, after the temporary holds the data
        xr.Dataset.to_netcdf = slow
        ds = xr.Dataset({{"a": ("x", np.ones(100_000))}})
        lcmr_xr.save(ds, r"{target}")
    """)
    env = {**os.environ, "PYTHONPATH": str(Path(lcmr_xr.__file__).parent.parent)}
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True, env=env)
    try:
        assert proc.stdout.readline().strip() == "written"
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    leftovers = [p for p in tmp_path.iterdir() if p.name.startswith(".exp.nc.")]
    assert len(leftovers) == 1 and leftovers[0].stat().st_size > 100_000
    assert not target.exists()
    save(small, target)
    assert [p.name for p in tmp_path.iterdir()] == ["exp.nc"]
    xr.testing.assert_identical(open_experiment(target), small)
