"""``identify``: the paper's Procedure 1 against closed loops whose FRF is known exactly."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from scipy import signal

import lcmr_xr
from lcmr_xr.experiment import experiment
from lcmr_xr.identification import identify, identify_single_rate
from lcmr_xr.identification.lifted_system import frf_from_first_block_row, lifted_frf
from lcmr_xr.kernels import ltisim
from lcmr_xr.kernels.excitation import random_phase_multisine
from _closed_loop_fd import lifted_loop, matrix_frf, periodic_experiment

TH = 1e-3  # fast period, s

# A lightly damped second-order plant (poles 0.8 +- 0.5j, |p| = 0.94), a lead-lag slow
# controller and a first-order fast filter: a stable loop, low order, so a local rational
# model of degree 3 represents the lifted closed loop well.
PLANT = ([0.0, 0.10, 0.06], [1.0, -1.6, 0.89])
CONTROLLER = ([0.25, -0.15], [1.0, -0.3])
FILTER = ([0.6, 0.0], [1.0, -0.4])


def _ss(tf, dt):
    return ltisim.tf_q_inverse(tf[0], tf[1], dt)


def _siso_loop(factor):
    plant = _ss(PLANT, TH)
    controller = _ss(CONTROLLER, factor * TH)
    filt = _ss(FILTER, TH)
    return ltisim.multirate_closed_loop(plant, controller, filt, factor)


def _true_frf(tf, n):
    w = 2 * np.pi * np.arange(n // 2 + 1) / n
    return signal.freqz(tf[0], tf[1], worN=w)[1]


def _simulate(loop, r, factor, d_y=None):
    out = ltisim.simulate_multirate(loop, r, d_y=d_y)
    return experiment(r, out.u, out.y_slow, factor=factor, sampling_period=TH)


def _median_rel(est, true):
    return float(np.median(np.abs(est - true) / np.abs(true)))


@pytest.mark.parametrize("factor", [2, 3, 4])
def test_noiseless_transient_recovery_siso(factor):
    """Time-domain simulation from rest (transient included), one period of a multisine."""
    n = 240 * factor
    rng = np.random.default_rng(factor)
    r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, rng)
    exp = _simulate(_siso_loop(factor), r, factor)
    frf = identify(exp, window=15, degrees=(3, 3, 3))
    truth = _true_frf(PLANT, n)
    est = frf.P.isel(output=0, input=0).values
    assert frf.P.dims == ("frequency", "output", "input")
    assert frf.sizes["frequency"] == n // 2 + 1
    assert _median_rel(est, truth) < 1e-4
    # LPM on the same data is worse than LRM, but still a usable estimate
    lpm = identify(exp, method="lpm", window=15)
    assert _median_rel(lpm.P.isel(output=0, input=0).values, truth) > _median_rel(est, truth)


@pytest.mark.parametrize("factor", [2, 3])
def test_periodic_steady_state_recovers_lifted_G(factor):
    """Frequency-domain construction: S and PS_1 themselves are recovered."""
    n = 200 * factor
    m = n // factor
    P = matrix_frf([[PLANT]], n)
    C = matrix_frf([[CONTROLLER]], m)
    Fi = matrix_frf([[FILTER]], n)
    r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, np.random.default_rng(7))
    u, y = periodic_experiment(P, C, Fi, factor, r)
    exp = experiment(r, u, y, factor=factor, sampling_period=TH)
    frf = identify(exp, window=12)
    S, PS1, _ = lifted_loop(P, C, Fi, factor)
    S_est = frf.S.values.reshape(m, factor, factor)
    PS_est = frf.PS.values.reshape(m, 1, factor)
    assert np.median(np.abs(S_est - S)) / np.median(np.abs(S)) < 1e-5
    assert np.median(np.abs(PS_est - PS1)) / np.median(np.abs(PS1)) < 1e-5
    assert _median_rel(frf.P.values[:, 0, 0], P[: n // 2 + 1, 0, 0]) < 1e-4


def test_mimo_2x2_plant():
    factor = 2
    n = 960
    plant_tfs = [[([0.0, 0.10, 0.06], [1.0, -1.6, 0.89]), ([0.0, 0.03], [1.0, -0.7])],
                 [([0.0, -0.02], [1.0, -0.5]), ([0.0, 0.08, 0.05], [1.0, -1.2, 0.72])]]
    dt = TH
    rows = []
    for i in range(2):
        rows.append(ltisim.hstack(*[_ss(plant_tfs[i][j], dt) for j in range(2)]))
    plant = ltisim.vstack(*rows)
    controller = ltisim.block_diagonal(_ss(([0.2, -0.1], [1.0, -0.3]), 2 * dt),
                                       ltisim.static_gain(0.15, 2 * dt))
    loop = ltisim.multirate_closed_loop(plant, controller, None, factor)
    rng = np.random.default_rng(11)
    r = random_phase_multisine(n, 2, np.arange(1, n // 2 + 1), [1.0, 1.0], rng)
    out = ltisim.simulate_multirate(loop, r)
    exp = experiment(r, out.u, out.y_slow, factor=factor, sampling_period=dt,
                     inputs=["a", "b"], outputs=["p", "q"])
    frf = identify(exp, window=20)
    assert frf.P.sizes == {"frequency": n // 2 + 1, "output": 2, "input": 2}
    assert list(frf.input.values) == ["a", "b"] and list(frf.output.values) == ["p", "q"]
    for i in range(2):
        for j in range(2):
            truth = _true_frf(plant_tfs[i][j], n)
            assert _median_rel(frf.P.values[:, i, j], truth) < 1e-4, (i, j)


def _noisy_siso(factor, n, seed, noise_std):
    rng = np.random.default_rng(seed)
    r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, rng)
    d_y = noise_std * rng.standard_normal((n, 1))
    return _simulate(_siso_loop(factor), r, factor, d_y=d_y)


@pytest.mark.slow
def test_p_std_coverage_over_seeds():
    """The 95 % regions from P_std cover the truth in 90-99 % of (bin, seed) cases."""
    factor, n = 2, 480
    truth = _true_frf(PLANT, n)
    k95 = np.sqrt(np.log(20.0))
    hits, total, ratios = 0, 0, []
    for seed in range(60):
        exp = _noisy_siso(factor, n, seed, noise_std=0.02)
        frf = identify(exp, window=15)
        est = frf.P.values[1:-1, 0, 0]
        std = frf.P_std.values[1:-1, 0, 0]
        err = np.abs(est - truth[1:-1])
        hits += int(np.sum(err <= k95 * std))
        total += err.size
        ratios.append(np.mean(err**2) / np.mean(std**2))
    coverage = hits / total
    assert 0.90 <= coverage <= 0.99, coverage
    assert 0.6 < np.median(ratios) < 1.6


def test_direct_method_is_biased_under_feedback():
    """Output noise fed back through an integrating controller biases the direct estimate.

    At low frequency the loop gain is high, so ``u`` is dominated by fed-back noise and the
    direct regression of ``y`` on ``u`` is pulled away from ``P``.  The indirect estimate
    from the excitation is not: averaged over seeds, its error at low frequency stays
    within its standard error, the direct one does not.  (LPM: no noisy regressors, so
    the only bias left is the one caused by the feedback.)
    """
    factor, n, seeds = 2, 960, 20
    loop = ltisim.multirate_closed_loop(_ss(PLANT, TH), _ss(([0.2, 0.0], [1.0, -1.0]), factor * TH),
                                        _ss(FILTER, TH), factor)
    truth = _true_frf(PLANT, n)
    freq = np.arange(n // 2 + 1) / (n * TH)
    low = (freq > 0) & (freq < 60.0)
    errors = {"direct": [], "indirect": []}
    for seed in range(seeds):
        rng = np.random.default_rng(seed)
        r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, rng)
        exp = _simulate(loop, r, factor, d_y=0.3 * rng.standard_normal((n, 1)))
        for how in errors:
            est = identify(exp, method="lpm", window=20, closed_loop=how).P.values[:, 0, 0]
            errors[how].append((est - truth)[low])
    z = {}
    for how, err in errors.items():
        err = np.array(err)
        z[how] = np.median(np.abs(err.mean(axis=0)) / (err.std(axis=0) / np.sqrt(seeds)))
    # |mean| / standard error is ~1 without bias; measured: direct 3.4, indirect 1.1
    assert z["direct"] > 2.5 and z["indirect"] < 2.0, z


def test_single_rate_estimate_only_reaches_slow_nyquist_and_aliases():
    factor, n = 2, 960
    rng = np.random.default_rng(3)
    r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, rng)
    exp = _simulate(_siso_loop(factor), r, factor)
    sr = identify_single_rate(exp, window=20)
    m = n // factor
    assert sr.sizes["frequency"] == m // 2 + 1
    assert float(sr.frequency[-1]) == pytest.approx(1 / (2 * factor * TH))
    truth = _true_frf(PLANT, n)[: m // 2 + 1]
    lifted = identify(exp, window=20).P.values[: m // 2 + 1, 0, 0]
    # aliasing of the fast dynamics corrupts the single-rate estimate; lifting does not
    assert _median_rel(sr.P.values[:, 0, 0], truth) > 100 * _median_rel(lifted, truth)


def test_lifted_tools_are_inverse_and_match_kernel():
    n, factor = 48, 3
    P = matrix_frf([[PLANT, ([0.0, 0.2], [1.0, -0.5])]], n)
    da = xr.DataArray(P, dims=("frequency", "output", "input"),
                      coords={"frequency": np.arange(n) / (n * TH), "output": ["y"],
                              "input": ["a", "b"]}, attrs={"units": "m", "long_name": "plant"})
    lifted = lifted_frf(da, factor)
    assert lifted.dims == ("slow_frequency", "lift_phase", "output", "lift_phase2", "input")
    first = lifted.isel(lift_phase=0)
    back = frf_from_first_block_row(first)
    np.testing.assert_allclose(back.values, P[: n // 2 + 1], rtol=0, atol=1e-13)
    # one-sided input is completed by conjugate symmetry
    one_sided = lifted_frf(da.isel(frequency=slice(0, n // 2 + 1)), factor, n_samples=n)
    np.testing.assert_allclose(one_sided.values, lifted.values, atol=1e-13)


def test_leading_experiment_dim_broadcasts_and_dask_stays_lazy():
    factor, n = 2, 480
    exps = [_noisy_siso(factor, n, seed, noise_std=0.01) for seed in (1, 2)]
    stacked = xr.concat(exps, dim="experiment")
    eager = identify(stacked, window=15)
    assert eager.P.dims == ("experiment", "frequency", "output", "input")
    single = identify(exps[1], window=15)
    np.testing.assert_allclose(eager.P.isel(experiment=1).values, single.P.values, rtol=1e-12)
    lazy = identify(stacked.chunk({"experiment": 1}), window=15)
    assert lazy.P.chunks is not None
    xr.testing.assert_allclose(lazy.compute(), eager)


def assert_same_result(actual, expected, rtol=1e-7):
    """Every variable of two identify results equal (flags exactly, numbers to ``rtol``)."""
    for name in expected.data_vars:
        if expected[name].dtype == bool:
            np.testing.assert_array_equal(actual[name].values, expected[name].values)
        else:
            np.testing.assert_allclose(actual[name].values, expected[name].values, rtol=rtol,
                                       atol=1e-12 * float(np.nanmax(np.abs(expected[name]))))


def test_frequency_chunked_fit_is_lazy_and_equals_in_memory():
    """Chunks along slow frequency get wrapped halos of `window` bins: same answer."""
    import dask

    factor, n = 2, 480
    stacked = xr.concat([_noisy_siso(factor, n, s, noise_std=0.01) for s in (3, 4)], dim="experiment")
    eager = identify(stacked, window=15)
    calls = []

    def count(*args, **kwargs):  # a scheduler that records it was asked to compute
        calls.append(1)
        return dask.get(*args, **kwargs)

    with dask.config.set(scheduler=count):
        lazy = identify(stacked.chunk({"experiment": 1}), window=15, frequency_chunks=40)
        assert lazy.P.chunks is not None and not calls
    assert_same_result(lazy.compute(), eager)
    with pytest.raises(ValueError, match="frequency_chunks >= 15"):
        identify(stacked, window=15, frequency_chunks=10)


def test_settings_recorded_and_units():
    factor, n = 2, 480
    exp = _noisy_siso(factor, n, 0, noise_std=0.01)
    frf = identify(exp, window=15, degrees=(2, 2, 2))
    assert frf.attrs["conventions"] == "lcmr-xr-1"
    assert frf.attrs["method"] == "lrm" and frf.attrs["window"] == 15
    assert list(frf.attrs["degrees"]) == [2, 2, 2] and frf.attrs["factor"] == 2
    assert frf.attrs["slow_nyquist"] == pytest.approx(1 / (2 * factor * TH))
    for name in list(frf.data_vars) + list(frf.coords):
        assert "units" in frf[name].attrs and "long_name" in frf[name].attrs, name
    np.testing.assert_allclose(frf.frequency.values, np.arange(n // 2 + 1) / (n * TH))


class TestErrors:
    def _exp(self):
        return _noisy_siso(2, 480, 0, noise_std=0.01)

    def test_too_few_bins_says_how_many(self):
        with pytest.raises(ValueError, match=r"need 15 parameters per row.*Use window >= 8"):
            identify(self._exp(), window=5, degrees=(3, 3, 3))

    def test_window_wider_than_spectrum(self):
        with pytest.raises(ValueError, match="wider than the spectrum"):
            identify(self._exp(), window=200)

    def test_not_a_dataset(self):
        with pytest.raises(TypeError, match="experiment xarray.Dataset"):
            identify(self._exp()["r"])

    def test_lpm_with_denominator_refused(self):
        with pytest.raises(ValueError, match=r"degrees=\(3, 3, 0\)"):
            identify(self._exp(), method="lpm", degrees=(3, 3, 3))

    def test_unknown_method(self):
        with pytest.raises(ValueError, match="'lrm' or 'lpm'"):
            identify(self._exp(), method="arx")

    def test_zoh_excitation_is_rank_deficient(self):
        factor, n = 2, 480
        rng = np.random.default_rng(0)
        slow = random_phase_multisine(n // factor, 1, np.arange(1, n // 4 + 1), 1.0, rng)
        r = np.repeat(slow, factor, axis=0)  # held over each slow period: lifted phases equal
        exp = _simulate(_siso_loop(factor), r, factor)
        with pytest.raises(ValueError, match="rank 1 < F\\*nu = 2"):
            identify(exp, window=15)

    def test_singular_S_raises_or_flags(self, monkeypatch):
        import lcmr_xr.kernels.identification as kid

        exp = self._exp()
        real = kid.local_model

        def broken(R, Z, **kw):
            fit = real(R, Z, **kw)
            G = fit.G.copy()
            G[..., 7, :2, :] = 0.0  # S = 0 at slow bin 7
            return fit._replace(G=G)

        monkeypatch.setattr(kid, "local_model", broken)
        # (real signals: the slow bins above M/2 are the mirrors of those below, so bin
        # M - 7 = 233 is singular too)
        with pytest.raises(ValueError, match=r"not invertible at 2 slow bin\(s\) \(first: \[7, 233\]\)"):
            identify(exp, window=15)
        frf = identify(exp, window=15, errors="ignore")
        assert frf.s_singular.values.nonzero()[0].tolist() == [7, 233]
        assert np.isnan(frf.P.isel(frequency=7)).all()
        assert bool(frf.P_flag.isel(frequency=7)) and not bool(frf.P_flag.isel(frequency=8))


def test_top_level_entry_point():
    assert lcmr_xr.identify is identify


def test_first_row_covariance_is_the_linearisation_of_ps_s_inverse():
    """``Cov(vec P_1) = J Cov(vec G) J^H`` with ``J`` the derivative of ``PS_1 S^-1``
    (holomorphic in ``G``), here taken by central differences on random bins."""
    from lcmr_xr.kernels.closed_loop import indirect_first_row

    rng = np.random.default_rng(3)
    m, nr, ny = 3, 3, 2
    nz = nr + ny
    G = rng.standard_normal((m, nz, nr)) + 1j * rng.standard_normal((m, nz, nr))
    A = rng.standard_normal((m, nz * nr, nz * nr)) + 1j * rng.standard_normal((m, nz * nr, nz * nr))
    C = A @ A.conj().transpose(0, 2, 1)
    got = indirect_first_row(G, nr, C).first_row_cov
    h = 1e-6
    for b in range(m):
        J = np.empty((ny * nr, nz * nr), complex)
        for x in range(nz * nr):
            dG = np.zeros(nz * nr, complex)
            dG[x] = h
            dG = dG.reshape(nz, nr)
            plus = indirect_first_row(G[b] + dG, nr).first_row
            minus = indirect_first_row(G[b] - dG, nr).first_row
            J[:, x] = ((plus - minus) / (2 * h)).ravel()
        want = J @ C[b] @ J.conj().T
        assert np.abs(got[b] - want).max() <= 1e-7 * np.abs(want).max()


def test_s_condition_on_mirrored_bins_equals_every_bin():
    """The condition of ``S`` taken on half of an exactly mirrored estimate is that of
    every bin; an estimate that is not mirrored takes every bin."""
    from lcmr_xr.kernels.closed_loop import indirect_first_row

    rng = np.random.default_rng(4)
    m, nr = 9, 2
    G = rng.standard_normal((m, nr + 1, nr)) + 1j * rng.standard_normal((m, nr + 1, nr))
    G[0] = G[0].real
    G[m // 2 + 1:] = np.conj(G[1: (m + 1) // 2][::-1])
    want = np.linalg.cond(G[:, :nr])
    np.testing.assert_allclose(indirect_first_row(G, nr).s_condition, want, rtol=1e-13)
    G[-1, 0, 0] += 0.5
    np.testing.assert_allclose(indirect_first_row(G, nr).s_condition, np.linalg.cond(G[:, :nr]),
                               rtol=1e-13)


def test_weak_direction_on_mirrored_bins_equals_every_bin():
    """``recover_frf`` takes the weakest direction of ``S`` on half of an exactly
    mirrored estimate; it equals the one taken on every bin."""
    from lcmr_xr.kernels.adaptive import weak_direction
    from lcmr_xr.kernels.identification import recover_frf

    rng = np.random.default_rng(5)
    m, nu, factor = 10, 1, 2
    nr, nz = factor * nu, factor * nu + 1
    G = rng.standard_normal((m, nz, nr)) + 1j * rng.standard_normal((m, nz, nr))
    A = rng.standard_normal((m, nz * nr, nz * nr)) + 1j * rng.standard_normal((m, nz * nr, nz * nr))
    C = A @ A.conj().transpose(0, 2, 1) * 1e-3
    for x in (G, C):
        x[0] = x[0].real
        x[m // 2] = x[m // 2].real
        x[m // 2 + 1:] = np.conj(x[1: m // 2][::-1])
    from lcmr_xr.kernels.closed_loop import mirror_source

    np.testing.assert_array_equal(mirror_source(G), [0, 1, 2, 3, 4, 5, 4, 3, 2, 1])
    assert mirror_source(C) is not None and mirror_source(G[:-1]) is None
    got = recover_frf(G, C, n_fast=m * factor, factor=factor, nu=nu, ny=1)["s_weak_rel_std"]
    want, _ = weak_direction(G[:, :nr], C[:, : nr * nr, : nr * nr])
    np.testing.assert_allclose(got, want, rtol=1e-12)


def test_a_one_element_factor_attribute_is_read_as_its_number():
    """validate_experiment accepts ``factor`` as a one-element array (as an attribute may be
    set in memory or come back from a reader); identify, its pooled path and the sweep read
    it through ``experiment_factor`` (``int()`` of such an array is numpy's TypeError)."""
    from lcmr_xr import hdd
    from lcmr_xr.scaleout import sweep

    exp = hdd.simulate(n_samples=400, seed=1)
    odd = exp.assign_attrs(factor=np.array([2]))
    want = identify(exp, window=12)
    got = identify(odd, window=12)
    np.testing.assert_array_equal(got.P.values, want.P.values)
    assert got.attrs["factor"] == 2
    two = xr.concat([exp, hdd.simulate(n_samples=400, seed=2)], dim="experiment")
    pooled = identify(two.assign_attrs(factor=np.array([2])), window=12, combine="experiment")
    np.testing.assert_array_equal(
        pooled.P.values, identify(two, window=12, combine="experiment").P.values)
    swept = sweep(two.assign_attrs(factor=np.array([2])), window=[12]).compute()
    np.testing.assert_array_equal(swept.P.values, sweep(two, window=[12]).compute().P.values)
