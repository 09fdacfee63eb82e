"""Tests of the batched local polynomial / rational model kernel against truth.

* a literal per-bin ``numpy.linalg.lstsq`` oracle (``tests/_lrm_oracle.py``),
* systems for which the local model is exact (rational in the bin index, polynomial),
* noise statistics over many seeds (reported covariances vs empirical spread, coverage).
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

sys.path.insert(0, os.path.dirname(__file__))
from _lrm_oracle import (  # noqa: E402
    continuous_resonance,
    oracle_local_model,
    resonant_system,
)

from lcmr_xr.kernels.local_models import (  # noqa: E402
    CONDITION_LIMIT,
    local_model,
    parameters_per_row,
)


def _max_rel(a, b, mask=None):
    """Largest entrywise relative difference ``|a - b| / |b|`` over finite ``b``."""
    a, b = np.asarray(a), np.asarray(b)
    keep = np.isfinite(b) if mask is None else mask
    return float(np.max(np.abs(a[keep] - b[keep]) / np.abs(b[keep])))


def _random_spectra(rng, m, nr, nz):
    R = np.exp(2j * np.pi * rng.random((m, nr)))
    Z = rng.standard_normal((m, nz)) + 1j * rng.standard_normal((m, nz))
    return R, Z


# --------------------------------------------------------------------------- oracle
CASES = [
    # (nr, nz, half_width, degrees)
    (1, 1, 6, (2, 2, 2)),  # SISO LRM
    (1, 1, 5, (2, 1, 0)),  # SISO LPM
    (2, 1, 8, (3, 1, 1)),  # MISO
    (2, 3, 9, (2, 2, 2)),  # MIMO LRM
    (3, 2, 10, (2, 2, 0)),  # MIMO LPM
    (2, 2, 7, (1, 0, 3)),  # high denominator degree
    (2, 2, 7, (2, -1, 2)),  # no transient term (periodic data)
    (1, 2, 6, (2, -1, 0)),  # LPM without transient
]


@pytest.mark.parametrize("circular", [True, False])
@pytest.mark.parametrize("nr,nz,n,degrees", CASES)
def test_agrees_with_lstsq_oracle(nr, nz, n, degrees, circular):
    # resonant data: |Z| spans several decades over the bins
    R, Z, _, _ = resonant_system(96, nz, nr, seed=nr + 7 * nz + n, noise=1e-3)
    fit = local_model(R, Z, half_width=n, degrees=degrees, circular=circular)
    ref = oracle_local_model(R, Z, n, degrees, circular=circular)
    ok = ~fit.ill_posed
    assert fit.dof == ref["dof"] == 2 * n + 1 - parameters_per_row(nr, degrees)
    assert ok.sum() >= 96 - 2 * n
    assert _max_rel(fit.G, ref["G"], np.broadcast_to(ok[:, None, None], fit.G.shape)) < 1e-6
    if degrees[1] >= 0:
        assert _max_rel(fit.T, ref["T"], np.broadcast_to(ok[:, None], fit.T.shape)) < 1e-6
    else:  # no transient term (bins without a full window stay NaN)
        assert np.all(fit.T[ok] == 0)
    assert _max_rel(fit.noise_variance, ref["noise_variance"],
                    np.broadcast_to(ok[:, None], fit.T.shape)) < 1e-6
    # covariances: compare relative to the norm of each bin's matrix (entries may be ~0)
    def per_bin(a, b):
        a, b = a[ok], b[ok]
        axes = tuple(range(1, b.ndim))
        return float(np.max(np.sqrt(np.sum(np.abs(a - b) ** 2, axis=axes))
                            / np.sqrt(np.sum(np.abs(b) ** 2, axis=axes))))

    assert per_bin(fit.noise_covariance, ref["noise_covariance"]) < 1e-6
    assert per_bin(fit.G_cov, ref["G_cov"]) < 1e-6
    diag = local_model(R, Z, half_width=n, degrees=degrees, circular=circular,
                       covariance="diag").G_cov
    ref_var = np.real(np.diagonal(ref["G_cov"], axis1=-2, axis2=-1)).reshape(fit.G.shape)
    assert _max_rel(diag, ref_var, np.broadcast_to(ok[:, None, None], diag.shape)) < 1e-6
    none = local_model(R, Z, half_width=n, degrees=degrees, circular=circular, covariance=None)
    assert none.G_cov is None
    np.testing.assert_array_equal(none.G, fit.G)


def test_condition_estimate_brackets_true_condition():
    R, Z, _, _ = resonant_system(96, 3, 2, seed=3, noise=1e-3)
    fit = local_model(R, Z, half_width=9, degrees=(2, 2, 2))
    s = oracle_local_model(R, Z, 9, (2, 2, 2))["singular"]
    true = np.max(s[..., 0] / s[..., -1], axis=-1)  # worst row, column-scaled
    ratio = fit.condition / true
    # a lower bound from the Cholesky pivots; in practice within a factor p (= 11) of it
    assert np.all(ratio <= 1.0 + 1e-9)
    assert np.all(ratio >= 1.0 / parameters_per_row(2, (2, 2, 2)))
    assert np.median(ratio) > 0.2


def test_hdd_sized_problem_matches_oracle_on_sample_bins():
    """The paper's sizes: nr=4, nz=5, n=30, degrees (3,3,3) -> 23 parameters per row."""
    R, Z, _, _ = resonant_system(400, 5, 4, seed=11, noise=1e-3)
    assert np.ptp(np.log10(np.abs(Z))) > 4  # more than four decades of dynamic range
    fit = local_model(R, Z, half_width=30, degrees=(3, 3, 3))
    assert fit.dof == 61 - 23
    bins = np.arange(0, 400, 9)
    ref = oracle_local_model(R, Z, 30, (3, 3, 3), bins=bins)
    assert not fit.ill_posed[bins].any()
    assert _max_rel(fit.G[bins], ref["G"][bins]) < 1e-6
    assert _max_rel(fit.T[bins], ref["T"][bins]) < 1e-6
    assert _max_rel(fit.noise_variance[bins], ref["noise_variance"][bins]) < 1e-6
    # the sandwich covariance at this size, relative to each bin's matrix norm
    diff = np.linalg.norm(fit.G_cov[bins] - ref["G_cov"][bins], axis=(1, 2))
    assert np.max(diff / np.linalg.norm(ref["G_cov"][bins], axis=(1, 2))) < 1e-6


# ---------------------------------------------------------------------- window modes
def test_non_circular_mode_is_circular_on_padded_data():
    rng = np.random.default_rng(5)
    R, Z = _random_spectra(rng, 50, 2, 2)
    n = 7
    circ = local_model(R, Z, half_width=n, degrees=(1, 1, 1))
    wrap = np.arange(-n, 50 + n) % 50
    pad = local_model(R[wrap], Z[wrap], half_width=n, degrees=(1, 1, 1), circular=False)
    assert pad.G.shape == (64, 2, 2)
    # the n bins at each end lack a full window: NaN and flagged
    assert np.isnan(pad.G[:n]).all() and np.isnan(pad.G[-n:]).all()
    assert pad.ill_posed[:n].all() and pad.ill_posed[-n:].all()
    assert np.isnan(pad.noise_variance[-n:]).all() and np.isnan(pad.G_cov[:n]).all()
    np.testing.assert_allclose(pad.G[n:-n], circ.G, rtol=1e-10, atol=0)
    np.testing.assert_allclose(pad.G_cov[n:-n], circ.G_cov, rtol=1e-9, atol=1e-14)
    assert not pad.ill_posed[n:-n].any()


