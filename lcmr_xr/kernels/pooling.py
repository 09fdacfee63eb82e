"""Pooling repeated periods and several experiments, on plain arrays (no labels).

Periodic excitation (Pintelon and Schoukens, *System Identification: A Frequency Domain
Approach*, 2nd ed., Wiley/IEEE 2012, sections 2.4 and 7.2; the robust LPM of Pintelon,
Vandersteen, De Locht, Rolain and Schoukens, "Experimental characterization of operational
amplifiers: a system identification approach", IEEE TIM 53(3), 2004, and Pintelon,
Barbe, Vandersteen and Van Moer, "Improved (non-)parametric identification of dynamic
systems excited by periodic signals", MSSP 25(7), 2011).  With ``P`` steady-state periods
of one periodic excitation, the spectra ``Z[p](k)`` of the periods differ only by the
noise, so per bin

    Z_mean(k)  = 1/P sum_p Z[p](k)
    C_Z(k)     = 1/(P (P - 1)) sum_p (Z[p](k) - Z_mean(k)) (Z[p](k) - Z_mean(k))^H

``C_Z`` is the sample covariance of the periods divided by ``P``: an unbiased,
model-free estimate of the covariance of the noise on ``Z_mean`` with ``P - 1`` degrees
of freedom (complex).  It stays unbiased when the periods have unequal noise levels
(independent records), which is why records of several experiments with the same
excitation can be pooled with it too.

Window 0 (the classical multi-experiment design, Pintelon and Schoukens 2012, section
2.7; Dobrowiecki, Schoukens and Guillaume, IEEE TIM 55(6), 2006).  ``E >= nr``
steady-state experiments with different excitations give, at every bin, the
over-determined (or square) system ``A G^T = B`` with ``A[e] = R_e(k)^T`` (E x nr) and
``B[e] = Z_e(k)^T`` (E x nz), solved per bin by the pseudo-inverse ``W = A^+``:
``G^T = W B``.  With noise ``V_e`` of covariance ``C_e`` on ``Z_e`` (independent over
experiments), ``Cov(G_ip, G_jq) = sum_e C_e,ij W_pe conj(W_qe)``.

Everything is batched over bins (and leading dims): no Python loop over frequency.
"""

from __future__ import annotations

from typing import NamedTuple

import warnings

import numpy as np

from lcmr_xr.kernels.local_models import CONDITION_LIMIT
from lcmr_xr.kernels.moving import window_sums

__all__ = ["MIN_SPLIT_EXPERIMENTS", "PooledFit", "SPREAD_SMOOTHING", "group_weight",
           "half_variances", "mean_and_covariance", "nearest_correlation", "p_spread_factor",
           "pooled_least_squares",
           "rescale_covariance", "split_halves", "spread_calibration", "spread_ratio",
           "window_mean"]

#: Neighbouring slow bins (each side) over which the split-half spread ratio of pooled
#: experiments is averaged (a bin alone has a few degrees of freedom; the local model's
#: misstatement changes slowly with frequency).
SPREAD_SMOOTHING = 6
#: Fewest pooled experiments whose covariance is checked by split halves: halves of at
#: least two experiments each.  A half of ONE record is a single-record fit, whose IV
#: estimate has a heavy tail (docs/uncertainty.md, "Instrumental variables": 1 % of the
#: entries carry 84 % of the mean squared error), so its difference from the other half
#: says little about the pool's variance; and at 2 degrees of freedom in its first fit
#: it amplifies rounding (eager and frequency-chunked results then differ by 1e-5).
MIN_SPLIT_EXPERIMENTS = 4


