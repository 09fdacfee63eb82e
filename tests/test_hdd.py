"""Tests of the HDD benchmark (lcmr_xr.hdd) and the labelled closed-loop simulation."""

from __future__ import annotations

import dask.array
import numpy as np
import pytest
import xarray as xr

import lcmr_xr.hdd as hdd
from _multirate_oracle import simulate_multirate_oracle
from lcmr_xr.experiment import validate_experiment
from lcmr_xr.hdd.disturbances import NOISE_SCALE, UNIFORM_STD
from lcmr_xr.hdd.plants import PZT_DAMPINGS, PZT_FREQS, PZT_MODAL_GAINS, TEMPERATURES
from lcmr_xr.kernels.lti import (dc_gain, frequency_response, simulate_lti, simulate_multirate,
                                 static_gain, tf_q_inverse)
from lcmr_xr.simulation import simulate_closed_loop

TH = 1 / 100800


def continuous_modal(s, gains, freqs, dampings):
    w = 2 * np.pi * np.asarray(freqs)
    return np.sum(np.asarray(gains) / (s**2 + 2 * np.asarray(dampings) * w * s + w**2))


def continuous_vcm(f_hz):
    s = 2j * np.pi * f_hz
    return 3.7976e7 * continuous_modal(
        s, [1, -1.0, 0.1, -0.1, 0.04, -0.7, -0.2, -1.0, 3.0, -3.2, 2.1, -1.5, 2.0, -0.2, 0.3, -0.5],
        [0, 5300, 6100, 6500, 8050, 9600, 14800, 17400, 21000, 26000, 26600, 29000, 32200, 38300,
         43300, 44800],
        [0, 0.02, 0.04, 0.02, 0.01, 0.03, 0.01, 0.02, 0.02, 0.012, 0.007, 0.01, 0.03, 0.01, 0.01,
         0.01])


def continuous_pzt(f_hz):
    s = 2j * np.pi * f_hz
    k = [-0.005, -0.01, -0.1, 0.8, 0.3, -0.25, 0.3, 10.0]
    f = [14800, 21500, 28000, 40200, 42050, 44400, 46500, 100000]
    z = [0.025, 0.03, 0.05, 0.008, 0.008, 0.01, 0.02, 0.3]
    return continuous_modal(s, k, f, z) / abs(continuous_modal(0.0, k, f, z))


# ----------------------------------------------------------------------------- plants


def test_zoh_frf_approaches_the_continuous_plants_at_low_frequency():
    # ZOH: P_d(exp(jwT)) = P(jw) exp(-jwT/2) (1 + O((wT)^2)) for the VCM, dominated by
    # Kp/s^2.  The PZT's 100 kHz mode sits next to the fast sampling frequency, so its
    # aliases (the ZOH sum over P(j(w + 2 pi k / T))) add an O(wT) term: looser there.
    f = np.array([20.0, 100.0, 300.0])
    P = hdd.true_frf(f).values[:, 0, :] * np.exp(1j * np.pi * f * TH)[:, None]
    for i, fi in enumerate(f):
        wT = 2 * np.pi * fi * TH
        np.testing.assert_allclose(P[i, 0], continuous_vcm(fi), rtol=5 * wT**2)
        np.testing.assert_allclose(P[i, 1], continuous_pzt(fi), rtol=wT / 2)


def test_pzt_frf_near_a_resonance_follows_the_continuous_model_up_to_aliasing():
    # near 40.2 kHz the PZT mode dominates; the ZOH response is the sampled continuous one to
    # within the hold's sinc and the half-sample delay (a few percent), not a wrong model
    f = 40200.0
    wT = 2 * np.pi * f * TH
    hold = np.sinc(f * TH) * np.exp(-1j * wT / 2)
    ratio = hdd.true_frf([f]).values[0, 0, 1] / (continuous_pzt(f) * hold)
    assert abs(ratio - 1) < 0.1


@pytest.mark.parametrize("case", range(1, 10))
def test_pzt_dc_gain_is_the_case_gain(case):
    gain = hdd.CASES[case][1]
    np.testing.assert_allclose(dc_gain(hdd.pzt_plant(case)), [[gain]], rtol=1e-12)
    np.testing.assert_allclose(hdd.true_frf([0.0], case=case).sel(input="pzt").values.real,
                               [[gain]], rtol=1e-12)


