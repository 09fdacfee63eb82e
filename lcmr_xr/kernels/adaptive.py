"""Honest uncertainty and frequency-adaptive local windows, on plain arrays.

Two questions the first-order covariance of ``P = PS_1 S^-1`` does not answer:

1. **Do the data determine ``P`` at all?**  The estimation error of the indirect step is,
   exactly (no linearisation),::

       P_hat - P = e_lin (I - dS S_hat^-1)^-1,   e_lin = (dPS_1 - P_hat dS) S_hat^-1

   where ``e_lin`` is the error the first-order covariance describes (it is evaluated at
   the estimates, as :func:`lcmr_xr.kernels.closed_loop.indirect_first_row` does).  Under
   high loop gain ``S`` has one singular value ``sigma`` near ``1/|PC|`` (rank-one slow
   feedback of one output), and ``dS S_hat^-1`` is dominated by that weakest direction
   ``(u, v)``: by Sherman-Morrison ``P_hat - P = e_lin + (e_lin dS v) u^H / (sigma - u^H dS v)``.
   With ``rho = std(u^H dS v) / sigma`` (the relative uncertainty of the weakest direction)
   and ``rho_v = sqrt(E||dS v||^2) / sigma``, a 95 % bound of the correction, each factor
   at its own 95 % bound, is ``|P_hat - P| <= |e_lin| (1 + k rho_v / (1 - k rho))``,
   ``k = sqrt(ln 20)`` (conservative; the variance form ``sqrt(1 + (rho_v / (1 - k rho))^2)``
   left too little coverage at 5-25 kHz on the HDD benchmark; Fieller's argument for a ratio of noisy quantities: Fieller 1954, J. R. Stat. Soc. B
   16, 175-185; the confidence set of a ratio is unbounded when the denominator is not
   significantly non-zero; the exact second-order variance,
   :func:`second_order_variance`, was measured to be far smaller: the bound compensates
   for an understated local-model covariance, docs/uncertainty.md).  Where ``k rho`` exceeds :data:`UNDETERMINED_LIMIT` the
   higher-order terms are as large as the first-order one: the first-order band is
   meaningless, the bin is flagged *undetermined* and its band is unbounded.  Where the
   weakest direction is drowned in noise the estimated ``rho`` saturates near 1 (the
   estimate's smallest singular value is then the noise's) and scatters bin by bin, so a
   draw under the limit can release a bin that is not determined; ``window="auto"``
   therefore also flags a bin where most of its neighbourhood fails the widest window's
   test (:func:`crowd_undetermined`), and a fixed window on one record where most of its
   neighbourhood fails the window's own test.
   With ``window="auto"`` and a least-squares LRM denominator (one record) the band uses
   the second-order factor (:func:`second_order_factor`) and adds the denominator's bias
   estimated from an IV fit of the widest window (:func:`denominator_bias`) instead: the
   bound form had been covering that bias, 2.9x too wide at 500-5000 Hz.

2. **Which window?**  Per slow bin the window is chosen among a ladder of half-widths by a
   local mean-squared-error criterion (Lepski's method, in the form of the "intersection of
   confidence intervals" rule for local polynomial estimators: Goldenshluger & Nemirovski
   1997, Math. Methods Statist. 6, 135-170; Katkovnik 1999, IEEE Trans. Signal Process.
   47, 2567-2571).  The smallest window is the pilot, nearly free of model error; for a
   wider window the squared model error is estimated from its distance to the pilot,
   ``b^2 = max(0, |P_n - P_0|^2 - 4 (var_0 - var_n))`` (nested windows: the difference of
   two noisy estimates has variance ``var_0 - var_n``; only a difference beyond two of its
   standard deviations counts, Lepski's threshold), averaged (like the variance term) over a few
   neighbouring bins to tame its scatter, and the window minimising ``calibrated variance + b^2``
   (relative to ``|P|^2``, the worst of the plant's entries, summed over the fast bins that the slow
   bin serves) wins.  The chosen window's ``b`` is added to the band (model error).  The
   pilot's own model error is 0 by this construction, and where the pilot wins the
   criterion has read its distance to the wider windows as their model error: on the HDD
   benchmark that distance was mostly the pilot's own noise, larger than its 2-dof
   variance estimate says (window 19 or 30 was closer to the truth at 79-93 % of those
   bins, whose band covered 0.32-0.85).  So where the pilot is chosen its band adds the
   check by the next-wider window, the mean over the same neighbours of ``|P_1 - P_0|^2``
   without the threshold: for nested windows ``E|P_1 - P_0|^2 = (var_0 - var_1) + |b_1 -
   b_0|^2``, the pilot's noise variance measured from the data (less the smaller
   ``var_1``) plus the change of model error between the two.  The choice itself is
   Lepski's (the pilot's term enters only the band).  Every mean runs over the
   neighbours whose term is finite.

Small samples: the noise variance is estimated from ``dof`` complex residuals, so
``|P_hat - P|^2 / P_var`` follows ``F(2, 2 dof)`` rather than ``Exp(1)``; the band's 95 %
radius is ``sqrt(dof (20^(1/dof) - 1))`` times the standard deviation instead of
``sqrt(ln 20)``, and :func:`small_sample_factor` rescales ``P_std`` so that the README's disc
``sqrt(ln 20) P_std`` keeps its 95 % meaning.
"""

