"""Instrumental variables for the local model's denominator (``local_model(instruments=)``).

* a literal per-bin IV oracle (``tests/_lrm_oracle.py``: ``numpy.linalg.solve`` of the IV
  normal equations, the explicit sandwich and the oblique projector's ``tau``), single
  records and pooled experiments;
* identities: instruments equal to ``Z`` are least squares, the LPM ignores them;
* noiseless exactly modelled data give the true ``G``;
* statistics over seeds: least squares is biased by the noise in its denominator
  regressors, IV is not, and its covariance and noise estimate match the spread.
"""

from __future__ import annotations

import os
import sys

import numpy as np
import pytest

sys.path.insert(0, os.path.dirname(__file__))
from _lrm_oracle import (  # noqa: E402
    continuous_resonance,
    oracle_local_model,
    oracle_pooled_local_model,
    resonant_system,
)

from lcmr_xr.kernels.local_models import local_model  # noqa: E402


def _per_bin(a, b, ok):
    """Largest per-bin relative difference (Frobenius norm of each bin's entries)."""
    a, b = a[ok], b[ok]
    axes = tuple(range(1, b.ndim))
    return float(np.max(np.sqrt(np.sum(np.abs(a - b) ** 2, axis=axes))
                        / np.sqrt(np.sum(np.abs(b) ** 2, axis=axes))))


def _prediction(clean, rng, error=0.05):
    """A noise-free but imperfect prediction of ``Z`` (the instruments): the clean
    spectra with a relative model error."""
    c = np.abs(clean).mean()
    return clean + error * c * (rng.standard_normal(clean.shape)
                                + 1j * rng.standard_normal(clean.shape))


# --------------------------------------------------------------------------- oracle
IV_CASES = [
    # (nr, nz, half_width, degrees, circular)
    (1, 1, 7, (2, 2, 2), True),
    (2, 3, 9, (2, 2, 2), False),
    (2, 2, 7, (1, 0, 3), True),
    (2, 2, 8, (2, -1, 2), True),  # no transient term
    (1, 2, 9, (3, 3, 1), False),
]


@pytest.mark.parametrize("nr,nz,n,degrees,circular", IV_CASES)
def test_iv_agrees_with_oracle(nr, nz, n, degrees, circular):
    m = 64
    R, Z, G, T = resonant_system(m, nz, nr, seed=nr + 5 * nz + n, noise=1e-2)
    Zhat = _prediction(np.einsum("kip,kp->ki", G, R) + T, np.random.default_rng(n))
    ref = oracle_local_model(R, Z, n, degrees, circular=circular, instruments=Zhat)
    fit = local_model(R, Z, half_width=n, degrees=degrees, circular=circular,
                      instruments=Zhat)
    ok = ~fit.ill_posed
    assert ok.sum() == (m if circular else m - 2 * n)
    assert fit.dof == ref["dof"]
    assert _per_bin(fit.G, ref["G"], ok) < 1e-9
    if degrees[1] >= 0:
        assert _per_bin(fit.T, ref["T"], ok) < 1e-9
    assert _per_bin(fit.noise_covariance, ref["noise_covariance"], ok) < 1e-9
    assert _per_bin(fit.G_cov, ref["G_cov"], ok) < 1e-9
    diag = local_model(R, Z, half_width=n, degrees=degrees, circular=circular,
                       instruments=Zhat, covariance="diag")
    ref_var = np.real(np.diagonal(ref["G_cov"], axis1=-2, axis2=-1)).reshape(fit.G.shape)
    assert _per_bin(diag.G_cov, ref_var, ok) < 1e-9
    none = local_model(R, Z, half_width=n, degrees=degrees, circular=circular,
                       instruments=Zhat, covariance=None)
    assert none.G_cov is None
    np.testing.assert_array_equal(none.G, fit.G)
    np.testing.assert_array_equal(diag.G, fit.G)


