"""The band of noiseless data: residuals below what the local model's moments resolve
(``lcmr_xr.kernels.identification._resolution_floor``), against exact results and the
HDD benchmark's true FRF."""

from __future__ import annotations

import numpy as np
import pytest

from lcmr_xr import hdd, identify
from lcmr_xr.kernels.adaptive import K95
from lcmr_xr.kernels.identification import _resolution_floor, _resolution_level, slow_bin_terms
from lcmr_xr.kernels.local_models import local_model
from lcmr_xr.kernels.pooling import rescale_covariance

EPS = np.finfo(float).eps


def _lpm_data(noise, m=64, seed=0):
    """Two outputs of a two-input system plus a transient that the LPM models exactly
    (on the whole circle): exact to rounding without ``noise``."""
    rng = np.random.default_rng(seed)
    R = np.exp(2j * np.pi * rng.random((m, 2)))
    Z = np.einsum("mij,mj->mi", _lpm_truth(m), R) + 0.3 - 0.1j
    return R, Z + noise * (rng.standard_normal(Z.shape) + 1j * rng.standard_normal(Z.shape))


def _floor(R, Z, n, degrees):
    fit = local_model(R, Z, half_width=n, degrees=degrees, covariance="full")
    terms = dict(nr=2, closed_loop="direct", mirrors=False, first_row_only=False)
    out = slow_bin_terms(fit.G, fit.G_cov, **terms)
    return fit, out, _resolution_floor(out, fit, fit.G_cov, R, Z, terms, half_width=n,
                                       degrees=degrees, circular=True)


def test_resolution_floor_of_an_exact_lpm_is_eps_times_the_window_energy():
    """Exact data: the LPM's residual variance is rounding (0, negative or tiny), its
    ``G_cov`` gives bands of width ~0.  The floor is the Cauchy-Schwarz bound of an
    unresolved equation error: ``var(G_ip) = eps sum_window |Z_i|^2 [K^+ K^+H]_pp``, with
    the LPM's ``K^+ K^+H`` (which does not depend on ``Z``) from a fit of noisy data."""
    n, degrees = 6, (2, 2, 0)
    R, Z = _lpm_data(0.0)
    fit, out, (mended, G_cov, s) = _floor(R, Z, n, degrees)
    level = _resolution_level(Z, half_width=n, dof=fit.dof, circular=True)
    var = np.real(np.diagonal(fit.noise_covariance, axis1=-2, axis2=-1))
    assert (var < level * fit.dof).all()  # every row of every bin below the floor
    # the oracle: X = K^+ K^+H from a noisy fit's G_cov / s (the same R, so the same X)
    noisy = local_model(R, _lpm_data(1e-3)[1], half_width=n, degrees=degrees,
                        covariance="full")
    energy = EPS * np.array([np.sum(np.abs(np.take(Z[:, i], np.arange(b - n, b + n + 1),
                                                   mode="wrap")) ** 2) for b in range(64)
                             for i in range(2)]).reshape(64, 2)
    new = energy[..., :, None] * np.eye(2)
    expected = rescale_covariance(noisy.G_cov, noisy.noise_covariance, new)
    # (to the probe's own resolution: its residual, 1e-12 of |Z|^2, is resolved to ~1e-4)
    np.testing.assert_allclose(G_cov, expected, rtol=1e-3, atol=0)
    np.testing.assert_allclose(mended["G_var"], np.real(np.diagonal(expected, axis1=-2,
                               axis2=-1)).reshape(fit.G.shape), rtol=1e-3)
    # before: the band of width ~0 did not cover G's own rounding error somewhere
    truth = _lpm_truth()
    err = np.abs(fit.G - truth)
    assert (err > K95 * np.sqrt(np.maximum(out["G_var"], 0))).any()
    assert (err <= K95 * np.sqrt(mended["G_var"])).all()


def _lpm_truth(m=64):
    return np.broadcast_to(np.array([[1.0, 2.0 - 1.0j], [0.5j, 1e-3]]), (m, 2, 2))


def test_resolution_floor_leaves_noisy_fits_bit_for_bit():
    n, degrees = 6, (2, 2, 0)
    R, Z = _lpm_data(1e-6)
    fit, out, (mended, G_cov, s) = _floor(R, Z, n, degrees)
    assert mended == {} and G_cov is fit.G_cov and s is fit.noise_covariance