from __future__ import annotations

import numpy as np

from lcmr_xr.kernels.lifting import first_block_row_weights
from lcmr_xr.kernels.moving import window_sums

__all__ = [
    "K95", "UNDETERMINED_LIMIT", "candidate_windows", "denominator_bias", "nonlinearity_factor",
    "pooled_nonlinearity_factor", "second_order_factor",
    "second_order_variance", "small_sample_factor", "weak_direction", "whitened_weak_direction", "select_windows",
    "MODEL_ERROR_LEVEL", "noise_share", "crowd_undetermined",
]

#: Radius, in standard deviations, of the 95 % disc of a circular complex Gaussian error.
K95 = float(np.sqrt(np.log(20.0)))

#: A bin is undetermined where the 95 % bound ``K95 * rho`` of the relative error of the
#: weakest direction of ``S`` exceeds this: the neglected terms of ``(I - dS S^-1)^-1``
#: then reach the first-order one (geometric series with ratio >= 1/2).
UNDETERMINED_LIMIT = 0.5

#: Ratio between consecutive candidate half-widths of ``window="auto"``.
WINDOW_RATIO = 1.6
#: Widest candidate half-width of ``window="auto"`` (the paper's fixed choice).
MAX_WINDOW = 30
#: A difference between a window's estimate and the pilot's counts as model error only
#: beyond this multiple of its expected noise variance (Lepski's threshold, two standard
#: deviations; measured on the HDD: with 2, window="auto" was 5 % worse than window 30
#: for the VCM at 25-50 kHz, with 4 equal, and better than 30 in every other band).
BIAS_THRESHOLD = 4.0
#: Neighbouring fast bins (each side) over which the model-error estimate is averaged.
BIAS_SMOOTHING = 6


def small_sample_factor(dof) -> np.ndarray:
    """Factor on the first-order standard deviation for a 95 % disc with estimated variance.

    ``sqrt(q / ln 20)`` with ``q = dof (20^(1/dof) - 1)`` the 95 % quantile of ``F(2, 2 dof)``;
    1 for ``dof -> inf``, 1.52 for ``dof = 2``, 1.05 for ``dof = 16``, 1.05 for ``dof = 16``.

    Examples
    --------
    >>> round(float(small_sample_factor(2)), 3), round(float(small_sample_factor(10**6)), 3)
    (1.523, 1.0)
    """
    d = np.asarray(dof, dtype=float)
    return np.sqrt(d * np.expm1(np.log(20.0) / d) / np.log(20.0))


def _whitened_ratio(u, sv, vh, C, column_trace=None):
    """:func:`whitened_weak_direction` from the SVD ``S = u diag(sv) vh`` and ``C``
    reshaped to (..., nr, nr, nr, nr); ``column_trace`` is ``sum_i C[..., i, :, i, :]``
    when the caller has it."""
    sigma = np.einsum("...ibjb->...ij", C)
    w = (np.einsum("...ibic->...bc", C) if column_trace is None else column_trace).conj()
    variances = np.einsum("...ibib->...ib", C).real
    total = variances.sum(axis=(-2, -1))
    # a covariance at rounding level (an exact fit of noiseless data) is no covariance: its
    # trace a cancellation, or entries off the diagonal beyond every variance (HDD, N =
    # 180 000: trace 1.8e-33 against entries of 1e-14, rho 8.1; variances 2e-33 against
    # entries of 1e-15, rho 0.43).  No noise is measured where the negative variances reach a
    # third of the positive ones or an entry exceeds twice the largest variance (a
    # covariance has |C_ab| <= sqrt(C_aa C_bb))
    measured = (total > 0.5 * np.abs(variances).sum(axis=(-2, -1))) \
        & (np.abs(C).max(axis=(-4, -3, -2, -1)) <= 2.0 * variances.max(axis=(-2, -1)))
    # 1/sigma_min(Sigma^-1/2 S conj(W)^-1/2)^2 = lambda_max(S^-1 Sigma S^-H conj(W))
    # = lambda_max(B^H Sigma B), B = S^-H conj(W)^1/2 (similar matrices), S^-H = U D V^H:
    # one square root (of the column factor, clipped to PSD), no inverse of a factor, so
    # noise-free directions simply contribute nothing
    lam, vec = np.linalg.eigh(w)
    root = (vec * np.sqrt(np.maximum(lam, 0.0))[..., None, :]) @ np.swapaxes(vec.conj(), -1, -2)
    d = 1.0 / np.maximum(sv, np.finfo(float).tiny)
    with np.errstate(over="ignore", invalid="ignore"):  # singular S: inf, flagged below
        b = u @ (d[..., :, None] * (vh @ root))
        h = np.swapaxes(b.conj(), -1, -2) @ sigma @ b
    finite = np.isfinite(h).all(axis=(-2, -1))
    top = np.linalg.eigvalsh(np.where(finite[..., None, None], h, 0.0))[..., -1]
    with np.errstate(invalid="ignore", divide="ignore"):
        rho = np.sqrt(np.maximum(top, 0.0) / np.where(measured, total, 1.0))
    return np.where(measured, np.where(finite, rho, np.inf), 0.0)


