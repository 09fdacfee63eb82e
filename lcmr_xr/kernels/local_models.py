"""Local polynomial / local rational modelling (LPM / LRM) of spectra, batched over bins.

The paper's local model (van Haren et al., section "Multivariable Identification through
Local Modeling") at every DFT bin ``k``, for ``r = -n..n``::

    D(r) Z(k+r) - N(r) R(k+r) - Mt(r) = e(r)
    D(r)  = I + sum_{s=1..Rd} D_s rho^s          (diagonal: one row per output)
    N(r)  = G + sum_{s=1..Rn} N_s rho^s
    Mt(r) = T + sum_{s=1..Rm} M_s rho^s,         rho = r / n

minimising ``sum_r ||e(r)||^2``.  ``G`` and ``T`` (the values at ``r = 0``) do not depend on
the scaling of the local variable, so ``rho = r/n`` is used for the numerics.

How it is computed (and why)
----------------------------
With a diagonal ``D`` the output rows decouple.  Row ``i`` has the regressors
``rho^b R_p`` and ``rho^c`` (the *shared* block ``A``, the same for every row) and the
row-specific ``-rho^s Z_i`` (block ``B_i``).  Every entry of the normal equations is a
windowed moment ``sum_{|r|<=n} rho^a x(k+r)`` of a product series ``x`` (``conj(R_p) R_q``,
``conj(R_p) Z_i``, ``conj(Z_i) Z_j``, ...).  Moving the window by one bin changes these by
a fixed triangular combination (binomial in ``1/n``) plus the two end samples, so all
moments of the next bin cost ``O(p^2)`` per product whatever the window width; direct
sums restart the recurrence every ``n`` bins or less, which bounds its rounding (see
:mod:`.local_model_bins`).  Per bin, the shared block is Cholesky-factored once with all
rows' right-hand sides ``A^H rho^s Z_i`` carried along, and each row only needs its small
``Rd x Rd`` Schur complement.  All of this is one compiled loop over bins
(:func:`.local_model_bins.fit_bins`, numba, no BLAS); this module validates, pads,
chunks (threads), and mirrors.  Flops per bin for the HDD problem (nr = 4, nz = 5,
degrees (3, 3, 3)): about 1.5k complex multiply-adds for the moments and 7.5k for the
fit; the covariance adds about 75k, explicit over the window (``O(2n+1)``).

Numerics.  A sliding sum carries an absolute rounding error of about ``eps`` times the
energy that passed through it since its restart, so a bin whose local energy is far
below that of its neighbours loses relative accuracy; restarts every ``n`` bins or less keep the
error local (a bin is only polluted by data within about two windows of it).  For the
same reason an excitation energy ``sum_r |R_p|^2`` at or below that rounding level (the
``floor`` of :func:`.local_model_bins.fit_bins`: the data are zero there) is treated as
zero, so unexcited bins are flagged instead of being fitted to rounding noise.  The
Schur-complement form of the residual (``||D z||^2 - ||L^-1 A^H D z||^2``) is exact for
the computed ``D`` and stationary in it, so the residual variance keeps the accuracy of
the moments.  Normal equations square the condition number; ``condition`` reports an
estimate per bin and bins whose shared block (which holds ``G``) is above
:data:`CONDITION_LIMIT` are flagged.  The test suite checks agreement with a per-bin
``numpy.linalg.lstsq`` oracle to 1e-6 relative on data with a 1e4 dynamic range.

Instrumental variables (``instruments=``, Soderstrom & Stoica 1983).  The denominator
regressors ``-rho^s Z_i`` carry the noise on ``Z``, so least squares is biased by it, the
same way in every experiment (pooling does not shrink it; measured on the HDD benchmark,
docs/uncertainty.md).  Given a noise-free prediction ``Zhat`` of ``Z``, the denominator
columns get the instruments ``-rho^s Zhat_i``; the instruments are ``nz`` more channels
of the same moment recurrence and the same compiled loop (compiled apart from least
squares, on first use), the per-row Schur complement becomes
non-Hermitian (LU), and the covariance and ``tau`` those of the IV estimate (an oblique
residual projector).  Tested against a per-bin ``numpy.linalg.solve`` IV oracle to
1e-9.
"""

from __future__ import annotations

import functools
import operator
import threading
from concurrent.futures import ThreadPoolExecutor
from typing import NamedTuple

import numpy as np

from . import compile_ahead
from .pages import empty_pages

__all__ = ["CONDITION_LIMIT", "CovarianceBuffer", "LocalModelFit", "fits_half", "hermitian",
           "local_model", "parameters_per_row"]

#: Bins whose (column-scaled) regression matrix has a condition number estimate above
#: this are flagged ``ill_posed``.  The normal equations lose about ``eps * cond**2`` of
#: relative accuracy, so at 1e6 about four correct digits remain in the worst case.
CONDITION_LIMIT = 1e6

# Memory of one chunk's data copy and outputs (see _chunk_elements).
_CHUNK_BYTES = 6 << 20


class LocalModelFit(NamedTuple):
    """Result of :func:`local_model` (all arrays share the leading batch dims ``...``).

    Attributes
    ----------
    G : ndarray, complex, shape (..., M, nz, nr)
        Local estimate of the FRF at each bin (units of Z / units of R).
    T : ndarray, complex, shape (..., M, nz)
        Local estimate of the transient at each bin (units of Z).
    noise_variance : ndarray, float, shape (..., M, nz)
        Estimated variance of the noise on ``Z`` per output row (units of Z squared): the
        diagonal of ``noise_covariance``.
    noise_covariance : ndarray, complex, shape (..., M, nz, nz)
        Estimated covariance ``s_ij = E[V_i V_j^*]`` of the noise ``V`` on the rows of
        ``Z``: ``sum_r e_i(r) conj(e_j(r)) / tau_ij`` with the residuals ``e`` and their
        expected energy ``tau_ij`` (see :func:`local_model`, Notes).  For the LPM
        ``tau_ij = dof``, the plain residual covariance.
    dof : int or ndarray of int, shape (..., M)
        Degrees of freedom per row, ``2 n + 1 - (nr (Rn + 1) + Rm + 1 + Rd)`` (an array
        when ``half_width`` is one; dropped denominator terms are not counted back).
    G_cov : ndarray or None
        ``covariance="full"``: complex, shape (..., M, nz nr, nz nr), ``E[dG dG^H]`` of the
        vectorised ``G`` (index ``i nr + p``), cross-row terms included.
        ``covariance="diag"``: float, shape (..., M, nz, nr), variances ``E|dG|^2``.
        ``None`` when not requested.
    condition : ndarray, float, shape (..., M)
        Estimate of the condition number of the column-scaled regression per bin (worst
        row).
    ill_posed : ndarray, bool, shape (..., M)
        ``G`` is not determined: the shared block (R and constant columns, which hold
        ``G``) has a condition estimate above ``CONDITION_LIMIT`` or is singular, an R
        column is unexcited, a dropped denominator direction moves ``G``, or (with
        ``circular=False``) the bin lacks a full window.  ``G``, ``T`` are NaN where the
        factorisation failed or the window is incomplete.
    dropped : ndarray, int, shape (..., M)
        Denominator terms dropped in the bin (summed over rows) because the data cannot
        resolve them (see :func:`local_model`, Notes); 0 for noisy data.
    """

    G: np.ndarray
    T: np.ndarray
    noise_variance: np.ndarray
    noise_covariance: np.ndarray
    dof: int
    G_cov: np.ndarray | None
    condition: np.ndarray
    ill_posed: np.ndarray
    dropped: np.ndarray | None = None


