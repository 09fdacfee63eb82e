"""Honest uncertainty and window="auto" (lcmr_xr.kernels.adaptive) against exact results."""

from __future__ import annotations

import numpy as np
import xarray as xr
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import stats

from lcmr_xr import hdd, identify
from lcmr_xr.kernels.adaptive import (K95, MODEL_ERROR_LEVEL, UNDETERMINED_LIMIT,
                                      candidate_windows, crowd_undetermined, denominator_bias,
                                      noise_share, nonlinearity_factor,
                                      second_order_factor, select_windows, small_sample_factor,
                                      weak_direction, whitened_weak_direction)

BANDS = ((0.0, 500.0), (500.0, 5000.0), (5000.0, 25200.0), (25200.0, 50400.0))


def test_small_sample_factor_is_the_f_quantile():
    dof = np.array([1, 2, 5, 16, 38, 1000])
    exact = np.sqrt(stats.f.ppf(0.95, 2, 2 * dof) / np.log(20.0))
    np.testing.assert_allclose(small_sample_factor(dof), exact, rtol=1e-10)


def test_weak_direction_of_a_diagonal_S_with_white_errors():
    sigma, s = 0.01, 1e-3
    S = np.diag([1.0, sigma]).astype(complex)[None]
    cov = (s**2 * np.eye(4, dtype=complex))[None]  # vec(S) errors white, variance s^2
    rho, rho_v = weak_direction(S, cov)
    # u^H dS v = dS[1, 1]: std s; dS v = column 1 of dS: E||.||^2 = 2 s^2
    np.testing.assert_allclose(rho, [s / sigma], rtol=1e-12)
    np.testing.assert_allclose(rho_v, [np.sqrt(2) * s / sigma], rtol=1e-12)


def test_nonlinearity_factor_and_flag():
    rho = np.array([0.0, 0.1, UNDETERMINED_LIMIT / K95 * 0.999, UNDETERMINED_LIMIT / K95 * 1.001, np.inf])
    factor, flag = nonlinearity_factor(rho, 2 * rho)
    assert flag.tolist() == [False, False, False, True, True]
    np.testing.assert_allclose(factor[:3], 1 + K95 * 2 * rho[:3] / (1 - K95 * rho[:3]))
    assert np.isposinf(factor[3:]).all()


def test_second_order_factor_and_flag():
    rho = np.array([0.0, 0.1, UNDETERMINED_LIMIT / K95 * 0.999, UNDETERMINED_LIMIT / K95 * 1.001])
    factor, flag = second_order_factor(rho)
    assert flag.tolist() == nonlinearity_factor(rho, rho)[1].tolist() == [False, False, False, True]
    np.testing.assert_allclose(factor[:3], np.sqrt(1 + 2 * (rho[:3] / (1 - K95 * rho[:3])) ** 2))
    assert np.isposinf(factor[3])


def test_second_order_factor_bounds_the_sherman_morrison_term_by_monte_carlo():
    """Where one weak direction dominates, P_hat - P = alpha c (1 + x / (1 - x)), x = u^H dS v
    / sigma: the variance to second order, var_lin (1 + E|x|^2 + ...), lies under the factor's
    square (and the bound form's square is far above it when rho_v >> rho)."""
    rng = np.random.default_rng(0)
    n, rho = 400_000, 0.14

    def cn(scale):
        return scale * (rng.standard_normal(n) + 1j * rng.standard_normal(n)) / np.sqrt(2)

    alpha = cn(1.0)
    without_2 = 1 + (rho / (1 - K95 * rho)) ** 2  # the form without Isserlis' factor 2
    # independent alpha and x; then x along alpha (x = rho alpha), where Isserlis' bound
    # E|alpha x|^2 <= 2 E|alpha|^2 E|x|^2 is attained (ratio 1 + 2 rho^2 + 6 rho^4 + ...)
    for x, attained in ((cn(rho), False), (rho * alpha, True)):
        keep = np.abs(x) < 0.5  # the flag's region (k rho < 1/2 bounds |x| at 95 %)
        err = alpha * (1 + x / (1 - x))
        ratio = np.mean(np.abs(err[keep]) ** 2) / np.mean(np.abs(alpha[keep]) ** 2)
        assert 1 + rho**2 < ratio < second_order_factor(rho)[0] ** 2
        assert nonlinearity_factor(rho, 0.83)[0] ** 2 > 5 * ratio
        if attained:  # the factor 2 is needed: without it the form is below the variance
            assert ratio > without_2 + 0.004, (ratio, without_2)


def test_denominator_bias_recovers_a_known_bias_and_no_bias():
    """Hausman's structure: P_iv = P_ls - b + an independent error of variance var_iv -
    var_ls.  The estimate averages to |b|^2 with a bias (within a few per cent) and stays
    near 0 without one."""
    rng = np.random.default_rng(1)
    k, v_ls, v_iv = 20_000, 1.0, 1.3

    def cn(var):
        return np.sqrt(var / 2) * (rng.standard_normal((k, 1, 2))
                                   + 1j * rng.standard_normal((k, 1, 2)))

    for b in (0.0, 0.8):
        P_ls = b * np.exp(1j * np.arange(k) / 7.0)[:, None, None] + cn(v_ls)
        P_iv = P_ls - b * np.exp(1j * np.arange(k) / 7.0)[:, None, None] + cn(v_iv - v_ls)
        est = denominator_bias(P_ls, P_iv, np.full(P_ls.shape, v_ls), np.full(P_ls.shape, v_iv))
        assert est.shape == P_ls.shape and np.all(est >= 0)
        if b:
            np.testing.assert_allclose(est.mean(), b**2, rtol=0.05)
        else:  # the floor keeps the positive part of a mean of 13 zero-mean terms
            assert est.mean() < 0.15 * (v_iv - v_ls) and np.median(est) < 0.01
    bad = np.full((30, 1, 1), np.nan + 0j)
    assert np.array_equal(denominator_bias(bad, bad, np.ones(bad.shape), np.ones(bad.shape)),
                          np.zeros(bad.shape))


def test_denominator_bias_averages_over_finite_determined_neighbours_only():
    """A NaN bin does not dilute its neighbours' mean (it used to count as 0), and an
    undetermined bin's term (on the HDD about 600x the median) does not enter theirs."""
    P = np.zeros((50, 1, 1), complex)
    ones = np.ones(P.shape)
    P_ls = P + 0.3
    P_ls[25] = np.nan
    est = denominator_bias(P_ls, P, ones, ones)
    np.testing.assert_allclose(est[np.arange(50) != 25], 0.09, rtol=1e-12)
    np.testing.assert_allclose(est[25], 0.09, rtol=1e-12)  # its neighbours' mean
    P_ls[25] = 30.0  # a wild term at an undetermined bin
    determined = (np.arange(50) != 25)[:, None, None]
    np.testing.assert_allclose(denominator_bias(P_ls, P, ones, ones, determined=determined),
                               0.09, rtol=1e-12)
    assert denominator_bias(P_ls, P, ones, ones)[24, 0, 0] > 60  # what it would add
    none = denominator_bias(P_ls, P, ones, ones, determined=np.zeros(P.shape, bool))
    assert np.array_equal(none, np.zeros(P.shape))


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), nr=st.integers(1, 4), ny=st.integers(1, 2),
       scale=st.floats(1e-3, 0.5))
def test_exact_error_identity_of_the_indirect_step(seed, nr, ny, scale):
    """P_hat - P = e_lin (I - dS S_hat^-1)^-1, e_lin = (dPS - P_hat dS) S_hat^-1 (module notes)."""
    rng = np.random.default_rng(seed)

    def c(*shape):
        return rng.standard_normal(shape) + 1j * rng.standard_normal(shape)

    S, PS = c(nr, nr) + 3 * np.eye(nr), c(ny, nr)
    dS, dPS = scale * c(nr, nr), scale * c(ny, nr)
    S_hat, PS_hat = S + dS, PS + dPS
    P, P_hat = PS @ np.linalg.inv(S), PS_hat @ np.linalg.inv(S_hat)
    e_lin = (dPS - P_hat @ dS) @ np.linalg.inv(S_hat)
    exact = e_lin @ np.linalg.inv(np.eye(nr) - dS @ np.linalg.inv(S_hat))
    np.testing.assert_allclose(P_hat - P, exact, atol=1e-9 * (1 + np.abs(P).max()))