def test_temperature_cases_move_the_pzt_poles():
    for case in (1, 3):
        _, f_scale, z_scale = TEMPERATURES[hdd.CASES[case][0]]
        w = 2 * np.pi * PZT_FREQS * f_scale
        z = PZT_DAMPINGS * z_scale
        s = np.concatenate([-z * w + 1j * w * np.sqrt(1 - z * z), -z * w - 1j * w * np.sqrt(1 - z * z)])
        expected = np.sort_complex(np.exp(s * TH))
        got = np.sort_complex(np.linalg.eigvals(hdd.pzt_plant(case).A))
        np.testing.assert_allclose(got, expected, rtol=1e-10)
    assert len(PZT_MODAL_GAINS) == 8


def test_vcm_rigid_body_dominates_at_low_frequency():
    # Kp / s^2 at 10 Hz, within the flexible modes' static contribution (< 1 %)
    P = hdd.true_frf([10.0]).sel(input="vcm").values[0, 0]
    rigid = 3.7976e7 / (2j * np.pi * 10.0)**2
    assert abs(P / rigid - 1) < 1e-2


def test_true_frf_labels_and_units():
    f = xr.DataArray(np.array([0.0, 1000.0, 50400.0]), dims="frequency")
    P = hdd.true_frf(f, case=4)
    assert P.dims == ("frequency", "output", "input")
    assert P.input.values.tolist() == ["vcm", "pzt"] and P.output.values.tolist() == ["position"]
    assert P.attrs["units"] == "m" and P.frequency.attrs["units"] == "Hz"
    for c in ("frequency", "output", "input"):
        assert "long_name" in P[c].attrs and "units" in P[c].attrs
    np.testing.assert_allclose(P.values[1:], frequency_response(hdd.plant(4), f.values[1:]),
                               rtol=1e-14)
    assert np.isinf(P.values[0, 0, 0])  # the VCM's double integrator at DC
    assert P.values[0, 0, 1] == pytest.approx(1.05, rel=1e-12)  # the PZT column stays finite
    with pytest.raises(ValueError, match="cases 1..9"):
        hdd.true_frf([0.0], case=10)


def test_true_frf_at_negative_and_aliased_frequencies():
    """A real system: P(-f) = conj(P(f)), and P(f + 1/Th) = P(f) (the discrete-time FRF is
    periodic); both against C (zI - A)^-1 B + D solved directly at z = exp(2j pi f Th)."""
    f = np.array([-44400.0, -1000.0, -20.0, 20.0, 1000.0, 44400.0, 1 / TH - 1000.0])
    P = hdd.true_frf(f).values
    np.testing.assert_allclose(P[:3], np.conj(P[[5, 4, 3]]), rtol=1e-12)
    np.testing.assert_allclose(P[-1], P[1], rtol=1e-9)
    for column, sys in enumerate((hdd.vcm_plant(), hdd.pzt_plant())):
        for i, fi in enumerate(f):
            z = np.exp(2j * np.pi * fi * TH)
            want = sys.C @ np.linalg.solve(z * np.eye(sys.A.shape[0]) - sys.A, sys.B) + sys.D
            np.testing.assert_allclose(P[i, :, column], want[:, 0], rtol=1e-9)


@pytest.mark.parametrize("bad, error, words", [
    ([1000.0, np.nan], ValueError, ("1 NaN or inf value(s) of 2", "index 1", "drop them")),
    (xr.DataArray([np.inf, 1.0], dims="frequency"), ValueError, ("NaN or inf", "index 0")),
    (["1000"], TypeError, ("real numbers in Hz",)),
    ([1000j], TypeError, ("real numbers in Hz",)),
])
def test_true_frf_refuses_nan_and_non_numbers(bad, error, words):
    with pytest.raises(error) as info:
        hdd.true_frf(bad)
    for word in words:
        assert word in str(info.value), str(info.value)


# ----------------------------------------------------------------------------- control


def test_controllers_are_the_papers_transfer_functions():
    f = np.array([0.0, 1000.0, 12000.0, 25000.0])
    q = np.exp(-2j * np.pi * f * hdd.SLOW_PERIOD)
    cv = (0.65 + 0.020 * q - 0.63 * q**2) / (1 - 1.4 * q + 0.51 * q**2)
    cp = (0.01346 + 0.01346 * q) / (1 - 0.8825 * q)
    C = frequency_response(hdd.controller(), f)
    np.testing.assert_allclose(C[:, 0, 0], cv, rtol=1e-12)
    np.testing.assert_allclose(C[:, 1, 0], cp, rtol=1e-12)
    assert hdd.controller().dt == hdd.SLOW_PERIOD == 2 * hdd.FAST_PERIOD