def whitened_weak_direction(S: np.ndarray, S_cov: np.ndarray) -> np.ndarray:
    """Relative noise of ``S`` in its weakest direction, measured in the noise's own metric.

    The covariance of ``vec(S)`` is approximated by a Kronecker product, ``E[dS_ib
    conj(dS_jc)] ~ Sigma_ij W_bc`` (exact for the LPM, whose rows share their regressors;
    the factors are the partial traces, ``Sigma W = Tr_2(C) Tr_1(C) / tr(C)``), so that
    ``dS = Sigma^(1/2) X W^(T/2)`` with ``X`` white.  In that metric the relative noise of
    the weakest direction is ``1 / sigma_min(Sigma^(-1/2) S conj(W)^(-1/2))``: the smallest
    singular value is taken AFTER whitening, over every direction at once.  (The plain
    ``std(u^H dS v) / sigma_min`` uses the weakest singular vectors of the *estimated* ``S``,
    which the noise itself selects: where one noise direction dominates (the loop feeds one
    disturbance into every lifted input) the estimate's weakest direction is the one where
    the noise happened to be small, and that ratio read 0.08-0.29 on the HDD benchmark where
    the true one was 0.6 to 200.)  Equal to the plain ratio for white errors.  Computed
    as ``sqrt(lambda_max(S^-1 Sigma S^-H conj(W)))``, so no inverse of a (possibly
    rank-deficient) factor is needed.

    Parameters
    ----------
    S : ndarray, complex, shape (..., nr, nr)
        Estimated lifted sensitivity per bin (finite).
    S_cov : ndarray, complex, shape (..., nr nr, nr nr)
        ``E[dS dS^H]`` of ``vec(S)`` (row-major, index ``i nr + b``), finite.

    Returns
    -------
    ndarray, shape (...)
        ``1 / sigma_min`` of the whitened ``S`` (0 where the covariance is 0, inf where
        ``S`` is singular).

    Examples
    --------
    >>> S = np.diag([1.0, 0.01]).astype(complex)
    >>> round(float(whitened_weak_direction(S, 1e-6 * np.eye(4, dtype=complex))), 6)
    0.1
    """
    nr = S.shape[-1]
    C = np.asarray(S_cov).reshape(S_cov.shape[:-2] + (nr, nr, nr, nr))
    u, sv, vh = np.linalg.svd(S)
    return _whitened_ratio(u, sv, vh, C)


def weak_direction(S: np.ndarray, S_cov: np.ndarray, svd=None):
    """Relative uncertainty of the weakest direction of the estimated ``S``.

    Parameters
    ----------
    S : ndarray, complex, shape (..., nr, nr)
        Estimated lifted sensitivity per bin.
    S_cov : ndarray, complex, shape (..., nr nr, nr nr)
        ``E[dS dS^H]`` of ``vec(S)`` (row-major, index ``i nr + b``).
    svd : tuple of ndarray, optional
        ``(u, s, vh)`` of ``S`` (the identity where ``S`` is not finite), when the
        caller has it (:func:`lcmr_xr.kernels.closed_loop.indirect_first_row`); computed
        when None.

    Returns
    -------
    rho : ndarray, shape (...)
        The larger of ``std(u^H dS v) / sigma_min`` with ``(u, sigma_min, v)`` the weakest
        singular triple of the estimate, and the selection-free
        :func:`whitened_weak_direction` (the two agree for white errors).
    rho_v : ndarray, shape (...)
        ``sqrt(E ||dS v||^2) / sigma_min``.
    """
    nr = S.shape[-1]
    finite = np.isfinite(S).all(axis=(-2, -1)) & np.isfinite(S_cov).all(axis=(-2, -1))
    if finite.all():  # no copies: S_cov may be a view into the whole covariance of G
        S_safe, cov_safe = S, S_cov
    else:
        S_safe = np.where(finite[..., None, None], S, np.eye(nr))
        cov_safe = np.where(finite[..., None, None], S_cov, 0.0)
    u, sv, vh = np.linalg.svd(S_safe) if svd is None else svd
    um, vm, smin = u[..., :, -1], vh[..., -1, :].conj(), sv[..., -1]
    C = np.asarray(cov_safe).reshape(cov_safe.shape[:-2] + (nr, nr, nr, nr))
    # u^H dS v = sum_ib conj(u_i) v_b dS_ib; one vector at a time (a single einsum over
    # all operands loops over every index combination at once, several times slower)
    x = np.einsum("...ibjc,...c->...ibj", C, vm.conj())
    x = np.einsum("...ibj,...j->...ib", x, um)
    x = np.einsum("...ib,...b->...i", x, vm)
    var = np.einsum("...i,...i->...", x, um.conj()).real
    # ||dS v||^2 = sum_i |sum_b v_b dS_ib|^2
    column_trace = np.einsum("...ibic->...bc", C)  # also the whitening's column factor
    x = np.einsum("...bc,...c->...b", column_trace, vm.conj())
    var_v = np.einsum("...b,...b->...", x, vm).real
    with np.errstate(divide="ignore", invalid="ignore"):
        rho = np.sqrt(np.maximum(var, 0.0)) / smin
        rho_v = np.sqrt(np.maximum(var_v, 0.0)) / smin
        rho = np.maximum(rho, _whitened_ratio(u, sv, vh, C, column_trace))
    bad = ~finite | ~np.isfinite(rho)
    return np.where(bad, np.inf, rho), np.where(bad, np.inf, rho_v)