def parameters_per_row(nr: int, degrees=(3, 3, 3)) -> int:
    """Number of local parameters per output row, ``nr (Rn + 1) + Rm + 1 + Rd``.

    Parameters
    ----------
    nr : int
        Number of excitation channels.
    degrees : tuple of int, default (3, 3, 3)
        ``(Rn, Rm, Rd)``: numerator, transient and denominator degrees.

    Returns
    -------
    int

    Examples
    --------
    >>> parameters_per_row(4, (3, 3, 3))
    23
    """
    rn, rm, rd = _check_degrees(degrees)
    return nr * (rn + 1) + rm + 1 + rd


def _check_degrees(degrees):
    try:
        rn, rm, rd = (int(d) for d in degrees)
    except (TypeError, ValueError):
        raise ValueError(
            f"degrees must be three integers (Rn, Rm, Rd), got {degrees!r}; "
            "for example degrees=(3, 3, 3), or (2, 2, 0) for the LPM."
        ) from None
    if min(rn, rd) < 0 or rm < -1:
        raise ValueError(
            f"degrees must be non-negative (Rm = -1: no transient term), got {(rn, rm, rd)}."
        )
    return rn, rm, rd


# ----------------------------------------------------------------------------- moments
@functools.lru_cache(maxsize=32)
def _analytic_moments(half_width: int, max_power: int) -> np.ndarray:
    """``sum_{r=-n..n} rho^a`` for ``a = 0..max_power`` (the constant-column moments).

    Cached; read-only.
    """
    n = half_width
    rho = np.arange(-n, n + 1) / n if n > 0 else np.zeros(1)
    out = np.array([np.sum(rho**a) for a in range(max_power + 1)])
    out.flags.writeable = False
    return out


def _top_powers(degrees, ext):
    """Highest power of ``rho`` needed per pair of base kinds (R, 1, Z), plus ``ext``."""
    rn, rm, rd = degrees
    top = {"RR": 2 * rn, "R1": rn + rm, "RZ": rn + rd, "11": 2 * rm, "1Z": rm + rd,
           "ZZ": 2 * rd}
    return {k: v + ext for k, v in top.items()}


class _Slots(NamedTuple):
    """Where each base pair's moments live in a bin's row of the moment table."""

    slot: np.ndarray  # (nb, nb) slot of the pair (i, j), i <= j (upper triangle only)
    groups: tuple  # (highest power, first slot, pairs i, pairs j) per FFT batch
    n_slots: int
    p1: int  # powers per slot (0..p1-1)


@functools.lru_cache(maxsize=32)
def _table_slots(nr, nz, degrees, ext):
    """Slots of the upper-triangle base pairs (i <= j), grouped by the highest power each
    needs (``_top_powers``) so that every FFT batch writes one contiguous slice.  The
    constant pair (1, 1) comes last: its moments are analytic."""
    one = nr
    nb = nr + 1 + nz
    top = _top_powers(degrees, ext)
    kind = ["R"] * nr + ["1"] + ["Z"] * nz
    by_power = {}
    for a in range(nb):
        for b in range(a, nb):
            if a != one or b != one:
                by_power.setdefault(top[kind[a] + kind[b]], []).append((a, b))
    slot = np.full((nb, nb), -1)
    groups = []
    start = 0
    for power in sorted(by_power):
        ia, ib = (np.array(v) for v in zip(*by_power[power]))
        slot[ia, ib] = start + np.arange(len(ia))
        groups.append((power, start, ia, ib))
        start += len(ia)
    slot[one, one] = start
    slot.flags.writeable = False
    return _Slots(slot, tuple(groups), start + 1, max(top.values()) + 1)


def _table_index(slots: _Slots, b1, b2, power):
    """Flat row index of ``sum_r rho^power conj(base_b1) base_b2`` (arrays broadcast).

    The FFTs give the upper triangle of base pairs (``b1 <= b2``); a lower-triangle entry
    is the conjugate of its mirror, read from the table's conjugated half (offset
    ``n_slots p1``), so that a gather is one ``np.take`` with no fix-up pass.
    """
    b1, b2, power = np.broadcast_arrays(b1, b2, power)
    lo, hi = np.minimum(b1, b2), np.maximum(b1, b2)
    index = slots.slot[lo, hi] * slots.p1 + power
    index = index + np.where(b1 > b2, slots.n_slots * slots.p1, 0)
    index.flags.writeable = False
    return index


class _Layout(NamedTuple):
    """Column bookkeeping of one model structure (see ``_layout``)."""

    a_base: np.ndarray  # base index of every shared column
    a_pow: np.ndarray  # its power of rho
    aug_index: np.ndarray  # (q, q + nx) flat table index of [Gaa | A^H X]
    zz_index: np.ndarray  # (nz, nz, Rd+1, Rd+1) flat table index of X_i^H X_j


@functools.lru_cache(maxsize=32)
def _layout(nr, nz, degrees, ext):
    """Shared columns (ordered so that T and then G, the r^0 terms, come last) and the
    moment-table indices of the augmented Gram ``[Gaa | A^H X]``, where ``X`` holds the
    columns ``rho^s Z_i`` (index ``i (Rd+1) + s``, ``s = 0..Rd``), and of ``X^H X``."""
    rn, rm, rd = degrees
    one, zb = nr, nr + 1
    slots = _table_slots(nr, nz, degrees, ext)
    cols = [(p, b) for b in range(rn, 0, -1) for p in range(nr)]
    cols += [(one, c) for c in range(rm, -1, -1)]
    cols += [(p, 0) for p in range(nr)]
    a_base = np.array([c[0] for c in cols])
    a_pow = np.array([c[1] for c in cols])
    x_base = np.repeat(zb + np.arange(nz), rd + 1)
    x_pow = np.tile(np.arange(rd + 1), nz)
    aug = _table_index(
        slots, a_base[:, None], np.concatenate([a_base, x_base])[None, :],
        a_pow[:, None] + np.concatenate([a_pow, x_pow])[None, :])
    s = np.arange(rd + 1)
    zi = zb + np.arange(nz)
    zz = _table_index(slots, zi[:, None, None, None], zi[None, :, None, None],
                               s[None, None, :, None] + s[None, None, None, :])
    for arr in (a_base, a_pow):
        arr.flags.writeable = False
    return _Layout(a_base, a_pow, aug, zz)


# ---------------------------------------------------------------------------- the model
#: A denominator column of the local model whose squared distance from the span of the
#: other (unit-norm) columns is below this is dropped in that bin (reduced degree):
#: below it the normal equations cannot resolve the column (same limit as the flag).
DROP_TOLERANCE = 1.0 / CONDITION_LIMIT**2

#: A dropped denominator direction moves ``G`` (column-scaled) by at most this fraction
#: of its own size, or the bin is flagged: there ``G`` itself is not determined.
G_SENSITIVITY_LIMIT = 1e-2

#: Instrumental variables (``local_model(..., instruments=)``): a row whose instruments,
#: projected off the shared columns, correlate with its denominator regressors less
#: than this (geometric mean of the canonical correlations) flags the bin: there the
#: IV estimate's spread exceeds least squares' about 1/corr^2 times and its first-order
#: covariance is no longer a description of it (weak instruments).
WEAK_INSTRUMENT_LIMIT = 1e-2