def test_notch_filters_have_unit_dc_gain_and_notch_their_resonances():
    F = hdd.notch_filters()
    np.testing.assert_allclose(dc_gain(F), np.eye(2), atol=1e-12)
    Fv = np.abs(frequency_response(hdd.vcm_filter(), [8000.0, 21000.0, 44800.0])[:, 0, 0])
    Fp = np.abs(frequency_response(hdd.pzt_filter(), [21500.0, 40000.0])[:, 0, 0])
    assert np.all(Fv < 0.6) and np.all(Fp < 0.2)


@pytest.mark.parametrize("case", range(1, 10))
def test_closed_loop_is_stable_for_all_nine_cases(case):
    loop = hdd.closed_loop(case)
    assert 0.95 < loop.spectral_radius < 0.995  # stable, with the slow rigid-body closed-loop pole


# ----------------------------------------------------------------------------- disturbances


def test_fan_vibration_std_is_near_the_benchmarks_2_9_nm():
    analytic = hdd.stationary_std(hdd.fan_filter(), NOISE_SCALE * UNIFORM_STD)[0]
    assert analytic == pytest.approx(2.9e-9, rel=0.05)
    # the analytic value agrees with the FRF (Parseval on a fine grid)
    f = (np.arange(2**16) + 0.5) / 2**16 * 0.5 / TH
    H = frequency_response(hdd.fan_filter(), f)[:, 0, 0]
    assert analytic == pytest.approx(NOISE_SCALE * UNIFORM_STD * np.sqrt(np.mean(np.abs(H)**2)),
                                     rel=1e-3)
    # simulated: stationary from the first sample (short records, many seeds)
    d = np.array([hdd.fan_vibration(400, np.random.default_rng(s)) for s in range(200)])
    assert np.sqrt(np.mean(d[:, :50]**2)) == pytest.approx(analytic, rel=0.08)
    assert np.sqrt(np.mean(d**2)) == pytest.approx(analytic, rel=0.06)


def test_rotational_vibration_filter_matches_continuous_formula_at_low_frequency():
    f = np.array([1.0, 10.0, 100.0, 250.0])
    s = 2j * np.pi * f
    w1, w2 = 2 * np.pi * 2000, 2 * np.pi * 250
    cont = (3e-10 * (s + 2 * np.pi * 50) / (s + 2 * np.pi * 3)
            * (s**2 + 2 * 20 * w1 * s + w1**2) / (s**2 + 2 * 0.1 * w2 * s + w2**2))
    got = frequency_response(hdd.rotational_filter(), f)[:, 0, 0] * np.exp(1j * np.pi * f * TH)
    np.testing.assert_allclose(got, cont, rtol=1e-3)
    d = hdd.rotational_vibration(20000, np.random.default_rng(0))
    assert np.all(np.isfinite(d)) and np.std(d) > 0


def test_repeatable_runout_spectrum_and_std():
    d = hdd.repeatable_runout(3 * 420, np.random.default_rng(5))
    np.testing.assert_allclose(d[420:840], d[:420], rtol=0, atol=1e-25)
    np.testing.assert_allclose(np.std(d[:420]), 0.05e-9 * np.sqrt(209 / 2), rtol=1e-12)
    assert np.std(d[:420]) == pytest.approx(0.511e-9, rel=1e-3)
    X = np.abs(np.fft.rfft(d[:420]))
    np.testing.assert_allclose(X[1:210], 420 / 2 * 0.05e-9, rtol=1e-10)
    assert X[0] < 1e-22 and X[210] < 1e-22


def test_disturbances_refuse_a_seed_instead_of_a_generator():
    with pytest.raises(TypeError, match="default_rng"):
        hdd.fan_vibration(10, 0)


# ----------------------------------------------------------------------------- simulation