def nonlinearity_factor(rho, rho_v, limit: float = UNDETERMINED_LIMIT):
    """Factor on the first-order error bound and the undetermined flag (module notes).

    Returns ``(factor, undetermined)``: ``1 + K95 rho_v / (1 - K95 rho)`` and
    ``K95 rho > limit``; the factor is ``inf`` where undetermined.
    """
    q = K95 * np.asarray(rho, dtype=float)
    undetermined = ~(q <= limit)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = 1.0 + K95 * np.asarray(rho_v, dtype=float) / (1.0 - q)
    return np.where(undetermined, np.inf, factor), undetermined


def pooled_nonlinearity_factor(rho, limit: float = UNDETERMINED_LIMIT):
    """The milder factor of pooled fits whose band of ``P`` is calibrated by split halves.

    Returns ``(factor, undetermined)`` as :func:`nonlinearity_factor`, with the factor
    ``1 / (1 - K95 rho)`` (the geometric series of ``(I - dS S^-1)^-1`` alone) instead of
    the bound form ``1 + K95 rho_v / (1 - K95 rho)``.  The bound form makes up for a
    first-order covariance that understates the error (single records); where the
    halves' ``P`` calibrate the band itself
    (:func:`lcmr_xr.kernels.pooling.p_spread_factor`) that part is measured, and the
    bound form over-covers 500-5000 Hz (docs/uncertainty.md, "Pooled bands").  The
    undetermined flag is the same.
    """
    q = K95 * np.asarray(rho, dtype=float)
    undetermined = ~(q <= limit)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = 1.0 / (1.0 - q)
    return np.where(undetermined, np.inf, factor), undetermined


def second_order_factor(rho, limit: float = UNDETERMINED_LIMIT):
    """Factor on the first-order standard deviation for the second-order term of ``S^-1``.

    Returns ``(factor, undetermined)`` as :func:`nonlinearity_factor`, with the factor
    ``sqrt(1 + 2 (rho / (1 - K95 rho))^2)``: the variance of ``P_hat - P`` to second order
    where the weakest direction of ``S`` dominates (module notes).  There ``e_lin ~ alpha
    u^H`` and the Sherman-Morrison term is ``alpha (u^H dS v) / sigma`` (times the same
    column weights), so ``E|e2|^2 <= 2 E|alpha|^2 E|u^H dS v / sigma|^2 = 2 rho^2 var_lin``
    (Isserlis' theorem for circular Gaussian ``alpha``, ``u^H dS v``; the cross moment at
    most equals the product of the second moments), and the geometric tail of
    ``(I - dS S^-1)^-1`` divides it by ``(1 - K95 rho)^2`` as in the exact form
    (:func:`second_order_variance`, which on the HDD benchmark is 0.1-1.1x ``rho^2
    var_lin``).  Used where the bias of a least-squares denominator is estimated
    (:func:`denominator_bias`): the bound form ``1 + K95 rho_v / (1 - K95 rho)`` is not the
    size of the ``S^-1`` correction (its ``rho_v`` counts the noise of ``S`` in every
    direction, 0.83 at 500-5000 Hz against ``rho`` 0.14) and was compensating for that bias
    (docs/uncertainty.md, "The denominator's bias from a Hausman comparison").  The flag is
    the same.
    """
    q = K95 * np.asarray(rho, dtype=float)
    undetermined = ~(q <= limit)
    with np.errstate(divide="ignore", invalid="ignore"):
        factor = np.sqrt(1.0 + 2.0 * (np.asarray(rho, dtype=float) / (1.0 - q)) ** 2)
    return np.where(undetermined, np.inf, factor), undetermined