def _released_hdd(n, window, seed):
    exp = hdd.simulate(n, case=2, noise=False, seed=seed)
    f = np.arange(n // 2 + 1) * (100800.0 / n)
    truth = np.full((n // 2 + 1, 1, 2), np.nan, complex)
    truth[1:] = hdd.true_frf(f[1:], case=2).values
    out = identify(exp, window=window)
    released = np.broadcast_to(~out.P_undetermined.values[:, None, None], truth.shape) \
        & np.isfinite(truth)
    err = np.abs(out.P.values - truth)[released]
    return out, err, out.P_std.values[released]


@pytest.mark.slow
@pytest.mark.parametrize("window", [30, "auto"])
def test_noiseless_band_holds_at_36000(window):
    """Noiseless HDD, N = 36 000 (seed 0), where 72 % of the slow bins have a row below the
    moments' resolution.  Measured before: 1750 (window 30) / 6750 (``auto``) released
    entries with ``P_std`` exactly 0 and an error, coverage 0.551 / 0.677; after: none,
    0.833 / 0.947 (the rest at window 30 is the local model's error at resolved bins,
    which one window's residual does not tell from noise)."""
    out, err, std = _released_hdd(36000, window, 0)
    assert not ((std == 0) & (err > 0)).any()
    assert (err <= K95 * std).mean() > {30: 0.8, "auto": 0.92}[window]
    # slow DC stays flagged (fast 0 and N/2)
    assert out.P_undetermined.values[[0, -1]].all()


@pytest.mark.slow
def test_noiseless_auto_chooses_from_the_unfloored_variances():
    """``window="auto"`` chooses its window per bin from the variances without the
    resolution floor (a bound for the released band, not a variance estimate), and
    releases the chosen window's floored band.  Noiseless HDD, N = 36 000, seed 0:
    median relative error of the released bins 6.14e-8 (the choice of before the floor),
    coverage 0.980, no ``P_std`` 0; chosen from the floored variances (every candidate's
    band near its floor), window 12 won 0.7 % of the slow bins instead of 2.4 %, the
    median was 6.62e-8 and the coverage 0.969."""
    n = 36000
    out, err, std = _released_hdd(n, "auto", 0)
    truth = hdd.true_frf(np.arange(1, n // 2 + 1) * (100800.0 / n), case=2).values
    released = ~out.P_undetermined.values[1:]
    rel = np.abs(out.P.values[1:] - truth)[released] / np.abs(truth[released])
    assert np.median(rel[np.isfinite(rel)]) < 6.4e-8
    assert not ((std == 0) & (err > 0)).any() and (err <= K95 * std).mean() > 0.975


def test_resolution_floor_of_a_haloed_block_as_of_the_circle():
    """The frequency-chunk path fits a haloed block with ``circular=False``: it floors the
    band as the circular fit does.  Before, ``_resolution_floor`` returned at once for
    ``circular=False``: the noiseless HDD at N = 36 000, window 30, ``frequency_chunks``
    2000 had 1926 entries of ``P_std`` exactly 0 (none without chunks).  The probe's
    phases follow the block's bins, not the circle's: the bands agree to the probe's
    effect (here 1e-4)."""
    from lcmr_xr.kernels.identification import _fit_terms

    n, degrees, m, h = 6, (2, 2, 0), 64, 9
    R, Z = _lpm_data(0.0, m=m)
    kw = dict(half_width=n, degrees=degrees, covariance=True, known_covariance=None,
              experiment_axis=None, closed_loop="direct")
    whole = _fit_terms(R, Z, circular=True, **kw)
    near = np.arange(-h, m + h) % m
    block = _fit_terms(R[near], Z[near], circular=False, **kw)
    # the floor: the Cauchy-Schwarz width, not rounding (as the first test's oracle)
    assert (whole["G_var"] > 1e-6 * EPS).all()
    np.testing.assert_allclose(block["G_var"][h:m + h], whole["G_var"], rtol=1e-3)


def test_resolution_floor_of_an_iv_fit_reads_the_iv_regression_factor():
    """``denominator="iv"`` with one exact row (0, modelled exactly, residual rounding)
    and one noisy row (1, resolved): the floor rebuilds ``G_cov`` from ``X`` of the
    probed refit, which must be the IV fit's own, so that the resolved row keeps its
    band (its variance is not floored).  Before, the refit was least squares: row 1's
    ``G_var`` moved by up to 88 % (the HDD's IV twin, case 9 seed 2 N = 3600: 32-43 %)."""
    from lcmr_xr.kernels.identification import _fit_terms, denominator_instruments

    m, n, degrees = 128, 8, (2, 2, 2)
    rng = np.random.default_rng(1)
    R = np.exp(2j * np.pi * rng.random((m, 2)))
    w = np.exp(2j * np.pi * np.arange(m) / m)
    noisy = np.einsum("mj,mj->m", np.stack([1 + 0 * w, 0.3 + 0 * w], -1) / (1 - 0.5 * w)[:, None], R)
    noisy = noisy + 1e-2 * (rng.standard_normal(m) + 1j * rng.standard_normal(m))
    Z = np.stack([2 * R[:, 0] - 1j * R[:, 1], noisy], -1)
    W = denominator_instruments(R, Z, degrees=degrees)
    fit = local_model(R, Z, half_width=n, degrees=degrees, covariance="full", instruments=W)
    level = _resolution_level(Z, half_width=n, dof=fit.dof, circular=True) * fit.dof
    var = np.real(np.diagonal(fit.noise_covariance, axis1=-2, axis2=-1))
    assert (var[:, 0] < level[:, 0]).all() and (var[:, 1] > level[:, 1]).all()
    out = _fit_terms(R, Z, half_width=n, degrees=degrees, circular=True, covariance=True,
                     known_covariance=None, experiment_axis=None, closed_loop="direct",
                     denominator="iv", instruments=W)
    own = np.real(np.diagonal(fit.G_cov, axis1=-2, axis2=-1)).reshape(fit.G.shape)
    np.testing.assert_allclose(out["G_var"][:, 1], own[:, 1], rtol=1e-2)
    assert (out["G_var"][:, 0] > own[:, 0]).all()  # the exact row's band floored