def _check_half_width(half_width, batch, m, nr, degrees, n_exp=1):
    """Validated half-widths: ``(scalar int or None, array (n_batch, M) of int)``."""
    hw = np.asarray(half_width)
    if hw.dtype.kind not in "iuf" or not np.all(np.isfinite(hw)) or np.any(hw != np.round(hw)):
        raise ValueError(
            f"half_width must be a positive integer or an integer array with one window "
            f"per bin (broadcastable to (..., M)), got {half_width!r}."
        )
    if hw.ndim > 0 and hw.shape[-1] not in (1, m):
        raise ValueError(
            f"half_width has {hw.shape[-1]} entries on its last axis but the spectra have "
            f"M = {m} bins; pass one half-width per bin (shape (..., {m}))."
        )
    hw = hw.astype(np.int64)
    if hw.size == 0 or hw.min() < 1:
        raise ValueError(f"half_width must be a positive integer, got {half_width!r}.")
    n_max, n_min = int(hw.max()), int(hw.min())
    w = 2 * n_max + 1
    if m < w:
        raise ValueError(
            f"{m} bins are too few for half_width={n_max}: a window needs 2n+1 = {w} bins. "
            f"Use half_width <= {(m - 1) // 2} or more bins."
        )
    p_row = parameters_per_row(nr, degrees)
    # pooled: E windows, G and D shared, a transient (Rm + 1 terms) per experiment
    p_all = p_row + (n_exp - 1) * (_check_degrees(degrees)[1] + 1)
    if n_exp * (2 * n_min + 1) - p_all < 1:
        need = -(-(p_all + 1 - n_exp) // (2 * n_exp))  # smallest n with a degree of freedom
        pooled = f" over {n_exp} pooled experiments" if n_exp > 1 else ""
        raise ValueError(
            f"no degrees of freedom: {p_all} parameters per row{pooled} (nr={nr}, degrees="
            f"{tuple(degrees)}) need at least {p_all + 1} bins in all windows together; use "
            f"half_width >= {need} or lower degrees."
        )
    try:
        full = np.broadcast_to(hw, batch + (m,))
    except ValueError:
        raise ValueError(
            f"half_width of shape {hw.shape} does not broadcast to the spectra's "
            f"(..., M) = {batch + (m,)}."
        ) from None
    scalar = int(hw.reshape(-1)[0]) if hw.ndim == 0 else None
    return scalar, full.reshape(-1, m)


def local_model(R, Z, *, half_width, degrees=(3, 3, 3), circular: bool = True,
                covariance: str | None = "full", experiment_axis: int | None = None,
                instruments=None, bins: tuple[int, int] | None = None,
                select=None, buffers: CovarianceBuffer | None = None) -> LocalModelFit:
    """Fit the local rational (LRM) or polynomial (LPM, ``Rd = 0``) model at every bin.

    Parameters
    ----------
    R : array_like, complex, shape (..., M, nr)
        Excitation spectra on ``M`` DFT bins (any unit).
    Z : array_like, complex, shape (..., M, nz)
        Output spectra on the same bins (any unit).  Leading dims of ``R`` and ``Z``
        broadcast.
    half_width : int or array_like of int, shape broadcastable to (..., M)
        ``n``: the local window is ``2 n + 1`` bins, ``r = -n..n`` (in bins).  An array
        gives every bin its own window (a frequency-adaptive choice); the cost per bin
        does not depend on the width (one moment table per distinct width within a
        chunk of a few hundred bins).
    degrees : tuple of int, default (3, 3, 3)
        ``(Rn, Rm, Rd)``: degrees of the numerator ``N``, transient ``Mt`` and the diagonal
        denominator ``D`` in the local variable.  ``Rd = 0`` is the LPM; ``Rm = -1``
        drops the transient term (periodic data, an integer number of periods: ``T`` is
        then 0).
    circular : bool, default True
        ``True``: the bins cover the whole unit circle, the window at bin ``k`` uses bins
        ``(k + r) mod M``.  ``False``: the caller passed data already padded with ``n`` halo
        bins on each side (as ``dask.array.map_overlap`` does); the output has the same
        length and the bins that lack a full window (the ``n`` at each end) are NaN and
        flagged.
    covariance : {"full", "diag", None}, default "full"
        What to return in ``G_cov``: the full cross-row covariance of the vectorised ``G``,
        only its variances, or nothing (saves time: the fit alone does not depend on the
        window width, the covariance costs ``O(2 n + 1)`` per bin).
    experiment_axis : int, optional
        A leading axis of ``R`` and ``Z`` (after broadcasting) holding ``E`` experiments
        fitted as ONE model: ``G`` and the denominator ``D`` shared, a transient term per
        experiment, one noise covariance (the windows of all experiments stacked:
        ``dof = E (2 n + 1) - p``).  The outputs lose that axis, except ``T``
        (..., E, M, nz).  Default: every leading index is fitted on its own.
    instruments : array_like, real or complex, shape (..., M, nz), optional
        Instrumental variables for the denominator: a noise-free prediction ``Zhat`` of
        ``Z`` (units of Z; for example ``G_hat R + T_hat`` from a first fit), with ``Z``'s
        trailing shape and leading dims that broadcast with ``Z``'s (with
        ``experiment_axis``: one prediction per experiment on that axis).  The regressors
        ``-rho^s Z_i`` carry the noise on ``Z``, which biases least squares (a bias that
        pooling experiments does not shrink); with instruments the fit solves
        ``[A, W_i]^H [A, B_i] theta = [A, W_i]^H Z_i`` with ``W_i = -rho^s Zhat_i`` instead
        (see Notes).  Default None: least squares.  Ignored for the LPM (``Rd = 0``,
        nothing to instrument).  Spectra of real signals are fitted on half the bins and
        mirrored only if the instruments are conjugate-symmetric too (to rounding); a
        fitted ``G_hat R + T_hat`` is so only to the fit's rounding: symmetrise it,
        ``(Zhat + Zhat[(-k) % M].conj()) / 2``, to keep the half cost.
    bins : (int, int), optional
        ``(start, stop)``: fit only the bins ``start..stop-1`` of the circular problem
        (windows wrap around all ``M`` bins of ``R`` and ``Z``) and return the outputs on
        those bins only, so that a caller can process a long record in blocks of bins
        without holding every bin's ``G_cov``.  Only the block and its halo of the widest
        window are read (and checked for NaN/inf).  The values are those of the whole fit
        at those bins, bit for bit when ``start`` is a multiple of the moment restart
        interval (the largest power of two not above the widest ``half_width``; the
        restarts then fall on the same bins) and ``stop`` is one too or ``M``; to
        rounding otherwise.  Every bin of the range is fitted by its own window: spectra
        of real signals are NOT mirrored (:func:`fits_half` says whether the whole fit
        would mirror; fit bins ``0..M/2`` then and mirror them).  Needs ``circular=True``.
    select : ndarray, bool, shape (M,), optional
        Fit only the bins of the ``M`` where ``select`` is True (with ``bins``: of
        ``start..stop-1``); the others are NaN and flagged as not fitted (as the bins
        without a full window of ``circular=False``), and nothing is mirrored.  A fitted
        bin's values are those of the fit of every bin (the moment recurrence still
        steps through the bins skipped).  E.g. a smoothed per-bin term that needs the fit
        at every third bin only (:func:`lcmr_xr.kernels.identification.twin_bins`).
    buffers : CovarianceBuffer, optional
        Write ``G_cov`` (``covariance="full"``) into this reusable buffer instead of fresh
        memory, for consecutive fits each of whose ``G_cov`` is used up before the next
        (``window="auto"``'s candidates and twin): fresh memory costs a page fault per
        4 kB page on its first write.  The returned ``G_cov`` is then a view of the
        buffer, overwritten by the next fit that uses it, and with ``select`` its rows at
        the bins not selected are left unwritten (not NaN; read the selected ones only).

    Returns
    -------
    LocalModelFit
        ``G`` (..., M, nz, nr), ``T`` (..., M, nz), ``noise_variance`` (..., M, nz),
        ``noise_covariance`` (..., M, nz, nz), ``dof``, ``G_cov``, ``condition`` (..., M),
        ``ill_posed`` (..., M), ``dropped`` (..., M); see :class:`LocalModelFit`.

    Raises
    ------
    ValueError
        Wrong shapes, fewer than ``2 n + 1`` bins, no degrees of freedom left, an unknown
        ``covariance``, or non-finite input (also in ``instruments``).  Ill-conditioned
        bins never raise: they are NaN and flagged.
    TypeError
        ``instruments`` not a real or complex numeric array.

    Notes
    -----
    Covariance (first order in the noise ``V`` on ``Z``, white over bins,
    ``E[V_i V_j^*] = s_ij``).  At the true parameters the equation error of row ``i`` is
    ``e_i(r) = d_i(r) V_i(k+r)`` (the ``-rho^s Z_i`` regressors carry noise too), so with
    ``D_i = diag(d_i(r))`` and ``theta_i - theta_i0 = K_i^+ e_i`` the sandwich is::

        Cov(theta_i, theta_j) = s_ij (K_i^H K_i)^-1 K_i^H D_i D_j^H K_j (K_j^H K_j)^-1

    (``d`` at its estimate; for the LPM ``D = I`` and it reduces to
    ``s_ij K_i^+ K_j^{+H}``).  The residual is ``r_i = P_i D_i V_i`` with
    ``P_i = I - K_i K_i^+``, so ``E[sum_r r_i conj(r_j)] = s_ij tau_ij`` with
    ``tau_ij = tr(D_j^H P_j P_i D_i)``, and ``s_ij`` is estimated as
    ``sum_r r_i conj(r_j) / tau_ij`` (unbiased to first order; ``tau = dof`` for the
    LPM).  With ``covariance=None`` and ``Rd > 0`` the exact ``tau`` is skipped for speed
    and ``tau_ij ~ dof * mean_r d_i(r) conj(d_j(r))`` is used (measured 2-30 % too large
    where ``d`` varies strongly in the window, so the noise estimate is then biased low
    by as much).  Beyond first order (noise comparable to the local signal) the LRM's
    errors-in-variables effects are not covered.

    Instrumental variables (``instruments``; Soderstrom & Stoica, "Instrumental variable
    methods for system identification", 1983; the denominator columns only, the ``R``
    and polynomial columns are their own instruments).  With ``Zhat`` free of the noise
    on ``Z``, ``E[W_i^H e_i] = 0`` and the estimate is consistent where least squares
    is not.  First order, ``theta_i - theta_i0 = (Phi_i^H K_i)^-1 Phi_i^H e_i``
    (``Phi_i = [A, W_i]``), so the sandwich above holds with ``K_i^+`` replaced by
    ``(Phi_i^H K_i)^-1 Phi_i^H`` and ``P_i = I - K_i (Phi_i^H K_i)^-1 Phi_i^H``, an oblique
    projector, in ``tau_ij``.  Which denominator terms the data determine is decided by
    least squares as below (dropped terms, ``condition``); the IV system is then solved
    on the kept terms.  A bin fails (NaN, flagged) where an instrument is numerically in
    the span of the ``R`` and polynomial columns (nothing is left of it after projection)
    and is flagged where the projected instruments correlate with the projected
    regressors less than :data:`WEAK_INSTRUMENT_LIMIT` (weak instruments: the estimate's
    spread grows as the inverse square of that correlation and the first-order
    covariance stops describing it).  The IV estimate has heavier tails than least
    squares (a draw whose IV system nearly vanishes), but its reported covariance grows
    with it.  Measured (``tests/test_local_models_iv.py``, 300 draws of a rational system
    with 10 % output noise, 17 bins): bias within the Monte Carlo error (median 1.4
    standard errors; least squares 17), reported variance of ``G`` 1.00 of the spread
    (0.86-1.10 over the bins; least squares 0.79-2.5 around its bias), noise variance
    0.99 of the truth (least squares 1.47), truth inside the 95 % disc in 93 % of draws
    (least squares 71 %).  At stronger noise the first-order formulas drift by
    ``O(noise^2)`` (noise variance 0.87 of the truth at 30 %).

    Exactly modelled data (noiseless, or a numerator and denominator sharing a factor)
    leave some local parameters undetermined while ``G`` is not: a denominator term
    whose column the data cannot resolve (pivot below :data:`DROP_TOLERANCE`) is dropped
    in that bin (``dropped`` counts them; ``condition`` still reports the full model),
    and the bin is flagged only if that moves ``G`` (:data:`G_SENSITIVITY_LIMIT`) or the
    shared block holding ``G`` is itself ill-conditioned (:data:`CONDITION_LIMIT`).

    Spectra of real signals (``X(M - k) = conj(X(k))`` to rounding, circular windows,
    a window per bin that is symmetric too) are fitted on bins ``0..M/2`` only and
    mirrored: ``G(M - k) = conj(G(k))``.

    Speed: the per-bin algebra is compiled (numba, :mod:`.local_model_bins`; no BLAS).
    Chunks of bins run on ``numba.get_num_threads()`` threads (set it with
    ``numba.set_num_threads`` or ``NUMBA_NUM_THREADS``) when called from the main
    thread, and on one thread inside worker threads (dask tasks), whose scheduler
    already runs tasks in parallel.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> M = 64
    >>> R = np.exp(2j * np.pi * rng.random((M, 1)))
    >>> G = 2.0 - 1.0j
    >>> fit = local_model(R, G * R + 0.5, half_width=4, degrees=(1, 1, 0))
    >>> bool(np.allclose(fit.G[..., 0, 0], G)), bool(np.allclose(fit.T[..., 0], 0.5))
    (True, True)
    >>> fit.dof
    5
    """
    rn, rm, rd = _check_degrees(degrees)
    degrees = (rn, rm, rd)
    R = np.asarray(R)
    Z = np.asarray(Z)
    if R.ndim < 2 or Z.ndim < 2:
        raise ValueError(
            f"R and Z must have shape (..., M, nr) and (..., M, nz), got {R.shape} and "
            f"{Z.shape}; add a trailing channel axis for one channel (R[..., None])."
        )
    m, nr = R.shape[-2:]
    nz = Z.shape[-1]
    if Z.shape[-2] != m:
        raise ValueError(
            f"R has {m} bins and Z has {Z.shape[-2]} (axis -2); pass spectra on the same bins."
        )
    use_iv = False
    Zhat = None
    if instruments is not None:
        Zhat = _check_instruments(instruments, Z)
        use_iv = rd > 0  # the LPM has no denominator: IV is least squares there
        if use_iv:  # the kernel reads the instruments as nz more channels after Z
            lead = np.broadcast_shapes(Z.shape[:-2], Zhat.shape[:-2])
            Z = np.broadcast_to(Z, lead + Z.shape[-2:])
            Zhat = np.broadcast_to(Zhat, lead + Z.shape[-2:])
            _, Zhat, _ = _experiments_last(R, Zhat, experiment_axis)
        else:  # checked all the same
            _check_finite_instruments(Zhat)
            Zhat = None
    nzc = nz * (2 if use_iv else 1)  # channels the kernel reads (2 nz with instruments)
    R, Z, n_exp = _experiments_last(R, Z, experiment_axis)
    pooled = experiment_axis is not None
    hw_lead = np.shape(half_width)[:-1]
    lead_r, lead_z = (R.shape[:-3], Z.shape[:-3]) if pooled else (R.shape[:-2], Z.shape[:-2])
    try:
        batch = np.broadcast_shapes(lead_r, lead_z, hw_lead)
    except ValueError:
        raise ValueError(
            f"leading dims of R {R.shape[:-2]}, Z {Z.shape[:-2]} (and half_width "
            f"{hw_lead}) do not broadcast."
        ) from None
    if nr < 1 or nz < 1:
        raise ValueError(f"need at least one channel in R and Z, got nr={nr}, nz={nz}.")
    scalar_n, widths = _check_half_width(half_width, batch, m, nr, degrees, n_exp)
    if covariance not in ("full", "diag", None):
        raise ValueError(
            f"covariance must be 'full', 'diag' or None, got {covariance!r}."
        )
    if select is not None:
        select = np.asarray(select, dtype=bool)
        if select.shape != (m,):
            raise ValueError(f"select must have shape (M,) = ({m},), one flag per bin; got "
                             f"{select.shape}.")
    if bins is not None:  # the block and its wrapped halo only, from here on
        start, stop = _check_bins(bins, m, circular)
        select = None if select is None else select[start:stop]
        widths = widths[:, start:stop]
        halo = int(widths.max())
        near = np.arange(start - halo, stop + halo) % m
        R, Z = np.take(R, near, axis=-2), np.take(Z, near, axis=-2)
        Zhat = None if Zhat is None else np.take(Zhat, near, axis=-2)
        m = stop - start
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(Z))):
        raise ValueError(
            "R and Z must be finite (found NaN or inf); drop or interpolate the bad bins "
            "before fitting."
        )
    if Zhat is not None:
        _check_finite_instruments(Zhat)
        Z = np.concatenate([Z, Zhat], axis=-1)
    p_row = parameters_per_row(nr, degrees)
    # pooled: the shared G, N, D plus one transient term (Rm + 1 parameters) per experiment
    p_pool = p_row + (n_exp - 1) * (rm + 1)

    # Bins-first layout (batch, bins, channel)
    n_batch = int(np.prod(batch, dtype=int))
    ex = (n_exp,) if pooled else ()
    n_max = int(widths.max())
    # bins= : the data come haloed, output bin j is the data's bin n_max + j (bin start + j
    # of the circle); otherwise the data are the M bins, each chunk takes its halo
    # (_haloed: no padded copy of the whole data, 75 MB at M = 2^19 with nr = 4, nz = 5)
    origin = 0 if bins is None else n_max
    # (read only from here on: a view of the caller's arrays when no copy is needed, not
    # a broadcast view where nothing is broadcast: those are read-only, see _haloed)
    rt, zt = ((x if x.shape == batch + ex + (m + 2 * origin, c)
               else np.broadcast_to(x, batch + ex + (m + 2 * origin, c)))
              .reshape(n_batch * n_exp, m + 2 * origin, c).astype(complex, copy=False)
              for x, c in ((R, nr), (Z, nzc)))
    k = np.arange(m)
    if bins is not None:
        todo = np.ones((n_batch, m), dtype=bool)
        mirror = False
    elif circular:
        todo = np.ones((n_batch, m), dtype=bool)
        mirror = select is None and _mirrors(rt, zt, widths)
        if mirror:  # real signals: fit 0..M/2, the rest is the conjugate
            todo[:, m // 2 + 1:] = False
    else:
        todo = (k - widths >= 0) & (k + widths <= m - 1)
        mirror = False
    region = todo  # the bins fitted but for ``select`` (a buffer's G_cov: NaN elsewhere)
    if select is not None:
        todo = todo & select

    # a wrong LCMR_XR_COMPILE_AHEAD is refused here, not inside numba's compiler
    compile_ahead.enabled()
    out = _allocate(n_batch, m, nz, nr, covariance, n_exp, buffers)
    bins = _bins()
    mode = {None: bins.COV_NONE, "diag": bins.COV_DIAG, "full": bins.COV_FULL}[covariance]
    elements = _chunk_elements(nr, nz, covariance)
    chunk = max(1, min(m, round(elements / (n_batch * n_exp))))
    batch_group = max(1, elements // chunk)
    threads = _threads()
    if threads > 1:  # enough chunks to keep every thread busy
        chunk = min(chunk, -(-m // (4 * threads)))
    # whole restart segments (results then do not depend on the chunking)
    align = _restart_interval(n_max)
    chunk = align * max(1, round(chunk / align))
    tasks = []
    for g0 in range(0, n_batch, batch_group):
        g = slice(g0, min(n_batch, g0 + batch_group))
        for c0 in range(0, m, chunk):
            c1 = min(m, c0 + chunk)
            sel = todo[g, c0:c1]
            if sel.any():
                for n in np.unique(widths[g, c0:c1][sel]):
                    tasks.append((g, c0, c1, int(n)))

    def run(task):
        g, c0, c1, n = task
        sel = todo[g, c0:c1] & (widths[g, c0:c1] == n)
        rows = slice(g.start * n_exp, g.stop * n_exp)  # the group's experiments, consecutive
        lo, hi = origin + c0 - n, origin + c1 + n
        _fit_chunk(_haloed(rt[rows], lo, hi, circular), _haloed(zt[rows], lo, hi, circular),
                   n, degrees, mode, sel,
                   g.start * m + c0, m, n_exp * (2 * n + 1) - p_pool, out, n_exp, use_iv)

    # mirrored: bins M/2+1..M-1 from bins (M-1)/2..1 (reversed views, written in place: no
    # gathered copy of outputs that reach hundreds of MB for M = 2^19), in as many
    # pieces as threads (numpy's copies release the GIL)
    pieces = []
    if mirror:
        for value in out.values():
            if value.size:
                v = value.reshape((n_batch, m) + value.shape[1:])
                src, dst = v[:, (m - 1) // 2:0:-1], v[:, m // 2 + 1:]
                cuts = np.linspace(0, dst.shape[1], threads + 1).astype(int)
                pieces += [(src[:, a:b], dst[:, a:b]) for a, b in zip(cuts, cuts[1:]) if b > a]
    with np.errstate(all="ignore"):
        if threads > 1 and len(tasks) > 1:
            with ThreadPoolExecutor(threads) as pool:
                list(pool.map(run, tasks))
                list(pool.map(_mirror_piece, pieces))
        else:
            for task in tasks:
                run(task)
            for piece in pieces:
                _mirror_piece(piece)
    if not mirror:  # (mirrored: the bins not fitted are the mirror's; in ``buffers`` the
        # covariance of the bins not selected stays unwritten: 2 of 3 rows for the twin;
        # that of the bins not fitted otherwise, e.g. the ends with circular=False, is NaN)
        _fill_not_fitted(out if buffers is None
                         else {k: v for k, v in out.items() if k != "G_cov"}, todo)
        if buffers is not None:
            _fill_not_fitted({"G_cov": out["G_cov"]}, region)
    shaped = {name: (v.reshape(batch + (m,) + v.shape[1:]) if v.shape[0] else None)
              for name, v in out.items()}
    # T: (..., M, E, nz) -> (..., E, M, nz) pooled, (..., M, nz) otherwise
    shaped["T"] = np.moveaxis(shaped["T"], -2, -3) if pooled else shaped["T"][..., 0, :]
    cond = shaped["condition"]
    dof = (n_exp * (2 * scalar_n + 1) - p_pool if scalar_n is not None
           else (n_exp * (2 * widths + 1) - p_pool).reshape(batch + (m,)))
    # (np.maximum keeps NaN: a failed bin's variance stays NaN)
    noise_var = np.maximum(np.real(np.diagonal(shaped["noise_covariance"], axis1=-2, axis2=-1)),
                           0.0)
    return LocalModelFit(
        G=shaped["G"], T=shaped["T"], noise_variance=noise_var,
        noise_covariance=shaped["noise_covariance"], dof=dof,
        G_cov=shaped["G_cov"] if covariance == "full" else shaped["G_var"],
        condition=cond, ill_posed=shaped["ill_posed"], dropped=shaped["dropped"],
    )


def _mirror_piece(piece):
    """``dst = conj(src)`` (complex) or ``src`` (real, int, bool) of one mirrored piece."""
    src, dst = piece
    if dst.dtype.kind == "c":
        np.conjugate(src, out=dst)
    else:
        dst[...] = src


def _haloed(x, lo, hi, circular):
    """Bins ``lo .. hi - 1`` of ``x`` (batch, M, channels), a chunk with its halo: a view
    inside the bins (a copy if ``x`` is read-only: numba compiles read-only arrays as
    another type, a second 20-30 s compilation); past either end, a copy with the bins
    of the other end (circular) or zeros.  No padded copy of the whole data."""
    m = x.shape[1]
    if lo >= 0 and hi <= m:
        return x[:, lo:hi] if x.flags.writeable else x[:, lo:hi].copy()
    if circular:
        return np.take(x, np.arange(lo, hi) % m, axis=1)
    out = np.zeros((x.shape[0], hi - lo, x.shape[2]), dtype=x.dtype)
    a, b = max(lo, 0), min(hi, m)
    out[:, a - lo: b - lo] = x[:, a:b]
    return out


def _check_instruments(instruments, Z):
    """The validated instruments (an array with ``Z``'s trailing shape whose leading dims
    broadcast with ``Z``'s)."""
    W = np.asarray(instruments)
    if W.dtype.kind not in "iufc":
        raise TypeError(
            f"instruments must be a real or complex numeric array (a noise-free prediction "
            f"of Z), got dtype {W.dtype}."
        )
    if W.ndim < 2 or W.shape[-2:] != Z.shape[-2:]:
        raise ValueError(
            f"instruments must have Z's shape (..., M, nz) = (..., {Z.shape[-2]}, "
            f"{Z.shape[-1]}), got {W.shape}; pass the prediction of Z on the same bins and "
            f"channels (for example G_hat R from a first fit)."
        )
    try:
        np.broadcast_shapes(W.shape[:-2], Z.shape[:-2])
    except ValueError:
        raise ValueError(
            f"the leading dims of instruments {W.shape[:-2]} do not broadcast with Z's "
            f"{Z.shape[:-2]}."
        ) from None
    return W  # (checked for NaN/inf by local_model, on the bins it reads)


def _check_finite_instruments(W):
    if not np.all(np.isfinite(W)):
        raise ValueError(
            "instruments must be finite (found NaN or inf); predict Z at every bin (where a "
            "first fit failed, use another prediction or instruments=None)."
        )


def _check_bins(bins, m, circular):
    """The validated ``(start, stop)`` of ``local_model(..., bins=)``."""
    if not circular:
        raise ValueError("bins= selects bins of the circular fit; with circular=False the "
                         "caller passes the haloed block itself (drop bins).")
    try:
        start, stop = (operator.index(b) for b in bins)
    except (TypeError, ValueError):
        raise ValueError(f"bins must be two integers (start, stop), got {bins!r}.") from None
    if not 0 <= start < stop <= m:
        raise ValueError(f"bins=({start}, {stop}) must satisfy 0 <= start < stop <= M = {m}.")
    return start, stop


def _mirrors(rt, zt, widths) -> bool:
    """Whether a circular fit of ``rt`` (batch, M, nr), ``zt`` (batch, M, nzc) with the
    half-widths ``widths`` (batch, M) fits bins ``0..M/2`` and mirrors the others."""
    m = widths.shape[-1]
    return hermitian(rt) and hermitian(zt) and np.array_equal(
        widths, widths[:, (-np.arange(m)) % m])


def fits_half(R, Z, *, half_width, instruments=None) -> bool:
    """Whether :func:`local_model` (circular) fits only bins ``0..M/2`` of these spectra
    and mirrors the others: spectra of real signals (:func:`hermitian`, instruments too)
    and a window per bin that is symmetric too.  A caller fitting in blocks of bins
    (``bins=``) then needs the blocks of bins ``0..M/2`` only.

    Parameters
    ----------
    R, Z, half_width, instruments
        As :func:`local_model` (``instruments``: pass None for a model without a
        denominator, whose fit ignores them).

    Returns
    -------
    bool

    Examples
    --------
    >>> import numpy as np
    >>> x = np.fft.fft(np.random.default_rng(0).standard_normal((16, 2)), axis=0)
    >>> fits_half(x[:, :1], x[:, 1:], half_width=3), fits_half(x[:, :1], 1j * x[:, 1:], half_width=3)
    (True, False)
    """
    R, Z = np.asarray(R), np.asarray(Z)
    m = R.shape[-2]
    flat = [np.reshape(x, (-1, m, x.shape[-1])) for x in
            (R, Z) + (() if instruments is None else (np.asarray(instruments),))]
    widths = np.broadcast_to(np.asarray(half_width), np.shape(half_width)[:-1] + (m,))
    return all(hermitian(x) for x in flat) and np.array_equal(
        widths, widths[..., (-np.arange(m)) % m])


def _experiments_last(R, Z, axis):
    """``R``, ``Z`` with the experiments axis moved to just before the bins, and ``E``
    (1 without one)."""
    if axis is None:
        return R, Z, 1
    lead = np.broadcast_shapes(R.shape[:-2], Z.shape[:-2])
    if isinstance(axis, (bool, np.bool_)) or not isinstance(axis, (int, np.integer)) \
            or not -len(lead) - 2 <= axis < len(lead) or -2 <= axis < 0:
        raise ValueError(
            f"experiment_axis must be a leading axis of R and Z (not the bins or channels, "
            f"the last two), an integer in [{-len(lead) - 2}, {len(lead) - 1}] excluding -1 "
            f"and -2; got {axis!r} for leading shape {lead}."
        )
    ax = axis if axis >= 0 else axis + len(lead) + 2
    R = np.moveaxis(np.broadcast_to(R, lead + R.shape[-2:]), ax, -3)
    Z = np.moveaxis(np.broadcast_to(Z, lead + Z.shape[-2:]), ax, -3)
    return R, Z, R.shape[-3]


def _bins():
    """The compiled module, imported on first use: numba takes about 0.4 s to import,
    which ``import lcmr_xr`` need not pay."""
    from lcmr_xr.kernels import local_model_bins

    return local_model_bins


def _threads() -> int:
    """Threads for one call: numba's setting in the main thread, one inside worker
    threads (dask's schedulers already run one task per core)."""
    if threading.current_thread() is not threading.main_thread():
        return 1
    import numba
    from numba.np.ufunc import parallel

    # numba.get_num_threads() launches numba's thread pool (0.02 s, and threads this
    # module never uses: its threads are its own) just to read the setting; until the
    # pool is launched (numba.set_num_threads launches it) the setting is
    # NUMBA_NUM_THREADS, as numba documents
    if not getattr(parallel, "_is_initialized", True):
        return max(1, numba.config.NUMBA_NUM_THREADS)
    return max(1, numba.get_num_threads())


def hermitian(x: np.ndarray) -> bool:
    """Whether spectra are those of real signals: ``x[(-k) mod M] == conj(x[k])`` to
    rounding (64 eps of each channel's largest magnitude).

    Parameters
    ----------
    x : ndarray, complex, shape (batch, M, channels)
        Spectra on the ``M`` DFT bins of the full circle.

    Returns
    -------
    bool
        True when every record and channel is conjugate-symmetric (bins ``0`` and
        ``M/2`` real) to rounding: a local model of such spectra is fitted on half the
        bins and mirrored.

    Examples
    --------
    >>> import numpy as np
    >>> x = np.fft.fft(np.random.default_rng(0).standard_normal((1, 8, 2)), axis=1)
    >>> hermitian(x), hermitian(1j * x)
    (True, False)
    """
    m = x.shape[1]
    tol = 64 * np.finfo(float).eps * np.max(np.abs(x), axis=1, keepdims=True)
    # each pair (k, M - k) once, on views; bins 0 and M/2 against their own conjugate
    pairs = x[:, 1:(m + 1) // 2] - np.conj(x[:, m - 1:m // 2:-1])
    self_mirrored = x[:, ::m // 2] if m % 2 == 0 else x[:, :1]
    return bool(np.all(np.abs(pairs) <= tol) and np.all(2 * np.abs(self_mirrored.imag) <= tol))


def _chunk_elements(nr, nz, covariance):
    """(batch x bin) elements per chunk: ``_CHUNK_BYTES`` of the chunk's contiguous copy
    of the data and of its outputs.  A chunk restarts the moment recurrence (direct sums
    over one window), so chunks are long; they are the unit of work of the threads."""
    ng = nz * nr
    per_bin = nr + nz + ng + nz + nz * nz + (ng * ng if covariance == "full" else ng)
    return max(1, int(_CHUNK_BYTES // (16 * per_bin)))


#: What a bin that is not fitted holds (NaN, flagged).
_NOT_FITTED = {"G": complex(np.nan, np.nan), "T": complex(np.nan, np.nan),
               "noise_covariance": complex(np.nan, np.nan), "condition": np.inf,
               "ill_posed": True, "dropped": 0, "G_cov": complex(np.nan, np.nan),
               "G_var": np.nan}


class CovarianceBuffer:
    """One buffer for the ``G_cov`` of consecutive local-model fits, each consumed before
    the next is fitted (``window="auto"``'s candidates and Hausman twin where each fit
    takes one block of bins, :func:`lcmr_xr.kernels.identification.identify_spectra_auto`).
    A fresh buffer costs a page fault per 4 kB page on its first write (the system
    zero-fills it): at N = 3600 about 1400 faults and 7 ms of system time per fit, a tenth
    of a fixed-window ``identify``; reused, only the first fit pays them.  The buffer grows to
    the largest request (with 1/16 to spare, so that blocks a few bins longer, e.g. on
    another window's restart grid, fit in it)."""

    def __init__(self):
        self._buffer = None

    def take(self, shape, dtype) -> np.ndarray:
        """An uninitialised array of ``shape`` and ``dtype`` on the buffer (the array
        taken before is overwritten)."""
        dtype = np.dtype(dtype)
        nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if self._buffer is None or self._buffer.nbytes < nbytes:
            self._buffer = empty_pages(nbytes + nbytes // 16, np.uint8)
        return self._buffer[:nbytes].view(dtype).reshape(shape)


def _allocate(n_batch, m, nz, nr, covariance, n_exp=1, buffers=None):
    """Outputs, not prefilled: every fitted bin writes its whole row (a failed one NaN),
    the mirror or :func:`_fill_not_fitted` the others (prefilling hundreds of MB at
    M = 2^19 cost about a tenth of the fit).  On pages numpy has not advised for huge
    pages (:mod:`.pages`: their first write stalled on memory compaction).  ``buffers``
    (:class:`CovarianceBuffer`): ``G_cov`` on it."""
    size = n_batch * m
    ng = nz * nr
    cov_shape = (size if covariance == "full" else 0, ng, ng)
    return {
        "G": empty_pages((size, nz, nr), complex),
        "T": empty_pages((size, n_exp, nz), complex),
        "noise_covariance": empty_pages((size, nz, nz), complex),
        "condition": empty_pages(size),
        "ill_posed": empty_pages(size, dtype=bool),
        "dropped": empty_pages(size, dtype=np.int64),
        "G_cov": (empty_pages(cov_shape, complex) if buffers is None or not cov_shape[0]
                  else buffers.take(cov_shape, complex)),
        "G_var": empty_pages((size if covariance == "diag" else 0, nz, nr)),
    }


def _fill_not_fitted(out, todo):
    """Bins outside ``todo`` (flat over batch and bins): NaN and flagged."""
    skip = ~todo.reshape(-1)
    if skip.any():
        for name, value in out.items():
            if value.size:
                value[skip] = _NOT_FITTED[name]


def _fit_chunk(rt, zt, n, degrees, mode, sel, out_offset, m, dof, out, n_exp=1, iv=False):
    """Fit the bins ``sel`` (nbat, K) of one chunk; ``rt`` (nbat, K + 2n, nr), ``zt``
    (nbat, K + 2n, nz) the haloed data (``iv``: (nbat, K + 2n, 2 nz), ``Z`` then the
    instruments); flat output row of bin ``(b, k)`` is ``out_offset + b M + k``."""
    rd = degrees[2]
    nr, nz = rt.shape[-1], zt.shape[-1] // (2 if iv else 1)
    lay = _power_major_layout(nr, nz, degrees)
    if iv:
        tab = _iv_tables(nr, nz, degrees)
        slots, aug, zz = tab.slots, tab.aug_index, tab.zz_index
        iv_arg = (tab.wx_index, tab.ww_index, WEAK_INSTRUMENT_LIMIT)
    else:
        slots, aug, zz, iv_arg = _slot_pairs(nr, nz, degrees), lay.aug_index, lay.zz_index, _NO_IV
    mean_pow = _analytic_moments(n, 2 * rd) / (2 * n + 1)
    gather = _gather_tables(nr, nz, degrees, iv)
    _bins().fit_bins(np.ascontiguousarray(rt), np.ascontiguousarray(zt), n, np.ascontiguousarray(sel),
                  out_offset, m, _restart_interval(n), *slots, aug, zz, gather, lay.a_base, lay.a_pow, np.ascontiguousarray(mean_pow), float(dof), mode,
                  DROP_TOLERANCE, CONDITION_LIMIT, G_SENSITIVITY_LIMIT,
                  out["G"], out["T"], out["noise_covariance"], out["condition"],
                  out["ill_posed"], out["dropped"], out["G_cov"], out["G_var"],
                  # least squares passes the empty index tables (_NO_IV): the same
                  # argument types as IV, so one compiled version serves both (branches
                  # taken at run time); one record (None) and pooled (int) compile apart
                  None if n_exp == 1 else int(n_exp), iv_arg)


def _readonly(a):
    a.flags.writeable = False
    return a


#: ``fit_bins``'s ``iv`` argument for least squares: empty instrument tables of the IV
#: tables' type (read-only C int64 arrays), so that least squares and instrumental
#: variables call one compiled version (``iv[0].shape[0] == 0`` selects least squares)
_NO_IV = (_readonly(np.zeros((0, 1, 1), dtype=np.int64)),
          _readonly(np.zeros((0, 1, 1), dtype=np.int64)), WEAK_INSTRUMENT_LIMIT)


def _restart_interval(half_width: int) -> int:
    """Bins between direct moment sums: the largest power of two <= ``n``.  Over at most
    ``n`` steps the recurrence's rounding grows by at most ``2^p``; a restart costs
    ``2 n + 1`` products per slot, so two to four per slot and bin.  Powers of two, so
    that chunks aligned to the widest window's interval align every narrower one."""
    return 1 << (max(1, int(half_width)).bit_length() - 1)


@functools.lru_cache(maxsize=32)
def _slot_pairs(nr, nz, degrees):
    """``(slot_i, slot_j, p1)`` of the moment slots (``_table_slots``): the base pairs
    whose windowed moments the fit reads, with ``p1`` powers each."""
    slots = _table_slots(nr, nz, degrees, 0)
    slot_i = np.empty(slots.n_slots, dtype=np.int64)
    slot_j = np.empty(slots.n_slots, dtype=np.int64)
    for _, start, ia, ib in slots.groups:
        slot_i[start: start + len(ia)] = ia
        slot_j[start: start + len(ia)] = ib
    slot_i[-1] = slot_j[-1] = nr  # the constant pair comes last
    for arr in (slot_i, slot_j):
        arr.flags.writeable = False
    return slot_i, slot_j, slots.p1


def _power_major(index, slots: _Slots):
    """Table indices remapped from slot-major (``s p1 + a``, as ``_table_index`` numbers
    them) to the compiled kernel's power-major ``a n_slots + s`` (conjugated half offset
    by ``n_slots p1`` in both)."""
    n_flat = slots.n_slots * slots.p1
    half, f = np.divmod(index, n_flat)
    s, a = np.divmod(f, slots.p1)
    out = np.ascontiguousarray(half * n_flat + a * slots.n_slots + s)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=32)
def _power_major_layout(nr, nz, degrees):
    """``_layout``'s gather indices in the compiled kernel's power-major numbering."""
    lay = _layout(nr, nz, degrees, 0)
    slots = _table_slots(nr, nz, degrees, 0)
    return lay._replace(aug_index=_power_major(lay.aug_index, slots),
                        zz_index=_power_major(lay.zz_index, slots))


@functools.lru_cache(maxsize=32)
def _gather_tables(nr, nz, degrees, iv=False):
    """``fit_bins``'s ``gather`` argument: its ``aug_index`` and ``zz_index`` (least
    squares' or, ``iv``, the instrumental-variable tables') decoded for the one-record
    gathers, which read a moment as two floats without a branch per entry: per entry the
    position of its real part in the moments' float view (``2 f``, ``f`` the moment's
    index with the conjugated half folded back) and the sign of its imaginary part (-1 in
    the conjugated half).  Returns ``(aug positions, aug signs, zz positions, zz signs)``,
    read-only (computed here once per layout, not compiled: less code to compile)."""
    if iv:
        tab = _iv_tables(nr, nz, degrees)
        (slot_i, _, p1), aug, zz = tab.slots, tab.aug_index, tab.zz_index
    else:
        lay = _power_major_layout(nr, nz, degrees)
        slot_i, _, p1 = _slot_pairs(nr, nz, degrees)
        aug, zz = lay.aug_index, lay.zz_index
    n_flat = len(slot_i) * p1
    out = []
    for index in (aug, zz):
        conj = index >= n_flat
        out += [np.ascontiguousarray(2 * np.where(conj, index - n_flat, index), dtype=np.int64),
                np.ascontiguousarray(np.where(conj, -1.0, 1.0))]
    for arr in out:
        arr.flags.writeable = False
    return tuple(out)


class _IVTables(NamedTuple):
    """Moment slots and gather indices of the instrumental-variable fit (``_iv_tables``)."""

    slots: tuple  # (slot_i, slot_j, p1): the least-squares slots, then the instruments'
    aug_index: np.ndarray  # (q, q + 2 nx) [Gaa | A^H X | A^H W], power-major
    zz_index: np.ndarray  # (nz, nz, Rd+1, Rd+1) X_i^H X_j (as _layout's, in this table)
    wx_index: np.ndarray  # (nz, Rd+1, Rd+1) W_s^H X_t of the same row
    ww_index: np.ndarray  # (nz, Rd+1, Rd+1) W_s^H W_t


@functools.lru_cache(maxsize=32)
def _iv_tables(nr, nz, degrees):
    """The instruments ``Zhat_i`` are ``nz`` more bases after ``Z`` (the kernel's ``zt``
    holds ``[Z, Zhat]``).  Their moments with the shared columns (``R_p``, ``1``), with
    their own row's ``Z_i`` and with themselves are extra slots after the least-squares
    ones (whose numbering, and so the least-squares gathers, stay as they are); the
    powers per slot (``p1``) are those of the ``Z`` pairs, which bound them."""
    ls = _table_slots(nr, nz, degrees, 0)
    one, zb, wb = nr, nr + 1, nr + 1 + nz
    extra = ([(p, wb + i) for p in range(nr) for i in range(nz)]
             + [(one, wb + i) for i in range(nz)]
             + [(zb + i, wb + i) for i in range(nz)] + [(wb + i, wb + i) for i in range(nz)])
    slot = np.full((wb + nz, wb + nz), -1)
    slot[:wb, :wb] = ls.slot
    for x, (a, b) in enumerate(extra):
        slot[a, b] = ls.n_slots + x
    slots = _Slots(slot, (), ls.n_slots + len(extra), ls.p1)
    slot_i, slot_j, p1 = _slot_pairs(nr, nz, degrees)
    slot_i = np.concatenate([slot_i, [a for a, _ in extra]])
    slot_j = np.concatenate([slot_j, [b for _, b in extra]])
    rd = degrees[2]
    lay = _layout(nr, nz, degrees, 0)
    w_base = np.repeat(wb + np.arange(nz), rd + 1)
    w_pow = np.tile(np.arange(rd + 1), nz)
    # every index anew: the conjugated half of the table starts later (more slots)
    cols = np.concatenate([lay.a_base, w_base - nz, w_base])  # [A | X | W]
    pows = np.concatenate([lay.a_pow, w_pow, w_pow])
    aug = _table_index(slots, lay.a_base[:, None], cols[None, :],
                       lay.a_pow[:, None] + pows[None, :])
    s = np.arange(rd + 1)
    zi, wi = zb + np.arange(nz), wb + np.arange(nz)
    pw = s[None, :, None] + s[None, None, :]
    zz = _table_index(slots, zi[:, None, None, None], zi[None, :, None, None],
                      s[None, None, :, None] + s[None, None, None, :])
    wx = _table_index(slots, wi[:, None, None], zi[:, None, None], pw)
    ww = _table_index(slots, wi[:, None, None], wi[:, None, None], pw)
    for arr in (slot_i, slot_j):
        arr.flags.writeable = False
    return _IVTables((slot_i, slot_j, p1), *(_power_major(x, slots) for x in (aug, zz, wx, ww)))