def test_fast_simulator_matches_oracle_on_the_hdd_loop_with_disturbances():
    N = 400
    rng = np.random.default_rng(1)
    r = rng.standard_normal((N, 2)) * [8e-8, 3.6e-9]
    d_u = np.zeros((N, 2))
    d_u[:, 0] = hdd.rotational_vibration(N, rng)
    d_y = hdd.fan_vibration(N, rng)[:, None]
    ref = hdd.repeatable_runout(N // 2, rng)[:, None]
    expected = simulate_multirate_oracle(hdd.plant(), hdd.controller(), hdd.notch_filters(), 2,
                                         r, d_u, d_y, ref)
    got = simulate_multirate(hdd.closed_loop(), r, d_u, d_y, ref)
    for a, b in zip(got, expected):
        assert np.max(np.abs(a - b)) / np.max(np.abs(b)) < 1e-10


@pytest.fixture(scope="module")
def paper_experiment():
    return hdd.simulate(fast_output=True)


def test_pzt_stroke_in_the_papers_experiment(paper_experiment):
    peak = float(np.abs(paper_experiment.pzt_displacement).max())
    assert 35e-9 < peak < hdd.PZT_STROKE_LIMIT  # paper: 48.7 nm for its own realisation
    peaks = [float(np.abs(hdd.simulate(seed=s, fast_output=True).pzt_displacement).max())
             for s in range(1, 7)]
    assert 38e-9 < np.median(peaks) < 47e-9  # the benchmark file: about 41-46 nm


def test_simulated_experiment_is_a_valid_dataset(paper_experiment):
    ds = paper_experiment
    validate_experiment(ds)
    assert ds.sizes == {"time": 3600, "slow_time": 1800, "input": 2, "output": 1}
    assert ds.input.values.tolist() == ["vcm", "pzt"]
    assert ds.attrs["case"] == 2 and ds.attrs["seed"] == 0 and ds.attrs["noise"] == 1
    np.testing.assert_array_equal(ds.attrs["rms"], [8.0e-8, 3.6e-9])
    assert "benchmark" in ds.attrs
    np.testing.assert_allclose(np.sqrt((ds.r**2).mean("time")), [8.0e-8, 3.6e-9], rtol=1e-12)
    np.testing.assert_array_equal(ds.y.values, ds.y_fast.values[::2])
    assert ds.y.attrs["units"] == "m" and ds.u.attrs["units"] == "1"
    for name in list(ds.variables):
        assert "units" in ds[name].attrs and "long_name" in ds[name].attrs, name
    # u = r + filtered control: the excitation is in it, but the loop changes it
    assert not np.allclose(ds.u, ds.r)
    # pzt displacement is Pp applied to the recorded PZT input
    np.testing.assert_allclose(
        ds.pzt_displacement.values,
        simulate_lti(hdd.pzt_plant(), ds.u.sel(input="pzt").values[:, None])[:, 0], rtol=1e-12)


def test_simulate_is_reproducible_from_the_seed():
    a = hdd.simulate(n_samples=400, seed=3)
    b = hdd.simulate(n_samples=400, seed=3)
    c = hdd.simulate(n_samples=400, seed=4)
    quiet = hdd.simulate(n_samples=400, seed=3, noise=False)
    xr.testing.assert_identical(a, b)
    assert not np.allclose(a.r, c.r)
    np.testing.assert_array_equal(quiet.r, a.r)  # the excitation does not depend on noise
    assert not np.allclose(quiet.y, a.y) and quiet.attrs["noise"] == 0


def test_noise_free_output_is_linear_in_the_excitation():
    a = hdd.simulate(n_samples=400, seed=2, noise=False, rms=(8.0e-8, 3.6e-9))
    b = hdd.simulate(n_samples=400, seed=2, noise=False, rms=(16.0e-8, 7.2e-9))
    np.testing.assert_allclose(b.y, 2 * a.y, rtol=1e-12, atol=1e-24)


@pytest.mark.parametrize("periods", [None, 2])
def test_disturbances_taken_one_at_a_time_add_up_to_the_benchmark(periods):
    # The loop is linear and each disturbance draws from its own stream: the responses to
    # the subsets add up to the full benchmark's, and the excitation is unchanged.
    kw = dict(n_samples=400, seed=5, periods=periods)
    full, quiet = hdd.simulate(**kw), hdd.simulate(noise=False, **kw)
    parts = [hdd.simulate(disturbances=[d], **kw) for d in hdd.DISTURBANCES]
    for name in ("u", "y"):
        total = quiet[name] + sum(p[name] - quiet[name] for p in parts)
        scale = float(np.abs(full[name]).max())
        np.testing.assert_allclose(total, full[name], rtol=0, atol=1e-12 * scale)
        for p in parts:  # each disturbance moves the signal on its own
            assert float(np.abs(p[name] - quiet[name]).max()) > 1e-6 * scale
    for p, d in zip(parts, hdd.DISTURBANCES):
        np.testing.assert_array_equal(p.r, full.r)
        assert p.attrs["disturbances"] == d and p.attrs["noise"] == 1
    assert full.attrs["disturbances"] == "rotational fan runout"
    assert "disturbances" not in quiet.attrs
    two = hdd.simulate(disturbances=["runout", "fan"], **kw)  # listed in the benchmark's order
    assert two.attrs["disturbances"] == "fan runout"


def test_simulate_refuses_bad_disturbances():
    with pytest.raises(ValueError, match=r"unknown disturbances \['wind'\]; choose from"):
        hdd.simulate(n_samples=400, disturbances=["fan", "wind"])
    with pytest.raises(TypeError, match=r"pass \['fan'\] for one"):
        hdd.simulate(n_samples=400, disturbances="fan")
    with pytest.raises(TypeError, match="sequence of names"):
        hdd.simulate(n_samples=400, disturbances=3)
    with pytest.raises(ValueError, match="twice"):
        hdd.simulate(n_samples=400, disturbances=["fan", "fan"])
    with pytest.raises(ValueError, match="noise=False switches them all off"):
        hdd.simulate(n_samples=400, noise=False, disturbances=["fan"])
    quiet = hdd.simulate(n_samples=400, noise=False)
    for same in (dict(noise=False, disturbances=[]), dict(disturbances=[]),
                 dict(noise=False, disturbances=["runout", "rotational", "fan"])):
        xr.testing.assert_identical(hdd.simulate(n_samples=400, **same), quiet)


def test_simulate_refuses_bad_settings():
    with pytest.raises(ValueError, match="multiple of the factor 2"):
        hdd.simulate(n_samples=401)
    with pytest.raises(ValueError, match="cases 1..9"):
        hdd.simulate(case=0)


# ----------------------------------------------------------------------------- labelled wrapper


def _small_loop():
    plant = tf_q_inverse([0.0, 0.5], [1.0, -0.9], dt=0.5)
    return plant, static_gain(0.2, dt=1.0)


def test_labelled_wrapper_equals_kernel_and_broadcasts():
    plant, controller = _small_loop()
    rng = np.random.default_rng(0)
    r = xr.DataArray(rng.standard_normal((3, 16, 1)), dims=("experiment", "time", "input"),
                     coords={"time": np.arange(16) * 0.5}, attrs={"units": "V"})
    d_y = xr.DataArray(rng.standard_normal((16, 1)), dims=("time", "output"),
                       coords={"output": ["pos"]}, attrs={"units": "mm"})
    ds = simulate_closed_loop(plant, controller, None, 2, r, d_y=d_y, fast_output=True)
    from lcmr_xr.kernels.lti import multirate_closed_loop
    loop = multirate_closed_loop(plant, controller, None, 2)
    ref = simulate_multirate(loop, r.values, d_y=d_y.values)
    np.testing.assert_allclose(ds.u.transpose("experiment", "time", "input").values, ref.u)
    np.testing.assert_allclose(ds.y.transpose("experiment", "slow_time", "output").values,
                               ref.y_slow)
    assert ds.output.values.tolist() == ["pos"]
    assert ds.y.attrs["units"] == "mm" and ds.u.attrs["units"] == "V"
    assert ds.y_fast.attrs["units"] == "mm"
    np.testing.assert_allclose(ds.slow_time.values, np.arange(8) * 1.0)


def test_labelled_wrapper_stays_lazy_on_dask():
    plant, controller = _small_loop()
    r = xr.DataArray(np.ones((4, 16, 1)), dims=("experiment", "time", "input")).chunk(
        {"experiment": 2})
    ds = simulate_closed_loop(plant, controller, None, 2, r)
    assert dask.array.Array is type(ds.u.data) or hasattr(ds.u.data, "dask")
    np.testing.assert_allclose(ds.u.values, simulate_closed_loop(plant, controller, None, 2,
                                                                 r.compute()).u.values)


def test_labelled_wrapper_refuses_bad_signals():
    plant, controller = _small_loop()
    with pytest.raises(TypeError, match="DataArray"):
        simulate_closed_loop(plant, controller, None, 2, np.ones((8, 1)))
    with pytest.raises(ValueError, match="missing"):
        simulate_closed_loop(plant, controller, None, 2, xr.DataArray(np.ones((8, 1)),
                                                                      dims=("t", "input")))
    bad_time = xr.DataArray(np.ones((8, 1)), dims=("time", "input"),
                            coords={"time": np.arange(8) * 0.25})
    with pytest.raises(ValueError, match="spaced by 0.25 s but the plant is sampled"):
        simulate_closed_loop(plant, controller, None, 2, bad_time)
    with pytest.raises(ValueError, match="r has 2 inputs but the plant has 1"):
        simulate_closed_loop(plant, controller, None, 2,
                             xr.DataArray(np.ones((8, 2)), dims=("time", "input")))
