"""Indirect closed-loop step of the lifted identification, with first-order uncertainty.

Pure numpy on trailing axes.  The local model estimates, per slow bin,

    G = [S; PS_1]      (F nu + ny) x (F nu)

from the lifted excitation to ``Z = [lifted u; y_l]``.  The first block row of the
lifted plant is ``P_1 = PS_1 S^-1`` (paper, eq. FirstRowPbar) and the fast FRF follows
from :func:`lcmr_xr.kernels.lifting.frf_from_first_block_row`.

Uncertainty: to first order ``dP_1 = (dPS_1 - P_1 dS) S^-1 = (L dG) S^-1`` with
``L = [-P_1, I]``, so the covariance of ``vec(P_1)`` is ``J Cov(vec G) J^H`` with
``J[(a, c), (i, b)] = L[a, i] S^-1[b, c]``.  ``P(k)`` is linear in ``P_1(k mod M)``.
Covariances are ``E[d d^H]`` of complex estimates; pseudo-covariances are neglected
(circular noise), as is standard for frequency-domain estimators.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from lcmr_xr.kernels.lifting import first_block_row_weights

#: S is declared not invertible where its condition number exceeds this (relative
#: precision left in P_1 would be below ~1e-4 for noiseless double-precision data).
S_CONDITION_LIMIT = 1e12


class IndirectResult(NamedTuple):
    """Result of :func:`indirect_first_row` (arrays over leading dims and slow bins)."""

    first_row: np.ndarray  #: (..., M, ny, F nu) estimate of P_1
    first_row_cov: np.ndarray | None  #: (..., M, ny F nu, ny F nu) or None
    s_condition: np.ndarray  #: (..., M) condition number of S
    singular: np.ndarray  #: (..., M) bool: S could not be inverted
    #: with ``G_cov``: ``(u, s, vh, half)``, the SVD of ``S`` (identity where ``G`` is not
    #: finite) on bins ``0..M/2`` of an exactly mirrored estimate (``half``,
    #: :func:`mirror_source`) or on every bin, for
    #: :func:`lcmr_xr.kernels.adaptive.weak_direction` (one SVD serves both)
    s_svd: tuple | None = None
    #: with ``G_cov``: :func:`mirror_source` of ``G`` when ``G`` and ``G_cov`` are both
    #: exact mirrors, else None (checked once here: the check reads all of ``G_cov``)
    mirror: np.ndarray | None = None


def indirect_first_row(G: np.ndarray, n_lifted_inputs: int, G_cov: np.ndarray | None = None,
                       s_condition_limit: float = S_CONDITION_LIMIT,
                       mirrors: bool = True, s_vectors: bool = True) -> IndirectResult:
    """First block row of the lifted plant from ``G = [S; PS_1]``.

    Parameters
    ----------
    G : ndarray, shape (..., M, F nu + ny, F nu)
        Local-model estimate per slow bin; its first ``F nu`` rows are the lifted sensitivity.
    n_lifted_inputs : int
        ``F nu``, the number of rows of ``S``.
    G_cov : ndarray, shape (..., M, nz nr, nz nr), optional
        Covariance of ``vec(G)`` (row-major, index ``i nr + b``).  When given, the
        first-order covariance of ``vec(P_1)`` is returned.
    s_condition_limit : float, default 1e12
        Bins where ``cond(S)`` exceeds this are flagged and set to NaN.
    mirrors : bool, default True
        Look for an exactly mirrored estimate (:func:`mirror_source`: the bins are the
        whole circle) and compute on half the bins then.  False: the bins are a block of
        the circle (``lcmr_xr.kernels.identification`` fits long records in blocks and
        mirrors the results itself); every bin is computed.
    s_vectors : bool, default True
        With ``G_cov``, also keep the singular vectors of ``S`` (``s_svd``, for the weak
        direction).  False: only the singular values (the condition number) are computed,
        for a caller that needs ``P_1`` and its covariance alone (``s_svd`` is then None).

    Returns
    -------
    IndirectResult
    """
    G = np.asarray(G)
    nr = int(n_lifted_inputs)
    nz = G.shape[-2]
    if G.shape[-1] != nr or nz <= nr:
        raise ValueError(
            f"G must have shape (..., M, F*nu + ny, F*nu) = (..., M, >{nr}, {nr}); got {G.shape}."
        )
    S = G[..., :nr, :]
    PS = G[..., nr:, :]
    finite = np.isfinite(G).all(axis=(-2, -1))
    S_safe = np.where(finite[..., None, None], S, np.eye(nr))
    cond_s, svd = _condition(S_safe, vectors=G_cov is not None and s_vectors,
                              mirrors=mirrors)
    cond = np.where(finite, cond_s, np.inf)
    singular = ~(cond < s_condition_limit)
    S_safe = np.where(singular[..., None, None], np.eye(nr), S_safe)
    S_inv = np.linalg.inv(S_safe)
    P1 = PS @ S_inv
    P1 = np.where(singular[..., None, None], np.nan, P1)

    cov = src = None
    if G_cov is not None:
        ny = nz - nr
        L = np.concatenate(
            [-P1, np.broadcast_to(np.eye(ny), P1.shape[:-2] + (ny, ny))], axis=-1
        )  # (..., M, ny, nz)
        G_cov = np.asarray(G_cov)
        # an exactly mirrored estimate: the covariance of bin M - k is the conjugate of
        # that of bin k, so the products run on bins 0..M/2 only
        m = G.shape[-3]
        src = mirror_source(G) if mirrors else None  # (the small array first)
        if src is not None and mirror_source(G_cov) is None:
            src = None
        part = slice(None) if src is None else slice(0, m // 2 + 1)
        C = G_cov[..., part, :, :]
        C = C.reshape(C.shape[:-2] + (nz, nr, nz, nr))
        Lp, Sp = L[..., part, :, :], S_inv[..., part, :, :]
        # Cov = J C J^H with J[a, c, i, b] = L[a, i] Sinv[b, c], one factor at a time:
        # a single three-operand einsum loops over all eight indices at once (about 12x
        # slower); two-operand einsums avoid BLAS on these tiny matrices.  L on both sides
        # first: only the first product has nz rows (ny nr nz nr values per bin, 11.5 MB
        # for N = 36 000), the others ny nr ny nr
        cov = np.einsum("...ai,...ibjd->...abjd", Lp, C)
        cov = np.einsum("...abjd,...ej->...abed", cov, Lp.conj())
        cov = np.einsum("...abed,...bc->...aced", cov, Sp)
        cov = np.einsum("...aced,...dg->...aceg", cov, Sp.conj())
        cov = cov.reshape(cov.shape[:-4] + (ny * nr, ny * nr))
        if src is not None:
            cov = np.take(cov, src, axis=-3)
            cov = np.where((np.arange(m) > m // 2)[:, None, None], cov.conj(), cov)
        cov = np.where(singular[..., None, None], np.nan, cov)
    return IndirectResult(P1, cov, cond, singular, svd, src)


def mirror_source(G: np.ndarray) -> np.ndarray | None:
    """Where bin ``k`` of an exactly mirrored estimate can be read on bins ``0..M/2``.

    The local model fits real signals' spectra on half the bins and mirrors them,
    ``G(M - k) = conj(G(k))``; quantities that a conjugation leaves unchanged (singular
    values, variances) are then computed on ``M/2 + 1`` bins and gathered with this index.

    Parameters
    ----------
    G : ndarray, shape (..., M, a, b)
        Estimate per slow bin (any leading dims).

    Returns
    -------
    ndarray of int, shape (M,), or None
        ``min(k, M - k)`` when bins ``M - k`` are exactly the conjugates of bins ``k``,
        ``0 < k < M/2`` (NaN where NaN), else None.  Bins 0 and ``M/2`` are their own
        mirrors and are read in place, so they need not be real (a fitted real-signal
        estimate is real there only to rounding).
    """
    if G.ndim < 3 or G.shape[-3] <= 2:
        return None
    m = G.shape[-3]
    k = np.arange(m)
    # bins 1..(M-1)/2 against M-1 down to M/2+1: views, no gathered copy; NaN-free data
    # pass the plain comparison, the NaN-aware one only runs when that fails.  In blocks
    # of bins: the comparison's temporaries (a negated copy, masks) would otherwise be
    # half the size of G, 36 MB for the covariance of an N = 36 000 record
    step = max(1, _COMPARE_BLOCK // max(1, G[..., :1, :, :].size))
    for lo in range(1, (m + 1) // 2, step):
        hi = min(lo + step, (m + 1) // 2)
        a, b = G[..., lo:hi, :, :], G[..., m - lo:m - hi:-1, :, :]
        if not (((a.real == b.real) & (a.imag == -b.imag)).all()
                or np.array_equal(a, b.conj(), equal_nan=True)):
            return None
    return np.minimum(k, (-k) % m)


#: Values compared at a time by :func:`mirror_source` (2 MB of float temporaries).
_COMPARE_BLOCK = 2**18


def _condition(S: np.ndarray, vectors: bool = False, mirrors: bool = True):
    """``np.linalg.cond`` of every ``S`` (..., M, nr, nr), on half the bins of an exactly
    mirrored estimate (:func:`mirror_source`): one small SVD costs about 10 us through
    numpy, 1 s for the 90 000 bins of ``N = 180 000``.

    Returns the condition numbers and, with ``vectors``, ``(u, s, vh, half)``: the SVD
    on the bins it was computed on (``half``: bins ``0..M/2``), else None.
    """
    src = mirror_source(S) if mirrors else None
    part = S if src is None else S[..., : S.shape[-3] // 2 + 1, :, :]
    if vectors:
        u, sv, vh = np.linalg.svd(part)
    else:
        sv = np.linalg.svd(part, compute_uv=False)
    with np.errstate(all="ignore"):
        cond = sv[..., 0] / sv[..., -1]
    cond = np.where(np.isnan(cond), np.inf, cond)  # 0 / 0 (as np.linalg.cond)
    if src is not None:
        cond = np.take(cond, src, axis=-1)
    return cond, ((u, sv, vh, src is not None) if vectors else None)


def frf_variance_from_first_row(first_row_cov: np.ndarray, n_fast: int, factor: int,
                                bins: np.ndarray, ny: int, nu: int) -> np.ndarray:
    """Variance ``E|dP(k)|^2`` of the recovered fast FRF at fast ``bins``.

    Parameters
    ----------
    first_row_cov : ndarray, shape (..., M, ny F nu, ny F nu)
        Covariance of ``vec(P_1)`` per slow bin (row-major, index ``a F nu + j nu + b``).
    n_fast, factor : int
        ``N`` and ``F``.
    bins : ndarray of int
        Fast bins ``k`` at which ``P(k)`` is recovered.
    ny, nu : int
        Plant outputs and inputs.

    Returns
    -------
    ndarray, shape (..., len(bins), ny, nu), real
    """
    f_ = int(factor)
    m = n_fast // f_
    bins = np.asarray(bins)
    C = np.asarray(first_row_cov)
    C = C.reshape(C.shape[:-2] + (ny, f_, nu, ny, f_, nu))
    # only the slow bins the fast ones read (all of them when every fast bin is asked)
    slow, at = np.unique(bins % m, return_inverse=True)
    if slow.size < m:
        C = np.take(C, slow, axis=-7)
    else:
        at = bins % m
    # only same-(a, b) entries are needed: C[a, j, b, a, j', b]
    diag = np.einsum("...ajbAkB,aA,bB->...abjk", C, np.eye(ny), np.eye(nu))  # (..., M, ny, nu, F, F)
    diag = np.take(diag, at, axis=-5)  # (..., K, ny, nu, F, F)
    w = first_block_row_weights(n_fast, f_, bins)  # (K, F)
    var = np.einsum("kj,...kabjl,kl->...kab", w, diag, w.conj())
    return np.maximum(var.real, 0.0)
