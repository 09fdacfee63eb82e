"""The paper's Procedure 1 on plain arrays: lift, DFT, local model, indirect step, recovery.

Shapes (leading dims broadcast): ``r, u`` are ``(..., N, nu)`` fast signals, ``y`` is
``(..., M, ny)`` with ``M = N / F``.  Everything returned is a dict of arrays so the
labelled layer can map each one onto named dimensions.
"""

from __future__ import annotations

import numpy as np

from lcmr_xr.kernels.closed_loop import (
    frf_variance_from_first_row,
    indirect_first_row,
)
from lcmr_xr.kernels.lifting import frf_from_first_block_row, lift
from lcmr_xr.kernels.local_models import local_model

#: The lifted excitation counts as rank deficient when its smallest singular value
#: (over all bins) is below this fraction of its largest.
EXCITATION_RANK_TOL = 1e-9

CLOSED_LOOP_METHODS = ("indirect", "direct")


def lifted_spectra(x: np.ndarray, factor: int) -> np.ndarray:
    """DFT of the lifted signal: ``(..., N, c) -> (..., M, F c)``, phase-major channels."""
    x = np.asarray(x)
    n, c = x.shape[-2:]
    lifted = lift(np.moveaxis(x, -1, -2), factor)  # (..., c, M, F)
    spec = np.fft.fft(lifted, axis=-2)  # along slow time
    spec = np.moveaxis(spec, -3, -1)  # (..., M, F, c)
    return spec.reshape(spec.shape[:-2] + (factor * c,))


def excitation_rank(R: np.ndarray) -> tuple[int, np.ndarray]:
    """Numerical rank of the lifted excitation spectra over all bins, and the singular values.

    ``R`` is ``(..., M, nr)``; the rank is that of the ``(M, nr)`` matrix (the worst over
    leading dims).  Local modelling needs rank ``nr``: every lifted channel must be excited
    independently of the others.
    """
    sv = np.linalg.svd(np.asarray(R), compute_uv=False)  # (..., nr)
    rel = sv / np.maximum(sv[..., :1], np.finfo(float).tiny)
    rank = int((rel > EXCITATION_RANK_TOL).sum(axis=-1).min())
    return rank, sv


def experiment_spectra(r, u, y, *, factor: int, closed_loop: str = "indirect"):
    """Spectra of the local-model problem: ``R`` (..., M, nr) and ``Z`` (..., M, nz).

    ``"indirect"``: ``R`` = DFT of the lifted ``r`` (``F nu`` channels), ``Z`` = DFTs of the
    lifted ``u`` and of ``y`` (``F nu + ny``).  ``"direct"``: ``R`` = lifted ``u``, ``Z = Y``.
    """
    if closed_loop not in CLOSED_LOOP_METHODS:
        raise ValueError(
            f"closed_loop must be one of {CLOSED_LOOP_METHODS}, got {closed_loop!r}."
        )
    r = np.asarray(r, dtype=float)
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    n = r.shape[-2]
    m = y.shape[-2]
    f_ = int(factor)
    if n != m * f_:
        raise ValueError(
            f"N = {n} fast samples and M = {m} slow samples do not match factor {f_} "
            f"(need N = M * F = {m * f_})."
        )
    U = lifted_spectra(u, f_)
    Y = np.fft.fft(y, axis=-2)
    if closed_loop == "indirect":
        return lifted_spectra(r, f_), np.concatenate([U, Y], axis=-1)
    return U, Y