def denominator_bias(P_ls, P_iv, var_ls, var_iv, smoothing: int = None, axis: int = -3,
                     determined=None):
    """Noise-inflated upper term for the squared bias of a least-squares LRM estimate, from
    its instrumental-variables twin.

    A Hausman comparison (Hausman 1978, Econometrica 46, 1251-1271; Durbin 1954, Wu 1973):
    least squares ``P_ls`` is biased by the noise in its own denominator regressors
    (errors-in-variables); the IV estimate ``P_iv`` of the same window, whose instruments
    are least squares' own prediction in that window, is (nearly) free of that bias
    (docs/uncertainty.md: 0.00-0.01 of ``G_var`` left against 0.18-0.21 at 5-25.2 kHz on
    the HDD benchmark) at a larger variance.  If both variances were exact and least
    squares unbiased, ``var(P_ls - P_iv) = var_iv - var_ls`` (Hausman's lemma) and

        b^2 = max(0, mean over +-smoothing bins of (|P_ls - P_iv|^2 - max(0, var_iv - var_ls)))

    would estimate ``|E P_ls - E P_iv|^2``.  It does not: each fit reports its variance
    from its own noise estimate, least squares' too large (its empirical variance 0.84-0.99
    of the reported one, IV's 1.00-1.14; a Monte Carlo of 60 records of HDD case 2, medians
    per band above 500 Hz), so ``var_iv - var_ls`` understates ``var(P_ls - P_iv)`` (by
    1.12-1.45x) and the flooring adds more; ``E b^2`` was 1.3-14x the true squared bias of
    least squares there (2.1-15x ``|E P_ls - E P_iv|^2``; largest at 500-5000 Hz, where
    that bias is smallest).  So ``b^2`` is an upper term: the squared bias plus part of the difference's
    noise, which makes the band wider, not an unbiased estimate.  It is averaged over
    neighbouring bins like the model error of :func:`select_windows`, without Lepski's
    threshold (it enters the band as a mean squared error, not a test).  The two reported
    variances' difference is below 0 in 33-43 % of the HDD's bins and is floored at 0 bin
    by bin.  The consistent form (least squares' variance from the IV fit's noise estimate)
    was measured and not adopted: it leaves ``b^2`` about 0 and the band under 0.90 in the
    worst case (docs/uncertainty.md).  The mean runs over the neighbours whose term is finite and that are
    ``determined`` (a bin with none gets 0).

    Parameters
    ----------
    P_ls, P_iv : ndarray, complex, shape (..., K, ny, nu)
        The two estimates on the fast bins.
    var_ls, var_iv : ndarray, real, shape (..., K, ny, nu)
        Their first-order variances.
    smoothing : int, optional
        Neighbours each side (default :data:`BIAS_SMOOTHING`).
    axis : int, default -3
        The bin axis.
    determined : ndarray, bool, broadcastable to ``P_ls``, optional
        Bins whose terms may enter the mean (e.g. finite calibrated variance of the least
        squares fit: its weakest direction of ``S`` determined); default all.

    Returns
    -------
    ndarray, real, >= 0, shape of ``P_ls``

    Examples
    --------
    >>> P = np.zeros((50, 1, 1), complex)
    >>> round(float(denominator_bias(P + 0.3, P, np.ones(P.shape), np.ones(P.shape))[25, 0, 0]), 12)
    0.09
    """
    half = BIAS_SMOOTHING if smoothing is None else int(smoothing)
    with np.errstate(invalid="ignore", over="ignore"):
        raw = np.abs(np.asarray(P_ls) - np.asarray(P_iv)) ** 2 \
            - np.maximum(np.asarray(var_iv) - np.asarray(var_ls), 0.0)
    use = None if determined is None else \
        np.broadcast_to(np.asarray(determined, dtype=bool), raw.shape)
    return np.maximum(_finite_running_mean(raw, half, axis % raw.ndim, use=use), 0.0)


def _kron(a, b):
    """Kronecker product of the trailing matrices, broadcast over leading axes."""
    out = a[..., :, None, :, None] * b[..., None, :, None, :]
    return out.reshape(out.shape[:-4] + (a.shape[-2] * b.shape[-2], a.shape[-1] * b.shape[-1]))