def test_circular_window_wraps_around():
    # bin 0's window uses bins M-n..M-1: a shift of the data shifts the estimates exactly
    rng = np.random.default_rng(6)
    R, Z = _random_spectra(rng, 40, 1, 2)
    fit = local_model(R, Z, half_width=5, degrees=(2, 1, 1))
    shifted = local_model(np.roll(R, 13, axis=0), np.roll(Z, 13, axis=0), half_width=5,
                          degrees=(2, 1, 1))
    np.testing.assert_allclose(shifted.G, np.roll(fit.G, 13, axis=0), rtol=1e-10)
    np.testing.assert_allclose(shifted.noise_variance, np.roll(fit.noise_variance, 13, axis=0),
                               rtol=1e-9)


def test_leading_dims_broadcast():
    rng = np.random.default_rng(7)
    R = np.exp(2j * np.pi * rng.random((3, 1, 60, 2)))
    Z = rng.standard_normal((1, 2, 60, 3)) + 1j * rng.standard_normal((1, 2, 60, 3))
    fit = local_model(R, Z, half_width=6, degrees=(2, 1, 1))
    assert fit.G.shape == (3, 2, 60, 3, 2)
    assert fit.G_cov.shape == (3, 2, 60, 6, 6)
    assert fit.condition.shape == fit.ill_posed.shape == (3, 2, 60)
    for a in range(3):
        for b in range(2):
            one = local_model(R[a, 0], Z[0, b], half_width=6, degrees=(2, 1, 1))
            np.testing.assert_allclose(fit.G[a, b], one.G, rtol=1e-12)
            np.testing.assert_allclose(fit.G_cov[a, b], one.G_cov, rtol=1e-12, atol=1e-300)


# ------------------------------------------------------------------------ exactness
def _exact_rational_data(m, nr, nz):
    """Noiseless spectra of a resonance rational in the bin index (second order)."""
    G, T = continuous_resonance(np.arange(m), nz, nr, seed=nr + nz, damping=0.02, width=6.0)
    R = np.exp(2j * np.pi * np.random.default_rng(1).random((m, nr)))
    return R, np.einsum("kip,kp->ki", G, R) + T, G, T


@pytest.mark.parametrize("nr,nz", [(1, 1), (2, 3)])
@pytest.mark.parametrize("degrees", [(1, 1, 2), (2, 2, 2)])
def test_lrm_exact_for_rational_system(nr, nz, degrees):
    """G and T rational in the bin index with a shared second-order denominator: exact.

    With Rd = 2 the local rational model contains the true one; any extra numerator or
    transient degree must come out zero, so G and T are recovered to rounding.
    """
    m, n = 120, 12
    R, Z, G, T = _exact_rational_data(m, nr, nz)
    # not periodic on the circle: use the padded mode (windows never wrap)
    fit = local_model(R, Z, half_width=n, degrees=degrees, circular=False)
    inner = slice(n, m - n)
    assert np.ptp(np.log10(np.abs(G[inner]))) > 1.5  # a sharp resonance inside the band
    # normal equations: forward error ~ eps cond(K)^2 (cond up to ~600 here, so the
    # tolerance is 1e-10 .. 1e-9; the QR-based oracle reaches 1e-13 on the same data)
    eps = np.finfo(float).eps
    tol = max(1e-10, 10 * eps * fit.condition[inner].max() ** 2)
    assert tol < 1e-9
    assert _max_rel(fit.G[inner], G[inner]) < tol
    assert _max_rel(fit.T[inner], T[inner]) < 10 * tol
    # zero residual up to rounding of the window's energy (the moments carry eps * energy)
    energy = np.convolve(np.sum(np.abs(Z) ** 2, axis=1), np.ones(2 * n + 1), "valid")
    assert np.max(fit.noise_variance[inner].max(axis=1) * fit.dof / energy) < 1e-13


def test_lpm_exact_for_polynomial_system():
    m, n, rn, rm = 80, 8, 3, 2
    k = np.arange(m) / m
    rng = np.random.default_rng(2)
    cg = rng.standard_normal((rn + 1, 2, 2)) + 1j * rng.standard_normal((rn + 1, 2, 2))
    ct = rng.standard_normal((rm + 1, 2)) + 1j * rng.standard_normal((rm + 1, 2))
    G = np.einsum("bip,kb->kip", cg, k[:, None] ** np.arange(rn + 1))
    T = np.einsum("ci,kc->ki", ct, k[:, None] ** np.arange(rm + 1))
    R = np.exp(2j * np.pi * rng.random((m, 2)))
    Z = np.einsum("kip,kp->ki", G, R) + T
    fit = local_model(R, Z, half_width=n, degrees=(rn, rm, 0), circular=False)
    inner = slice(n, m - n)
    assert _max_rel(fit.G[inner], G[inner]) < 1e-10
    assert _max_rel(fit.T[inner], T[inner]) < 1e-9


def test_lpm_error_on_smooth_system_within_derived_bound():
    """LPM on a heavily damped (smooth, not polynomial) system.

    Derivation: the estimate is linear, G_hat = g @ Z with g the G-rows of K^+, and it
    reproduces any local polynomial exactly (g @ (P R) = P(0)).  So for the LS polynomial
    fit P of G over the window, G_hat - G(k) = g @ ((G - P) R) + (P(0) - G(k)), and by
    Cauchy-Schwarz |G_hat - G(k)| <= ||g|| ||(G - P) R|| + |P(0) - G(k)|.
    """
    m, n, rn = 100, 10, 2
    k = np.arange(m)
    G, _ = continuous_resonance(k, 1, 1, seed=4, damping=0.7, width=25.0)
    rng = np.random.default_rng(3)
    R = np.exp(2j * np.pi * rng.random((m, 1)))
    Z = G[:, :, 0] * R
    fit = local_model(R, Z, half_width=n, degrees=(rn, 0, 0), circular=False)
    ref = oracle_local_model(R, Z, n, (rn, 0, 0), circular=False)
    r = np.arange(-n, n + 1)
    V = (r[:, None] / n) ** np.arange(rn + 1)
    worst = 0.0
    for kk in range(n, m - n):
        g_win = G[kk + r, 0, 0]
        coef, *_ = np.linalg.lstsq(V, g_win, rcond=None)
        poly = V @ coef
        # ||g||: the G-row of K^+; G_cov / noise variance gives ||g||^2 exactly
        gnorm = np.sqrt(np.real(ref["G_cov"][kk, 0, 0]) / ref["noise_variance"][kk, 0])
        bound = gnorm * np.linalg.norm((g_win - poly) * R[kk + r, 0]) + abs(coef[0] - G[kk, 0, 0])
        err = abs(fit.G[kk, 0, 0] - G[kk, 0, 0])
        assert err <= bound * (1 + 1e-9) + 1e-13
        worst = max(worst, err / abs(G[kk, 0, 0]))
    assert 1e-8 < worst < 1e-2  # not exact (the system is not polynomial), but close


