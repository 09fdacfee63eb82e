"""python-control exchange: to_frd / from_frd against exact FRFs and a loop closed in python-control."""

from __future__ import annotations

import sys

import numpy as np
import pytest
import xarray as xr

import lcmr_xr
from lcmr_xr import hdd

control = pytest.importorskip("control")  # the [control] extra; `make test` installs it


def _ss(system):
    """lcmr_xr's state space as a python-control one (same matrices and period)."""
    return control.ss(system.A, system.B, system.C, system.D, system.dt)


@pytest.fixture(scope="module")
def noiseless_frf():
    """Identified P of the noiseless HDD benchmark, DC left out (the VCM is infinite there)."""
    exp = hdd.simulate(n_samples=1200, noise=False, seed=0)
    return lcmr_xr.identify(exp, window=20).isel(frequency=slice(1, None))


def test_round_trip_values_labels_and_attrs(noiseless_frf):
    frd = lcmr_xr.to_frd(noiseless_frf)
    assert isinstance(frd, control.FrequencyResponseData)
    assert frd.dt == noiseless_frf.attrs["sampling_period"]
    assert frd.input_labels == ["vcm", "pzt"] and frd.output_labels == ["position"]
    assert frd.name == "P"
    P = noiseless_frf.P
    back = lcmr_xr.from_frd(frd, units=P.attrs["units"], long_name=P.attrs["long_name"])
    np.testing.assert_array_equal(back.values, P.values)  # bit for bit
    for dim in ("output", "input"):
        xr.testing.assert_identical(back[dim], P[dim])
    # rad/s and back costs at most one rounding of each frequency
    np.testing.assert_allclose(back.frequency, P.frequency, rtol=2.3e-16, atol=0)
    assert back.frequency.attrs == P.frequency.attrs
    expected = P.assign_coords(frequency=back.frequency).assign_attrs(
        sampling_period=noiseless_frf.attrs["sampling_period"])
    xr.testing.assert_identical(back, expected)
    # and the other way: the FRD from the DataArray needs no argument
    again = lcmr_xr.to_frd(back)
    np.testing.assert_array_equal(again.frdata, frd.frdata)
    np.testing.assert_array_equal(again.omega, frd.omega)


def test_exact_frf_matches_python_controls_own_evaluation():
    """omega in rad/s, dt = Th and (output, input, frequency) order: control agrees to rounding."""
    f = np.linspace(10.0, 50400.0, 97)
    truth = hdd.true_frf(f, case=3).assign_attrs(sampling_period=hdd.FAST_PERIOD)
    frd = lcmr_xr.to_frd(truth)
    reference = control.frd(_ss(hdd.plant(3)), 2 * np.pi * f)
    np.testing.assert_allclose(frd.omega, reference.omega, rtol=1e-15)
    np.testing.assert_allclose(frd.frdata, reference.frdata, rtol=1e-12)


def test_sensitivity_of_a_loop_closed_in_python_control(noiseless_frf):
    """S = 1 / (1 + P F C) with the identified P against the same loop with hdd.true_frf.

    The slow controller C is evaluated on the fast grid (C(exp(j w Tl)), the loop-shaping
    view of the multirate loop), the notch filters F at the fast rate.
    """
    P_id = lcmr_xr.to_frd(noiseless_frf)
    truth = hdd.true_frf(noiseless_frf.frequency).assign_attrs(sampling_period=hdd.FAST_PERIOD)
    P_true = lcmr_xr.to_frd(truth)
    omega, dt = P_id.omega, hdd.FAST_PERIOD
    C = control.frd(_ss(hdd.controller())(np.exp(1j * omega * hdd.SLOW_PERIOD), squeeze=False),
                    omega, dt=dt)
    notch = control.frd(_ss(hdd.notch_filters()), omega)
    one = control.frd(np.ones(omega.size), omega, dt=dt)
    loop, sensitivity = {}, {}
    for name, P in (("identified", P_id), ("true", P_true)):
        loop[name] = (P * notch * C).frdata[0, 0]
        sensitivity[name] = control.feedback(one, P * notch * C).frdata[0, 0]
        # python-control closed the loop as written: S = 1 / (1 + L)
        np.testing.assert_allclose(sensitivity[name], 1 / (1 + loop[name]), rtol=1e-12)
    S_id, S_true = sensitivity["identified"], sensitivity["true"]
    # S_id - S_true = S_id S_true (L_true - L_id): the difference is the identification error
    np.testing.assert_allclose(
        S_id - S_true, S_id * S_true * (loop["true"] - loop["identified"]), rtol=1e-9, atol=1e-15)
    f = omega / (2 * np.pi)
    relative = np.abs(S_id - S_true) / np.abs(S_true)
    # noiseless data: only the local models' approximation error remains (measured: median
    # 3e-4 from 1 kHz up, on both sides of the slow Nyquist frequency)
    for band in ((f >= 1e3) & (f < 25.2e3), f > 25.2e3):
        assert np.median(relative[band]) < 1e-3
    assert np.max(relative[f >= 1e3]) < 0.3