def second_order_variance(S_inv, first_row, G_cov, first_row_cov, *, n_fast: int, factor: int,
                          bins) -> np.ndarray:
    """Variance of the second-order term of the indirect estimate, per fast bin and entry.

    With ``D = dS S_hat^-1`` the error of ``P_1`` is ``e_lin (I - D)^-1 = e_lin + e_lin D +
    ...`` (module notes); ``e2 = e_lin D`` is a bilinear form in ``x = vec(dG)`` (no
    conjugate).  At fast bin ``k``, entry ``(a, b)``, after the map of
    :func:`lcmr_xr.kernels.lifting.frf_from_first_block_row`,
    ``e2 = sum_d e_d y_d`` with ``e = e_lin[a, :]`` (the first-order error of row ``a`` of
    ``P_1``) and ``y = dS s``, ``s = sum_j exp(2j pi k j / N) S_hat^-1[:, j nu + b]``.  For
    circular complex Gaussian ``x`` (``E[x x^T] = 0``) Isserlis' theorem gives, exactly,::

        E|e2|^2 = sum_dd' ( E[e_d e_d'^*] E[y_d y_d'^*] + E[e_d y_d'^*] E[y_d e_d'^*] )

    (equal to ``2 tr(Qs C Qs^H C^T)`` for the symmetric matrix ``Qs`` of the bilinear form
    and ``C = cov(x)``), and ``E[e_lin conj(e2)] = 0`` (an odd moment), so to second order
    ``var(P_hat) = var_lin + E|e2|^2``, with the actual geometry of ``e`` and ``dS`` (the
    product of norms ``rho_v`` counts them as aligned).

    Not used by the band: on the HDD benchmark ``E|e2|^2`` is 0.2 % of ``var_lin`` at
    500-5000 Hz (where ``c_S`` is 2.9), and the band with it instead of ``c_S`` is the
    first-order band, which the understated local-model covariance leaves at 0.86-0.89
    coverage in three bands (docs/uncertainty.md, "The exact second-order variance of the
    ``S^-1`` correction"; ``benchmarks/accuracy.py --band-forms`` measures it).  Pooled
    fits, whose covariance the split halves calibrate, likewise: with it instead of
    ``c_S`` 500-5000 Hz comes under 0.99 but 5-50.4 kHz loses 2-5 points of coverage
    (``benchmarks/pooling.py --only-disturbances --band-forms``; docs/uncertainty.md,
    "The ``S^-1`` factor of pooled bands").

    Parameters
    ----------
    S_inv : ndarray, complex, shape (..., M, nr, nr)
        ``S_hat^-1`` per slow bin.
    first_row : ndarray, complex, shape (..., M, ny, nr)
        ``P_1`` per slow bin (``L = [-P_1, I]``).
    G_cov : ndarray, complex, shape (..., M, nz nr, nz nr)
        Covariance of ``vec(G)`` (row-major, ``i nr + b``; rows ``i < nr`` are ``S``).
    first_row_cov : ndarray, complex, shape (..., M, ny nr, ny nr)
        First-order covariance of ``vec(P_1)``
        (:func:`lcmr_xr.kernels.closed_loop.indirect_first_row`).
    n_fast, factor : int
        ``N`` and ``F``.
    bins : ndarray of int
        Fast bins ``k`` (slow bin ``k mod M``).

    Returns
    -------
    ndarray, shape (..., len(bins), ny, nu), real, >= 0
    """
    S_inv = np.asarray(S_inv)
    m, nr = S_inv.shape[-3], S_inv.shape[-1]
    ny = first_row.shape[-2]
    nz = nr + ny
    f_ = int(factor)
    nu = nr // f_
    lead = S_inv.shape[:-3]
    C = np.asarray(G_cov)
    L = np.concatenate([-first_row, np.broadcast_to(np.eye(ny), lead + (m, ny, ny))], axis=-1)
    # Per slow bin, as products of (nz nr)-sized matrices (no strided copies of cov(G)):
    # vec(e_lin) = (L (x) S^-T) vec(dG), vec(dS S^-1) = (I (x) S^-T) vec(dS), so
    # X[(a, d), (d', c')] = E[e_lin[a, d] conj((dS S^-1)[d', c'])] and
    # U[(d, c), (d', c')] = E[(dS S^-1)[d, c] conj((dS S^-1)[d', c'])].
    sit = np.swapaxes(S_inv, -2, -1)
    right = _kron(np.broadcast_to(np.eye(nr), S_inv.shape), S_inv.conj())  # (I (x) S^-H)^T
    x = _kron(L, sit) @ C[..., :, : nr * nr] @ right
    u = _kron(np.broadcast_to(np.eye(nr), S_inv.shape), sit) @ C[..., : nr * nr, : nr * nr] @ right
    # only pairs of columns c = (j, b), c' = (j', b) of the same input b enter
    x = x.reshape(lead + (m, ny, nr, nr, f_, nu))  # (a, d, d', j', b)
    u = np.einsum("...xjbykb->...xyjkb", u.reshape(lead + (m, nr, f_, nu, nr, f_, nu)))
    c11 = np.asarray(first_row_cov).reshape(lead + (m, ny, nr, ny, nr))
    c11 = np.einsum("...adAf,aA->...adf", c11, np.eye(ny))  # E[e_d conj(e_d')] per row a
    # fast bin k: S^-1 columns of input b summed with w_kj = exp(2j pi k j / N)
    bins = np.asarray(bins)
    idx = bins % m
    w = first_block_row_weights(n_fast, f_, bins)  # (K, F)
    u, x = np.take(u, idx, axis=-6), np.take(x, idx, axis=-6)
    cyy = sum(u[..., j, k, :] * (w[:, j] * w[:, k].conj())[:, None, None, None]
              for j in range(f_) for k in range(f_))  # (K, d, d', b)
    c1y = sum(x[..., j, :] * w[:, j].conj()[:, None, None, None, None] for j in range(f_))
    var = (np.einsum("...kadf,...kdfb->...kab", np.take(c11, idx, axis=-4), cyy)
           + np.einsum("...kadfb,...kafdb->...kab", c1y, c1y.conj()))
    return np.maximum(var.real, 0.0)


def candidate_windows(n_min: int, n_max: int, *, ratio: float = WINDOW_RATIO,
                      widest: int = MAX_WINDOW) -> tuple[int, ...]:
    """Ladder of half-widths ``n_min, ~ratio n_min, ...`` up to ``min(widest, n_max)``.

    Examples
    --------
    >>> candidate_windows(12, 899)
    (12, 19, 30)
    """
    top = max(n_min, min(int(widest), int(n_max)))
    ladder = [int(n_min)]
    while ladder[-1] < top:
        ladder.append(min(top, max(ladder[-1] + 1, int(round(ladder[-1] * ratio)))))
    return tuple(ladder)


def _running_mean(x: np.ndarray, half: int, axis: int) -> np.ndarray:
    """Mean over ``2 half + 1`` neighbours along ``axis`` (edges: the available ones).

    Each window is summed from its own bins (:func:`lcmr_xr.kernels.moving.window_sums`,
    ``half`` zeros beyond each end): the squared biases it smooths follow ``|P|^2`` over
    tens of decades, and a running sum over all bins left a small window with the
    rounding of every large bin before it."""
    if half <= 0:
        return x
    x = np.moveaxis(np.asarray(x), axis, 0)
    k = np.arange(x.shape[0])
    count = np.minimum(k + half + 1, x.shape[0]) - np.maximum(k - half, 0)
    out = window_sums(x, 2 * half + 1, pad=half) / count.reshape((-1,) + (1,) * (x.ndim - 1))
    return np.moveaxis(out, 0, axis)