def test_candidate_windows_ladder():
    assert candidate_windows(12, 899) == (12, 19, 30)
    assert candidate_windows(8, 899) == (8, 13, 21, 30)
    assert candidate_windows(12, 20) == (12, 19, 20)
    assert candidate_windows(40, 899) == (40,)


def test_select_windows_prefers_the_pilot_where_wider_windows_are_biased():
    # two candidates, 10 fast bins = 10 slow bins; the wide one is biased on bins 0..4 only
    rng = np.random.default_rng(0)
    P0 = 1.0 + 0.01 * rng.standard_normal((10, 1, 1))
    P1 = np.where(np.arange(10)[:, None, None] < 5, 1.5, 1.0) + 0.001 * rng.standard_normal((10, 1, 1))
    var = np.stack([np.full((10, 1, 1), 1e-4), np.full((10, 1, 1), 1e-6)])
    choice, bias2 = select_windows(np.stack([P0, P1]), var, var, 10, smoothing=0)
    assert choice.tolist() == [0] * 5 + [1] * 5
    assert np.all(bias2[1, :5] > 0.2)
    # the pilot's band term is its distance to the next-wider candidate (no threshold)
    np.testing.assert_allclose(bias2[0], np.abs(P1 - P0) ** 2, rtol=1e-12)
    _, alone = select_windows(P0[None], var[:1], var[:1], 10, smoothing=0)
    assert np.array_equal(alone, np.zeros((1, 10, 1, 1)))  # nothing to check it against


@pytest.mark.parametrize("seed", [0, 1])
def test_select_windows_pilot_band_covers_where_the_pilot_wins(seed):
    """Nested windows without model error, the pilot's noise variance estimated from 2 dof,
    the wider one's from 16 (truth 0).  Lepski's rule picks the pilot where its variance
    estimate is low and its error high (the pilot's noise reads as the wider window's
    model error), so the pilot's own band covers about 0.72 of those bins (0.95 of all
    bins); with the next-wider candidate's check (``bias2[0]``) added, 0.90-0.99 (0.97
    measured; on the HDD benchmark the window-12 bins covered 0.23-0.62 before,
    docs/uncertainty.md)."""
    rng = np.random.default_rng(seed)
    K, v0, v1, dof = 20000, 1.0, 0.4, np.array([2, 16])

    def c(n):
        return (rng.standard_normal(n) + 1j * rng.standard_normal(n)) / np.sqrt(2)

    e1 = np.sqrt(v1) * c(K)
    P = np.stack([e1 + np.sqrt(v0 - v1) * c(K), e1])[:, :, None, None]
    lin = np.stack([v * rng.chisquare(2 * d, K) / (2 * d) for v, d in zip((v0, v1), dof)])
    lin = lin[:, :, None, None]
    var = lin * (small_sample_factor(dof) ** 2)[:, None, None, None]
    choice, bias2 = select_windows(P, var, lin, K, smoothing=0)
    pilot = choice == 0
    err2 = np.abs(P[0, :, 0, 0]) ** 2
    own = err2 <= K95 ** 2 * var[0, :, 0, 0]
    assert 0.1 < pilot.mean() < 0.3 and own.mean() > 0.93  # the mechanism is there
    assert own[pilot].mean() < 0.8  # ... and the pilot's own band lies where it wins
    covered = err2 <= K95 ** 2 * (var[0, :, 0, 0] + bias2[0, :, 0, 0])
    assert 0.90 <= covered[pilot].mean() <= 0.99, covered[pilot].mean()


def test_select_windows_averages_over_finite_terms_only():
    """A candidate's NaN at one bin does not dilute its neighbours' model-error mean
    (it used to count as 0, as in denominator_bias before session 12)."""
    P0 = np.zeros((50, 1, 1), complex)
    P1 = P0 + 0.5
    P1[25] = np.nan
    var = np.stack([np.full(P0.shape, 1e-2), np.full(P0.shape, 1e-3)])
    lin = var.copy()
    choice, bias2 = select_windows(np.stack([P0, P1]), var, lin, 50)
    expected = 0.25 - 4 * (1e-2 - 1e-3)
    np.testing.assert_allclose(bias2[1, 10:40, 0, 0], expected, rtol=1e-12)
    np.testing.assert_allclose(bias2[0, 10:40, 0, 0], 0.25, rtol=1e-12)
    none = np.full(P0.shape, np.nan + 0j)
    _, bias2 = select_windows(np.stack([P0, none]), var, lin, 50)
    assert np.array_equal(bias2, np.zeros(bias2.shape))  # no finite neighbour: 0


def _band_masks(f):
    return [(f > lo) & (f < hi) for lo, hi in BANDS]


def _hdd(noise, seed, case=2):
    exp = hdd.simulate(3600, case=case, noise=noise, seed=seed)
    truth = np.full((1801, 1, 2), np.nan, complex)
    f = np.arange(1801) * 28.0
    truth[1:] = hdd.true_frf(f[1:], case=case).values
    return exp, truth, f


def test_auto_window_recovers_noiseless_truth_like_the_best_fixed_window():
    exp, truth, f = _hdd(False, 0)
    auto = identify(exp)
    assert auto.attrs["window"] == "auto"
    assert set(np.unique(auto.local_window.values)) <= set(auto.attrs["candidate_windows"].tolist())
    fixed = {w: identify(exp, window=w, errors="ignore") for w in (12, 30)}

    def err(frf, sel):
        return np.nanmedian(np.abs(frf.P.values[sel] - truth[sel]) / np.abs(truth[sel]), axis=0)[0]

    for sel in _band_masks(f):
        best = np.minimum(err(fixed[12], sel), err(fixed[30], sel))
        assert np.all(err(auto, sel) <= 2.0 * best), (err(auto, sel), best)
    # noiseless: below 500 Hz window 30 is off by ~20 % (VCM), auto by < 0.5 %
    assert err(auto, _band_masks(f)[0])[0] < 5e-3
    # and the band covers the truth (model error is all there is)
    k = np.abs(auto.P.values[1:-1] - truth[1:-1]) <= K95 * auto.P_std.values[1:-1]
    assert k.mean() > 0.9


def test_noise_share_is_the_variance_ratio_f_test():
    rng = np.random.default_rng(3)
    dof_w, dof_n, n = 38, 2, 400_000
    # residual variances of pure noise (variance 1): mean of dof |complex Gaussian|^2
    var_w = rng.chisquare(2 * dof_w, n) / (2 * dof_w)
    var_n = rng.chisquare(2 * dof_n, n) / (2 * dof_n)
    rate = (noise_share(var_w, var_n, dof_w, dof_n) < 1.0).mean()
    p = 1.0 - MODEL_ERROR_LEVEL  # false alarms of the test, binomial over n draws
    assert abs(rate - p) < 4.0 * np.sqrt(p / n), rate
    q = stats.f.ppf(MODEL_ERROR_LEVEL, 2 * dof_w, 2 * dof_n)
    np.testing.assert_allclose(noise_share(np.array([0.5, 2.0, 10.0]) * q, np.ones(3), dof_w, dof_n),
                               [1.0, 0.5, 0.1], rtol=1e-10)
    # model error in the wide window's residuals (100x the noise): found with the F law's
    # power (0.93 with 2 dof in the narrow window), and then the share left for noise
    # bounds the noise's true share, 1/100, from above at the test's level
    share = noise_share(100.0 * var_w, var_n, dof_w, dof_n)
    power = (share < 1.0).mean()
    exact = stats.f.sf(q / 100.0, 2 * dof_w, 2 * dof_n)
    assert abs(power - exact) < 4.0 * np.sqrt(exact * (1 - exact) / n) and exact > 0.9
    assert (share >= 0.01).mean() > MODEL_ERROR_LEVEL - 4.0 * np.sqrt(p / n)
    # an exact narrow fit (residual 0) under a wide one with residuals: no noise; 0 / 0: all
    assert noise_share(np.array([1e-30, 0.0]), np.zeros(2), dof_w, dof_n).tolist() == [0.0, 1.0]