def test_from_frd_of_other_systems():
    omega = np.array([1.0, 10.0, 100.0])
    continuous = control.frd(control.tf([1.0], [1.0, 1.0]), omega)
    P = lcmr_xr.from_frd(continuous)
    assert "sampling_period" not in P.attrs and "units" not in P.attrs
    assert P.attrs["long_name"] == "frequency response"
    np.testing.assert_allclose(P.values[:, 0, 0], 1 / (1j * omega + 1), rtol=1e-14)
    assert P.output.values.tolist() == ["y[0]"] and P.input.values.tolist() == ["u[0]"]
    with pytest.raises(ValueError, match="no 'sampling_period'"):
        lcmr_xr.to_frd(P)  # continuous time: no dt to give the FRD
    with pytest.raises(TypeError, match=r"control.frd\(sys, omega\)"):
        lcmr_xr.from_frd(control.tf([1.0], [1.0, 1.0]))


def _small(**attrs):
    return xr.DataArray(
        np.array([1.0, 0.5j, -0.25])[:, None, None], dims=("frequency", "output", "input"),
        coords={"frequency": [0.0, 100.0, 200.0], "output": ["y"], "input": ["u"]},
        attrs=attrs)


def test_to_frd_refuses_bad_input():
    with pytest.raises(ValueError, match=r"isel\(experiment=0\)"):
        lcmr_xr.to_frd(xr.concat([_small(sampling_period=1e-3)] * 2, dim="experiment"))
    with pytest.raises(ValueError, match="pass sampling_period="):
        lcmr_xr.to_frd(_small())
    assert lcmr_xr.to_frd(_small(), sampling_period=1e-3).dt == 1e-3
    with pytest.raises(ValueError, match="contradicts"):
        lcmr_xr.to_frd(_small(sampling_period=1e-3), sampling_period=2e-3)
    with pytest.raises(ValueError, match="positive number of seconds"):
        lcmr_xr.to_frd(_small(), sampling_period=-1.0)
    with pytest.raises(ValueError, match=r"\[0, 125\] Hz"):
        lcmr_xr.to_frd(_small(sampling_period=4e-3))  # 200 Hz is above its Nyquist frequency
    with pytest.raises(ValueError, match="no variable 'Q'"):
        lcmr_xr.to_frd(_small(sampling_period=1e-3).to_dataset(name="P"), variable="Q")
    with pytest.raises(ValueError, match="expand_dims"):
        lcmr_xr.to_frd(_small(sampling_period=1e-3).isel(input=0, drop=True))
    with pytest.raises(TypeError, match="got ndarray"):
        lcmr_xr.to_frd(np.ones(3))


def test_missing_python_control_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "control", None)  # `import control` raises ImportError
    with pytest.raises(ImportError, match=r"pip install \"lcmr_xr\[control\]\""):
        lcmr_xr.to_frd(_small(sampling_period=1e-3))
    with pytest.raises(ImportError, match="python-control"):
        lcmr_xr.from_frd(object())