# -------------------------------------------------------------------- noise statistics
def _noise_experiment(seeds, degrees, *, rho=0.6, sigma=0.05, m=48, n=8, rational=False):
    """Fixed R, exact local model, correlated complex noise on two output rows."""
    rng = np.random.default_rng(123)
    R = np.exp(2j * np.pi * rng.random((m, 2)))
    if rational:
        G, T = continuous_resonance(np.arange(m), 2, 2, seed=9, damping=0.3, width=40.0)
    else:  # locally polynomial: degree 1 in k
        kk = np.arange(m)[:, None, None] / m
        G = (1 + 0.5j) + (0.3 - 1j) * kk * np.array([[1, 2], [-1, 0.5]])
        T = 0.2 * (1 - kk[:, :, 0])
    clean = np.einsum("kip,kp->ki", G, R) + T
    # rows correlated with coefficient rho: V2 = rho V1 + sqrt(1 - rho^2) W
    noise_rng = np.random.default_rng(seeds)
    w = (noise_rng.standard_normal((seeds, m, 2)) + 1j * noise_rng.standard_normal((seeds, m, 2)))
    w *= sigma / np.sqrt(2)
    V = np.stack([w[..., 0], rho * w[..., 0] + np.sqrt(1 - rho**2) * w[..., 1]], axis=-1)
    Z = clean + V  # (seeds, m, 2): the seeds are a leading batch dim
    fit = local_model(R, Z, half_width=n, degrees=degrees, circular=False)
    inner = slice(n, m - n)
    return fit, G, inner, sigma


def test_lpm_reported_uncertainty_matches_spread_and_covers():
    """LPM on an exact polynomial system: e = V exactly, the covariance formula is exact."""
    seeds = 200
    fit, G, inner, sigma = _noise_experiment(seeds, (1, 1, 0), rational=False)
    Gh = fit.G[:, inner]  # (seeds, bins, nz, nr)
    err = Gh - G[inner]
    var = fit.G_cov[:, inner].diagonal(axis1=-2, axis2=-1).real.reshape(Gh.shape)
    # the noise variance estimate is unbiased for the exact model
    assert abs(fit.noise_variance[:, inner].mean() / sigma**2 - 1) < 0.03
    ratio = np.mean(np.abs(err) ** 2, axis=0) / np.mean(var, axis=0)
    assert 0.85 < np.median(ratio) < 1.15
    assert np.all((ratio > 0.6) & (ratio < 1.6))  # 200 seeds: chi2(400)/400 stays in here
    # 95% region of a circular complex Gaussian: |err|^2 / var ~ Exp(1), radius sqrt(ln 20)
    covered = np.abs(err) <= np.sqrt(np.log(20)) * np.sqrt(var)
    assert 0.90 <= covered.mean() <= 0.99


RESONANCE = dict(center=32.3, width=4.0, damping=0.1)


def _lrm_resonance_experiment(seeds, *, level=0.01, rho=0.8, m=64, n=12, degrees=(2, 2, 2)):
    """LRM on a lightly damped resonance *inside* the window, so d(r) is far from 1.

    ``G``, ``T`` are exactly rational in the bin index (second-order denominator), so the
    model with ``Rd = 2`` is exact and only noise matters.  Complex Gaussian noise with
    standard deviation ``level`` times the RMS of the clean output, correlated between the
    two rows with coefficient ``rho``; the seeds are a leading batch dim.
    """
    k = np.arange(m)
    G, T = continuous_resonance(k, 2, 2, seed=3, **RESONANCE)
    rng = np.random.default_rng(0)
    R = np.exp(2j * np.pi * rng.random((m, 2)))
    clean = np.einsum("kip,kp->ki", G, R) + T
    sigma = level * np.sqrt(np.mean(np.abs(clean) ** 2))
    noise_rng = np.random.default_rng(1)
    w = noise_rng.standard_normal((seeds, m, 2)) + 1j * noise_rng.standard_normal((seeds, m, 2))
    w *= sigma / np.sqrt(2)
    V = np.stack([w[..., 0], rho * w[..., 0] + np.sqrt(1 - rho**2) * w[..., 1]], axis=-1)
    fit = local_model(R, clean + V, half_width=n, degrees=degrees, circular=False)
    return fit, G, slice(n, m - n), sigma, n


@pytest.fixture(scope="module")
def lrm_resonance():
    return _lrm_resonance_experiment(240)


def test_lrm_window_has_denominator_far_from_one():
    """Guard of the statistical LRM tests: |d(r)| varies by > 10x in the typical window."""
    _, _, inner, _, n = _lrm_resonance_experiment(2)
    c, wd, z = RESONANCE["center"], RESONANCE["width"], RESONANCE["damping"]
    r = np.arange(-n, n + 1)
    spread = []
    for k in range(inner.start, inner.stop):
        s = 1j * (k + r - c) / wd
        a = np.abs(s**2 + 2 * z * s + 1)
        spread.append(a.max() / a.min())
    assert np.median(spread) > 10


def test_lrm_reported_uncertainty_matches_spread_and_covers(lrm_resonance):
    """Sandwich covariance with the noise on Z estimated through tau_ij: spread and coverage.

    With a white-residual formula (the equation error is d(r) V(r), not V) the reported
    variances were measured 30-40 % too small on such data; the noise estimate below
    would be off by the factor tau / dof (> 3 here).
    """
    fit, G, inner, sigma, _ = lrm_resonance
    Gh = fit.G[:, inner]
    err = Gh - G[inner]
    var = fit.G_cov[:, inner].diagonal(axis1=-2, axis2=-1).real.reshape(Gh.shape)
    ratio = np.mean(np.abs(err) ** 2, axis=0) / np.mean(var, axis=0)
    assert 0.85 < np.median(ratio) < 1.15
    covered = np.abs(err) <= np.sqrt(np.log(20)) * np.sqrt(var)
    assert 0.90 <= covered.mean() <= 0.99
    # noise_variance estimates the noise on Z (first order: within the 15 % bound)
    nv = fit.noise_variance[:, inner].mean(axis=(0, 1)) / sigma**2
    np.testing.assert_allclose(nv, 1.0, atol=0.15)
    # the "diag" mode reports exactly the diagonal of "full"
    one = local_model(*_first_seed_inputs(), half_width=12, degrees=(2, 2, 2), circular=False,
                      covariance="diag")
    full = local_model(*_first_seed_inputs(), half_width=12, degrees=(2, 2, 2), circular=False)
    diag = full.G_cov.diagonal(axis1=-2, axis2=-1).real.reshape(full.G.shape)
    np.testing.assert_allclose(one.G_cov[inner], diag[inner], rtol=1e-10)


def _first_seed_inputs():
    k = np.arange(64)
    G, T = continuous_resonance(k, 2, 2, seed=3, **RESONANCE)
    R = np.exp(2j * np.pi * np.random.default_rng(0).random((64, 2)))
    Z = np.einsum("kip,kp->ki", G, R) + T
    Z = Z + 0.01 * np.abs(Z).mean() * np.random.default_rng(5).standard_normal(Z.shape)
    return R, Z


