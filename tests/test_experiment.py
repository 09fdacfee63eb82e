"""Experiment dataset constructor and validator (data contract lcmr-xr-1)."""

from __future__ import annotations

import dask
import numpy as np
import pytest
import xarray as xr
from dask.callbacks import Callback

from lcmr_xr.conventions import CONVENTIONS
from lcmr_xr.excitation import multisine
from lcmr_xr.experiment import experiment, validate_experiment

TH = 1e-3
F = 3


def _arrays(n=12, nu=2, ny=1, lead=(), seed=0):
    rng = np.random.default_rng(seed)
    return (rng.standard_normal(lead + (n, nu)), rng.standard_normal(lead + (n, nu)),
            rng.standard_normal(lead + (n // F, ny)))


def _valid():
    r, u, y = _arrays()
    return experiment(r, u, y, factor=F, sampling_period=TH, inputs=["vcm", "pzt"],
                      outputs=["position"], input_units="A", output_units="m",
                      attrs={"case": 2})


def test_experiment_from_numpy_follows_the_contract():
    ds = _valid()
    assert ds.attrs["conventions"] == CONVENTIONS and ds.attrs["factor"] == F
    assert ds.attrs["case"] == 2
    assert ds["r"].dims == ("time", "input") and ds["u"].dims == ("time", "input")
    assert ds["y"].dims == ("slow_time", "output")
    np.testing.assert_allclose(ds.time.values, np.arange(12) * TH)
    np.testing.assert_allclose(ds.slow_time.values, np.arange(4) * F * TH)
    assert ds.input.values.tolist() == ["vcm", "pzt"]
    assert ds.output.values.tolist() == ["position"]
    for name in ds.variables:
        assert "units" in ds[name].attrs and "long_name" in ds[name].attrs, name
    assert ds["r"].attrs["units"] == "A" and ds["y"].attrs["units"] == "m"
    assert ds.time.attrs["standard_name"] == "time" and ds.time.attrs["axis"] == "T"
    assert ds.slow_time.attrs["units"] == "s"


def test_experiment_default_labels_and_leading_experiment_dim():
    r, u, y = _arrays(lead=(2,))
    ds = experiment(r, u, y, factor=F, sampling_period=TH)
    assert ds["r"].dims == ("experiment", "time", "input")
    assert ds.input.values.tolist() == ["u0", "u1"] and ds.output.values.tolist() == ["y0"]
    assert ds.experiment.attrs["units"] == "1"
    np.testing.assert_array_equal(ds["y"].values, y)
    assert ds["y"].attrs["units"] == "1"


def test_experiment_from_dataarrays_renames_channel():
    r = multisine(12, sampling_period=TH, rms=[1.0, 2.0], seed=1, units="V")
    y = xr.DataArray(np.ones((4, 1)), dims=("slow_time", "output"),
                     coords={"output": ["pos"]}, attrs={"units": "m"})
    ds = experiment(r, 2 * r, y, factor=F)
    assert ds["r"].dims == ("time", "input")
    assert ds.input.values.tolist() == ["u0", "u1"]
    assert ds["r"].attrs["units"] == "V" and ds["y"].attrs["units"] == "m"
    np.testing.assert_array_equal(ds["u"].values, 2 * r.values)
    assert "crest_factor" not in ds.coords  # foreign coordinates are not carried along


def test_experiment_refuses_mismatched_labels_and_missing_period():
    r, u, y = _arrays()
    ra = xr.DataArray(r, dims=("time", "input"), coords={"input": ["a", "b"]})
    ua = xr.DataArray(u, dims=("time", "input"), coords={"input": ["a", "c"]})
    with pytest.raises(ValueError, match="same input labels"):
        experiment(ra, ua, y, factor=F, sampling_period=TH)
    with pytest.raises(ValueError, match="sampling_period=Th"):
        experiment(r, u, y, factor=F)
    with pytest.raises(ValueError, match="2 labels but the data has 1"):
        experiment(r, u, y, factor=F, sampling_period=TH, outputs=["a", "b"])
    with pytest.raises(ValueError, match="must not set 'factor'"):
        experiment(r, u, y, factor=F, sampling_period=TH, attrs={"factor": 2})
    ut = xr.DataArray(u, dims=("time", "input"), coords={"time": np.arange(12) * 2 * TH})
    rt = xr.DataArray(r, dims=("time", "input"), coords={"time": np.arange(12) * TH})
    with pytest.raises(ValueError, match="different 'time' coordinates"):
        experiment(rt, ut, y, factor=F)
    with pytest.raises(ValueError, match="N=12.*M=5"):
        experiment(r, u, np.ones((5, 1)), factor=F, sampling_period=TH)


def _drop_attr(ds, key):
    out = ds.copy()
    del out.attrs[key]
    return out


def _with_attr(ds, **kw):
    out = ds.copy()
    out.attrs.update(kw)
    return out


def _replace(ds, name, values):
    out = ds.copy()
    out[name] = out[name].copy(data=values)
    return out


def _shift_time(ds, dim, values):
    return ds.assign_coords({dim: (dim, values, ds[dim].attrs)})


def _relabel(ds, dim, labels):
    return ds.assign_coords({dim: (dim, labels, ds[dim].attrs)})


_N = 12
BAD = {
    "no conventions": (lambda ds: _drop_attr(ds, "conventions"), "'conventions' is missing"),
    "foreign conventions": (lambda ds: _with_attr(ds, conventions="CF-1.8"), "expected 'lcmr-xr-1'"),
    "no factor": (lambda ds: _drop_attr(ds, "factor"), "'factor' is missing"),
    "factor zero": (lambda ds: _with_attr(ds, factor=0), "positive integer"),
    "factor fraction": (lambda ds: _with_attr(ds, factor=2.5), "positive integer"),
    "factor mismatch": (lambda ds: _with_attr(ds, factor=2), r"N=12 .*M=4 .*F=2"),
    "factor not dividing N": (lambda ds: _with_attr(ds, factor=5), "not a multiple of factor F=5"),
    "missing r": (lambda ds: ds.drop_vars("r"), "variable 'r' is missing"),
    "missing y": (lambda ds: ds.drop_vars("y"), "variable 'y' is missing"),
    "y on fast time": (
        lambda ds: ds.assign(y=ds["r"].isel(input=[0]).rename(input="output")
                             .assign_coords(output=["position"])),
        r"'y' has dims .*missing \['slow_time'\]",
    ),
    "r with output dim": (
        lambda ds: ds.assign(r=ds["r"].expand_dims(output=ds.output.values)),
        "include \\['output'\\]",
    ),
    "missing time coord": (lambda ds: ds.drop_vars("time"), "coordinate 'time' is missing"),
    "missing input labels": (lambda ds: ds.drop_vars("input"), "'input' is missing"),
    "duplicate labels": (lambda ds: _relabel(ds, "input", ["a", "a"]), "duplicates"),
    "empty label": (lambda ds: _relabel(ds, "input", ["a", ""]), "non-empty strings"),
    "numeric labels": (lambda ds: _relabel(ds, "output", [0]), "non-empty strings"),
    "time not at 0": (lambda ds: _shift_time(ds, "time", ds.time.values + 0.5), "starts at 0.5"),
    "slow time not at 0": (
        lambda ds: _shift_time(ds, "slow_time", ds.slow_time.values + TH), "starts at 0.001"
    ),
    "uneven time": (
        lambda ds: _shift_time(ds, "time", np.r_[0, np.cumsum(np.r_[[TH] * 5, 2 * TH, [TH] * 5])]),
        "not evenly spaced",
    ),
    "slow spacing not F times fast": (
        lambda ds: _shift_time(ds, "slow_time", np.arange(4) * 2 * TH), "factor \\* \\(time spacing\\)"
    ),
    "NaN in u": (lambda ds: _replace(ds, "u", np.where(np.arange(_N)[:, None] == 3, np.nan, ds.u.values)),
                 "NaN or inf"),
    "inf in y": (lambda ds: _replace(ds, "y", np.full((4, 1), np.inf)), "NaN or inf"),
    "complex r": (lambda ds: ds.assign(r=ds["r"] * (1 + 1j)), "complex"),
    "string y": (lambda ds: ds.assign(y=ds["y"].astype(str)), "non-numeric"),
    "bool u": (lambda ds: ds.assign(u=(ds["u"] > 0).assign_attrs(ds["u"].attrs)), "non-numeric"),
    "missing units": (
        lambda ds: ds.assign(r=ds["r"].drop_attrs()), "'units' or 'long_name'"
    ),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_validate_experiment_refuses(case):
    mutate, match = BAD[case]
    bad = mutate(_valid())
    with pytest.raises(ValueError, match=match) as info:
        validate_experiment(bad)
    assert "invalid experiment dataset" in str(info.value)


def test_validate_experiment_accepts_valid_and_returns_same_object():
    ds = _valid()
    assert validate_experiment(ds) is ds
    with pytest.raises(TypeError, match="xarray.Dataset"):
        validate_experiment(ds["r"])


class _CountComputes(Callback):
    def __init__(self):
        super().__init__()
        self.count = 0

    def _start(self, dsk):
        self.count += 1


def test_validate_experiment_on_dask_computes_once_and_stays_lazy():
    r, u, y = _arrays(lead=(4,))
    ds = experiment(r, u, y, factor=F, sampling_period=TH).chunk({"experiment": 1})
    with _CountComputes() as counter:
        out = validate_experiment(ds)
    assert counter.count == 1
    assert dask.is_dask_collection(out["r"].data) and dask.is_dask_collection(out["y"].data)
    poisoned = ds.copy()
    poisoned["y"] = ds["y"].where(ds.experiment != 2)  # NaN in one experiment, still lazy
    with pytest.raises(ValueError, match=r"y contains 4 NaN or inf value\(s\) \(experiment=2, output='y0'\)"):
        validate_experiment(poisoned)


def test_validate_experiment_on_dask_says_where_the_bad_samples_are():
    """Lazy data with NaN were refused naming only the variables (``['u'] contain NaN or
    inf``): not which experiment, channel or time.  Now the message is the one for the
    same data in memory (count, channels, experiments, samples and time range)."""
    r, u, y = _arrays(lead=(4,))
    ds = experiment(r, u, y, factor=F, sampling_period=TH)
    u_bad = ds["u"].values.copy()
    u_bad[2, 5:8, 1] = np.nan
    u_bad[3, 7, 1] = np.inf
    bad = ds.assign(u=ds["u"].copy(data=u_bad))
    with pytest.raises(ValueError) as eager:
        validate_experiment(bad)
    for chunks in ({"experiment": 1}, {"time": 4}):
        with pytest.raises(ValueError) as lazy:
            validate_experiment(bad.chunk(chunks))
        assert str(lazy.value) == str(eager.value)
    message = str(eager.value)
    for words in ("u contains 4 NaN or inf value(s)", "experiment in [2, 3]", f"input='{ds.input.values[1]}'",
                  "at 3 of its", f"from time = {5 * TH:.6g} s to {7 * TH:.6g} s", "(indices 5..7)"):
        assert words in message, message


def test_experiment_keeps_dask_inputs_lazy():
    r, u, y = _arrays()
    rd = xr.DataArray(r, dims=("time", "input")).chunk({"time": 6})
    ds = experiment(rd, u, y, factor=F, sampling_period=TH)
    assert dask.is_dask_collection(ds["r"].data)


def test_time_spacings_must_agree_to_1e_6_relative_without_absolute_slack():
    # Sample times of fast sampled-data systems are ~10 us: an absolute slack of 1e-8 s
    # (np.isclose's default) would be 0.1 % of them, and let a 0.05 % mismatch through.
    th = 1e-5
    r = np.ones((8, 1))
    ds = experiment(r, r, np.ones((4, 1)), factor=2, sampling_period=th)
    with pytest.raises(ValueError, match="'slow_time' is spaced by 2.001.*e-05 s.*= 2e-05 s"):
        validate_experiment(ds.assign_coords(slow_time=ds.slow_time * 1.0005))
    validate_experiment(ds.assign_coords(slow_time=ds.slow_time * (1 + 1e-9)))  # rounding: fine
    rt = xr.DataArray(r, dims=("time", "input"), coords={"time": np.arange(8) * th})
    with pytest.raises(ValueError, match="disagrees with the spacing"):
        experiment(rt, rt, np.ones((4, 1)), factor=2, sampling_period=th * 1.0005)