def _finite_running_mean(x: np.ndarray, half: int, axis: int, use=None) -> np.ndarray:
    """Mean over the ``2 half + 1`` neighbours along ``axis`` whose ``x`` is finite (and
    ``use``, if given); 0 where there is none.  A non-finite term does not count (as 0 it
    would dilute its neighbours' mean)."""
    ok = np.isfinite(x) if use is None else np.isfinite(x) & use
    total = _running_mean(np.where(ok, x, 0.0), half, axis)
    count = _running_mean(ok.astype(float), half, axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / np.where(count > 0, count, 1.0), 0.0)


def select_windows(P: np.ndarray, P_var: np.ndarray, P_var_lin: np.ndarray, n_slow: int,
                   smoothing: int = BIAS_SMOOTHING):
    """Choose a candidate per slow bin by the local MSE criterion (module notes).

    Parameters
    ----------
    P : ndarray, complex, shape (J, ..., K, ny, nu)
        Fast FRF estimates of the ``J`` candidates (ascending windows) at fast bins
        ``k = 0..K-1``.
    P_var : ndarray, shape (J, ..., K, ny, nu)
        Calibrated variances (small-sample and nonlinearity factors applied; inf where
        undetermined).
    P_var_lin : ndarray, shape (J, ..., K, ny, nu)
        First-order variances (for the nested-difference correction).
    n_slow : int
        ``M``: fast bin ``k`` is served by slow bin ``k mod M``.
    smoothing : int, optional
        Neighbouring fast bins (each side) over which the terms are averaged.

    Returns
    -------
    choice : ndarray of int, shape (..., M)
        Index of the chosen candidate per slow bin.
    bias2 : ndarray, shape (J, ..., K, ny, nu)
        Estimated squared model error of every candidate, for the band.  For a wider
        candidate ``n``: Lepski's term, the mean over the neighbours of ``|P_n - P_0|^2 -
        4 max(0, var_0 - var_n)`` (floored at 0).  For the pilot (``n = 0``), whose distance to
        itself is 0 by construction: the check by the next-wider candidate, the mean of
        ``|P_1 - P_0|^2`` without the threshold (module notes; 0 when ``J = 1``).  The
        choice reads the pilot's term as 0 (Lepski's rule: the pilot is the reference).
        The means run over the neighbours whose term is finite (a bin with none gets 0).
    """
    J = P.shape[0]
    fast_axis = P.ndim - 3
    with np.errstate(invalid="ignore", over="ignore"):
        d2 = np.abs(P - P[:1]) ** 2
        raw = d2 - BIAS_THRESHOLD * np.maximum(P_var_lin[:1] - P_var_lin, 0.0)
        bias2 = np.maximum(_finite_running_mean(raw, smoothing, fast_axis), 0.0)
        bias2[0] = 0.0
        scale = np.abs(P[:1]) ** 2 + P_var_lin[:1]
        scale = np.where(np.isfinite(scale) & (scale > 0), scale, 1.0)
        # the worst entry decides: a window that suits one actuator must not ruin another
        crit = ((P_var + bias2) / scale).max(axis=(-2, -1))  # (J, ..., K)
        # the variance estimates scatter as much as the bias estimates (a few dof per bin):
        # the criterion is averaged over the same neighbourhood, over its finite values
        ok = np.isfinite(crit)
        mean = _running_mean(np.where(ok, crit, 0.0), smoothing, crit.ndim - 1)
        frac = _running_mean(ok.astype(float), smoothing, crit.ndim - 1)
        crit = np.where(ok, mean / np.where(frac > 0, frac, 1.0), np.inf)
        if J > 1:  # the pilot checked by the next-wider candidate (band only)
            bias2[0] = _finite_running_mean(d2[1], smoothing, fast_axis - 1)
    k = crit.shape[-1]
    slow = np.arange(k) % n_slow
    per_slow = np.zeros(crit.shape[:-1] + (n_slow,))
    np.add.at(per_slow, (..., slow), crit)  # inf + anything stays inf
    served = np.zeros(n_slow, dtype=bool)
    served[slow] = True
    choice = np.argmin(per_slow, axis=0)
    # no finite candidate (undetermined everywhere) or a bin no fast bin uses: the widest
    none = ~np.isfinite(per_slow).any(axis=0) | ~served
    choice = np.where(none, J - 1, choice)
    return choice, bias2