def test_lrm_cross_row_covariance_matches_empirical(lrm_resonance):
    """Correlated noise (rho = 0.8) on two rows: the cross terms of G_cov and s_ij."""
    fit, G, inner, sigma, _ = lrm_resonance
    Gh = fit.G[:, inner]
    c = fit.G_cov[:, inner]
    nr = 2
    for p in range(nr):
        # Var(G_0p - G_1p) = c_00 + c_11 - 2 Re c_01; ignoring the cross term is far off
        d = Gh[..., 0, p] - Gh[..., 1, p]
        pred = c[..., p, p].real + c[..., nr + p, nr + p].real - 2 * c[..., p, nr + p].real
        emp = np.mean(np.abs(d - (G[inner, 0, p] - G[inner, 1, p])) ** 2, axis=0)
        assert 0.85 < np.median(emp / pred.mean(axis=0)) < 1.15
        no_cross = (c[..., p, p].real + c[..., nr + p, nr + p].real).mean(axis=0)
        assert np.median(emp / no_cross) < 0.5
    # the cross-row noise estimate s_01 tracks rho sigma^2
    nc = fit.noise_covariance[:, inner].mean(axis=(0, 1)) / sigma**2
    np.testing.assert_allclose(nc, [[1, 0.8], [0.8, 1]], atol=0.15)


def test_cross_row_covariance_matches_empirical():
    seeds = 200
    fit, G, inner, sigma = _noise_experiment(seeds, (1, 1, 0), rho=0.8)
    Gh = fit.G[:, inner]
    # difference of the two rows for input 0: Var = c11 + c22 - 2 Re c12
    d = Gh[..., 0, 0] - Gh[..., 1, 0]
    c = fit.G_cov[:, inner]
    nr = 2
    pred = c[..., 0, 0].real + c[..., nr, nr].real - 2 * c[..., 0, nr].real
    emp = np.var(d, axis=0)
    ratio = emp / pred.mean(axis=0)
    assert 0.85 < np.median(ratio) < 1.15
    # ignoring the cross term would be wrong by a factor 1 / (1 - rho) here
    no_cross = (c[..., 0, 0].real + c[..., nr, nr].real).mean(axis=0)
    assert np.median(emp / no_cross) < 0.4
    # and the residual cross-covariance estimates rho sigma^2
    nc = fit.noise_covariance[:, inner].mean(axis=(0, 1))
    np.testing.assert_allclose(nc, sigma**2 * np.array([[1, 0.8], [0.8, 1]]), atol=0.03 * sigma**2)


# ----------------------------------------------------------------- flags and errors
def test_unexcited_bins_are_flagged_not_raised():
    rng = np.random.default_rng(8)
    R, Z = _random_spectra(rng, 60, 1, 2)
    R[20:45] = 0.0  # no excitation: the regression is singular there
    fit = local_model(R, Z, half_width=5, degrees=(1, 1, 1))
    dead = np.arange(25, 40)  # every window inside the unexcited band
    assert fit.ill_posed[dead].all()
    assert np.isnan(fit.G[dead]).all()
    assert not fit.ill_posed[:10].any() and np.isfinite(fit.G[:10]).all()
    assert np.all((fit.condition > CONDITION_LIMIT) | ~fit.ill_posed | np.isinf(fit.condition))


@pytest.mark.parametrize("covariance", [None, "diag", "full"])
def test_failed_and_unfitted_bins_hold_nan_in_every_output(covariance):
    """The outputs are not prefilled: a bin whose fit fails and a bin without a full
    window (non-circular) must still hold NaN and the flag in every output."""
    rng = np.random.default_rng(8)
    R, Z = _random_spectra(rng, 60, 1, 2)
    R[20:45] = 0.0  # unexcited: the fit fails in bins 25..39
    for circular, bad in ((True, np.arange(25, 40)), (False, np.r_[0:5, 55:60])):
        fit = local_model(R if circular else R[:60], Z, half_width=5, degrees=(1, 1, 1),
                          circular=circular, covariance=covariance)
        assert fit.ill_posed[bad].all() and np.isinf(fit.condition[bad]).all()
        assert (fit.dropped[bad] == 0).all()
        for x in (fit.G, fit.T, fit.noise_covariance, fit.noise_variance):
            assert np.isnan(x[bad]).all()
        if covariance is not None:
            assert np.isnan(fit.G_cov[bad]).all()
        ok = np.setdiff1d(np.r_[5:15], bad)
        assert np.isfinite(fit.G[ok]).all() and not fit.ill_posed[ok].any()


def test_errors_say_what_to_fix():
    rng = np.random.default_rng(9)
    R, Z = _random_spectra(rng, 30, 2, 1)
    with pytest.raises(ValueError, match="2n\\+1 = 31"):
        local_model(R, Z, half_width=15)
    with pytest.raises(ValueError, match="half_width >= 8"):
        local_model(R, Z, half_width=7, degrees=(3, 3, 3))  # 15 parameters, 15 bins
    with pytest.raises(ValueError, match="same bins"):
        local_model(R, Z[:20], half_width=3, degrees=(1, 1, 1))
    with pytest.raises(ValueError, match="trailing channel axis"):
        local_model(R[:, 0], Z, half_width=3, degrees=(1, 1, 1))
    with pytest.raises(ValueError, match="covariance must be"):
        local_model(R, Z, half_width=6, degrees=(1, 1, 1), covariance="yes")
    with pytest.raises(ValueError, match="degrees must be three integers"):
        local_model(R, Z, half_width=6, degrees=(1, 1))
    with pytest.raises(ValueError, match="Rm = -1: no transient"):
        local_model(R, Z, half_width=6, degrees=(1, -2, 1))
    bad = Z.copy()
    bad[3] = np.nan
    with pytest.raises(ValueError, match="finite"):
        local_model(R, bad, half_width=6, degrees=(1, 1, 1))
    with pytest.raises(ValueError, match="do not broadcast"):
        local_model(np.stack([R] * 2), np.stack([Z] * 3), half_width=6, degrees=(1, 1, 1))


# ----------------------------------------------------------------------- invariants
@settings(max_examples=25, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    nr=st.integers(1, 2),
    nz=st.integers(1, 3),
    degrees=st.tuples(st.integers(0, 2), st.integers(0, 2), st.integers(0, 2)),
    alpha=st.floats(1e-3, 1e3),
    beta=st.floats(1e-3, 1e3),
)
def test_scaling_equivariance_and_oracle(seed, nr, nz, degrees, alpha, beta):
    rng = np.random.default_rng(seed)
    n = 8
    m = 40
    R, Z = _random_spectra(rng, m, nr, nz)
    fit = local_model(R, Z, half_width=n, degrees=degrees)
    scaled = local_model(alpha * R, beta * Z, half_width=n, degrees=degrees)
    ok = ~fit.ill_posed
    np.testing.assert_allclose(scaled.G[ok], fit.G[ok] * beta / alpha, rtol=1e-8)
    np.testing.assert_allclose(scaled.T[ok], fit.T[ok] * beta, rtol=1e-8)
    np.testing.assert_allclose(scaled.noise_variance[ok], fit.noise_variance[ok] * beta**2,
                               rtol=1e-8)
    np.testing.assert_allclose(scaled.condition, fit.condition, rtol=1e-6)
    bins = [0, 17, m - 1]
    ref = oracle_local_model(R, Z, n, degrees, bins=bins)
    assert _max_rel(fit.G[bins], ref["G"][bins]) < 1e-6
    assert _max_rel(fit.noise_variance[bins], ref["noise_variance"][bins]) < 1e-6