def mean_and_covariance(Z: np.ndarray, n_pool_axes: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Mean of repeated records and the covariance of that mean, per bin.

    Parameters
    ----------
    Z : ndarray, complex, shape (..., K1, ..., M, nz)
        Spectra of repeated records (periods, or periods x experiments with the same
        excitation): the ``n_pool_axes`` axes just before ``(M, nz)`` are pooled.
    n_pool_axes : int, default 1
        How many axes to pool (``K = K1 K2 ...`` records in all).

    Returns
    -------
    mean : ndarray, shape (..., M, nz)
        ``1/K sum Z``.
    cov : ndarray, shape (..., M, nz, nz)
        ``1/(K (K-1)) sum (Z - mean)(Z - mean)^H``: the sample covariance of the records
        divided by ``K`` (covariance of the mean; ``K - 1`` complex degrees of freedom).
        NaN when ``K < 2``.

    Examples
    --------
    >>> Z = np.array([[[1.0 + 0j]], [[3.0 + 0j]]])   # K = 2 records, M = 1, nz = 1
    >>> mean, cov = mean_and_covariance(Z)
    >>> complex(mean[0, 0]), float(cov[0, 0, 0].real)
    ((2+0j), 1.0)
    """
    Z = np.asarray(Z)
    lead = Z.shape[: Z.ndim - 2 - n_pool_axes]
    k = int(np.prod(Z.shape[len(lead): -2], dtype=int))
    Zk = Z.reshape(lead + (k,) + Z.shape[-2:])
    mean = Zk.mean(axis=-3)
    if k < 2:
        return mean, np.full(mean.shape + mean.shape[-1:], np.nan + 0j)
    dev = Zk - mean[..., None, :, :]
    # sum over records of dev dev^H per bin: (..., M, nz, K) @ (..., M, K, nz)
    dev_b = np.moveaxis(dev, -3, -1)  # (..., M, nz, K)
    cov = dev_b @ np.conj(np.swapaxes(dev_b, -1, -2)) / (k * (k - 1))
    return mean, cov


def window_mean(x: np.ndarray, half_width: int, *, axis: int = -3, circular: bool = True) -> np.ndarray:
    """Mean over the ``2 n + 1``-bin window centred on every bin, in ``O(1)`` per bin.

    Noise spectra span many decades, so a running sum over all bins would lose the small
    values to the rounding of the large ones: the sums are
    :func:`lcmr_xr.kernels.moving.window_sums` (each window summed from its own bins,
    rounding relative to the local magnitude; the cost does not grow with the window).
    ``circular``: bins wrap around (as the local models' windows); otherwise the ``n``
    bins at each end lack a full window and are NaN.

    Parameters
    ----------
    x : ndarray
        Values per bin along ``axis``.
    half_width : int
        ``n``; ``0`` returns a copy of ``x``.
    axis : int, default -3
        The bin axis.
    circular : bool, default True
        Wrap the window around the ends.

    Returns
    -------
    ndarray
        Same shape as ``x``.

    Examples
    --------
    >>> window_mean(np.array([1.0, 2.0, 3.0, 4.0]), 1, axis=0)
    array([2.33333333, 2.        , 3.        , 2.66666667])
    """
    x = np.moveaxis(np.asarray(x), axis, 0)
    n = int(half_width)
    m = x.shape[0]
    if n == 0:
        return np.moveaxis(x.copy(), 0, axis)
    w = 2 * n + 1
    if w > m:
        raise ValueError(f"a window of {w} bins is wider than the {m} bins.")
    padded = x[np.arange(-n, m + n) % m] if circular else x
    sums = window_sums(padded, w)
    out = sums / w
    if not circular:
        nan = np.full((n,) + x.shape[1:], np.nan, dtype=out.dtype)
        out = np.concatenate([nan, out, nan])
    return np.moveaxis(out, 0, axis)


def rescale_covariance(G_cov: np.ndarray, noise_used: np.ndarray, noise_new: np.ndarray) -> np.ndarray:
    """Swap the noise covariance in a local-model ``G_cov`` for another estimate.

    The local model's first-order covariance has the form
    ``Cov(G_ip, G_jq) = s_ij X_ij[p, q]`` with the noise covariance ``s`` it estimated
    from its residuals (``LocalModelFit.noise_covariance``) and a data-dependent factor
    ``X_ij`` (:func:`lcmr_xr.kernels.local_models.local_model`, Notes).  Replacing ``s``
    by another estimate of the same quantity (e.g. the nonparametric one from periods)
    is the element-wise rescaling ``G_cov * s_new_ij / s_used_ij``.  Where ``s_used_ij``
    is exactly 0 the factor is unknown: NaN.

    Parameters
    ----------
    G_cov : ndarray, shape (..., M, nz nr, nz nr)
        Covariance of ``vec(G)`` (row-major, index ``i nr + p``).
    noise_used, noise_new : ndarray, shape (..., M, nz, nz)
        The noise covariance behind ``G_cov``, and its replacement.

    Returns
    -------
    ndarray, shape (..., M, nz nr, nz nr)
    """
    nz = noise_used.shape[-1]
    nr = G_cov.shape[-1] // nz
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(noise_used != 0, noise_new / noise_used, np.nan)
    C = G_cov.reshape(G_cov.shape[:-2] + (nz, nr, nz, nr))
    out = C * ratio[..., :, None, :, None]
    return out.reshape(G_cov.shape)


def nearest_correlation(s: np.ndarray) -> np.ndarray:
    """A positive semidefinite noise covariance with the diagonal of ``s``, per bin.

    The local model estimates every entry of its noise covariance on its own,
    ``s_ij = sum_r e_i(r) conj(e_j(r)) / tau_ij`` with each pair's own expected residual
    energy ``tau_ij`` (:func:`lcmr_xr.kernels.local_models.local_model`, Notes): unbiased
    entry by entry, but not a covariance as a whole.  ``|tau_ij| <= sqrt(tau_ii tau_jj)``
    (Cauchy-Schwarz: ``tau_ij`` is an inner product of the rows' residual-maker matrices),
    so where the rows' noise is nearly collinear (the lifted ``u`` and ``y`` of a loop share
    their disturbances) the estimated correlations exceed 1, the matrix has negative
    eigenvalues, and so may the first-order variance of ``P`` derived from it
    (:func:`lcmr_xr.kernels.closed_loop.frf_variance_from_first_row` clips it to 0).  Here
    the correlation matrix ``s_ij / sqrt(s_ii s_jj)`` loses its negative eigenvalues and is
    scaled back to a unit diagonal (one step of Higham's nearest correlation matrix,
    IMA J. Numer. Anal. 22(3), 2002), and every row keeps its variance.  A bin whose
    correlation matrix has no negative eigenvalue, or with a variance that is not finite
    and positive, is returned as it is (bit for bit).

    Parameters
    ----------
    s : ndarray, complex, shape (..., nz, nz)
        Hermitian noise covariance estimates (per bin).

    Returns
    -------
    ndarray, shape of ``s``

    Examples
    --------
    >>> s = np.array([[1.0, 1.2], [1.2, 4.0]]) + 0j        # correlation 0.6: kept
    >>> bool(np.array_equal(nearest_correlation(s), s))
    True
    >>> t = nearest_correlation(np.array([[1.0, 2.2], [2.2, 4.0]]) + 0j)   # 1.1: not
    >>> np.round(t.real, 6).tolist()
    [[1.0, 2.0], [2.0, 4.0]]
    """
    s = np.asarray(s)
    with np.errstate(all="ignore"):  # (a variance < 0 or NaN: returned as it is, below)
        d = np.sqrt(np.real(np.diagonal(s, axis1=-2, axis2=-1)))
        c = s / (d[..., :, None] * d[..., None, :])
        c = (c + np.conj(np.swapaxes(c, -1, -2))) / 2
        valid = np.all(np.isfinite(c), axis=(-2, -1)) & np.all(d > 0, axis=-1)
        lam, vec = np.linalg.eigh(np.where(valid[..., None, None], c, np.eye(c.shape[-1])))
        fix = valid & (lam[..., 0] < 0)
        c = (vec * np.maximum(lam, 0.0)[..., None, :]) @ np.conj(np.swapaxes(vec, -1, -2))
        e = np.sqrt(np.real(np.diagonal(c, axis1=-2, axis2=-1)))
        out = c / (e[..., :, None] * e[..., None, :]) * d[..., :, None] * d[..., None, :]
    return np.where(fix[..., None, None], out, s)


class PooledFit(NamedTuple):
    """Result of :func:`pooled_least_squares` (leading dims ``...``, ``M`` bins)."""

    G: np.ndarray  #: (..., M, nz, nr) complex, NaN where ill-posed
    G_cov: np.ndarray | None  #: (..., M, nz nr, nz nr) or None
    noise_covariance: np.ndarray  #: (..., M, nz, nz) the noise covariance used (mean over experiments)
    condition: np.ndarray  #: (..., M) condition number of the stacked excitation
    ill_posed: np.ndarray  #: (..., M) bool


def pooled_least_squares(R: np.ndarray, Z: np.ndarray, noise_covariance: np.ndarray | None = None,
                         *, covariance: bool = True,
                         condition_limit: float = CONDITION_LIMIT) -> PooledFit:
    """``G(k) = Z(k) R(k)^+`` over experiments at every bin: no local model, no transient.

    Parameters
    ----------
    R : ndarray, complex, shape (..., E, M, nr)
        Steady-state excitation spectra of ``E`` experiments.
    Z : ndarray, complex, shape (..., E, M, nz)
        Their (period-averaged) output spectra.
    noise_covariance : ndarray, shape (..., E, M, nz, nz), optional
        Covariance of the noise on each ``Z_e`` (e.g. from :func:`mean_and_covariance`
        over periods).  Default: the residual covariance of the fit, pooled over the
        experiments, ``sum_e res_e res_e^H / (E - nr)`` (needs ``E > nr`` and assumes the
        same noise covariance in every experiment).
    covariance : bool, default True
        Return ``G_cov``.
    condition_limit : float, default ``CONDITION_LIMIT``
        Bins where the stacked excitation ``A = [R_e(k)^T]`` has a larger condition number
        (or is zero) are NaN and flagged ``ill_posed``.

    Returns
    -------
    PooledFit

    Raises
    ------
    ValueError
        Fewer experiments than excitation channels, or no noise estimate when one is
        needed.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> R = np.exp(2j * np.pi * rng.random((2, 8, 2)))   # E = 2 experiments, 8 bins, nr = 2
    >>> G = np.array([[1.0, 2.0j]])                       # nz = 1
    >>> fit = pooled_least_squares(R, R @ G.T, covariance=False)
    >>> bool(np.allclose(fit.G, G))
    True
    """
    R = np.asarray(R)
    Z = np.asarray(Z)
    e, m, nr = R.shape[-3:]
    nz = Z.shape[-1]
    if e < nr:
        raise ValueError(
            f"{e} experiment(s) cannot determine G bin by bin from {nr} excitation channels: "
            f"window=0 needs at least as many experiments (with different excitations) as "
            f"lifted excitation channels, E >= {nr}."
        )
    if noise_covariance is None and covariance and e == nr:
        raise ValueError(
            f"with E = {e} = nr experiments the fit is exact, so its residuals carry no noise "
            "information: give the noise covariance (at least 2 steady-state periods per "
            "experiment), more experiments, or covariance=False."
        )
    lead = np.broadcast_shapes(R.shape[:-3], Z.shape[:-3])
    A = np.moveaxis(np.broadcast_to(R, lead + R.shape[-3:]), -3, -2)  # (..., M, E, nr)
    B = np.moveaxis(np.broadcast_to(Z, lead + Z.shape[-3:]), -3, -2)  # (..., M, E, nz)
    with np.errstate(all="ignore"):
        u, s, vh = np.linalg.svd(A, full_matrices=False)  # batched over bins
        cond = np.where(s[..., -1] > 0, s[..., 0] / s[..., -1], np.inf)
        ill = ~(cond <= condition_limit)
        s_inv = np.where(ill[..., None], 0.0, 1.0 / np.where(s > 0, s, 1.0))
        # W = A^+ = V diag(1/s) U^H  (..., M, nr, E)
        W = np.conj(np.swapaxes(vh, -1, -2)) @ (s_inv[..., :, None] * np.conj(np.swapaxes(u, -1, -2)))
        Gt = W @ B  # (..., M, nr, nz)
        G = np.swapaxes(Gt, -1, -2)
        G = np.where(ill[..., None, None], np.nan, G)
        if noise_covariance is None:
            res = B - A @ Gt  # (..., M, E, nz)
            dof = e - nr
            s_res = (np.conj(np.swapaxes(res, -1, -2)) @ res).conj() / dof if dof > 0 else \
                np.full(lead + (m, nz, nz), np.nan + 0j)  # s_ij = sum_e res_i conj(res_j)
            per_exp = np.broadcast_to(s_res[..., :, None, :, :], lead + (m, e, nz, nz))
        else:
            per_exp = np.moveaxis(np.broadcast_to(noise_covariance, lead + (e, m, nz, nz)), -4, -3)
        G_cov = None
        if covariance:
            # Cov(G_ip, G_jq) = sum_e C_e,ij W_pe conj(W_qe)
            G_cov = np.einsum("...eij,...pe,...qe->...ipjq", per_exp, W, np.conj(W))
            G_cov = G_cov.reshape(lead + (m, nz * nr, nz * nr))
            G_cov = np.where(ill[..., None, None], np.nan, G_cov)
    return PooledFit(G, G_cov, per_exp.mean(axis=-3), cond, ill)


def split_halves(n_exp: int) -> tuple[np.ndarray, np.ndarray]:
    """The two random groups of :func:`spread_ratio`: even- and odd-numbered experiments.

    Examples
    --------
    >>> [h.tolist() for h in split_halves(5)]
    [[0, 2, 4], [1, 3]]
    """
    if int(n_exp) < 2:
        raise ValueError(f"splitting pooled experiments in two needs at least 2, got {n_exp}; "
                         f"pass n_exp >= 2 (identify splits only {MIN_SPLIT_EXPERIMENTS} or more).")
    return np.arange(0, int(n_exp), 2), np.arange(1, int(n_exp), 2)


def half_variances(R: np.ndarray, half_width: int, *, circular: bool = True,
                   condition_limit: float = CONDITION_LIMIT) -> np.ndarray:
    """Relative variance of every input column of a group's local estimate, per bin.

    The group's information about ``G`` at bin ``k`` is (up to the noise level, which the
    groups of one pool share) the windowed Gram of its excitation,
    ``Gamma(k) = sum_e sum_{r=-n..n} R_e(k+r) R_e(k+r)^H`` (the local model's window), so
    entry ``(i, j)`` of its ``G`` has variance ``sigma_i^2 [Gamma(k)^-1]_jj``.  The noise
    level and the transient and polynomial terms of the local model are left out: they
    scale both groups alike, and only the ratio of the groups' variances is used
    (:func:`group_weight`).  A moving sum (:func:`window_mean`): no loop over bins.

    Parameters
    ----------
    R : ndarray, complex, shape (..., E, M, nr)
        The group's excitation spectra (its ``E`` experiments on axis ``-3``).
    half_width : int
        ``n`` of the local window.
    circular : bool, default True
        As :func:`window_mean` (``False``: the ``n`` bins at each end are NaN).
    condition_limit : float, default ``CONDITION_LIMIT``
        Bins whose Gram has a condition number above ``condition_limit ** 2`` (the
        square of the excitation's) are NaN: the group cannot tell the inputs apart.

    Returns
    -------
    ndarray, real, shape (..., M, nr)
        ``[Gamma(k)^-1]_jj`` (in units of ``1 / |R|^2`` per window bin).

    Examples
    --------
    >>> R = np.ones((2, 5, 1))           # two experiments, 5 bins, one input
    >>> half_variances(R, 1).tolist()     # window mean of 1 over 2 experiments: 1/2
    [[0.5], [0.5], [0.5], [0.5], [0.5]]
    """
    R = np.asarray(R)
    outer = R[..., :, None] * np.conj(R[..., None, :])  # (..., E, M, nr, nr)
    gram = window_mean(outer.sum(axis=-4), half_width, axis=-3, circular=circular)
    with np.errstate(all="ignore"):
        ok = np.all(np.isfinite(gram), axis=(-2, -1))
        lam, vec = np.linalg.eigh(np.where(ok[..., None, None], gram, np.eye(gram.shape[-1])))
        well = ok & (lam[..., 0] > 0) & (lam[..., -1] <= condition_limit ** 2 * lam[..., 0])
        # [Gamma^-1]_jj = sum_k |V_jk|^2 / lambda_k
        v = (np.abs(vec) ** 2 / np.where(lam > 0, lam, np.inf)[..., None, :]).sum(axis=-1)
    return np.where(well[..., None], v, np.nan)


def group_weight(var_a: np.ndarray, var_b: np.ndarray) -> np.ndarray:
    """``V_a V_b / (V_a + V_b)^2``: the variance of a pooled estimate over the mean squared
    difference of its two groups' estimates.

    The pooled estimate is about the information-weighted mean of the groups'
    ``(G_a / V_a + G_b / V_b) / (1 / V_a + 1 / V_b)`` (``V`` the groups' variances, in any
    common unit), of variance ``V_a V_b / (V_a + V_b)``, while ``E|G_a - G_b|^2 = V_a + V_b``.
    With ``V`` inversely proportional to the groups' sizes (exchangeable experiments) it is
    ``n_a n_b / (n_a + n_b)^2``.

    Examples
    --------
    >>> float(group_weight(1 / 3, 1 / 5)), 3 * 5 / 8 ** 2
    (0.234375, 0.234375)
    """
    var_a, var_b = np.asarray(var_a), np.asarray(var_b)
    with np.errstate(invalid="ignore", divide="ignore"):
        return var_a * var_b / (var_a + var_b) ** 2


def spread_ratio(G_a: np.ndarray, G_b: np.ndarray, var: np.ndarray, weight=0.25
                 ) -> np.ndarray:
    """The random-group variance of a pooled estimate over the variance it reports.

    Random groups (Mahalanobis 1946; Wolter, *Introduction to Variance Estimation*, 2nd
    ed., Springer 2007, ch. 2): the experiments of a pooled fit are split into two groups
    fitted apart.  The groups share no noise, and the pooled estimate is about their
    information-weighted mean, so ``weight |G_a - G_b|^2`` with ``weight =
    V_a V_b / (V_a + V_b)^2`` (:func:`group_weight`; ``V`` the groups' relative variances
    of that entry, :func:`half_variances`; ``n_a n_b / (n_a + n_b)^2`` for exchangeable
    experiments, 1/4 for equal halves) estimates the variance of every entry of the pooled
    ``G`` whatever the noise is (coloured, leaking, correlated over bins) and however the
    local model misdescribes it.  Per bin, the mean over the entries of that estimate over
    the reported ``var`` (1 if calibrated; each term is ``Exp(1)``-distributed for Gaussian
    errors).  A bias common to both groups cancels in the difference: the ratio sees
    misstated noise, not model error.

    Parameters
    ----------
    G_a, G_b : ndarray, complex, shape (..., M, nz, nr)
        The two groups' estimates.
    var : ndarray, real, shape (..., M, nz, nr)
        The variances the pooled fit reports for its ``G``.
    weight : float or ndarray broadcastable to ``(..., M, nz, nr)``, default 0.25
        ``V_a V_b / (V_a + V_b)^2`` per entry; NaN entries give no term.

    Returns
    -------
    ndarray, shape (..., M)
        NaN where no entry has finite estimates, a finite weight and a positive variance.

    Examples
    --------
    >>> g = np.zeros((1, 1, 1))
    >>> spread_ratio(g + 2.0, g, g + 0.5).tolist()
    [2.0]
    """
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        d2 = np.asarray(weight) * np.abs(np.asarray(G_a) - np.asarray(G_b)) ** 2
        v = np.asarray(var)
        ok = np.isfinite(d2) & np.isfinite(v) & (v > 0)
        terms = np.where(ok, d2 / np.where(ok, v, 1.0), 0.0).sum(axis=(-2, -1))
        count = ok.sum(axis=(-2, -1))
        return np.where(count > 0, terms / np.maximum(count, 1), np.nan)


def spread_calibration(ratio: np.ndarray, smoothing: int = SPREAD_SMOOTHING) -> np.ndarray:
    """Factor on a pooled fit's covariance from :func:`spread_ratio` per slow bin.

    The ratio averaged over ``2 smoothing + 1`` neighbouring bins (circular, like the
    local windows; over the finite values), and never below 1: the local model's own
    covariance is kept where the groups agree better than it predicts (the ratio then
    only measures its own scatter, or a bias the two groups share).

    Parameters
    ----------
    ratio : ndarray, shape (..., M)
    smoothing : int, default :data:`SPREAD_SMOOTHING`

    Returns
    -------
    ndarray, shape (..., M), at least 1 (1 where no bin nearby has a finite ratio)

    Examples
    --------
    >>> spread_calibration(np.array([1.0, 4.0, np.nan, 0.5, 0.2]), 1).round(3).tolist()
    [1.733, 2.5, 2.25, 1.0, 1.0]
    """
    ratio = np.asarray(ratio, dtype=float)
    ok = np.isfinite(ratio)
    n = min(int(smoothing), (ratio.shape[-1] - 1) // 2)
    total = window_mean(np.where(ok, ratio, 0.0), n, axis=-1)
    count = window_mean(ok.astype(float), n, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.where(count > 0, count, 1.0), 1.0)
    return np.maximum(mean, 1.0)


def p_spread_factor(P_a, P_b, P_var, undetermined, weight=0.25,
                    smoothing: int = SPREAD_SMOOTHING) -> np.ndarray:
    """Factor on the pooled band of ``P`` from the split halves' ``P``, per fast bin and entry.

    The halves are fitted apart (:func:`split_halves`, each half's ``G`` through the
    indirect step and the recovery gives ``P_a``, ``P_b``); the pooled ``P`` is about
    their information-weighted mean, so ``w |P_a - P_b|^2`` estimates its error variance
    with one complex degree of freedom (an exponential variable times the variance),
    ``w`` the :func:`group_weight` (1/4 for equal halves of one design; exact for every
    entry of ``P`` where the halves' Grams are proportional, e.g. one half excited more
    weakly: each half's variance of ``P`` then scales alike).  Over
    ``P_var``, the pooled fit's first-order variance (calibrated by
    :func:`spread_calibration`), not at ``undetermined`` bins nor where not finite, the
    ratio's median over ``2 smoothing + 1`` neighbouring fast bins (not circular: the
    fast bins end at 0 and ``N/2``; over the finite values) divided by ``ln 2`` (the
    median of ``Exp(1)``; robust to the few bins where a half is nearly singular), and
    never below 1; 1 where no neighbour has a ratio.  It measures what the halves see of
    ``P``'s own error: the misstatement along the weak direction of ``S`` that dominates
    ``P``, which :func:`spread_calibration` (a mean over the entries of ``G``) cannot
    (docs/uncertainty.md, "Pooled bands").

    Parameters
    ----------
    P_a, P_b : ndarray, complex, shape (..., K, ny, nu)
    P_var : ndarray, shape (..., K, ny, nu)
    undetermined : ndarray of bool, shape (..., K)
    weight : float or ndarray, shape (..., K), default 0.25
        ``w``; NaN: no ratio at that bin.
    smoothing : int, default :data:`SPREAD_SMOOTHING`

    Returns
    -------
    ndarray, shape (..., K, ny, nu), at least 1

    Examples
    --------
    >>> a = np.array([2.0, 2.0, 0.0, 2.0]).reshape(4, 1, 1) + 0j
    >>> f = p_spread_factor(a, 0 * a, np.ones((4, 1, 1)), np.zeros(4, bool), smoothing=1)
    >>> f.ravel().round(3).tolist()
    [1.443, 1.443, 1.443, 1.0]
    """
    with np.errstate(all="ignore"):
        w = np.asarray(weight, dtype=float)
        w = w[..., None, None] if w.ndim else w
        ratio = w * np.abs(np.asarray(P_a) - np.asarray(P_b)) ** 2 / np.asarray(P_var)
    ratio = np.where(np.asarray(undetermined)[..., None, None] | ~np.isfinite(ratio), np.nan,
                     ratio)
    axis = ratio.ndim - 3
    n = int(smoothing)
    pad = [(0, 0)] * ratio.ndim
    pad[axis] = (n, n)
    windows = np.lib.stride_tricks.sliding_window_view(
        np.pad(ratio, pad, constant_values=np.nan), 2 * n + 1, axis=axis)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows: factor 1
        local = np.nanmedian(windows, axis=-1) / np.log(2.0)
    return np.maximum(np.where(np.isfinite(local), local, 1.0), 1.0)