@pytest.mark.parametrize("n", [3600, pytest.param(36000, marks=pytest.mark.slow),
                               pytest.param(180000, marks=pytest.mark.slow)])
def test_noiseless_auto_flags_only_the_slow_dc_bin(n):
    """Noiseless data determine ``P`` wherever ``S`` is invertible: ``auto`` flags only
    the fast bins 0 and N/2 of slow DC, where the VCM's double integrator makes ``P(0)``
    infinite and the lifted ``S`` singular.  At N = 3600 the widest window's model error
    had flagged 28-84 Hz (its residual variance 1e3-4e4 times the chosen window 12's); at
    N = 180 000 a covariance at rounding level had flagged 4 slow bins
    (:func:`whitened_weak_direction`), and had released slow DC with a band of zero width
    (the PZT at 0 Hz off by 5.3x, at N/2 by 4.3x; the rounding floor of the weak
    direction, ``lcmr_xr.kernels.identification._rounding_floor``, flags it)."""
    exp = hdd.simulate(n, case=2, noise=False, seed=0)
    f = np.arange(n // 2 + 1) * (100800.0 / n)
    truth = np.full((n // 2 + 1, 1, 2), np.nan, complex)
    truth[1:] = hdd.true_frf(f[1:], case=2).values
    auto = identify(exp)
    flagged = np.flatnonzero(auto.P_undetermined.values)
    # N = 180 000: also slow bin 1 (0.56 Hz and N/2 - 1), whose window-30 estimate (PZT off
    # by 31 %, VCM at N/2 - 1 by 19x) had a band of zero width before the resolution floor
    # (``lcmr_xr.kernels.identification._resolution_floor``): the widest window's test,
    # carried over; the chosen window 12's PZT there is off by 0.9 % (measured, seed 0;
    # docs/uncertainty.md, "Slow DC and fast N/2")
    assert flagged.tolist() == ([0, 1, n // 2 - 1, n // 2] if n == 180000 else [0, n // 2])
    assert np.isinf(auto.P_std.values[[0, n // 2]]).all()
    # what the flag withholds: P(N/2) is finite, but its estimate from slow DC is not it
    # (measured: PZT off by 2.9x at N = 3600, 4.3x at N = 180 000)
    pzt = auto.P.values[n // 2, 0, 1]
    assert abs(pzt - truth[n // 2, 0, 1]) > abs(truth[n // 2, 0, 1])
    ok = np.arange(n // 2 + 1)[1:-1]
    # measured: median 5.4e-5 (N = 3600), 5.1e-8 (36 000), 1.7e-9 (180 000); window 30:
    # 2.3e-3, 1.8e-7, 2.3e-9.  The choice reads the variances without the resolution floor
    # (a bound for the band): chosen from the floored ones, window 30 won every bin of
    # N = 180 000 (2.26e-9) and most of 36 000 (6.6e-8).  Until session 17 the neighbour
    # means were differences of one cumulative sum: 6.1e-8 and 7.0e-10, the latter from
    # that sum's rounding (the same means from exact sums, math.fsum, give 1.68e-9, as
    # seeds 1 and 2 did before; docs/uncertainty.md, "The denominator's bias")
    ok = ok[~auto.P_undetermined.values[ok]]
    rel = np.abs(auto.P.values[ok] - truth[ok]) / np.abs(truth[ok])
    assert np.median(rel) < {3600: 1e-4, 36000: 2e-7, 180000: 2e-9}[n]
    # and the released bins' band holds the truth (measured 1.000 / 0.987 / 1.000, with one
    # cumulative sum for the neighbour means 0.993 / 0.980 / 1.000; before
    # the resolution floor 0.993 / 0.677 / 0.534, with P_std exactly 0 at 6750 / 76 314
    # entries at N = 36 000 / 180 000; the floor with the choice from it 0.993 / 0.969 / 0.998)
    err, std = np.abs(auto.P.values[ok] - truth[ok]), auto.P_std.values[ok]
    assert (err <= K95 * std).mean() > 0.95 and not ((std == 0) & (err > 0)).any()
    if n == 3600:
        widest = identify(exp, window=30)
        low = [1, 2, 3]  # 28, 56, 84 Hz: flagged by the widest window alone ...
        assert widest.P_undetermined.values[low].all()
        assert (auto.local_window.values[low] == 12).all()
        # ... whose chosen window-12 estimate (off by 6-140 % there: model error) its band covers
        err = np.abs(auto.P.values[low] - truth[low])
        assert (err <= K95 * auto.P_std.values[low]).all()


def _near_singular_exact(sigma, m=64, seed=0):
    """Spectra fitted exactly by a constant local model (degrees (0, -1, 0)): ``Z = G R``
    with ``G = [S; P_1 S]``, ``S`` of singular values 1 and ``sigma``; returns ``R``,
    ``Z`` and the true fast ``P`` on bins 0..M (F = 2, one input, one output)."""
    from lcmr_xr.kernels.lifting import frf_from_first_block_row
    rng = np.random.default_rng(seed)
    q, _ = np.linalg.qr(rng.standard_normal((2, 2)) + 1j * rng.standard_normal((2, 2)))
    S = q @ np.diag([1.0, sigma]) @ q.conj().T
    P1 = np.array([[1.0 + 0.5j, -2.0 + 0.25j]])
    R = np.exp(2j * np.pi * rng.random((m, 2)))
    Z = R @ np.concatenate([S, P1 @ S]).T
    truth = frf_from_first_block_row(np.broadcast_to(P1, (m, 1, 2)), 2)[: m + 1]
    return R, Z, truth


def test_an_exact_fit_does_not_release_a_weak_direction_below_its_rounding():
    """Noiseless data fitted exactly leave residuals below what the local model's moments
    resolve (``eps sum |Z|^2 / dof``): the residual covariance is rounding, and the weak
    direction of ``S`` is known to ``sqrt(eps (2 n + 1) / dof) cond(S)`` relative at best.
    With ``cond(S)`` 1e9 every bin is undetermined; before, 20 of 65 fast bins were
    released with a band of zero width around an estimate off by up to 5.5e-7 (the HDD's
    slow DC at N = 180 000, ``cond(S)`` 2.3e7-2.8e7: P off by 4-7x, band 0).  Where the floor
    passes, nothing changes (``cond(S)`` 1e3: every band finite, rho as measured)."""
    from lcmr_xr.kernels.identification import identify_spectra
    kw = dict(n_fast=128, factor=2, nu=1, half_width=6, degrees=(0, -1, 0))
    R, Z, truth = _near_singular_exact(1e-9)
    out = identify_spectra(R, Z, **kw)
    band = K95 * np.sqrt(out["P_var"])
    released = np.isfinite(band).all(axis=(-2, -1))
    assert (np.abs(out["P"] - truth)[released] <= band[released]).all()
    assert out["P_undetermined"].all()
    floor = np.sqrt(np.finfo(float).eps * 13 / 11) * out["s_condition"]
    np.testing.assert_array_equal(out["s_weak_rel_std"], np.maximum(floor, 0.0))
    R, Z, truth = _near_singular_exact(1e-3)
    out = identify_spectra(R, Z, **kw)
    assert not out["P_undetermined"].any()
    assert np.abs(out["P"] - truth).max() < 1e-11
    assert (out["s_weak_rel_std"] < 1e-4).all()


def test_rounding_floor_touches_only_unresolved_bins_it_flags():
    """``_rounding_floor`` returns ``rho`` unchanged (the same object) where every row's
    noise variance is resolved or the floor passes the test; a block of the circle gets
    the whole circle's values."""
    from lcmr_xr.kernels.identification import _rounding_floor
    rng = np.random.default_rng(1)
    m, n, dof = 40, 5, 7
    Z = rng.standard_normal((m, 3)) + 1j * rng.standard_normal((m, 3))
    rho = rng.random(m) * 0.1
    cond = np.full(m, 1e10)
    resolved = np.full((m, 3), 1e-3)
    assert _rounding_floor(rho, cond, resolved, Z, half_width=n, dof=dof,
                           circular=True) is rho
    tiny = resolved.copy()
    tiny[7, 1] = 0.0  # one row of bin 7 below the moments' resolution
    out = _rounding_floor(rho, cond, tiny, Z, half_width=n, dof=dof, circular=True)
    floor = np.sqrt(np.finfo(float).eps * (2 * n + 1) / dof) * 1e10
    assert out[7] == floor and K95 * floor > UNDETERMINED_LIMIT
    np.testing.assert_array_equal(np.delete(out, 7), np.delete(rho, 7))
    small = np.full(m, 1e3)  # the floor passes: unchanged
    assert _rounding_floor(rho, small, tiny, Z, half_width=n, dof=dof,
                           circular=True) is rho
    block = _rounding_floor(rho[4:20], cond[4:20], tiny[4:20], Z, half_width=n, dof=dof,
                            circular=True, bins=(4, 20))
    np.testing.assert_array_equal(block, out[4:20])
    wrap = _rounding_floor(rho[:8], cond[:8], tiny[:8], Z, half_width=n, dof=dof,
                           circular=True, bins=(0, 8))  # the window wraps at bin 0
    np.testing.assert_array_equal(wrap, out[:8])


def test_whitened_ratio_of_a_covariance_at_rounding_level_is_zero():
    """An exact fit of noiseless data leaves a covariance of rounding noise, indefinite:
    its trace may cancel to nearly 0 or its entries exceed every variance.  No noise is
    measured there (the HDD at N = 180 000 had read rho 0.43 and 8.1 and flagged the bins)."""
    rng = np.random.default_rng(0)
    S = np.diag([1.4, 1.0, 1.0, 0.46]).astype(complex) + 0.01 * rng.standard_normal((4, 4))
    x = 1e-15 * (rng.standard_normal((16, 16)) + 1j * rng.standard_normal((16, 16)))
    junk = x + x.conj().T  # Hermitian, indefinite
    np.fill_diagonal(junk, 1e-33)  # variances far below the entries (a cancelled trace)
    assert np.linalg.eigvalsh(junk)[0] < 0
    assert whitened_weak_direction(S, junk) == 0.0
    cancelled = 1e-15 * np.diag(np.r_[np.ones(8), -np.ones(8)] + 1e-18).astype(complex)
    assert whitened_weak_direction(S, cancelled) == 0.0
    # a covariance with the same entries, made positive definite, still measures its noise
    psd = junk @ junk.conj().T / 1e-15
    rho = whitened_weak_direction(S, psd)
    assert 0.0 < rho < np.inf


def test_noisy_auto_keeps_the_widest_windows_flag():
    """With the disturbances the widest window's flag stands where the chosen window's own
    test passes (its residual variance is noise: no model-error excess)."""
    exp, truth, f = _hdd(True, 1)
    auto = identify(exp)
    m = auto.sizes["slow_frequency"]
    below = np.flatnonzero((f > 0) & (f < 500))
    assert auto.P_undetermined.values[below].all()
    win = auto.local_window.values[below % m]
    own = np.zeros(below.size, dtype=bool)
    for w in np.unique(win):  # its own test at each bin (a fixed window's flag also reads
        # its neighbourhood's)
        fixed = identify(exp, window=int(w), errors="ignore")
        rho = fixed.s_weak_rel_std.values[below[win == w] % m]
        own[win == w] = K95 * rho > UNDETERMINED_LIMIT
    # bins the chosen window alone would have left determined (measured: 476 Hz, window 12)
    assert (~own).any()
    # the widest window flags them
    widest = identify(exp, window=30, errors="ignore")
    assert widest.P_undetermined.values[below[~own]].all()


def test_undetermined_bins_have_unbounded_bands():
    exp, truth, f = _hdd(True, 1)
    frf = identify(exp, window=30)
    und = frf.P_undetermined.values
    assert und.any()
    assert np.isposinf(frf.P_std.values[und]).all()
    assert np.isfinite(frf.P_std.values[~und & ~frf.P_flag.values]).all()
    # the flag follows the weakest direction of S, per slow bin, or the majority of the
    # slow bins within +-6 (one record at a fixed window)
    rho = frf.s_weak_rel_std.values
    slow = np.arange(1801) % 1800
    own = K95 * rho > UNDETERMINED_LIMIT
    crowd = np.array([own[np.arange(b - 6, b + 7) % 1800].mean() > 0.5 for b in range(1800)])
    np.testing.assert_array_equal(und, (own | crowd)[slow])
    # below 500 Hz the disturbances swamp the weak direction; above it the data decide
    below, above = f < 500, f > 500
    assert und[below & (f > 0)].mean() > 0.8 and und[above].mean() <= 0.05
    # P_std never narrower than the first-order standard deviation
    assert np.all(frf.P_std.values >= frf.P_std_linear.values)


@pytest.mark.slow
def test_coverage_over_seeds_on_realistic_hdd_data():
    """95 % discs (flagged bins: unbounded) cover the truth in >= 88 % of bins in every band."""
    hits = np.zeros((4, 2))
    count = np.zeros((4, 2))
    flagged = []
    for seed in (0, 1, 2):
        exp, truth, f = _hdd(True, seed, case=1 + 4 * seed)  # cases 1, 5, 9
        frf = identify(exp)
        err = np.abs(frf.P.values - truth)[:, 0]
        ok = (err <= K95 * frf.P_std.values[:, 0]) | frf.P_undetermined.values[:, None]
        for b, sel in enumerate(_band_masks(f)):
            hits[b] += ok[sel].sum(axis=0)
            count[b] += sel.sum()
        flagged.append(frf.P_undetermined.values[f > 500].mean())
    coverage = hits / count
    assert np.all(coverage >= 0.88), coverage
    assert np.mean(flagged) <= 0.05, flagged


def test_band_above_500_hz_neither_too_narrow_nor_too_wide():
    """Cases 1-3, seeds 0-3 (12 records): the 95 % discs cover 0.90-0.99 of the bins in every
    band above 500 Hz, both actuators.  The bound form of the S^-1 factor made 500-5000 Hz
    0.999 (its rho_v is 0.83 there while the correction scales with rho, 0.14); the
    second-order factor with the least-squares denominator's bias from its IV twin
    (docs/uncertainty.md, "The denominator's bias from a Hausman comparison") gives
    0.957 / 0.987 there and keeps 5-50.4 kHz at 0.93-0.95.  The same holds at the bins
    where window 19 is chosen (about 10 %; 0.94-0.98): the bias term is added at every
    bin (added only where window 30 is chosen, they covered 0.84-0.94)."""
    hits = np.zeros((2, 4, 2))  # (all bins, window-19 bins), band, actuator
    count = np.zeros((2, 4, 1))
    for case in (1, 2, 3):
        for seed in range(4):
            exp, truth, f = _hdd(True, seed, case=case)
            frf = identify(exp)
            err = np.abs(frf.P.values - truth)[:, 0]
            und = frf.P_undetermined.values
            ok = (err <= K95 * frf.P_std.values[:, 0]) | und[:, None]
            m = frf.sizes["slow_frequency"]
            w19 = (frf.local_window.values[np.arange(f.size) % m] == 19) & ~und
            for b, sel in enumerate(_band_masks(f)):
                for i, s in enumerate((sel, sel & w19)):
                    hits[i, b] += ok[s].sum(axis=0)
                    count[i, b] += s.sum()
    coverage = hits[:, 1:] / count[:, 1:]
    assert np.all(count[1, 1:] >= 100), count  # enough window-19 bins to tell
    assert np.all((coverage >= 0.90) & (coverage <= 0.99)), coverage


@pytest.mark.slow
@pytest.mark.parametrize("seed", [5, 7, 8, 9])
def test_below_500_hz_the_seeds_that_fooled_the_plain_ratio_are_covered(seed):
    """Case 2, the seeds where the weakest direction of the ESTIMATED S read a small noise
    (rho 0.08-0.29 while the estimate was 0.3-100 % of the truth; coverage 0.29-0.88
    below 500 Hz): the whitened ratio flags those bins (docs/uncertainty.md)."""
    exp, truth, f = _hdd(True, seed, case=2)
    frf = identify(exp)
    sel = _band_masks(f)[0]
    err = np.abs(frf.P.values - truth)[sel, 0]
    ok = (err <= K95 * frf.P_std.values[sel, 0]) | frf.P_undetermined.values[sel, None]
    assert ok.mean(axis=0).min() >= 0.9, ok.mean(axis=0)


@given(st.integers(0, 2**32 - 1), st.integers(0, 8), st.integers(1, 40), st.booleans())
@settings(max_examples=60, deadline=None)
def test_crowd_undetermined_is_the_majority_of_the_neighbourhood(seed, half, n, circular):
    """Bin by bin: more than half of the bins within ``half`` of it fail (those that exist,
    or on the circle of bins: ``2 half + 1`` of them, or every bin of a shorter circle, each
    counted once)."""
    rng = np.random.default_rng(seed)
    u = rng.random((3, n)) < rng.random()
    got = crowd_undetermined(u, half, circular=circular)
    for row in range(3):
        for k in range(n):
            near = (u[row, np.unique(np.arange(k - half, k + half + 1) % n)] if circular
                    else u[row, max(0, k - half):k + half + 1])
            assert got[row, k] == (near.sum() > near.size / 2)
    # along another axis alike
    np.testing.assert_array_equal(crowd_undetermined(u.T, half, axis=0, circular=circular), got.T)


def test_crowd_undetermined_counts_each_bin_of_a_short_circle_once():
    """Fewer slow bins than the neighbourhood (M < 13: a short record, low degrees): the
    neighbourhood is every bin once.  Two of four failing is not more than half; counting
    the circle round (13 positions on 4 bins, the opposite bin 4 times) flagged all four."""
    u = np.array([0, 1, 1, 0], bool)
    np.testing.assert_array_equal(crowd_undetermined(u, 6, circular=True), [0, 0, 0, 0])
    np.testing.assert_array_equal(crowd_undetermined(np.array([0, 1, 1, 1]), 6, circular=True),
                                  [1, 1, 1, 1])


@pytest.mark.parametrize("m", [16, 17, 40])
@pytest.mark.parametrize("factor", [1, 2, 3])
def test_auto_neighbourhood_sees_the_mirrored_slow_bins(m, factor):
    """The neighbourhood rule of window='auto' runs on the circle of all M slow bins.  With
    F = 1 the fast bins (N/2 + 1 of them) reach only slow bins 0..M/2: the others are their
    mirrors (slow bin M - t has bin t's test, real signals), and were read as passing, so
    near DC and the slow Nyquist bin a majority was missed."""
    from lcmr_xr.kernels.identification import _finish_choice

    rng = np.random.default_rng(m * 10 + factor)
    n_fast = factor * m
    k = np.arange(n_fast // 2 + 1)
    for _ in range(20):
        slow = rng.random(m) < rng.random()
        slow[m - np.arange(1, m)] |= slow[1:]  # a real signal's slow bins: t and M - t alike
        out = {"P_undetermined": np.zeros(k.size, bool), "P_var": np.ones((k.size, 1, 1))}
        got = _finish_choice(out, np.zeros(m, int), np.zeros(k.size, int),
                             np.zeros((1, k.size, 1, 1)), slow[k % m], np.array([5]))
        want = slow[k % m] | np.array([
            slow[np.unique(np.arange(j - 6, j + 7) % m)].mean() > 0.5 for j in k % m])
        np.testing.assert_array_equal(got["P_undetermined"], want)


@pytest.mark.parametrize("window", ["auto", 30])
def test_auto_releases_no_lying_bin_below_500_hz(window):
    """Cases 1 and 8, seeds 0-9 (20 records): below 500 Hz the weakest direction of S is
    drowned in the rotational vibration (its ratio 1.9-11, its estimate saturated near 1),
    and the few bins whose estimate drew a ratio under the limit were released with a band
    40-150 times too narrow for an estimate 99.5 % off (auto: 112 Hz in seed 7, 56 Hz in
    case 8 seed 7, 476 Hz in case 8 seed 8: 1 of these 4 covered).  A released bin's band
    must hold the truth as it promises: with most of its neighbourhood failing the widest
    window's test (auto) or the window's own (a fixed window, one record) such a bin is
    flagged (``kernels.adaptive.crowd_undetermined``)."""
    released = covered = 0
    for case in (1, 8):
        for seed in range(10):
            exp, truth, f = _hdd(True, seed, case=case)
            frf = identify(exp, window=window)
            sel = _band_masks(f)[0] & ~frf.P_undetermined.values
            err = np.abs(frf.P.values - truth)[sel, 0]
            released += sel.sum()
            covered += (err <= K95 * frf.P_std.values[sel, 0]).all(axis=-1).sum()
    assert released == 0 or covered >= 0.9 * released, (released, covered)


def test_fixed_window_flags_where_most_of_the_neighbourhood_fails_its_test(monkeypatch):
    """One record at a fixed window: ``P_undetermined`` is the window's own test or the
    majority of the slow bins within +-6 on their circle failing it (a loop oracle over the
    flags of the fit without the rule, ``recover_frf``); the flagged bins' band is
    unbounded and every other output is the fit's.  The same in frequency chunks.  Pooled
    fits and a known noise covariance keep their own test (not changed here)."""
    from lcmr_xr.kernels import identification as ki
    from lcmr_xr.kernels.local_models import local_model

    exp = hdd.simulate(3600, case=2, noise=True, seed=7)
    factor = int(exp.attrs["factor"])
    R, Z = ki.experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=factor)
    shape = dict(n_fast=exp.sizes["time"], factor=factor, nu=exp.sizes["input"])
    m = R.shape[-2]
    got = ki.identify_spectra(R, Z, half_width=30, **shape)
    fit = local_model(R, Z, half_width=30)
    own = ki.recover_frf(fit.G, fit.G_cov, ny=Z.shape[-1] - R.shape[-1], ill_posed=fit.ill_posed,
                         dof=fit.dof, noise_covariance=fit.noise_covariance, **shape)
    k = np.arange(own["P"].shape[-3])
    slow = np.zeros(m, dtype=bool)
    slow[k % m] = own["P_undetermined"]
    crowd = np.array([slow[np.arange(b - 6, b + 7) % m].sum() > 6.5 for b in range(m)])
    want = (slow | (crowd & ~own["s_singular"]))[k % m]
    np.testing.assert_array_equal(got["P_undetermined"], want)
    added = want & ~own["P_undetermined"]
    assert 0 < added.sum() < 0.05 * added.size  # the rule flags a few bins, not a band
    assert np.isinf(got["P_var"][added]).all() and np.isfinite(own["P_var"][added]).all()
    np.testing.assert_allclose(got["P_var"][~want], own["P_var"][~want], rtol=1e-9)
    np.testing.assert_allclose(got["P"], own["P"], rtol=1e-9, atol=1e-12)
    eager = identify(exp, window=30, errors="ignore")
    np.testing.assert_array_equal(eager.P_undetermined.values, want)
    lazy = identify(exp.chunk(), window=30, frequency_chunks=100, errors="ignore").compute()
    np.testing.assert_array_equal(lazy.P_undetermined.values, want)
    # pooled experiments and a known noise covariance (periods): their own test only
    def refused(*args, **kwargs):
        raise AssertionError("the neighbourhood's test is for one record's own residuals")

    monkeypatch.setattr(ki, "crowd_undetermined", refused)
    other = hdd.simulate(3600, case=2, noise=True, seed=8)
    R2, Z2 = ki.experiment_spectra(other.r.values, other.u.values, other.y.values, factor=factor)
    pooled = ki.identify_spectra(np.stack([R, R2]), np.stack([Z, Z2]), half_width=30,
                                 experiment_axis=-3, **shape)
    known = ki.identify_spectra(R, Z, half_width=30, noise_covariance=fit.noise_covariance,
                                **shape)
    assert pooled["P_undetermined"].any() and known["P_undetermined"].any()


def test_auto_in_frequency_chunks_is_the_eager_result():
    """Every candidate fitted in chunks with its own halo, the choice made on the gathered
    fits: the same numbers as the eager window='auto' (one record, and pooled)."""
    exp = hdd.simulate(1200, noise=True, seed=3)
    eager = identify(exp, errors="ignore")
    lazy = identify(exp.chunk(), frequency_chunks=100, errors="ignore")
    assert lazy.P.chunks is not None and lazy.attrs["window"] == "auto"
    # rounding: the chunks fit every bin without the circular mirror, and window 12 leaves
    # two degrees of freedom (a fixed window 12 differs by 6e-8 in P, 2e-6 in P_std here;
    # s_weak_rel_std, a ratio of such variances, by up to 7e-5)
    for name in ("P", "P_std", "P_bias", "s_weak_rel_std"):
        np.testing.assert_allclose(lazy[name].values, eager[name].values, rtol=1e-4, atol=1e-12)
    np.testing.assert_array_equal(lazy.local_window.values, eager.local_window.values)
    np.testing.assert_array_equal(lazy.P_undetermined.values, eager.P_undetermined.values)
    # the widest window's IV twin (least-squares denominator's bias) takes its instruments
    # from the widest candidate's chunks: the halo of that window suffices
    with pytest.raises(ValueError, match="frequency_chunks >= 30"):
        identify(exp, frequency_chunks=29)
    two = xr.concat([exp, hdd.simulate(1200, noise=True, seed=4)], "experiment")
    pooled = identify(two, combine="experiment", errors="ignore")
    chunked = identify(two, combine="experiment", frequency_chunks=100, errors="ignore")
    np.testing.assert_allclose(chunked.P_std.values, pooled.P_std.values, rtol=1e-5)


def test_packed_auto_chooses_from_the_unfloored_variances_as_the_eager_path():
    """Noiseless HDD, N = 12 000: most slow bins have a row below the moments' resolution,
    where the band is floored (``_resolution_floor``) and ``window="auto"`` chooses from
    the variances without the floor.  ``finish_packed_auto`` on the candidates' packed
    fits of the whole circle (``fit_packed(..., unfloored=True)``) chooses the eager
    path's window at every slow bin and gathers its ``P`` bit for bit: the fits' moments
    are the same (the eager blocks start on the moment recurrence's restart grid), so
    their unfloored variances are too.  Before, the packed path chose from the floored
    variances: another window at 403 of the 6000 slow bins."""
    from lcmr_xr.kernels import identification as ki

    n, windows = 12000, (12, 19, 30)
    exp = hdd.simulate(n, case=2, noise=False, seed=0)
    R, Z = ki.experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=hdd.FACTOR)
    nz, nr = Z.shape[-1], R.shape[-1]
    shape = dict(n_fast=n, factor=hdd.FACTOR, nu=exp.sizes["input"])
    eager = ki.identify_spectra_auto(R, Z, windows=windows, **shape)
    packed = np.stack([ki.fit_packed(R, Z, half_width=w, unfloored=True) for w in windows])
    # (without the Hausman twin, which adds to the band after the choice)
    got = ki.finish_packed_auto(packed, windows=windows, nz=nz, nr=nr, ny=nz - nr,
                                unfloored=True, **shape)
    assert (eager["window"] == 12).any() and (eager["window"] == 19).any()
    np.testing.assert_array_equal(got["window"], eager["window"])
    np.testing.assert_array_equal(got["P"], eager["P"])


def test_auto_in_frequency_chunks_chooses_as_the_plain_path_on_noiseless_data():
    """Noiseless HDD, N = 12 000, seed 0, ``frequency_chunks=300``: the chunked
    ``window="auto"`` chooses from the unfloored variances, as the plain path does.  On
    noiseless data those variances are rounding (the residuals are below the moments'
    resolution), so the choice at a bin is decided by rounding: the plain path itself,
    with ``y`` scaled by ``1 + 2^-50`` or ``1 + 2^-49``, chose another window at 97-110
    of the 6000 slow bins (seed 1: 102-126) and moved the count of window-12 bins by 5-8
    (seed 1: 8-20).  Measured, chunked against plain: 65 bins, count +19 (seed 1: 79,
    +15; 94, +16 and 82, +34 while the neighbour means were one cumulative sum, session
    16); before (the chunked path chose from the floored variances, whose floor favours
    wider windows): 384 bins, count -374 (seed 1: 350, -350).  The bounds sit between.
    The released bands at floored bins are rounding-driven alike (``P_std`` of the
    perturbed plain path moves by more than 1 % at 4700-5000 of 12 002 entries), so
    ``P_std`` is compared only through the window chosen."""
    exp = hdd.simulate(12000, case=2, noise=False, seed=0)
    plain = identify(exp, errors="ignore")
    chunked = identify(exp, frequency_chunks=300, errors="ignore").compute()
    w, wc = plain.local_window.values, chunked.local_window.values
    assert 0.5 < (w == 12).mean() < 0.9 and (w == 19).mean() > 0.1  # both contend
    assert (w != wc).mean() < 0.03
    assert abs(int((wc == 12).sum()) - int((w == 12).sum())) < 100


@pytest.mark.parametrize("real", [True, False], ids=["real-mirrored", "complex-every-bin"])
def test_hausman_twin_takes_the_widest_candidates_fit_bit_for_bit(real):
    """What window='auto' reuses for its Hausman comparison instead of fitting again: the
    widest candidate's G and T (fitted with covariance, in blocks) give the instruments of a
    separate first fit without covariance, and the IV twin's first-row-only terms are those
    of the full terms, bit for bit."""
    import lcmr_xr.kernels.identification as ki

    exp = hdd.simulate(1200, noise=True, seed=5)
    R, Z = ki.experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=hdd.FACTOR)
    if not real:  # every bin fitted, nothing mirrored
        R, Z = R * np.exp(0.3j), Z * np.exp(0.3j)
    kw = dict(half_width=30, degrees=(3, 3, 3), covariance=True, noise_covariance=None,
              experiment_axis=None, closed_loop="indirect")
    ls = ki._fit_blocks(R, Z, **kw)
    zhat = ki._prediction(ls["G"], ls["T"], R, Z)
    np.testing.assert_array_equal(zhat, ki.denominator_instruments(R, Z, half_width=30))
    full = ki._fit_blocks(R, Z, denominator="iv", instruments=zhat, **kw)
    lean = ki._fit_blocks(R, Z, denominator="iv", instruments=zhat, first_row_only=True, **kw)
    assert sorted(lean) == sorted(set(full) - {"G_var", "rho", "rho_v"})
    for name in lean:
        if name == "s_condition":  # the SVD of S without its vectors: the same to rounding
            np.testing.assert_allclose(lean[name], full[name], rtol=1e-12)
        else:
            np.testing.assert_array_equal(lean[name], full[name], err_msg=name)


def test_chunked_auto_fits_no_first_fit_for_the_twin(monkeypatch):
    """With frequency_chunks the Hausman twin's instruments are the widest candidate's own
    chunked prediction, as in the eager path: no first fit (denominator_instruments) runs,
    frequency_chunks of the widest window's halo suffice, and the result is the eager one."""
    import lcmr_xr.kernels.identification as ki

    exp = hdd.simulate(1200, noise=True, seed=6)
    eager = identify(exp, errors="ignore")

    def no_first_fit(*args, **kwargs):
        raise AssertionError("window='auto' fitted a first fit for the twin's instruments")

    monkeypatch.setattr(ki, "denominator_instruments", no_first_fit)
    lazy = identify(exp, frequency_chunks=30, errors="ignore").compute()
    for name in ("P", "P_std", "P_bias"):
        np.testing.assert_allclose(lazy[name].values, eager[name].values, rtol=1e-4, atol=1e-12)
    np.testing.assert_array_equal(lazy.local_window.values, eager.local_window.values)


def test_chunked_twin_fits_the_eager_bins_when_dask_merges_a_short_chunk():
    """M = 604 in chunks of 100 leaves a last chunk of 4 bins, shorter than the halo: dask's
    overlap merges it into its neighbour, which shifts where that block's bins start.  The
    twin, fitted at every third slow bin only, must still be fitted at the eager path's
    bins (a shift by 1 or 2 bins changed P_std by up to 42 % near the end)."""
    exp = hdd.simulate(1208, noise=True, seed=2)
    eager = identify(exp, errors="ignore")
    lazy = identify(exp, frequency_chunks=100, errors="ignore").compute()
    for name in ("P", "P_std", "P_bias"):
        np.testing.assert_allclose(lazy[name].values, eager[name].values, rtol=1e-4, atol=1e-12)
    np.testing.assert_array_equal(lazy.P_undetermined.values, eager.P_undetermined.values)


def test_auto_refuses_what_it_cannot_do():
    exp = hdd.simulate(600, noise=False, seed=0)
    with pytest.raises(ValueError, match="covariance=True"):
        identify(exp, covariance=False)
    with pytest.raises(TypeError, match="window must be an integer or 'auto'"):
        identify(exp, window="wide")


def _loop_case(kind):
    """(loop, plant tfs, F, N, nu, ny, fixed windows of the existing tests) for small known loops."""
    from lcmr_xr.kernels import ltisim
    from test_identify import PLANT, TH, _siso_loop, _ss

    if kind == "siso-F3":
        return _siso_loop(3), [[PLANT]], 3, 720, 1, 1, (15, 30)
    if kind == "miso-F4":
        p2 = ([0.0, 0.2], [1.0, -0.5])
        plant = ltisim.hstack(_ss(PLANT, TH), _ss(p2, TH))
        ctrl = ltisim.vstack(_ss(([0.25, -0.15], [1.0, -0.3]), 4 * TH), ltisim.static_gain(0.1, 4 * TH))
        return ltisim.multirate_closed_loop(plant, ctrl, None, 4), [[PLANT, p2]], 4, 1600, 2, 1, (25, 30)
    tfs = [[([0.0, 0.10, 0.06], [1.0, -1.6, 0.89]), ([0.0, 0.03], [1.0, -0.7])],
           [([0.0, -0.02], [1.0, -0.5]), ([0.0, 0.08, 0.05], [1.0, -1.2, 0.72])]]
    plant = ltisim.vstack(*[ltisim.hstack(*[_ss(tfs[i][j], TH) for j in range(2)]) for i in range(2)])
    ctrl = ltisim.block_diagonal(_ss(([0.2, -0.1], [1.0, -0.3]), 2 * TH), ltisim.static_gain(0.15, 2 * TH))
    return ltisim.multirate_closed_loop(plant, ctrl, None, 2), tfs, 2, 960, 2, 2, (20, 30)


@pytest.mark.slow
@pytest.mark.parametrize("kind, noise", [("siso-F3", 0.0), ("siso-F3", 1e-4), ("miso-F4", 1e-4),
                                         ("mimo-F2", 0.0), ("mimo-F2", 1e-4)])
def test_defaults_not_worse_than_fixed_windows_on_known_loops(kind, noise):
    """Measured worst-entry median errors: noiseless auto 1.4e-6..2.2e-5 (fixed 8e-6..3e-4),
    noise 1e-4: auto 6.6e-4..1.8e-3, the best fixed window the same or higher."""
    from lcmr_xr.experiment import experiment
    from lcmr_xr.kernels import ltisim
    from lcmr_xr.kernels.excitation import random_phase_multisine
    from test_identify import TH, _true_frf

    loop, tfs, factor, n, nu, ny, windows = _loop_case(kind)
    rng = np.random.default_rng(5)
    r = random_phase_multisine(n, nu, np.arange(1, n // 2 + 1), [1.0] * nu, rng)
    out = ltisim.simulate_multirate(loop, r, d_y=noise * rng.standard_normal((n, ny)))
    exp = experiment(r, out.u, out.y_slow, factor=factor, sampling_period=TH)

    def worst(frf):
        return max(np.median(np.abs(frf.P.values[:, i, j] - _true_frf(tfs[i][j], n))
                             / np.abs(_true_frf(tfs[i][j], n))) for i in range(ny) for j in range(nu))

    auto = worst(identify(exp))
    best_fixed = min(worst(identify(exp, window=w)) for w in windows)
    assert auto <= 1.05 * best_fixed, (auto, best_fixed)
    assert auto < (1e-4 if noise == 0 else 3e-3)


def test_auto_with_repeated_periods_uses_the_period_noise_per_candidate():
    """Pooled periods: each bin's band is the chosen candidate's band with the period noise."""
    exp = hdd.simulate(n_samples=1200, periods=3, seed=1)
    auto = identify(exp, transient_periods=1)
    assert auto.attrs["noise_estimate"] == "periods" and auto.attrs["window"] == "auto"
    fast = np.arange(auto.sizes["frequency"]) % auto.sizes["slow_frequency"]
    chosen = auto.local_window.values[fast]
    for w in np.unique(chosen):
        fixed = identify(exp, window=int(w), transient_periods=1, errors="ignore")
        sel = chosen == w
        np.testing.assert_allclose(auto.P.values[sel], fixed.P.values[sel], rtol=1e-12, atol=0)
        np.testing.assert_allclose(auto.P_std_linear.values[sel], fixed.P_std_linear.values[sel],
                                   rtol=1e-12, atol=0)


def test_auto_on_data_of_extreme_magnitude_is_the_scaled_result():
    exp = hdd.simulate(600, noise=True, seed=0)
    big = exp.assign(y=exp.y * 2.0**180, u=exp.u * 2.0**-200)  # both beyond the safe range
    a, b = identify(exp), identify(big)
    np.testing.assert_array_equal(a.local_window.values, b.local_window.values)
    k = 2.0**380  # P = y / u
    np.testing.assert_allclose(b.P.values, a.P.values * k, rtol=1e-9)
    np.testing.assert_allclose(b.P_bias.values, a.P_bias.values * k, rtol=1e-9)
    np.testing.assert_allclose(b.P_std_linear.values, a.P_std_linear.values * k, rtol=1e-9)
    np.testing.assert_array_equal(a.P_undetermined.values, b.P_undetermined.values)


def test_auto_where_it_is_refused():
    from lcmr_xr import identify_single_rate
    from lcmr_xr.scaleout import sweep
    from lcmr_xr.settings import estimator_settings

    exp = hdd.simulate(600, noise=False, seed=0)
    with pytest.raises(ValueError, match="sweep compares fixed windows"):
        sweep(exp.expand_dims(experiment=2), window="auto")
    with pytest.raises(ValueError, match="integer window"):
        identify_single_rate(exp, window="auto")
    # the validator's strictness is kept next to 'auto'
    with pytest.raises(ValueError, match="not rounded"):
        estimator_settings(window=30.5)
    assert estimator_settings().window == "auto"


def test_bode_hatches_unbounded_bands():
    import matplotlib

    matplotlib.use("Agg")
    from lcmr_xr.plot import bode

    exp, truth, f = _hdd(True, 1)
    frf = identify(exp, window=30)
    und = frf.P_undetermined.values
    assert und.any()
    plot = bode(frf, band=0.95)
    from matplotlib.patches import Rectangle

    spans = [a for a in plot.lines[next(iter(plot.lines))]["band"] if isinstance(a, Rectangle)]
    assert spans and all(s.get_hatch() == "//" for s in spans)
    labels = [t.get_text() for t in plot.axes[0, 0].get_legend().get_texts()]
    assert "not determined (unbounded band)" in labels


def test_sweep_command_line_refuses_auto_before_reading(tmp_path, capsys):
    from lcmr_xr import cli

    status = cli.main(["sweep", str(tmp_path / "no-archive"), "-o", str(tmp_path / "r.nc"),
                       "--window", "auto"])
    assert status == 2
    assert "sweep compares fixed windows" in capsys.readouterr().err
    assert not (tmp_path / "r.nc").exists()


def _plain_weak_ratio(S_hat, C):
    """std(u^H dS v) / sigma_min along the estimate's own weakest singular vectors."""
    nr = S_hat.shape[-1]
    u, sv, vh = np.linalg.svd(S_hat)
    um, vm = u[..., :, -1], vh[..., -1, :].conj()
    a = np.einsum("...i,...b->...ib", um.conj(), vm).reshape(S_hat.shape[:-2] + (nr * nr,))
    var = np.einsum("...x,xy,...y->...", a, C, a.conj()).real
    return np.sqrt(var) / sv[..., -1]


def test_whitened_weak_direction_equals_the_plain_ratio_for_white_errors():
    rng = np.random.default_rng(3)
    S = rng.standard_normal((50, 3, 3)) + 1j * rng.standard_normal((50, 3, 3))
    cov = 1e-4 * np.eye(9, dtype=complex)
    np.testing.assert_allclose(whitened_weak_direction(S, np.broadcast_to(cov, (50, 9, 9))),
                               _plain_weak_ratio(S, cov), rtol=1e-10)
    assert whitened_weak_direction(S[:1], np.zeros((1, 9, 9), complex))[0] == 0.0


@pytest.mark.parametrize("loud_columns", [1.0, 2e-3])
def test_whitened_ratio_flags_a_singular_S_and_passes_a_determined_one(loud_columns):
    """Size and power of the undetermined flag under strongly anisotropic noise.

    A lifted loop with one fed-back output, ``S = I - L/(1+L) k k^H``: weakest direction
    ``k`` on both sides, ``sigma_min = 1/(1+L)``.  The disturbances reach the lifted inputs
    through the same controller, so the noise of ``S`` lies along ``k`` in the rows (plus a
    weak white part), and its column metric is anisotropic (two weakly, two strongly
    excited inputs).  With ``L = 1e6`` (``S`` singular to the noise) the null vector ``k``
    makes the whitened ``sigma_min`` at most the whitened noise along it, ``Gamma(nr)``-
    distributed in square, so >= 95 % of the draws must be flagged; with ``L = 0.5`` (a
    weak singular value 2/3, far above the noise) none may be.
    """
    rng = np.random.default_rng(11)
    nr, draws = 4, 400

    def c(*shape):
        return (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2)

    q, _ = np.linalg.qr(c(nr, nr))
    w = q @ np.diag([1.0, 1.0, loud_columns, loud_columns]) @ q.conj().T
    k = 0.9 * q[:, 2] + np.sqrt(0.19) * q[:, 0]
    sigma = 0.01 * np.outer(k, k.conj()) + 1e-6 * np.eye(nr)
    C = np.broadcast_to(np.kron(sigma, w), (draws, nr * nr, nr * nr))  # sigma_ij w_bc
    noise = np.linalg.cholesky(sigma) @ c(draws, nr, nr) @ np.linalg.cholesky(w).T
    for gain, want in ((1e6, True), (0.5, False)):
        S = np.eye(nr) - gain / (1 + gain) * np.outer(k, k.conj())
        rho, _ = weak_direction(S + noise, C)
        flagged = K95 * rho > UNDETERMINED_LIMIT
        if want:
            assert flagged.mean() >= 0.95, flagged.mean()
        else:
            assert not flagged.any()


def _random_indirect(rng, M=3, F=2, nu=2, ny=1, correlated=1.0):
    """A random G = [S; PS_1] per slow bin and a covariance of vec(G) with a strong
    common (rank-one) part, so that first- and second-order errors are correlated."""
    nr, nz = F * nu, F * nu + ny
    n = nz * nr

    def c(*shape):
        return rng.standard_normal(shape) + 1j * rng.standard_normal(shape)

    G = c(M, nz, nr)
    G[:, :nr] += 3 * np.eye(nr)
    root = 0.05 * c(M, n, n) + correlated * 0.05 * c(M, n, 1) @ c(M, 1, n)
    return G, root


def test_second_order_variance_against_monte_carlo():
    """E|e_lin D|^2 (D = dS S^-1, mapped to the fast FRF) from Isserlis' theorem equals
    the mean over 200 000 circular Gaussian draws of vec(dG) to 3 % (the Monte Carlo
    scatter is 0.5-1 %); the first- and second-order errors are uncorrelated."""
    from lcmr_xr.kernels.adaptive import second_order_variance
    from lcmr_xr.kernels.closed_loop import indirect_first_row
    from lcmr_xr.kernels.lifting import first_block_row_weights

    rng = np.random.default_rng(1)
    F, nu, ny, M = 2, 2, 1, 3
    nr, nz, N = F * nu, F * nu + ny, M * F
    G, root = _random_indirect(rng, M, F, nu, ny)
    C = root @ np.swapaxes(root.conj(), -1, -2)
    ind = indirect_first_row(G, nr, C)
    S_inv = np.linalg.inv(G[:, :nr])
    bins = np.arange(N // 2 + 1)
    var2 = second_order_variance(S_inv, ind.first_row, C, ind.first_row_cov, n_fast=N,
                                 factor=F, bins=bins)
    K = 200_000
    z = (rng.standard_normal((K, M, nz * nr)) + 1j * rng.standard_normal((K, M, nz * nr))) / np.sqrt(2)
    dG = np.einsum("mij,kmj->kmi", root, z).reshape(K, M, nz, nr)  # cov(vec dG) = C
    L = np.concatenate([-ind.first_row, np.broadcast_to(np.eye(ny), (M, ny, ny))], axis=-1)
    e1 = L @ dG @ S_inv
    e2 = e1 @ dG[:, :, :nr] @ S_inv
    w = first_block_row_weights(N, F, bins)

    def fast(e):
        return np.einsum("kj,nkajb->nkab", w, e.reshape(K, M, ny, F, nu)[:, bins % M])

    E1, E2 = fast(e1), fast(e2)
    mc = (np.abs(E2) ** 2).mean(axis=0)
    np.testing.assert_allclose(var2, mc, rtol=0.03)
    corr = np.abs((E1 * E2.conj()).mean(axis=0)) / np.sqrt((np.abs(E1) ** 2).mean(axis=0) * mc)
    assert corr.max() < 0.03
    # the cross term E[e_d conj(y_d')] E[y_d conj(e_d')] matters here: pairing each draw's
    # e_lin with another draw's D (same moments, no correlation) gives 5-40 % less, so a
    # formula without the cross term would fail the 3 % check above
    decorrelated = (np.abs(fast(np.roll(e1, 1, axis=0) @ dG[:, :, :nr] @ S_inv)) ** 2).mean(axis=0)
    assert (mc / decorrelated).max() > 1.3, mc / decorrelated