# ---------------------------------------------------------- internals of the fast kernel
# (the compiled per-bin loop works on moments from a recurrence and on small hand-written
# factorisations; these pin each step to an independent reference so that a wrong index
# cannot hide in the tails)
from lcmr_xr.kernels import local_model_bins as lmb  # noqa: E402
from lcmr_xr.kernels import local_models as lm  # noqa: E402


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), q=st.integers(1, 11), extra=st.integers(0, 8))
def test_augmented_cholesky_matches_numpy(seed, q, extra):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((3 * q, q)) + 1j * rng.standard_normal((3 * q, q))
    gram = np.conj(a.T) @ a
    rhs = rng.standard_normal((q, extra)) + 1j * rng.standard_normal((q, extra))
    m = np.concatenate([gram, rhs], axis=1)
    m[np.tril_indices(q, -1)] = np.nan  # never read
    piv = lmb.cholesky_augmented(m, q)
    low = np.linalg.cholesky(gram)
    np.testing.assert_allclose(np.triu(m[:, :q]), np.conj(low.T),
                               rtol=1e-10, atol=1e-10 * np.abs(low).max())
    np.testing.assert_allclose(m[:, q:], np.linalg.solve(low, rhs), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(piv, np.abs(np.diagonal(low)) ** 2, rtol=1e-10)


def test_augmented_cholesky_stops_at_a_non_positive_pivot():
    rng = np.random.default_rng(3)
    a = rng.standard_normal((12, 6)) + 1j * rng.standard_normal((12, 6))
    gram = np.conj(a.T) @ a
    gram[4] = gram[:, 4] = 0.0  # column 4 is zero: not positive definite
    m = np.concatenate([gram, np.ones((6, 2), complex)], axis=1)
    piv = lmb.cholesky_augmented(m, 6)
    assert np.isnan(piv[4:]).all()
    np.testing.assert_allclose(piv[:4], np.diagonal(np.linalg.cholesky(gram[:4, :4])).real ** 2,
                               rtol=1e-10)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 6))
def test_small_factorisations_match_numpy(seed, k):
    rng = np.random.default_rng(seed)
    a = rng.standard_normal((2 * k, k)) + 1j * rng.standard_normal((2 * k, k))
    gram = np.conj(a.T) @ a
    b = rng.standard_normal(k) + 1j * rng.standard_normal(k)
    ref = np.linalg.cholesky(gram)
    scratch = np.zeros((k, k), complex)
    assert lmb._natural_min_pivot(gram, scratch) == pytest.approx(
        np.min(np.diagonal(ref).real ** 2), rel=1e-10)
    low = np.zeros((k, k), complex)
    perm = np.zeros(k, dtype=np.int64)
    piv = np.empty(k)
    rank = lmb.pivoted_cholesky(gram.copy(), 0.0, low, perm, piv)
    assert rank == k
    # pivoted: L L^H is the permuted matrix and the pivots do not increase
    np.testing.assert_allclose(np.tril(low) @ np.conj(np.tril(low).T), gram[perm][:, perm],
                               rtol=1e-10, atol=1e-10 * np.abs(gram).max())
    assert np.all(np.diff(piv) <= 1e-12 * piv[0])
    x = np.empty(k, complex)
    lmb._chol_solve(low, k, b[perm], x)
    np.testing.assert_allclose(gram[perm][:, perm] @ x, b[perm], rtol=1e-8, atol=1e-9)


def test_pivoted_cholesky_drops_dependent_columns():
    rng = np.random.default_rng(4)
    a = rng.standard_normal((8, 3)) + 1j * rng.standard_normal((8, 3))
    a = np.concatenate([a, a[:, :1] * (2 - 1j) + a[:, 2:] * 0.5], axis=1)  # column 3 dependent
    gram = np.conj(a.T) @ a
    low = np.zeros((4, 4), complex)
    perm = np.zeros(4, dtype=np.int64)
    piv = np.empty(4)
    rank = lmb.pivoted_cholesky(gram.copy(), 1e-10 * np.abs(gram).max(), low, perm, piv)
    assert rank == 3
    assert abs(piv[3]) < 1e-10 * np.abs(gram).max()
    kept = perm[:3]
    np.testing.assert_allclose(np.tril(low[:3, :3]) @ np.conj(np.tril(low[:3, :3]).T),
                               gram[kept][:, kept], rtol=1e-10, atol=1e-12)


@pytest.mark.parametrize("n,degrees,restart",
                         [(6, (2, 1, 1), 4), (5, (3, 3, 3), 4), (40, (1, 2, 0), 32),
                          (7, (2, 2, 2), 1)])
def test_recurrence_moments_match_direct_sums(n, degrees, restart):
    """Every moment the fit reads equals the literal windowed sum, and the rounding floor
    of the R energies bounds their error and follows its definition."""
    rng = np.random.default_rng(11)
    nr, nz, nbat, k_out = 2, 3, 2, 150
    length = k_out + 2 * n
    R = rng.standard_normal((nbat, length, nr)) + 1j * rng.standard_normal((nbat, length, nr))
    Z = rng.standard_normal((nbat, length, nz)) + 1j * rng.standard_normal((nbat, length, nz))
    R[0, 60:] *= 1e-4  # a drop in level: the recurrence carries the louder past along
    slot_i, slot_j, p1 = lm._slot_pairs(nr, nz, degrees)
    top = lm._top_powers(degrees, 0)
    kind = ["R"] * nr + ["1"] + ["Z"] * nz
    slot_top = [top["".join(sorted([kind[i], kind[j]], key="R1Z".index))]
                for i, j in zip(slot_i, slot_j)]
    sel = np.ones((nbat, k_out), dtype=bool)
    sel[1, :37] = False  # segments without a wanted bin are skipped
    mom = np.full((nbat, k_out, len(slot_i) * p1), np.nan + 0j)
    floor = np.full((nbat, k_out, nr), np.nan)
    lmb.moments_and_floor(R, Z, n, sel, restart, 0, slot_i, slot_j, p1, mom, floor)
    base = np.concatenate([R, np.ones((nbat, length, 1)), Z], axis=-1)
    rho = np.arange(-n, n + 1) / n
    for s in range(len(slot_i)):
        x = np.conj(base[..., slot_i[s]]) * base[..., slot_j[s]]
        windows = np.lib.stride_tricks.sliding_window_view(x, 2 * n + 1, axis=1)
        powers = np.arange(slot_top[s] + 1)
        want = np.einsum("bkr,ar->bka", windows, rho[None, :] ** powers[:, None])
        got = mom[:, :, s * p1: s * p1 + len(powers)]
        np.testing.assert_allclose(got[sel], want[sel], rtol=0,
                                   atol=1e-12 * np.abs(want).max())
        if slot_i[s] == slot_j[s] < nr:  # the floor bounds the error of sum |R_p|^2
            err = np.abs(got[..., 0] - want[..., 0])[sel]
            assert np.all(err <= floor[..., slot_i[s]][sel])
    assert np.all(floor[sel] > 0)
    # the floor is 2 eps (W + 2 restart) times the R energy of the samples covered by
    # the windows of the segment (restart bins) that holds the bin
    w = 2 * n + 1
    energy = np.abs(R) ** 2
    for b, k in [(0, 0), (0, restart - 1), (0, min(restart, k_out - 1)), (1, 37)]:
        k0 = k - k % restart  # segments start at multiples of restart
        want = 2 * np.finfo(float).eps * (w + 2 * restart) * energy[
            b, k0: k0 + restart + w - 1].sum(axis=0)
        np.testing.assert_allclose(floor[b, k], want, rtol=1e-12)