def _pooled(m, n_exp, nz, nr, rng):
    """``E`` experiments of one system (own excitation, transient and noise) and a
    noise-free imperfect prediction of each."""
    R, Z, Zhat = [], [], []
    G0 = resonant_system(m, nz, nr, seed=0, noise=1e-2)[2]
    for e in range(n_exp):
        Re, Ze, Ge, Te = resonant_system(m, nz, nr, seed=e, noise=1e-2)
        R.append(Re)
        Z.append(Ze + np.einsum("kip,kp->ki", G0 - Ge, Re))
        Zhat.append(_prediction(np.einsum("kip,kp->ki", G0, Re) + Te, rng))
    return np.array(R), np.array(Z), np.array(Zhat)


@pytest.mark.parametrize("degrees,covariance", [((2, 2, 2), "full"), ((1, 2, 1), "diag"),
                                                ((2, -1, 3), "full")])
def test_iv_pooled_agrees_with_stacked_oracle(degrees, covariance):
    R, Z, Zhat = _pooled(48, 3, 2, 2, np.random.default_rng(3))
    ref = oracle_pooled_local_model(R, Z, 8, degrees, instruments=Zhat)
    fit = local_model(R, Z, half_width=8, degrees=degrees, experiment_axis=0,
                      covariance=covariance, instruments=Zhat)
    ok = ~fit.ill_posed
    assert ok.all() and fit.dof == ref["dof"]
    assert _per_bin(fit.G, ref["G"], ok) < 1e-9
    if degrees[1] >= 0:
        assert _per_bin(np.moveaxis(fit.T, 0, 1), np.moveaxis(ref["T"], 0, 1), ok) < 1e-9
    if covariance == "full":
        assert _per_bin(fit.noise_covariance, ref["noise_covariance"], ok) < 1e-9
        assert _per_bin(fit.G_cov, ref["G_cov"], ok) < 1e-9
    else:
        ref_var = np.real(np.diagonal(ref["G_cov"], axis1=-2, axis2=-1)).reshape(fit.G.shape)
        assert _per_bin(fit.G_cov, ref_var, ok) < 1e-9


def test_iv_window_per_bin_matches_oracle():
    rng = np.random.default_rng(8)
    m, nr, nz, degrees = 64, 2, 2, (2, 1, 2)
    R, Z, G, T = resonant_system(m, nz, nr, seed=4, noise=1e-2)
    Zhat = _prediction(np.einsum("kip,kp->ki", G, R) + T, rng)
    widths = rng.choice([7, 9, 12], size=m)
    fit = local_model(R, Z, half_width=widths, degrees=degrees, instruments=Zhat)
    assert not fit.ill_posed.any()
    for n in (7, 9, 12):
        bins = np.flatnonzero(widths == n)
        ref = oracle_local_model(R, Z, n, degrees, bins=bins, instruments=Zhat)
        sel = np.isin(np.arange(m), bins)
        assert _per_bin(fit.G, ref["G"], sel) < 1e-9
        assert _per_bin(fit.noise_covariance, ref["noise_covariance"], sel) < 1e-9
        assert _per_bin(fit.G_cov, ref["G_cov"], sel) < 1e-9