def crowd_undetermined(undetermined, smoothing: int = BIAS_SMOOTHING, axis: int = -1,
                       circular: bool = False) -> np.ndarray:
    """Bins most of whose neighbours fail the determinacy test: ``undetermined`` at more
    than half of the ``2 smoothing + 1`` bins centred on each (``circular``: the bins are a
    circle, as the slow bins of a DFT, and a circle of fewer bins is each bin's
    neighbourhood whole, every bin counted once; else at the edges the available ones).

    The test's ``rho`` (:func:`weak_direction`) estimates the noise of the weakest direction
    of ``S`` relative to ``S``'s own smallest singular value.  Where that direction is
    drowned in noise the estimated singular value is the noise's, not the signal's, so the
    ratio saturates near 1 instead of growing with the true ratio, and scatters bin by bin
    with the noise (the noise is smooth in frequency, the draw is not): on the HDD benchmark
    below 500 Hz (case 2, excitation seed 7, 30 disturbance records, window 30) the true
    ratio, the standard deviation of ``u^H dS v / sigma`` over the records, is 1.9-11, its
    estimate's median 0.78-1.4, and about 1 % of such bins draw an estimate under the
    limit; there the estimate was 99.5 % off and its band 40-150 times too narrow.  The
    ratio itself varies slowly with frequency, so a bin whose neighbourhood mostly fails
    the test is undetermined too, whatever its own draw says.

    Parameters
    ----------
    undetermined : ndarray of bool
        The bins' own test, along ``axis``.
    smoothing : int, optional
        Neighbours each side (default :data:`BIAS_SMOOTHING`).
    axis : int, default -1
    circular : bool, default False

    Returns
    -------
    ndarray of bool, shape of ``undetermined``

    Examples
    --------
    >>> u = np.array([1, 1, 0, 1, 1, 0, 0, 0, 0, 1, 0], bool)
    >>> crowd_undetermined(u, 2).astype(int).tolist()
    [1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0]
    >>> crowd_undetermined(u, 2, circular=True).astype(int).tolist()
    [1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 1]
    """
    u = np.asarray(undetermined, dtype=bool)
    axis, half = axis % max(u.ndim, 1), int(smoothing)
    n = u.shape[axis]
    if not circular or half <= 0 or n == 0:
        return _running_mean(u.astype(float), half, axis) > 0.5
    if n < 2 * half + 1:  # the window would go round the circle: every bin once
        return np.broadcast_to(u.mean(axis=axis, keepdims=True) > 0.5, u.shape).copy()
    # the circle unrolled by ``half`` bins each side: every bin then has its whole window
    ring = np.take(u, np.arange(-half, n + half) % n, axis=axis).astype(float)
    frac = np.take(_running_mean(ring, half, axis), np.arange(half, half + n), axis=axis)
    return frac > 0.5


#: Level of the variance-ratio test of :func:`noise_share`: under noise alone the wider
#: window's residual variance exceeds the narrower one's by the test's limit in 0.1 % of
#: the bins.
MODEL_ERROR_LEVEL = 0.999


def noise_share(var_wide, var_narrow, dof_wide, dof_narrow,
                level: float = MODEL_ERROR_LEVEL) -> np.ndarray:
    """The largest share of a wider window's residual variance that can be noise, judged by
    a narrower window's residuals at the same bin: ``min(1, q var_narrow / var_wide)``.

    Both windows are centred on the same bin and see the same noise; a local model that
    describes the data leaves residuals of that noise's variance in either window, and
    ``var_wide / var_narrow`` (residual variances estimated from ``dof_wide`` and
    ``dof_narrow`` complex residuals) then follows ``F(2 dof_wide, 2 dof_narrow)``, to
    the extent that the noise variance is constant over the wider window (nested windows
    share residuals, which makes the ratio scatter less than that F law).  ``q`` is that
    law's ``level`` quantile: a ratio beyond it is the wider window's model error (the
    variance test of nested models), and of ``var_wide`` at most ``q var_narrow`` is
    noise.  A statistic built from ``var_wide``, such as the weak direction's ``rho``
    (proportional to the noise's standard deviation), measures the noise alone when scaled
    by the square root of this share.  On noiseless HDD data whose narrow fit is exact to
    rounding the ratio is 1e3-4e4 (share 1e-3-3e-2); with the disturbances its median is
    2.1.  ``var_narrow = 0 < var_wide`` gives 0; ``var_wide = 0`` gives 1.

    Parameters
    ----------
    var_wide, var_narrow : ndarray, real, >= 0
        Residual variances (e.g. summed over the rows of ``S``), broadcast together.
    dof_wide, dof_narrow : int or ndarray
        Their degrees of freedom (complex residuals).
    level : float, optional
        Quantile of the F law beyond which the ratio counts as model error.

    Returns
    -------
    ndarray, real, in [0, 1]

    Examples
    --------
    >>> noise_share(np.array([1.5, 446.0, 1.0, 0.0]), np.array([1.0, 1.0, 0.0, 0.0]), 38, 2).round(3).tolist()
    [1.0, 0.1, 0.0, 1.0]
    """
    from scipy.special import fdtri  # lazy: not needed to import the kernels

    # the quantile of each distinct pair of dofs once (a window per bin has a few: 1.3 ms
    # for the 1800 bins of N = 3600 bin by bin, 0.1 ms so); a pair as one complex key
    wide, narrow = np.broadcast_arrays(np.asarray(dof_wide, dtype=float),
                                       np.asarray(dof_narrow, dtype=float))
    pairs, at = np.unique((wide + 1j * narrow).ravel(), return_inverse=True)
    limit = fdtri(2.0 * pairs.real, 2.0 * pairs.imag, level)[at.ravel()].reshape(wide.shape)
    var_wide, var_narrow = np.asarray(var_wide, dtype=float), np.asarray(var_narrow, dtype=float)
    with np.errstate(divide="ignore", invalid="ignore"):
        share = np.where(var_wide > 0, limit * var_narrow / var_wide, 1.0)
    return np.clip(share, 0.0, 1.0)