def test_chunking_and_batch_grouping_do_not_change_results(monkeypatch):
    rng = np.random.default_rng(5)
    R = np.exp(2j * np.pi * rng.random((3, 150, 2)))
    Z = rng.standard_normal((3, 150, 2)) + 1j * rng.standard_normal((3, 150, 2))
    kw = {"half_width": 6, "degrees": (2, 1, 1)}
    ref = [local_model(R[b], Z[b], **kw) for b in range(3)]
    per_bin = lm._CHUNK_BYTES // lm._chunk_elements(2, 2, "full")  # bytes per bin
    # one bin per chunk (a restart per bin); 200 bins, batch elements grouped; one chunk
    for elements in (1, 200, 10**6):
        monkeypatch.setattr(lm, "_CHUNK_BYTES", elements * per_bin)
        fit = local_model(R, Z, **kw)
        for b in range(3):
            for name in ("G", "T", "noise_covariance", "G_cov", "condition"):
                np.testing.assert_allclose(getattr(fit, name)[b], getattr(ref[b], name),
                                           rtol=1e-9, atol=1e-300)




def test_least_squares_and_iv_share_one_compiled_version():
    """Least squares and instrumental variables call the compiled loop with the same
    argument types (empty instrument tables for least squares, run-time branches), for
    one record and for pooled experiments alike: an IV fit after a least-squares one
    compiles no further version (``identify``'s default, a least-squares fit and the IV
    twin of its widest window, compiles the loop once on a new install)."""
    rng = np.random.default_rng(7)
    R = np.exp(2j * np.pi * rng.random((2, 80, 2)))
    Z = rng.standard_normal((2, 80, 2)) + 1j * rng.standard_normal((2, 80, 2))
    kw = {"half_width": 6, "degrees": (2, 1, 1)}
    ls = [local_model(R[0], Z[0], covariance=cov, **kw) for cov in (None, "diag", "full")]
    pooled = local_model(R, Z, experiment_axis=0, covariance="full", **kw)
    before = set(lmb.fit_bins.signatures)
    for cov, fit in zip((None, "diag", "full"), ls):
        iv = local_model(R[0], Z[0], instruments=0.9 * Z[0] + 0.1 * Z[1], covariance=cov, **kw)
        assert not np.allclose(iv.G, fit.G)  # (the IV branches ran)
    iv = local_model(R, Z, experiment_axis=0, instruments=Z[::-1], covariance="full", **kw)
    assert not np.allclose(iv.G, pooled.G)
    assert set(lmb.fit_bins.signatures) == before
    # and over every version compiled in this process (earlier tests may have run IV
    # first): least squares and IV pass one instrument-argument type
    assert len({sig[-1] for sig in lmb.fit_bins.signatures}) == 1, lmb.fit_bins.signatures


@pytest.mark.parametrize("circular", [True, False])
def test_chunks_as_views_of_read_only_data_same_fit_no_new_compilation(monkeypatch, circular):
    """Chunks take their bins as views of the data (a copy only at the ends, or of
    read-only data): many chunks give the one-chunk fit, read-only input gives the
    writeable input's fit and compiles no second version of the loop."""
    rng = np.random.default_rng(6)
    R = np.exp(2j * np.pi * rng.random((150, 2)))
    Z = rng.standard_normal((150, 2)) + 1j * rng.standard_normal((150, 2))
    kw = {"half_width": 6, "degrees": (2, 1, 1), "circular": circular, "covariance": None}
    one = local_model(R, Z, **kw)
    per_bin = lm._CHUNK_BYTES // lm._chunk_elements(2, 2, None)
    monkeypatch.setattr(lm, "_CHUNK_BYTES", 16 * per_bin)  # 16-bin chunks
    many = local_model(R, Z, **kw)
    R_ro, Z_ro = R.copy(), Z.copy()
    R_ro.flags.writeable = Z_ro.flags.writeable = False
    ro = local_model(R_ro, Z_ro, **kw)
    assert lmb.fit_bins.signatures, "the fits above compiled (or loaded) no version of the loop"
    assert all(sig[0].mutable and sig[1].mutable for sig in lmb.fit_bins.signatures)
    for fit in (many, ro):
        for name in ("G", "T", "noise_covariance", "condition", "ill_posed"):
            np.testing.assert_allclose(getattr(fit, name), getattr(one, name), rtol=1e-9,
                                       atol=1e-300)
    assert not circular or not one.ill_posed.any()
    assert circular or one.ill_posed[:6].all() and not one.ill_posed[6:-6].any()


# ------------------------------------------------------- windows per bin, real signals
def test_window_per_bin_matches_oracle():
    """An integer array of half-widths: every bin is the oracle's fit at its own window."""
    rng = np.random.default_rng(21)
    m, nr, nz, degrees = 96, 2, 2, (2, 1, 1)
    R, Z, _, _ = resonant_system(m, nz, nr, seed=4, noise=1e-3)
    widths = rng.choice([6, 8, 11], size=m)
    fit = local_model(R, Z, half_width=widths, degrees=degrees)
    assert fit.dof.shape == (m,)
    np.testing.assert_array_equal(fit.dof, 2 * widths + 1 - parameters_per_row(nr, degrees))
    ok = ~fit.ill_posed
    assert ok.all()
    for n in (6, 8, 11):
        bins = np.flatnonzero(widths == n)
        ref = oracle_local_model(R, Z, n, degrees, bins=bins)
        assert _max_rel(fit.G[bins], ref["G"][bins]) < 1e-6
        assert _max_rel(fit.noise_variance[bins], ref["noise_variance"][bins]) < 1e-6
        diff = np.linalg.norm(fit.G_cov[bins] - ref["G_cov"][bins], axis=(1, 2))
        assert np.max(diff / np.linalg.norm(ref["G_cov"][bins], axis=(1, 2))) < 1e-6
    # a constant array is the scalar window
    same = local_model(R, Z, half_width=np.full(m, 8), degrees=degrees)
    scalar = local_model(R, Z, half_width=8, degrees=degrees)
    np.testing.assert_allclose(same.G, scalar.G, rtol=1e-12)
    np.testing.assert_allclose(same.G_cov, scalar.G_cov, rtol=1e-12, atol=1e-300)
    assert scalar.dof == 17 - parameters_per_row(nr, degrees)
    # padded mode: a bin lacks a full window for its own width only
    pad = local_model(R, Z, half_width=widths, degrees=degrees, circular=False)
    k = np.arange(m)
    full = (k - widths >= 0) & (k + widths <= m - 1)
    assert np.isnan(pad.G[~full]).all() and pad.ill_posed[~full].all()
    assert not pad.ill_posed[full].any()
    with pytest.raises(ValueError, match="one half-width per bin"):
        local_model(R, Z, half_width=widths[:-1], degrees=degrees)
    with pytest.raises(ValueError, match="integer"):
        local_model(R, Z, half_width=widths + 0.5, degrees=degrees)