def recover_frf(G, G_cov, *, n_fast: int, factor: int, nu: int, ny: int,
                closed_loop: str = "indirect", ill_posed=None) -> dict:
    """From the local-model ``G`` (..., M, nz, nr) per slow bin to the fast FRF.

    ``"indirect"``: ``P_1 = PS_1 S^-1`` with first-order covariance; ``"direct"``:
    ``P_1 = G``.  Then ``P(k) = sum_j exp(2j pi k j / N) P_1,j(k mod M)`` for
    ``k = 0..N/2``.

    Returns
    -------
    dict of ndarray
        ``P``, ``P_var`` (NaN when ``G_cov`` is None), ``P_bad``, ``s_condition``,
        ``s_singular``.
    """
    f_ = int(factor)
    nr = f_ * nu
    if closed_loop == "indirect":
        ind = indirect_first_row(G, nr, G_cov)
        P1, P1_cov, s_cond, s_sing = ind.first_row, ind.first_row_cov, ind.s_condition, ind.singular
    else:
        P1, P1_cov = G, G_cov
        s_cond = np.ones(G.shape[:-2])
        s_sing = np.zeros(G.shape[:-2], dtype=bool)
    m = G.shape[-3]
    bins = np.arange(n_fast // 2 + 1)
    P = frf_from_first_block_row(P1, f_)[..., : n_fast // 2 + 1, :, :]
    if P1_cov is not None:
        P_var = frf_variance_from_first_row(P1_cov, n_fast, f_, bins, ny, nu)
    else:
        P_var = np.full(P.shape, np.nan)
    slow_bad = s_sing if ill_posed is None else (ill_posed | s_sing)
    return {
        "P": P,
        "P_var": P_var,
        "P_bad": np.take(slow_bad, bins % m, axis=-1),
        "s_condition": s_cond,
        "s_singular": s_sing,
    }


def packed_width(nz: int, nr: int, covariance: bool) -> int:
    """Length of the last axis of :func:`fit_packed`'s output."""
    return nz * nr + 2 * nz + 2 + ((nz * nr) ** 2 if covariance else 0)


def fit_packed(R, Z, *, half_width: int, degrees=(3, 3, 3), circular: bool = True,
               covariance: bool = True) -> np.ndarray:
    """Local model per bin, packed into one complex array ``(..., M, K)``.

    One array (rather than a tuple) so that a frequency-chunked dask computation can run
    the fit with ``map_overlap``-style halos: columns are ``vec(G)`` (``nz nr``), ``T``
    (``nz``), the noise variances (``nz``), the condition number, the ill-posed flag and,
    with ``covariance``, ``vec(G_cov)``.  :func:`finish_packed` unpacks it.
    """
    fit = local_model(R, Z, half_width=half_width, degrees=tuple(degrees), circular=circular,
                      covariance="full" if covariance else None)
    lead_m = fit.G.shape[:-2]
    parts = [fit.G.reshape(lead_m + (-1,)), fit.T, fit.noise_variance,
             fit.condition[..., None], fit.ill_posed[..., None]]
    if covariance:
        parts.append(fit.G_cov.reshape(lead_m + (-1,)))
    return np.concatenate([np.asarray(p, dtype=complex) for p in parts], axis=-1)


def finish_packed(packed, *, nz: int, nr: int, n_fast: int, factor: int, nu: int, ny: int,
                  closed_loop: str = "indirect", covariance: bool = True) -> dict:
    """Unpack :func:`fit_packed` and recover the fast FRF (see :func:`identify_arrays`)."""
    packed = np.asarray(packed)
    lead_m = packed.shape[:-1]
    g = nz * nr
    # copies, not views: a view would keep all of ``packed`` (with the (nz nr)^2 covariance
    # columns, ~12 MB per HDD experiment) alive for as long as the small results live
    G = packed[..., :g].reshape(lead_m + (nz, nr)).copy()
    T = packed[..., g: g + nz].copy()
    noise_variance = packed[..., g + nz: g + 2 * nz].real.copy()
    condition = packed[..., g + 2 * nz].real.copy()
    ill_posed = packed[..., g + 2 * nz + 1].real != 0
    G_cov = packed[..., g + 2 * nz + 2:].reshape(lead_m + (g, g)) if covariance else None
    out = recover_frf(G, G_cov, n_fast=n_fast, factor=factor, nu=nu, ny=ny,
                      closed_loop=closed_loop, ill_posed=ill_posed)
    if covariance:
        G_var = np.real(np.diagonal(G_cov, axis1=-2, axis2=-1)).reshape(G.shape)
    else:
        G_var = np.full(G.shape, np.nan)
    out.update({"G": G, "G_var": G_var, "T": T, "noise_variance": noise_variance,
                "condition": condition, "ill_posed": ill_posed})
    return out


def identify_arrays(r, u, y, *, factor: int, half_width: int, degrees=(3, 3, 3),
                    closed_loop: str = "indirect", covariance: bool = True) -> dict:
    """Fast FRF of a plant in multirate closed loop from ``r``, ``u`` (fast) and ``y`` (slow).

    Parameters
    ----------
    r, u : ndarray, shape (..., N, nu)
        Fast-rate excitation and measured plant input.
    y : ndarray, shape (..., M, ny)
        Slow-rate measured output, ``y(l) = y_h(l F)``.
    factor : int
        Multirate factor ``F = N / M``.
    half_width : int
        Local window half-width ``n`` (``2 n + 1`` slow bins).
    degrees : (int, int, int), default (3, 3, 3)
        ``(Rn, Rm, Rd)``: numerator, transient and denominator degrees (``Rd = 0``: LPM).
    closed_loop : {"indirect", "direct"}, default "indirect"
        ``"indirect"``: ``G = [S; PS_1]`` from the lifted ``r``, then ``P_1 = PS_1 S^-1``
        (unbiased under feedback).  ``"direct"``: local model from the lifted ``u`` to
        ``y`` (biased under feedback; kept for comparison).
    covariance : bool, default True
        Propagate the local-model covariance to ``P`` (costs ``(nz nr)^2`` per bin).

    Returns
    -------
    dict of ndarray
        ``P`` (..., N/2+1, ny, nu) at fast bins ``k = 0..N/2``; ``P_var`` (same, real,
        ``E|dP|^2``; NaN without covariance); ``P_bad`` (..., N/2+1) bool; ``G`` (..., M, nz, nr);
        ``G_var`` (..., M, nz, nr); ``T`` (..., M, nz); ``noise_variance`` (..., M, nz);
        ``condition``, ``ill_posed``, ``s_condition``, ``s_singular`` (..., M).
    """
    R, Z = experiment_spectra(r, u, y, factor=factor, closed_loop=closed_loop)
    packed = fit_packed(R, Z, half_width=half_width, degrees=degrees, covariance=covariance)
    return finish_packed(packed, nz=Z.shape[-1], nr=R.shape[-1], n_fast=np.shape(r)[-2],
                         factor=factor, nu=np.shape(r)[-1], ny=np.shape(y)[-1],
                         closed_loop=closed_loop, covariance=covariance)


def identify_single_rate_arrays(r, u, y, *, factor: int, half_width: int,
                                degrees=(3, 3, 3), covariance: bool = True) -> dict:
    """Single-rate indirect estimate that ignores the multirate structure (for comparison).

    ``r`` and ``u`` are downsampled to the slow rate (``x(l F)``) and the ordinary
    closed-loop local model ``[S; PS] = LRM(R_l -> [U_l; Y_l])``, ``P = PS S^-1`` is
    formed.  It reaches only the slow Nyquist frequency, and the fast dynamics alias
    onto it: this is what the lifted method avoids.

    Returns
    -------
    dict of ndarray
        ``P`` (..., M//2+1, ny, nu) at slow bins ``m = 0..M/2``, ``P_var``, ``P_bad``.
    """
    f_ = int(factor)
    r_l = np.asarray(r, dtype=float)[..., ::f_, :]
    u_l = np.asarray(u, dtype=float)[..., ::f_, :]
    y = np.asarray(y, dtype=float)
    m, ny = y.shape[-2:]
    nu = r_l.shape[-1]
    R = np.fft.fft(r_l, axis=-2)
    Z = np.concatenate([np.fft.fft(u_l, axis=-2), np.fft.fft(y, axis=-2)], axis=-1)
    fit = local_model(R, Z, half_width=half_width, degrees=tuple(degrees), circular=True,
                      covariance="full" if covariance else None)
    ind = indirect_first_row(fit.G, nu, fit.G_cov if covariance else None)
    half = m // 2 + 1
    P = ind.first_row[..., :half, :, :]
    if ind.first_row_cov is not None:
        var = np.real(np.diagonal(ind.first_row_cov, axis1=-2, axis2=-1))
        P_var = var.reshape(var.shape[:-1] + (ny, nu))[..., :half, :, :]
    else:
        P_var = np.full(P.shape, np.nan)
    bad = (fit.ill_posed | ind.singular)[..., :half]
    return {"P": P, "P_var": P_var, "P_bad": bad}