def test_iv_real_signals_mirror_and_agree_with_oracle():
    """Spectra of real signals (instruments too): fitted on half the bins and mirrored,
    every bin still the oracle's IV fit."""
    rng = np.random.default_rng(12)
    m, nr, nz, n, degrees = 48, 2, 2, 8, (2, 1, 2)
    r = rng.standard_normal((m, nr))
    z = np.cumsum(rng.standard_normal((m, nz)), axis=0)  # real, coloured
    z_hat = z + 0.1 * rng.standard_normal((m, nz))
    R, Z, Zhat = (np.fft.fft(x, axis=0) for x in (r, z, z_hat))
    fit = local_model(R, Z, half_width=n, degrees=degrees, instruments=Zhat)
    ref = oracle_local_model(R, Z, n, degrees, instruments=Zhat)
    ok = ~fit.ill_posed
    assert ok.all()
    np.testing.assert_array_equal(fit.G[m // 2 + 1:], np.conj(fit.G[m // 2 - 1:0:-1]))
    assert _per_bin(fit.G, ref["G"], ok) < 1e-9
    assert _per_bin(fit.G_cov, ref["G_cov"], ok) < 1e-9


# ----------------------------------------------------------------------- identities
def test_instruments_equal_to_z_are_least_squares():
    """``W = B``: the IV normal equations are the least-squares ones (to rounding), single
    and pooled, with the same dropped-term and flag decisions."""
    R, Z, _, _ = resonant_system(64, 2, 2, seed=6, noise=1e-2)
    for kw, args in (({}, (R, Z)), ({"experiment_axis": 0}, _pooled(48, 2, 2, 2,
                                                                      np.random.default_rng(0))[:2])):
        ls = local_model(*args, half_width=8, degrees=(2, 2, 2), **kw)
        iv = local_model(*args, half_width=8, degrees=(2, 2, 2), instruments=args[1], **kw)
        ok = ~ls.ill_posed
        assert ok.all()
        np.testing.assert_array_equal(iv.ill_posed, ls.ill_posed)
        np.testing.assert_array_equal(iv.dropped, ls.dropped)
        # (LU and Cholesky round differently: eps times the squared condition, up to ~1e4)
        for name in ("G", "noise_covariance", "G_cov"):
            assert _per_bin(getattr(iv, name), getattr(ls, name), ok) < 1e-9, name


def test_lpm_ignores_instruments_bit_for_bit():
    """``Rd = 0``: no denominator, nothing to instrument: the least-squares result."""
    R, Z, _, _ = resonant_system(64, 2, 2, seed=6, noise=1e-2)
    ls = local_model(R, Z, half_width=8, degrees=(2, 2, 0))
    iv = local_model(R, Z, half_width=8, degrees=(2, 2, 0), instruments=2 * Z + 1)
    for name in ("G", "T", "noise_covariance", "G_cov", "condition", "ill_posed", "dropped"):
        np.testing.assert_array_equal(getattr(iv, name), getattr(ls, name))


def test_iv_exact_for_noiseless_rational_system():
    """Noiseless data that the model (with a denominator degree above the truth) fits
    exactly: IV with an imperfect prediction as instruments recovers ``G`` and ``T``, the
    undetermined denominator terms are dropped as in least squares, no bin flagged."""
    m, n, nr, nz = 120, 12, 2, 2
    G, T = continuous_resonance(np.arange(m), nz, nr, seed=4, damping=0.02, width=6.0)
    rng = np.random.default_rng(1)
    R = np.exp(2j * np.pi * rng.random((m, nr)))
    Z = np.einsum("kip,kp->ki", G, R) + T
    Zhat = Z * (1.0 + 0.3 * np.exp(2j * np.pi * rng.random((m, nz))))
    inner = slice(n, m - n)
    for degrees in ((1, 1, 2), (2, 2, 3)):
        ls = local_model(R, Z, half_width=n, degrees=degrees, circular=False)
        iv = local_model(R, Z, half_width=n, degrees=degrees, circular=False,
                         instruments=Zhat)
        assert not ls.ill_posed[inner].any() and not iv.ill_posed[inner].any()
        np.testing.assert_array_equal(iv.dropped, ls.dropped)
        assert np.max(np.abs(iv.G[inner] - G[inner]) / np.abs(G[inner])) < 1e-8
        assert np.max(np.abs(iv.T[inner] - T[inner]) / np.abs(T[inner])) < 1e-7


# ----------------------------------------------------------------------- statistics
def _draws(n_draws, noise, rng, m=64, center=32):
    """``n_draws`` records of a SISO resonance rational in the bin index (exact for
    degrees (1, 1, 2)), random-phase excitation, white noise ``noise`` times the RMS of
    the output on ``Z``; the noise-free output is returned as the instruments."""
    G, T = continuous_resonance(np.arange(m), 1, 1, seed=2, damping=0.05, center=center,
                                width=4)
    R = np.exp(2j * np.pi * rng.random((n_draws, m, 1)))
    clean = np.einsum("kip,dkp->dki", G, R) + T
    scale = noise * np.sqrt(np.mean(np.abs(clean) ** 2))
    V = scale * (rng.standard_normal(clean.shape) + 1j * rng.standard_normal(clean.shape))
    return R, clean + V / np.sqrt(2), clean, G, scale**2


def test_iv_removes_the_noise_induced_bias_and_its_band_is_calibrated():
    """300 draws, noise 10 % of the output RMS, 17 bins around the resonance.  Least
    squares: the noise in ``-rho^s Z`` biases ``G`` (many standard errors).  IV with the
    noise-free output as instruments: bias within the Monte Carlo error, reported
    variance of ``G`` within 15 % of the spread, the noise variance within 10 %."""
    n_draws, bins = 300, slice(24, 41)
    R, Z, clean, G, s2 = _draws(n_draws, 0.1, np.random.default_rng(0))
    kw = {"half_width": 8, "degrees": (1, 1, 2)}
    ls = local_model(R, Z, **kw)
    iv = local_model(R, Z, instruments=clean, **kw)
    assert not iv.ill_posed[:, bins].any()

    def bias_z(fit):
        dG = (fit.G - G)[:, bins, 0, 0]
        return np.abs(dG.mean(0)) / (dG.std(0) / np.sqrt(n_draws)), dG

    z_ls, _ = bias_z(ls)
    z_iv, dG = bias_z(iv)
    assert np.median(z_ls) > 8  # least squares: biased
    assert np.mean(z_iv**2) < 2.5 and z_iv.max() < 4  # IV: |bias| / s.e. ~ |N(0, 1)|
    spread = np.mean(np.abs(dG - dG.mean(0)) ** 2, axis=0)
    ratio = np.mean(iv.G_cov[:, bins, 0, 0].real, axis=0) / spread
    assert 0.85 < np.median(ratio) < 1.15 and np.all((ratio > 0.75) & (ratio < 1.3))
    s_ratio = np.mean(iv.noise_variance[:, bins, 0], axis=0) / s2
    assert 0.9 < np.median(s_ratio) < 1.1


def test_pooled_iv_error_falls_with_the_experiments():
    """60 pools of 4 draws (issue 14's floor): least squares pooled keeps its bias, its
    error falls far less than 1/E and its band is too narrow; IV's error falls about
    1/E and its band is calibrated.  Medians: a just-identified IV estimate has heavy
    tails (the rare draw whose IV system nearly vanishes reports a variance as large as
    its error), so the mean square is not the measure; for a calibrated complex
    estimate ``|dG|^2 / var`` is exponential, median ``ln 2``."""
    n_draws, n_exp, bins = 240, 4, slice(24, 41)
    R, Z, clean, G, _ = _draws(n_draws, 0.1, np.random.default_rng(1))
    kw = {"half_width": 8, "degrees": (1, 1, 2)}
    R4, Z4, C4 = (x.reshape((n_draws // n_exp, n_exp) + x.shape[1:]) for x in (R, Z, clean))
    one_iv = local_model(R, Z, instruments=clean, **kw)
    one_ls = local_model(R, Z, **kw)
    iv = local_model(R4, Z4, instruments=C4, experiment_axis=1, **kw)
    ls = local_model(R4, Z4, experiment_axis=1, **kw)
    err = lambda f: np.abs(f.G - G)[:, bins, 0, 0] ** 2  # noqa: E731
    med = lambda f: np.median(err(f))  # noqa: E731
    z = lambda f: np.median(err(f) / f.G_cov[:, bins, 0, 0].real)  # noqa: E731
    assert 0.15 < med(iv) / med(one_iv) < 0.4  # ~ 1/E
    assert med(ls) / med(one_ls) > 0.5 and med(ls) > 3 * med(iv)  # the bias stays
    assert 0.55 < z(iv) < 0.85  # ln 2 = 0.69
    assert z(ls) > 2


# ------------------------------------------------------------------ flags and errors
def test_useless_instruments_fail_or_flag_bins_not_raise():
    """Instruments in the span of the shared columns (``Zhat = R``: ``rho^s R`` is a
    numerator column) leave nothing after projection: NaN and flagged in every bin."""
    R, Z, _, _ = resonant_system(64, 1, 1, seed=2, noise=1e-2)
    dead = local_model(R, Z, half_width=8, degrees=(2, 2, 1), instruments=R)
    assert dead.ill_posed.all() and np.isnan(dead.G).all() and np.isnan(dead.G_cov).all()
    assert np.isnan(dead.noise_covariance).all()
    # not in the span: R's part is projected away, what is left is Z's, a good instrument
    # (1e-6 would leave a squared sine of 1e-12, DROP_TOLERANCE: numerically in the span)
    fine = local_model(R, Z, half_width=8, degrees=(2, 2, 1), instruments=R + 1e-3 * Z)
    assert not fine.ill_posed.any()


@pytest.mark.parametrize("admixture,flagged", [(1e-4, True), (0.3, False)])
def test_weak_instruments_are_flagged(admixture, flagged):
    """One window (padded mode, 2n + 1 bins, the centre fitted), Rd = 1: an instrument
    orthogonal to the shared columns and to the regressor ``rho Z`` plus a small
    admixture of ``rho Z``: its canonical correlation with the regressor is about the
    admixture, the IV system near singular where least squares is not: flagged (below
    ``WEAK_INSTRUMENT_LIMIT``), finite.  A strong admixture: not flagged."""
    from lcmr_xr.kernels.local_models import WEAK_INSTRUMENT_LIMIT

    assert 1e-4 < WEAK_INSTRUMENT_LIMIT < 0.3
    n, rng = 8, np.random.default_rng(4)
    rho = np.arange(-n, n + 1) / n
    R, Z, _, _ = resonant_system(2 * n + 1, 1, 1, seed=5, noise=3e-2)
    A = np.stack([R[:, 0] * rho**b for b in range(3)] + [rho**c + 0j for c in range(3)]
                 + [np.eye(2 * n + 1)[n] + 0j], axis=1)  # shared columns, and rho(0) = 0
    x = rho * Z[:, 0]
    Q, _ = np.linalg.qr(np.column_stack([A, x]))
    v = rng.standard_normal(2 * n + 1) + 1j * rng.standard_normal(2 * n + 1)
    v -= Q @ (Q.conj().T @ v)  # orthogonal to A, to rho Z and zero at the centre
    px = x - Q[:, :-1] @ (Q[:, :-1].conj().T @ x)  # rho Z projected off A
    w = v / np.linalg.norm(v) + admixture * px / np.linalg.norm(px)
    Zhat = np.divide(w, rho, out=np.zeros_like(w), where=rho != 0)[:, None]
    ls = local_model(R, Z, half_width=n, degrees=(2, 2, 1), circular=False)
    iv = local_model(R, Z, half_width=n, degrees=(2, 2, 1), circular=False, instruments=Zhat)
    assert not ls.ill_posed[n]
    assert iv.ill_posed[n] == flagged and np.isfinite(iv.G[n]).all()


def test_instruments_errors_say_what_to_fix():
    R, Z, _, _ = resonant_system(64, 2, 2, seed=2, noise=1e-2)
    kw = {"half_width": 8, "degrees": (2, 2, 2)}
    with pytest.raises(ValueError, match=r"instruments must have Z's shape \(\.\.\., M, nz\)"):
        local_model(R, Z, instruments=Z[:, :1], **kw)
    with pytest.raises(ValueError, match="instruments must have Z's shape"):
        local_model(R, Z, instruments=Z[0], **kw)
    with pytest.raises(ValueError, match="do not broadcast"):
        local_model(R, np.stack([Z, Z]), instruments=np.stack([Z, Z, Z]), **kw)
    bad = Z.copy()
    bad[3, 1] = np.nan
    with pytest.raises(ValueError, match="instruments must be finite"):
        local_model(R, Z, instruments=bad, **kw)
    with pytest.raises(TypeError, match="real or complex numeric"):
        local_model(R, Z, instruments=Z.astype(str), **kw)
    with pytest.raises(TypeError, match="real or complex numeric"):
        local_model(R, Z, instruments=np.abs(Z) > 1, **kw)
    # real instruments are accepted (a real prediction is a valid, if poor, instrument)
    assert local_model(R, Z, instruments=Z.real, **kw).G.shape == (64, 2, 2)
    # leading dims broadcast like Z's: one prediction per batch entry
    both = local_model(np.stack([R, R]), Z, instruments=np.stack([Z, 1.1 * Z]), **kw)
    assert both.G.shape == (2, 64, 2, 2)
    np.testing.assert_allclose(both.G[0], local_model(R, Z, instruments=Z, **kw).G, rtol=1e-12)