def test_real_signal_spectra_are_fitted_on_half_the_bins_and_mirrored():
    """Spectra of real signals: G(M-k) = conj(G(k)) exactly, and still the oracle's fit."""
    rng = np.random.default_rng(22)
    m, n, degrees = 80, 9, (2, 2, 2)
    r = rng.standard_normal((m, 2))
    z = np.stack([np.convolve(np.tile(r[:, 0], 2), [1.0, 0.5, -0.3])[m: 2 * m]
                  + 0.01 * rng.standard_normal(m),
                  np.convolve(np.tile(r[:, 1], 2), [0.2, 1.0])[m: 2 * m]
                  + 0.01 * rng.standard_normal(m)], axis=1)
    R, Z = np.fft.fft(r, axis=0), np.fft.fft(z, axis=0)
    fit = local_model(R, Z, half_width=n, degrees=degrees)
    k = np.arange(1, m // 2)  # (DC and Nyquist are their own mirrors)
    np.testing.assert_array_equal(fit.G[m - k], np.conj(fit.G[k]))
    np.testing.assert_array_equal(fit.G_cov[m - k], np.conj(fit.G_cov[k]))
    np.testing.assert_array_equal(fit.condition[m - k], fit.condition[k])
    bins = np.array([0, 3, m // 2, m // 2 + 1, m - 5, m - 1])
    ref = oracle_local_model(R, Z, n, degrees, bins=bins)
    assert _max_rel(fit.G[bins], ref["G"][bins]) < 1e-6
    diff = np.linalg.norm(fit.G_cov[bins] - ref["G_cov"][bins], axis=(1, 2))
    assert np.max(diff / np.linalg.norm(ref["G_cov"][bins], axis=(1, 2))) < 1e-6



@pytest.mark.parametrize("covariance", [None, "diag", "full"])
def test_mirror_in_pieces_per_thread_is_the_whole_mirror(monkeypatch, covariance):
    """The mirrored half is written in one piece per thread: every output equal, bit for
    bit, for one and for three threads (uneven pieces), odd and even M, a batch dim."""
    rng = np.random.default_rng(5)
    for m in (67, 80):
        x = np.fft.fft(rng.standard_normal((2, m, 5)), axis=1)
        fits = []
        for threads in (1, 3):
            monkeypatch.setattr(lm, "_threads", lambda t=threads: t)
            monkeypatch.setattr(lm, "_CHUNK_BYTES", 16 * 79 * 8)  # several tasks
            fits.append(local_model(x[..., :2], x[..., 2:], half_width=6,
                                    degrees=(1, 1, 1), covariance=covariance))
        k = np.arange(1, (m + 1) // 2)
        np.testing.assert_array_equal(fits[0].G[:, m - k], np.conj(fits[0].G[:, k]))
        for name in ("G", "T", "noise_covariance", "G_cov", "condition", "ill_posed",
                     "dropped"):
            np.testing.assert_array_equal(getattr(fits[1], name), getattr(fits[0], name),
                                          err_msg=name)


# -------------------------------------------------------- exactly modelled, noiseless data
@pytest.mark.parametrize("nr,nz", [(1, 1), (2, 3)])
def test_exactly_modelled_data_give_G_not_nan(nr, nz):
    """Denominator degree above the truth: numerator and denominator can share any factor
    (1 + c rho), so the local parameters are not unique, but G = N(0)/D(0) is.  The
    undetermined denominator term is dropped and G comes out exact, not NaN/flagged."""
    m, n = 120, 12
    R, Z, G, T = _exact_rational_data(m, nr, nz)
    fit = local_model(R, Z, half_width=n, degrees=(2, 2, 3), circular=False)
    inner = slice(n, m - n)
    assert not fit.ill_posed[inner].any()
    assert (fit.dropped[inner] >= nz).all()  # at least one term per row was dropped
    assert np.all(fit.condition[inner] > CONDITION_LIMIT)  # the full model is singular
    assert _max_rel(fit.G[inner], G[inner]) < 1e-8
    assert _max_rel(fit.T[inner], T[inner]) < 1e-7


def test_noiseless_hdd_experiments_flag_no_bin_and_error_falls_with_n():
    """Issue 12: noiseless HDD experiments lost up to half their slow bins (NaN, and
    identify raised for a singular S) once the window became narrow in frequency
    (N = 18000 flagged 2631 bins, N = 36000 9000).  N = 180000 is in
    ``benchmarks/local_models.py`` (too long for the suite)."""
    import lcmr_xr
    from lcmr_xr import hdd

    medians = []
    for n_samples in (3600, 18000, 36000):
        exp = hdd.simulate(n_samples=n_samples, noise=False, seed=1)
        frf = lcmr_xr.identify(exp, window=30, degrees=(3, 3, 3), covariance=False)
        assert not frf.ill_posed.any() and not frf.s_singular.any()
        assert not frf.P_flag[1:].any()  # DC: the VCM's double integrator is infinite
        true = hdd.true_frf(frf.frequency[1:]).values
        medians.append(float(np.median(np.abs(frf.P.values[1:] - true) / np.abs(true))))
    assert medians[0] > medians[1] > medians[2]
    assert medians[2] < 1e-5


def test_one_thread_inside_worker_threads():
    import threading

    assert lm._threads() >= 1
    seen = []
    worker = threading.Thread(target=lambda: seen.append(lm._threads()))
    worker.start()
    worker.join()
    assert seen == [1]
    rng = np.random.default_rng(23)
    R, Z = _random_spectra(rng, 300, 2, 2)
    main = local_model(R, Z, half_width=6, degrees=(1, 1, 1))
    got = []
    worker = threading.Thread(
        target=lambda: got.append(local_model(R, Z, half_width=6, degrees=(1, 1, 1))))
    worker.start()
    worker.join()
    np.testing.assert_allclose(got[0].G, main.G, rtol=1e-12)


def test_thread_count_read_without_launching_numbas_pool():
    """_threads() reads numba's setting without starting numba's thread pool (which the
    kernel never uses), and follows numba.set_num_threads once it is called."""
    import subprocess

    code = (
        "import numba\n"
        "from numba.np.ufunc import parallel\n"
        "from lcmr_xr.kernels import local_models as lm\n"
        "assert lm._threads() == max(1, numba.config.NUMBA_NUM_THREADS)\n"
        "assert not parallel._is_initialized\n"
        "numba.set_num_threads(1)\n"
        "assert lm._threads() == 1\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env=dict(os.environ, NUMBA_NUM_THREADS="2"))
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_no_transient_term_is_exact_for_periodic_data():
    """Rm = -1 (issue 14's periodic case): no transient column, T = 0, G exact."""
    m, n, rn = 80, 8, 2
    k = np.arange(m) / m
    rng = np.random.default_rng(24)
    cg = rng.standard_normal((rn + 1, 2, 2)) + 1j * rng.standard_normal((rn + 1, 2, 2))
    G = np.einsum("bip,kb->kip", cg, k[:, None] ** np.arange(rn + 1))
    R = np.exp(2j * np.pi * rng.random((m, 2)))
    Z = np.einsum("kip,kp->ki", G, R)
    fit = local_model(R, Z, half_width=n, degrees=(rn, -1, 0), circular=False)
    inner = slice(n, m - n)
    assert fit.dof == 2 * n + 1 - 2 * (rn + 1) == 2 * n + 1 - parameters_per_row(2, (rn, -1, 0))
    assert _max_rel(fit.G[inner], G[inner]) < 1e-10
    assert np.all(fit.T[inner] == 0)


# ---------------------------------------------------------------- pooled experiments
from _lrm_oracle import oracle_pooled_local_model  # noqa: E402


def _pooled_data(m, n_exp, nz, nr, noise=1e-2):
    """``E`` experiments of one system (shared G) with their own excitation, transient
    and noise."""
    R, Z = [], []
    G0 = resonant_system(m, nz, nr, seed=0, noise=noise)[2]
    for e in range(n_exp):
        Re, Ze, Ge, _ = resonant_system(m, nz, nr, seed=e, noise=noise)
        R.append(Re)
        Z.append(Ze + np.einsum("kip,kp->ki", G0 - Ge, Re))  # the same G, own T and noise
    return np.array(R), np.array(Z), G0


@pytest.mark.parametrize("degrees,covariance", [((2, 2, 2), "full"), ((2, 1, 0), None),
                                                ((1, 2, 1), "diag")])
def test_pooled_experiments_agree_with_stacked_oracle(degrees, covariance):
    R, Z, _ = _pooled_data(48, 3, 2, 2)
    fit = local_model(R, Z, half_width=8, degrees=degrees, experiment_axis=0,
                      covariance=covariance)
    ref = oracle_pooled_local_model(R, Z, 8, degrees)
    rel = lambda a, b: np.max(abs(a - b)) / np.max(abs(b))  # noqa: E731
    assert fit.G.shape == (48, 2, 2) and fit.T.shape == (3, 48, 2)
    assert fit.dof == ref["dof"] == 3 * 17 - (2 * (degrees[0] + 1) + 3 * (degrees[1] + 1)
                                              + degrees[2])
    assert rel(fit.G, ref["G"]) < 1e-9
    assert rel(fit.T, ref["T"]) < 1e-9
    if covariance == "full":
        assert rel(fit.noise_covariance, ref["noise_covariance"]) < 1e-9
        assert rel(fit.G_cov, ref["G_cov"]) < 1e-9
    elif covariance == "diag":
        assert rel(fit.G_cov, np.real(np.diagonal(ref["G_cov"], axis1=-2, axis2=-1))
                   .reshape(48, 2, 2)) < 1e-9
    if degrees[2] == 0:  # LPM: tau = dof exactly, also without the covariance
        assert rel(fit.noise_covariance, ref["noise_covariance"]) < 1e-9


def test_pooled_windows_may_be_narrower_than_one_record_allows():
    """(2, 2, 2) with nr = 2: 11 parameters per row, so one record needs n >= 6; four
    experiments together have 4 (2 n + 1) - 11 - 3 * 3 = 8 dof at n = 3 (stacked oracle)."""
    R, Z, _ = _pooled_data(48, 4, 2, 2)
    with pytest.raises(ValueError, match="half_width >= 6"):
        local_model(R[0], Z[0], half_width=3, degrees=(2, 2, 2))
    fit = local_model(R, Z, half_width=3, degrees=(2, 2, 2), experiment_axis=0)
    ref = oracle_pooled_local_model(R, Z, 3, (2, 2, 2))
    assert fit.dof == ref["dof"] == 8
    rel = lambda a, b: np.max(abs(a - b)) / np.max(abs(b))  # noqa: E731
    assert rel(fit.G, ref["G"]) < 1e-9 and rel(fit.G_cov, ref["G_cov"]) < 1e-9
    with pytest.raises(ValueError, match="over 4 pooled experiments.*half_width >= 3"):
        local_model(R, Z, half_width=2, degrees=(2, 2, 2), experiment_axis=0)


def test_pooled_one_experiment_is_the_single_record_fit_bit_for_bit():
    R, Z, _ = _pooled_data(48, 2, 2, 2)
    one = local_model(R[:1], Z[:1], half_width=8, degrees=(2, 2, 2), experiment_axis=0)
    ref = local_model(R[0], Z[0], half_width=8, degrees=(2, 2, 2))
    for name in ("G", "noise_covariance", "G_cov", "condition", "ill_posed", "dropped"):
        assert np.array_equal(getattr(one, name), getattr(ref, name), equal_nan=True), name
    assert np.array_equal(one.T[0], ref.T, equal_nan=True)


def test_pooled_experiment_axis_anywhere_in_the_leading_dims():
    R, Z, _ = _pooled_data(48, 2, 1, 1)
    batch = np.stack([R, 2 * R], axis=1)  # (E, batch, M, nr)
    zb = np.stack([Z, 2 * Z], axis=1)
    fit = local_model(batch, zb, half_width=8, degrees=(2, 2, 0), experiment_axis=0)
    ref = local_model(R, Z, half_width=8, degrees=(2, 2, 0), experiment_axis=-3)
    assert fit.G.shape == (2, 48, 1, 1) and fit.T.shape == (2, 2, 48, 1)
    np.testing.assert_allclose(fit.G[0], ref.G, rtol=1e-12)
    np.testing.assert_allclose(fit.G[1], ref.G, rtol=1e-12)  # G R scaled like Z
    with pytest.raises(ValueError, match="experiment_axis must be a leading axis"):
        local_model(R, Z, half_width=8, degrees=(2, 2, 0), experiment_axis=-1)


# ------------------------------------------- review19: pair-wise Cholesky and covariance=None
@pytest.mark.parametrize("q", [5, 6])
@pytest.mark.parametrize("zero", [0, 1, 2, 3, 4])
def test_augmented_cholesky_stops_at_either_pivot_of_a_pair(q, zero):
    """Two pivots at a time: a non-positive pivot in the first or the second of a pair (or
    in the odd tail) stops there: that and later pivots NaN, earlier ones exact."""
    rng = np.random.default_rng(q + 10 * zero)
    a = rng.standard_normal((3 * q, q)) + 1j * rng.standard_normal((3 * q, q))
    gram = np.conj(a.T) @ a
    gram[zero] = gram[:, zero] = 0.0
    m = np.concatenate([gram, np.ones((q, 2), complex)], axis=1)
    piv = lmb.cholesky_augmented(m, q)  # (cholesky_planes has no Python wrapper)
    assert np.isnan(piv[zero:]).all()
    if zero:
        np.testing.assert_allclose(
            piv[:zero], np.diagonal(np.linalg.cholesky(gram[:zero, :zero])).real ** 2, rtol=1e-10)


@pytest.mark.parametrize("nr,nz", [(1, 1), (2, 3)])
def test_exactly_modelled_data_same_G_for_every_covariance_mode(nr, nz):
    """Dropped denominator terms with covariance=None (which reads only the trailing block
    of the factor) give the G of "full" and "diag" to rounding, also at extreme scales."""
    m, n = 120, 12
    R, Z, G, _ = _exact_rational_data(m, nr, nz)
    inner = slice(n, m - n)
    full = local_model(R, Z, half_width=n, degrees=(2, 2, 3), circular=False)
    for scale in (1e-150, 1.0, 1e150):
        for cov in (None, "diag"):
            fit = local_model(R * scale, Z, half_width=n, degrees=(2, 2, 3), circular=False,
                              covariance=cov)
            assert not fit.ill_posed[inner].any()
            np.testing.assert_array_equal(fit.dropped[inner], full.dropped[inner])
            assert _max_rel(fit.G[inner] * scale, full.G[inner]) < 1e-10
