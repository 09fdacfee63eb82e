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
``conj(R_p) Z_i``, ``conj(Z_i) Z_j``, ...).  For all bins at once these are correlations
with the kernels ``rho^a``, computed by FFT in short overlap-save blocks (transforms
along the bin axis, so the result is already bins-first), so the cost does not grow with
the window width.  The moments go into a table ``tab[bin, base, base, power]`` from which
every Gram is gathered with precomputed flat indices.  Per bin, the shared block is
Cholesky-factored once, with all rows' right-hand sides ``A^H rho^s Z_i`` carried along
(a blocked, right-looking factorisation of ``[Gaa | A^H X]``: the forward substitution
comes out of the same matrix products), and each row only needs its small ``Rd x Rd``
Schur complement.

The linear algebra is written "bins first": arrays are ``(bins, matrix indices...)``, the
large products are stacked ``np.matmul`` calls (BLAS per bin) and the Python loops run
over matrix indices only.  Measured on this project's machine (one core): numpy's batched
``linalg`` calls cost microseconds *per matrix* (``cholesky`` ~5 us on 20 x 20, ``solve``
~15 us), stacked ``matmul`` ~0.4 ns per complex multiply-add on 20 x 20 blocks, about 4x
less than elementwise passes; elementwise work on tiny trailing axes is the slow part,
so it is kept to small arrays.

The LRM covariance is the first-order sandwich (the equation error is ``d(r) V(r)``,
not white): see :func:`local_model`, Notes.  Its weighted Grams are built from a table
of moments with powers raised by ``2 Rd`` (``_sandwich``, bins-first ``np.matmul``).

Numerics.  An FFT correlation has an absolute error of about ``eps`` times the norm of the
block it transforms, so a bin whose local energy is far below that of its neighbours loses
relative accuracy.  The blocks are therefore short (``_fft_length``: about four windows), which
keeps the error local: a bin is only polluted by data within about two windows of it.  For
the same reason an excitation energy ``sum_r |R_p|^2`` at or below that rounding level
(``eps nfft`` times the block's sum of ``|R_p|^2``: the data are zero there) is treated as
zero, so unexcited bins are flagged instead of being fitted to rounding noise.  The
Schur-complement form of the residual (``||D z||^2 - ||L^-1 A^H D z||^2``) is exact for
the computed ``D`` and stationary in it, so the residual variance keeps the accuracy of the
moments.  Normal equations square the condition number; ``condition`` reports an estimate
per bin and bins above :data:`CONDITION_LIMIT` are flagged.  The test suite checks agreement
with a per-bin ``numpy.linalg.lstsq`` oracle to 1e-6 relative on data with a 1e4 dynamic
range.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np
from scipy import fft as sp_fft

__all__ = ["CONDITION_LIMIT", "LocalModelFit", "local_model", "parameters_per_row"]

#: Bins whose (column-scaled) regression matrix has a condition number estimate above
#: this are flagged ``ill_posed``.  The normal equations lose about ``eps * cond**2`` of
#: relative accuracy, so at 1e6 about four correct digits remain in the worst case.
CONDITION_LIMIT = 1e6

# Memory target of the main per-chunk arrays (moment table, augmented Gram, projected
# Gram, the sandwich's basis Gram); chunks are rounded to whole overlap-save steps (a
# partial block costs a full FFT).  Small chunks keep temporaries cache-sized and avoid
# fresh multi-MB allocations (page faults); large ones amortise the ~200 numpy calls per
# chunk.  Measured on 2**15 bins, n = 30, nr = 4, nz = 5, degrees (3, 3, 3) (~27 kB per
# bin): 196 bins per chunk fastest (392 and 784: +15 %); small models get more bins.
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
    dof : int
        Degrees of freedom per row, ``2 n + 1 - (nr (Rn + 1) + Rm + 1 + Rd)``.
    G_cov : ndarray or None
        ``covariance="full"``: complex, shape (..., M, nz nr, nz nr), ``E[dG dG^H]`` of the
        vectorised ``G`` (index ``i nr + p``), cross-row terms included.
        ``covariance="diag"``: float, shape (..., M, nz, nr), variances ``E|dG|^2``.
        ``None`` when not requested.
    condition : ndarray, float, shape (..., M)
        Estimate of the condition number of the column-scaled regression per bin (worst
        row).
    ill_posed : ndarray, bool, shape (..., M)
        ``condition > CONDITION_LIMIT``, a non-finite estimate, or (with
        ``circular=False``) a bin without a full window.  ``G``, ``T`` are NaN where the
        factorisation failed or the window is incomplete.
    """

    G: np.ndarray
    T: np.ndarray
    noise_variance: np.ndarray
    noise_covariance: np.ndarray
    dof: int
    G_cov: np.ndarray | None
    condition: np.ndarray
    ill_posed: np.ndarray


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
    if min(rn, rm, rd) < 0:
        raise ValueError(f"degrees must be non-negative, got {(rn, rm, rd)}.")
    return rn, rm, rd


# ----------------------------------------------------------------------------- moments
def _fft_length(half_width: int) -> int:
    """FFT block length for the overlap-save moments: the power of two >= 4 windows.

    Four windows keep the FFT's absolute error local (see the module notes) while the
    overlap (2n of every block) costs at most about half of the work.  Measured: cost per
    bin changes by < 1.5x between n = 10 and n = 100.
    """
    w = 2 * half_width + 1
    return max(64, 1 << int(np.ceil(np.log2(4 * w))))


@functools.lru_cache(maxsize=32)
def _kernel_spectra(half_width: int, max_power: int, nfft: int) -> np.ndarray:
    """``conj(fft(h_a))`` for ``h_a[t] = rho^a`` at ``t = r + n``, ``a = 0..max_power``.

    Cached (every chunk of a call uses the same kernels); read-only.
    """
    n = half_width
    rho = np.arange(-n, n + 1) / n if n > 0 else np.zeros(1)
    h = np.zeros((max_power + 1, nfft))
    h[:, : 2 * n + 1] = rho[None, :] ** np.arange(max_power + 1)[:, None]
    out = np.conj(sp_fft.fft(h, axis=-1))
    out.flags.writeable = False
    return out


def _blocks(x: np.ndarray, half_width: int):
    """Overlap-save blocks of ``x`` (nbat, L, S) along the bin axis, zero padded at the end.

    Returns ``(blocks, n_blocks, step)``; ``blocks`` (nbat, n_blocks, nfft, S) is a strided
    view: block ``j`` covers bins ``j step .. j step + nfft - 1``.
    """
    n = half_width
    nbat, length = x.shape[:2]
    nfft = _fft_length(n)
    step = nfft - 2 * n
    n_blocks = -(-(length - 2 * n) // step)
    padded = np.zeros((nbat, n_blocks * step + 2 * n) + x.shape[2:], dtype=x.dtype)
    padded[:, :length] = x
    blocks = np.lib.stride_tricks.sliding_window_view(padded, nfft, axis=1)[:, ::step]
    return np.moveaxis(blocks, -1, 2), n_blocks, step


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


class _MomentTable(NamedTuple):
    """Windowed moments of a chunk: row ``(b, k)`` is output bin ``k`` of batch element
    ``b``; its first ``n_slots p1`` entries are the moments, the rest their conjugates."""

    data: np.ndarray  # (nbat, n_blocks step, 2 n_slots p1); rows k < n_out are valid
    n_out: int  # output bins per batch element (K)

    def gather(self, index):
        """``out[b k, ...] = row(b, k)[index]`` (bins-first, (nbat K, *index.shape))."""
        out = np.take(self.data[:, : self.n_out], index, axis=-1)
        return out.reshape((self.data.shape[0] * self.n_out,) + index.shape)


def _moment_table(rt, zt, half_width, degrees, ext):
    """Windowed moments ``sum_r rho^a conj(base_i) base_j`` of every base pair (i <= j).

    The bases are ``R_0..R_{nr-1}``, the constant ``1``, ``Z_0..Z_{nz-1}``; ``rt`` (nbat,
    K + 2n, nr) and ``zt`` (nbat, K + 2n, nz) are the haloed chunk.  Returns the table
    (read it with ``_MomentTable.gather`` and ``_table_index``) and the rounding floor
    (nbat K, nr) of the energies ``sum_r |R_p|^2`` (see the module notes).  Each FFT
    batch multiplies and inverse-transforms in place in its slice of a scratch array, whose
    valid rows are then copied into the table beside their conjugates; powers a pair does
    not need (``_top_powers``) are left uninitialised and never read.
    """
    nr, nz = rt.shape[-1], zt.shape[-1]
    nbat, length = rt.shape[:2]
    k_out = length - 2 * half_width
    slots = _table_slots(nr, nz, degrees, ext)
    p1 = slots.p1
    nfft = _fft_length(half_width)
    step = nfft - 2 * half_width
    n_blocks = -(-k_out // step)
    data = np.empty((nbat, n_blocks, nfft, slots.n_slots, p1), dtype=complex)
    base = np.concatenate([rt, np.ones((nbat, length, 1), dtype=complex), zt], axis=-1)
    energy = np.empty((nbat, n_blocks, nr))  # sum over each FFT block of |R_p|^2
    for power, start, ia, ib in slots.groups:
        blocks, _, _ = _blocks(np.conj(base[..., ia]) * base[..., ib], half_width)
        # scipy.fft: measured ~1.4x faster than numpy.fft on these short batched transforms
        spectra = sp_fft.fft(blocks, axis=2, workers=1)  # (nbat, n_blocks, nfft, S)
        own = np.nonzero((ia == ib) & (ia < nr))[0]
        if len(own):  # the DC bin of |R_p|^2 >= 0 is its block sum (the rounding floor)
            energy[..., ia[own]] = spectra[:, :, 0, own].real
        kernels = _kernel_spectra(half_width, power, nfft).T  # (nfft, A)
        view = data[:, :, :, start : start + len(ia), : power + 1]
        np.multiply(spectra[..., None], kernels[:, None, :], out=view)
        corr = sp_fft.ifft(view, axis=2, workers=1, overwrite_x=True)
        if not np.may_share_memory(corr, data):  # scipy may decline to work in place
            view[...] = corr
    top11 = _top_powers(degrees, ext)["11"]
    n_flat = slots.n_slots * p1
    # the valid rows (t < step) of every block, then their conjugates (lower triangle)
    table = np.empty((nbat, n_blocks, step, 2, n_flat), dtype=complex)
    table[:, :, :, 0] = data[:, :, :step].reshape(nbat, n_blocks, step, n_flat)
    const = table[:, :, :, 0].reshape(nbat, n_blocks, step, slots.n_slots, p1)
    const[..., -1, : top11 + 1] = _analytic_moments(half_width, top11)
    np.conjugate(table[:, :, :, 0], out=table[:, :, :, 1])
    # FFT rounding floor of the windowed energies: eps nfft (block sum of |R_p|^2), the
    # same bound for every output bin of a block (see the module notes)
    floor = np.repeat(energy * (nfft * np.finfo(float).eps), step, axis=1)[:, :k_out]
    table = _MomentTable(table.reshape(nbat, n_blocks * step, 2 * n_flat), k_out)
    return table, floor.reshape(nbat * k_out, nr)


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


# ------------------------------------------------------------------ bins-first linear algebra
# Arrays are (bins, ..., matrix indices).  Large products go through np.matmul on stacks
# (BLAS per bin: measured ~0.4 ns per complex multiply-add on 20 x 20 blocks, about 4x
# less than elementwise passes); the Python loops run over matrix indices only.
_CHOL_BLOCK = 5


def _augmented_cholesky(m: np.ndarray, q: int, split: int) -> np.ndarray:
    """Blocked Cholesky of ``[G | X]`` in place: rows become ``[L^H | L^-1 X]``.

    ``m`` has shape (B, q, c), ``c >= q``: a Hermitian positive definite ``G`` (upper
    triangle read) in the first ``q`` columns and right-hand sides after them.  Carrying
    the right-hand sides through the factorisation does the forward substitution for all
    of them in the same matrix products.  Right-looking, blocks of ``_CHOL_BLOCK`` rows:
    the small diagonal block is factored elementwise, its rows of ``L^H`` (and of
    ``L^-1 X``) come from one product with the inverse of its factor, and the trailing
    rows are updated with one product; elementwise work on the wide rows (slow on short
    trailing axes) is avoided.  Only the upper triangle of the first ``q`` columns is
    meaningful afterwards (the strict lower part holds scratch values).  Columns from
    ``split`` on are extra right-hand sides that must not change the others' rounding
    (the sandwich's identity columns).  Non-positive pivots become NaN (that bin's results
    are NaN, the others untouched).  Returns the pivots (B, q), the squared diagonal of
    ``L``.
    """
    piv = np.empty(m.shape[:-1])
    width = m.shape[-1]
    for j0 in range(0, q, _CHOL_BLOCK):
        j1 = min(q, j0 + _CHOL_BLOCK)
        # the block's Hermitian matrix from its upper triangle (the lower one is scratch)
        low, linv, piv[:, j0:j1] = _small_cholesky(
            np.conj(m[:, j0:j1, j0:j1]).swapaxes(-1, -2), inverse=True)
        m[:, j0:j1, j0:j1] = np.conj(low).swapaxes(-1, -2)
        if j1 < width:
            # separate products for the extra columns: BLAS rounding may depend on the
            # operand width, and the fit must not change when they are appended
            m[:, j0:j1, j1:split] = linv @ m[:, j0:j1, j1:split]
            if split < width:
                m[:, j0:j1, split:] = linv @ m[:, j0:j1, split:]
        if j1 < q:  # trailing update with the block's rows of L^H: one product per block
            lh = np.conj(m[:, j0:j1, j1:q]).swapaxes(-1, -2)
            m[:, j1:q, j1:split] -= lh @ m[:, j0:j1, j1:split]
            if split < width:
                m[:, j1:q, split:] -= lh @ m[:, j0:j1, split:]
    return piv


def _upper_tail_solve(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Solve ``U x = v`` for upper-triangular ``U`` (B, k, k); ``v`` (B, ..., k)."""
    k = u.shape[-1]
    x = np.empty(np.broadcast_shapes(v.shape, u.shape[:1] + (1,) * (v.ndim - 2) + (k,)),
                 dtype=complex)
    ue = u.reshape(u.shape[:1] + (1,) * (v.ndim - 2) + u.shape[1:])
    for j in range(k - 1, -1, -1):
        s = v[..., j] - np.sum(ue[..., j, j + 1 :] * x[..., j + 1 :], axis=-1)
        x[..., j] = s / ue[..., j, j]
    return x


# Small factorisations (k <= ~5) run "bins last" internally: one numpy call per matrix
# entry on a long contiguous vector of bins.  Bins-first arrays with k x k trailing axes
# make every elementwise call iterate over tiny inner loops (measured ~3x slower).
def _to_bins_last(a: np.ndarray, nmat: int) -> np.ndarray:
    return np.ascontiguousarray(np.moveaxis(a, tuple(range(-nmat, 0)), tuple(range(nmat))))


def _to_bins_first(a: np.ndarray, nmat: int) -> np.ndarray:
    return np.moveaxis(a, tuple(range(nmat)), tuple(range(-nmat, 0)))


def _small_cholesky(a: np.ndarray, inverse: bool = False):
    """Lower Cholesky factor of Hermitian ``a`` (..., k, k) for small ``k`` (lower triangle
    and diagonal read), and with ``inverse=True`` also ``L^-1``.

    Column by column, every column in one numpy call per step (bins last): ``L^-1`` row
    ``j`` needs only ``L[j, :j+1]``, known once column ``j`` is, so it comes out of the
    same loop.  Non-positive pivots become NaN.  Returns ``(L, pivots)`` or
    ``(L, L^-1, pivots)``; pivots (..., k) real.
    """
    k = a.shape[-1]
    at = _to_bins_last(a, 2)
    low = np.zeros_like(at)
    inv = np.zeros_like(at) if inverse else None
    piv = np.empty((k,) + at.shape[2:])
    for j in range(k):
        col = at[j:, j]
        if j:  # col -= L[j:, :j] conj(L[j, :j])
            col = col - np.sum(low[j:, :j] * np.conj(low[j, :j]), axis=1)
        p = col[0].real
        p[~(p > 0)] = np.nan
        piv[j] = p
        d = np.sqrt(p)
        low[j, j] = d
        if j + 1 < k:
            low[j + 1 :, j] = col[1:] / d
        if inverse:  # inv[j, :j] = -L[j, :j] inv[:j, :j] / L[j, j]
            inv[j, j] = 1.0 / d
            if j:
                inv[j, :j] = np.sum(low[j, :j, None] * inv[:j, :j], axis=0) * (-1.0 / d)
    if inverse:
        return _to_bins_first(low, 2), _to_bins_first(inv, 2), _to_bins_first(piv, 1)
    return _to_bins_first(low, 2), _to_bins_first(piv, 1)


def _small_solve(low: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``(L L^H) x = b`` with ``L`` (..., k, k) lower and ``b`` (..., k)."""
    k = low.shape[-1]
    lt = _to_bins_last(low, 2)
    y = _to_bins_last(np.broadcast_to(b, np.broadcast_shapes(b.shape, low.shape[:-1])), 1)
    y = y.astype(complex)
    for j in range(k):  # L y = b
        for c in range(j):
            y[j] -= lt[j, c] * y[c]
        y[j] /= lt[j, j]
    for j in range(k - 1, -1, -1):  # L^H x = y (in place)
        for c in range(j + 1, k):
            y[j] -= np.conj(lt[c, j]) * y[c]
        y[j] /= lt[j, j]
    return _to_bins_first(y, 1)


def _lower_inverse(low: np.ndarray) -> np.ndarray:
    """``L^-1`` of a small lower-triangular ``L`` (..., k, k), row by row."""
    k = low.shape[-1]
    lt = _to_bins_last(low, 2)
    inv = np.zeros_like(lt)
    for j in range(k):
        inv[j, j] = 1.0 / lt[j, j]
        if j:  # inv[j, :j] = -L[j, :j] inv[:j, :j] / L[j, j]
            inv[j, :j] = np.sum(lt[j, :j, None] * inv[:j, :j], axis=0) * -inv[j, j]
    return _to_bins_first(inv, 2)


# ---------------------------------------------------------------------------- the model
def local_model(R, Z, *, half_width: int, degrees=(3, 3, 3), circular: bool = True,
                covariance: str | None = "full") -> LocalModelFit:
    """Fit the local rational (LRM) or polynomial (LPM, ``Rd = 0``) model at every bin.

    Parameters
    ----------
    R : array_like, complex, shape (..., M, nr)
        Excitation spectra on ``M`` DFT bins (any unit).
    Z : array_like, complex, shape (..., M, nz)
        Output spectra on the same bins (any unit).  Leading dims of ``R`` and ``Z``
        broadcast.
    half_width : int
        ``n``: the local window is ``2 n + 1`` bins, ``r = -n..n`` (in bins).
    degrees : tuple of int, default (3, 3, 3)
        ``(Rn, Rm, Rd)``: degrees of the numerator ``N``, transient ``Mt`` and the diagonal
        denominator ``D`` in the local variable.  ``Rd = 0`` is the LPM.
    circular : bool, default True
        ``True``: the bins cover the whole unit circle, the window at bin ``k`` uses bins
        ``(k + r) mod M``.  ``False``: the caller passed data already padded with ``n`` halo
        bins on each side (as ``dask.array.map_overlap`` does); the output has the same
        length and the ``n`` bins at each end, which lack a full window, are NaN and flagged.
    covariance : {"full", "diag", None}, default "full"
        What to return in ``G_cov``: the full cross-row covariance of the vectorised ``G``,
        only its variances, or nothing (saves time).

    Returns
    -------
    LocalModelFit
        ``G`` (..., M, nz, nr), ``T`` (..., M, nz), ``noise_variance`` (..., M, nz),
        ``noise_covariance`` (..., M, nz, nz), ``dof``, ``G_cov``, ``condition`` (..., M),
        ``ill_posed`` (..., M); see :class:`LocalModelFit`.

    Raises
    ------
    ValueError
        Wrong shapes, fewer than ``2 n + 1`` bins, no degrees of freedom left, an unknown
        ``covariance``, or non-finite input.  Ill-conditioned bins never raise: they are NaN
        and flagged.

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
    LPM).  Every entry of ``K_i^H D_i D_j^H K_j`` and of ``tau`` is a combination of the
    same windowed moments with powers raised by up to ``2 Rd``, so the cost stays
    independent of the window width.  With ``covariance=None`` and ``Rd > 0`` the exact
    ``tau`` is skipped for speed and ``tau_ij ~ dof * mean_r d_i(r) conj(d_j(r))`` is
    used (measured 2-30 % too large where ``d`` varies strongly in the window, so the
    noise estimate is then biased low by as much).  Beyond first order (noise comparable
    to the local signal) the LRM's errors-in-variables effects are not covered.

    The moments are computed by FFT in
    short blocks (cost independent of ``n``; see the module docstring for the accuracy
    argument); the 1e-6 agreement with a per-bin ``lstsq`` is tested.

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
    try:
        batch = np.broadcast_shapes(R.shape[:-2], Z.shape[:-2])
    except ValueError:
        raise ValueError(
            f"leading dims of R {R.shape[:-2]} and Z {Z.shape[:-2]} do not broadcast."
        ) from None
    if nr < 1 or nz < 1:
        raise ValueError(f"need at least one channel in R and Z, got nr={nr}, nz={nz}.")
    n = int(half_width)
    if n < 1 or n != half_width:
        raise ValueError(f"half_width must be a positive integer, got {half_width!r}.")
    w = 2 * n + 1
    if m < w:
        raise ValueError(
            f"{m} bins are too few for half_width={n}: a window needs 2n+1 = {w} bins. "
            f"Use half_width <= {(m - 1) // 2} or more bins."
        )
    p_row = parameters_per_row(nr, (rn, rm, rd))
    dof = w - p_row
    if dof < 1:
        raise ValueError(
            f"no degrees of freedom: {p_row} parameters per row (nr={nr}, degrees="
            f"{(rn, rm, rd)}) need a window of at least {p_row + 1} bins; use half_width >= "
            f"{(p_row + 1) // 2} or lower degrees."
        )
    if covariance not in ("full", "diag", None):
        raise ValueError(
            f"covariance must be 'full', 'diag' or None, got {covariance!r}."
        )
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(Z))):
        raise ValueError(
            "R and Z must be finite (found NaN or inf); drop or interpolate the bad bins "
            "before fitting."
        )

    # Bins-first layout (batch, bins, channel), with the n-bin halo on both ends.
    n_batch = int(np.prod(batch, dtype=int))
    rt = np.broadcast_to(R, batch + (m, nr)).reshape(n_batch, m, nr).astype(complex)
    zt = np.broadcast_to(Z, batch + (m, nz)).reshape(n_batch, m, nz).astype(complex)
    if circular:
        idx = np.arange(-n, m + n) % m
        rt, zt = rt[:, idx], zt[:, idx]
        k_lo, k_hi = 0, m
    else:
        k_lo, k_hi = n, m - n
    n_valid = k_hi - k_lo

    out = _allocate(batch, m, nz, nr, covariance)
    # chunks of whole overlap-save steps; batch elements are grouped up to the same size
    elements = _chunk_elements(nr, nz, (rn, rm, rd), n, covariance is not None and rd > 0)
    step = _fft_length(n) - 2 * n
    chunk = step * max(1, round(elements / (step * n_batch)))
    batch_group = max(1, elements // chunk)
    out_flat = {k: v.reshape((n_batch,) + v.shape[len(batch):]) for k, v in out.items()}
    with np.errstate(all="ignore"):
        for g0 in range(0, n_batch, batch_group):
            g = slice(g0, min(n_batch, g0 + batch_group))
            for c0 in range(0, n_valid, chunk):
                c1 = min(n_valid, c0 + chunk)
                # padded coordinates: output bin k_lo + c needs padded samples c .. c + 2n
                res = _fit_chunk(rt[g, c0 : c1 + 2 * n], zt[g, c0 : c1 + 2 * n], n,
                                 (rn, rm, rd), covariance)
                _store(out_flat, res, g, slice(k_lo + c0, k_lo + c1), covariance)
        ill = ~(out["condition"] <= CONDITION_LIMIT)
    return LocalModelFit(
        G=out["G"], T=out["T"], noise_variance=out["noise_variance"],
        noise_covariance=out["noise_covariance"], dof=int(dof), G_cov=out.get("G_cov"),
        condition=out["condition"], ill_posed=ill,
    )


def _chunk_elements(nr, nz, degrees, half_width, sandwich):
    """(batch x bin) elements per chunk for ``_CHUNK_BYTES`` of the main per-bin arrays."""
    rd = degrees[2]
    slots = _table_slots(nr, nz, degrees, 2 * rd if sandwich else 0)
    nfft = _fft_length(half_width)
    q = parameters_per_row(nr, degrees) - rd
    nx = nz * (rd + 1)
    # FFT scratch (nfft rows per step) and the table with its conjugated half
    per_bin = slots.n_slots * slots.p1 * (nfft / (nfft - 2 * half_width) + 2)
    per_bin += q * (q + nx + (q if sandwich else 0)) + q * nx  # [Gaa | A^H X], Y rows
    if sandwich:  # the basis Gram Psi
        per_bin += (nr * (degrees[0] + rd + 1) + degrees[1] + rd + 1 + nz * 2 * rd) ** 2
    return max(1, int(_CHUNK_BYTES // (16 * per_bin)))


def _allocate(batch, m, nz, nr, covariance):
    nan_c = complex(np.nan, np.nan)
    out = {
        "G": np.full(batch + (m, nz, nr), nan_c),
        "T": np.full(batch + (m, nz), nan_c),
        "noise_variance": np.full(batch + (m, nz), np.nan),
        "noise_covariance": np.full(batch + (m, nz, nz), nan_c),
        "condition": np.full(batch + (m,), np.inf),
    }
    if covariance == "full":
        out["G_cov"] = np.full(batch + (m, nz * nr, nz * nr), nan_c)
    elif covariance == "diag":
        out["G_cov"] = np.full(batch + (m, nz, nr), np.nan)
    return out



def _store(out, res, g, sl, covariance):
    # res arrays are bins-first (nbat K, mat...); ``out`` arrays are (n_batch, M, mat...)
    def put(name, value):
        dest = out[name][g, sl]
        dest[...] = value.reshape(dest.shape)

    for name in ("G", "T", "noise_variance", "noise_covariance"):
        put(name, res[name])
    cond = res["condition"]
    put("condition", np.where(np.isfinite(cond), cond, np.inf))
    if covariance is not None:
        put("G_cov", res["G_cov"])


def _fit_chunk(rt, zt, n, degrees, covariance):
    """Fit all bins of one chunk; ``rt`` (nbat, K + 2n, nr), ``zt`` (nbat, K + 2n, nz).

    Returns bins-first arrays (nbat K, ...).
    """
    rn, rm, rd = degrees
    nr, nz = rt.shape[-1], zt.shape[-1]
    # the sandwich covariance multiplies every Gram by d_i(r) conj(d_j(r)) (degree 2 Rd):
    # only then are moments with powers raised by up to 2 Rd needed
    sandwich = covariance is not None and rd > 0
    ext = 2 * rd if sandwich else 0
    tab, floor = _moment_table(rt, zt, n, degrees, ext)
    nbin = floor.shape[0]
    lay = _layout(nr, nz, degrees, ext)
    q = len(lay.a_base)
    nx = nz * (rd + 1)
    n_aug = q + nx + (q if sandwich else 0)

    # ---- augmented Gram [Gaa | A^H X] (+ identity: L^-1 for the sandwich).  No explicit
    # Jacobi scaling: Cholesky commutes with diagonal scaling (up to the rounding of the
    # scaling itself), and y = L^-1 A^H X does not depend on it; the scaled quantities
    # (pivots for the condition estimate, L~^-1 for the sandwich) are derived from ds.
    m = np.empty((nbin, q, n_aug), dtype=complex)
    m[:, :, : q + nx] = tab.gather(lay.aug_index)
    qi = np.arange(q)
    diag = m[:, qi, qi].real
    # an R column whose energy is within FFT rounding of zero is unexcited: NaN (flagged)
    r_cols = np.nonzero(lay.a_base < nr)[0]
    dead = ~(diag[:, r_cols] > floor[:, lay.a_base[r_cols]])
    diag[:, r_cols] = np.where(dead, np.nan, diag[:, r_cols])
    m[:, qi, qi] = diag  # a NaN pivot makes that bin NaN throughout
    with np.errstate(divide="ignore", invalid="ignore"):
        ds = 1.0 / np.sqrt(diag)  # (B, q) Jacobi scaling; inf -> nan
    ds = np.where(np.isfinite(ds), ds, np.nan)
    if sandwich:
        m[:, :, q + nx :] = np.eye(q)
    piv_a = _augmented_cholesky(m, q, q + nx) * ds**2  # pivots of the scaled Gram
    u = m[:, :, :q]  # L^H (upper triangle)
    yx = m[:, :, q : q + nx]  # L^-1 A^H rho^s z_i, column i (Rd+1) + s: (B, q, nx)
    xx = tab.gather(lay.zz_index)  # (B, nz, nz, Rd+1, Rd+1) X_i^H X_j
    rows = np.arange(nz)
    # each row's columns rho^s Z_i projected off the shared ones: the Gram
    # C_ii = X_i^H X_i - Y_i^H Y_i with Y_i = L^-1 A^H X_i (B, nz, q, Rd+1).  Only the own
    # rows' blocks are needed for the fit (the cross-row residual products come from
    # v_i = Y_i delta_i below), a fifth of the full projected Gram's products for nz = 5.
    y_rows = np.ascontiguousarray(yx.reshape(nbin, q, nz, rd + 1).transpose(0, 2, 1, 3))
    c = xx[:, rows, rows] - np.conj(y_rows).swapaxes(-1, -2) @ y_rows  # (B, nz, Rd+1, Rd+1)

    if rd > 0:
        # D columns B_i[:, s] = -rho^s Z_i, scaled by tscale = 1 / ||rho^s Z_i||
        s_idx = np.arange(1, rd + 1)
        with np.errstate(divide="ignore", invalid="ignore"):
            tsc = 1.0 / np.sqrt(xx[:, rows, rows][:, :, s_idx, s_idx].real)  # (B, nz, Rd)
        tsc = np.where(np.isfinite(tsc), tsc, np.nan)
        # Schur complement per row S_i = B~^H Q B~ and right side B~^H Q z_i
        schur = c[:, :, 1:, 1:] * (tsc[..., :, None] * tsc[..., None, :])
        rhs_d = -c[:, :, 1:, 0] * tsc
        s_low, piv_s = _small_cholesky(schur)  # (B, nz, Rd, Rd)
        d_s = _small_solve(s_low, rhs_d)  # scaled D coefficients (B, nz, Rd)
        # D coefficients of u_i = D z_i = z_i + sum_s d_is rho^s z_i
        delta = np.concatenate([np.ones((nbin, nz, 1)), d_s * tsc], axis=2)
    else:
        delta = np.ones((nbin, nz, 1), dtype=complex)
        piv_s = np.ones((nbin, 1))

    # ---- estimates: the tail of a = L^-H v, v_i = L^-1 A^H (D z_i) = Y_i delta_i, holds
    # T and G
    nt = nr + 1
    v = (y_rows @ delta[..., None])[..., 0]  # (B, nz, q)
    tail = _upper_tail_solve(u[:, q - nt :, q - nt :], v[:, :, q - nt :])  # (B, nz, nt)
    T = tail[:, :, 0]
    G = tail[:, :, 1:]  # (B, nz, nr)

    # ---- residual (cross) products: e_i^H e_j = (D z_i)^H P (D z_j)
    #      = delta_i^H X_i^H X_j delta_j - v_i^H v_j  (P: projector off the shared columns)
    xd = (xx @ delta[:, None, :, :, None])[..., 0]  # (B, i, j, s): (X_i^H X_j delta_j)_s
    ehe = np.sum(np.conj(delta)[:, :, None, :] * xd, axis=-1)
    ehe -= np.conj(v) @ v.swapaxes(-1, -2)
    dof = 2 * n + 1 - (q + rd)
    raw = np.conj(ehe)  # raw[i, j] = sum_r e_i(r) conj(e_j(r))

    # ---- condition estimate: pivots of the column-scaled Gram (unit diagonal) bound
    # lambda_min from above, so 1/min pivot is a lower bound of its condition number
    min_piv = np.minimum(np.min(piv_a, axis=1), np.min(piv_s.reshape(nbin, -1), axis=1))
    with np.errstate(divide="ignore", invalid="ignore"):
        condition = np.sqrt(1.0 / min_piv)
    if rd > 0:
        if covariance is None:
            # no covariance requested: the cheap approximation of the residual's
            # expected energy, tau_ij ~ dof * mean_r d_i(r) conj(d_j(r)) (local_model Notes)
            noise_cov = raw / (dof * _mean_weight(delta, n))
            noise_var = np.maximum(np.real(noise_cov[:, rows, rows]), 0.0)
            return {"G": G, "T": T, "condition": condition, "noise_variance": noise_var,
                    "noise_covariance": noise_cov}
        # W_i = L^-1 A~^H B~_i: (B, nz, q, Rd)
        w = -yx.reshape(nbin, q, nz, rd + 1).transpose(0, 2, 1, 3)[..., 1:] * tsc[:, :, None, :]
        # B~_i^H Q B~_j = tscale tscale C_ij (cross rows), (B, nz, nz, Rd, Rd) with
        # C_ij = X_i^H X_j - Y_i^H Y_j over the columns s >= 1
        y1 = y_rows[..., 1:].transpose(0, 2, 1, 3).reshape(nbin, q, nz * rd)  # cols (j, t)
        c_cross = np.conj(y1).swapaxes(-1, -2) @ y1  # rows (i, s), cols (j, t)
        c_cross = c_cross.reshape(nbin, nz, rd, nz, rd).transpose(0, 1, 3, 2, 4)
        bqb = ((xx[:, :, :, 1:, 1:] - c_cross)
               * (tsc[:, :, None, :, None] * tsc[:, None, :, None, :]))
        linv = m[:, :, q + nx :] * np.sqrt(diag)[:, None, :]  # L~^-1 = L^-1 D^-1
        res = _sandwich(tab, ext, lay, linv, ds, w, tsc, _lower_inverse(s_low), bqb,
                        delta, raw, (nr, nz, rn, rm, rd), covariance)
        res.update(G=G, T=T, condition=condition)
        return res

    # ---- LPM (d = 1): the equation error is the noise itself, tau_ij = dof exactly
    noise_cov = raw / dof
    noise_var = np.maximum(np.real(noise_cov[:, rows, rows]), 0.0)
    res = {"G": G, "T": T, "noise_variance": noise_var, "noise_covariance": noise_cov,
           "condition": condition}
    if covariance is None:
        return res
    # Cov(G_i, G_j) = s_ij Lam Lam^H with Lam = L22^-H = U22^-1 (Lam Lam^H is the G block
    # of Gaa^-1), U22 the trailing block of L^H
    lam = _upper_tail_solve(u[:, q - nr :, q - nr :],
                            np.broadcast_to(np.eye(nr, dtype=complex), (nbin, nr, nr)))
    lam = lam.swapaxes(-1, -2)  # columns of U22^-1 were solved as rows
    base = lam @ np.conj(lam).swapaxes(-1, -2)  # (B, nr, nr)
    if covariance == "diag":
        var = np.real(base[:, np.arange(nr), np.arange(nr)])
        res["G_cov"] = var[:, None, :] * noise_var[:, :, None]
        return res
    res["G_cov"] = base[:, None, :, None, :] * noise_cov[:, :, None, :, None]
    return res


# ------------------------------------------------------------ LRM sandwich covariance
def _toeplitz_shift(delta: np.ndarray, width: int) -> np.ndarray:
    """``toe[..., e, e + t] = delta[..., t]``: (..., width, width + Rd) for ``delta``
    (..., Rd + 1); ``coef @ toe`` multiplies a polynomial by ``sum_t delta_t rho^t``."""
    rd = delta.shape[-1] - 1
    toe = np.zeros(delta.shape[:-1] + (width, width + rd), dtype=complex)
    e = np.arange(width)
    for t in range(rd + 1):
        toe[..., e, e + t] = delta[..., t, None]
    return toe


class _SandwichLayout(NamedTuple):
    """Basis bookkeeping of the sandwich (see ``_sandwich_layout``)."""

    n_shared: int  # basis functions shared by the rows (R and constant ones)
    grid_col: np.ndarray  # shared column j -> flat (base, power) grid position
    grid_basis: np.ndarray  # shared basis function -> flat (base, power + t) grid position
    psi_index: np.ndarray  # (basis, basis) moment-table index of Psi
    a_at_all: np.ndarray  # basis index of every shared column times rho^t, t = 0..Rd
    gu_index: np.ndarray  # (2 Rd + 1, q, q) table index of the moment matrices Gaa^(u)
    one_index: np.ndarray  # (2 Rd + 1,) table index of sum_r rho^u (the constant pair)


@functools.lru_cache(maxsize=32)
def _sandwich_layout(nr, nz, degrees, ext):
    """The sandwich's basis: shared functions, then 2 Rd functions rho^e Z_i (e >= 1) per
    row, and the moment-table indices of its Gram ``Psi`` (cached per structure)."""
    rn, rm, rd = degrees
    one, zb = nr, nr + 1
    slots = _table_slots(nr, nz, degrees, ext)
    basis = [(p, e) for p in range(nr) for e in range(rn + rd + 1)]
    basis += [(one, e) for e in range(rm + rd + 1)]
    n_sh = len(basis)
    for i in range(nz):
        basis += [(zb + i, e) for e in range(1, 2 * rd + 1)]
    where = {be: k for k, be in enumerate(basis)}
    b_base = np.array([b for b, _ in basis])
    b_pow = np.array([e for _, e in basis])
    psi = _table_index(slots, b_base[:, None], b_base[None, :],
                                 b_pow[:, None] + b_pow[None, :])
    lay = _layout(nr, nz, degrees, ext)
    a_base, a_pow = lay.a_base, lay.a_pow
    a_at = [np.array([where[(b, e + t)] for b, e in zip(a_base, a_pow)]) for t in range(rd + 1)]
    u = np.arange(2 * rd + 1)
    gu = _table_index(slots, a_base[None, :, None], a_base[None, None, :],
                               a_pow[None, :, None] + a_pow[None, None, :] + u[:, None, None])
    one_index = _table_index(slots, one, one, u)
    # the (base, power) grids of the shared part: bases R_0.., 1 (index nr); powers up to
    # max(Rn, Rm) for the columns, plus Rd after multiplying by d(r)
    n_pow = max(rn, rm) + 1
    grid_col = np.minimum(a_base, one) * n_pow + a_pow
    grid_basis = np.array([b * (n_pow + rd) + e for b, e in basis[:n_sh]])
    a_at_all = np.concatenate(a_at)
    for arr in (grid_col, grid_basis, a_at_all):
        arr.flags.writeable = False
    return _SandwichLayout(n_sh, grid_col, grid_basis, psi, a_at_all, gu,
                           one_index)


def _mean_weight(delta: np.ndarray, half_width: int) -> np.ndarray:
    """``mean_r d_i(r) conj(d_j(r))`` over the window; ``delta`` (B, nz, Rd+1)."""
    rd = delta.shape[-1] - 1
    mean_pow = _analytic_moments(half_width, 2 * rd) / (2 * half_width + 1)
    hankel = mean_pow[np.arange(rd + 1)[:, None] + np.arange(rd + 1)[None, :]]
    return (delta @ hankel) @ np.conj(delta).swapaxes(-1, -2)


def _sandwich(tab, ext, lay, linv, ds, w, ts, lsinv, bqb_bf, dl, raw, dims, covariance):
    """First-order (sandwich) covariance of ``G`` and the noise estimate of the LRM.

    Every quantity is a weighted Gram ``sum_r x(r) w(r) conj(y(r))`` of window vectors
    that are combinations of the *basis* ``conj(rho^e R_p)``, ``rho^e``, ``conj(rho^e Z_i)``
    (degrees raised by up to ``Rd`` when multiplied by ``d(r)``).  With coefficient rows
    ``x``, ``y`` on that basis the Gram is ``x Psi y^H``, ``Psi[a, b] = sum_r conj(psi_a)
    psi_b`` a table of windowed moments, so the cost does not depend on the window.
    Arrays are bins-first here (``np.matmul`` on stacks of small matrices).

    Returns ``noise_covariance`` ``s_ij = raw_ij / tau_ij``, ``noise_variance``, ``G_cov``.
    """
    nr, nz, rn, rm, rd = dims
    nb, q = linv.shape[:2]
    # the sandwich reads powers raised by up to 2 Rd (_top_powers with ext = 2 Rd)
    assert ext == 2 * rd, "the moment table lacks the powers the sandwich reads"
    sl = _sandwich_layout(nr, nz, (rn, rm, rd), ext)
    n_sh, n_zb = sl.n_shared, 2 * rd
    psi = tab.gather(sl.psi_index)  # (B, basis, basis)

    # ---- factors, bins-first: linv = L^-1 of the scaled shared Gram, lsinv = L_i^-1 of
    # each row's Schur complement S~_i = L_i L_i^H (products with S^-1 go through L_i^-1,
    # the whitened B columns: an explicit S^-1 X S^-1 loses eps cond(S)^2, this eps cond(S))
    ginv = np.conj(np.swapaxes(linv, -1, -2)) @ linv  # scaled Gaa^-1
    sg = ds[:, q - nr:]
    tt = np.conj(np.swapaxes(linv, -1, -2))[:, None] @ w  # T~_i = Gaa~^-1 A~^H B~_i
    sinv = np.conj(np.swapaxes(lsinv, -1, -2)) @ lsinv

    # ---- G rows of the inverse Gram of [A~, B~_i] (block inverse via the Schur complement)
    g_rows = np.arange(q - nr, q)
    ets = tt[:, :, g_rows, :] @ sinv  # (B, nz, nr, rd)
    xa = ginv[:, None, g_rows, :] + ets @ np.conj(np.swapaxes(tt, -1, -2))
    # gain g_i(r) on the basis, times d_i(r): h_i = d_i g_i  (rows (B, nz, nr, basis))
    ga = sg[:, None, :, None] * xa * ds[:, None, None, :]
    gz = sg[:, None, :, None] * ets * ts[:, :, None, :]  # -X_B * (-tscale)
    n_all = psi.shape[-1]
    # conj of Q B~_i on the basis: -D T~_i on A, -tscale on rho^s Z_i  (rows (.., rd, basis))
    qa = -ds[:, None, None, :] * np.conj(np.swapaxes(tt, -1, -2))  # (B, nz, rd, q)
    # the "left" rows on the basis, per output row i: hy_i (nr rows, h_i = d_i g_i) and
    # conj(f_ii) = d_i conj(Q B~_i) (rd rows); both A parts move together
    n_left = nr + rd
    left4 = np.empty((nb, nz, n_left, n_all), dtype=complex)
    # multiplying by d_i(r) = sum_t delta_t rho^t shifts a base's coefficients by t
    # powers: a product with the banded Toeplitz matrix toe[e, e + t] = delta_t, applied
    # to every shared base at once on a (base, power) grid (a stacked matmul per row i)
    n_pow = max(rn, rm) + 1
    grid_in = np.zeros((nb, nz, n_left, nr + 1, n_pow), dtype=complex)
    grid_in.reshape(nb, nz, n_left, -1)[..., sl.grid_col] = np.concatenate([ga, qa], axis=2)
    grid = (grid_in.reshape(nb, nz, n_left * (nr + 1), n_pow) @ _toeplitz_shift(dl, n_pow))
    left4[..., :n_sh] = np.take(grid.reshape(nb, nz, n_left, -1), sl.grid_basis, axis=-1)
    # each row's own Z block: [g_Z ; -tscale] (powers 1..Rd) shifted the same way
    zin = np.concatenate([gz, -ts[:, :, None, :] * np.eye(rd)], axis=2)  # (B, nz, n_left, rd)
    zpart = zin @ _toeplitz_shift(dl, rd)  # (B, nz, n_left, 2 Rd): powers 1..2 Rd
    left_z = left4[..., n_sh:].reshape(nb, nz, n_left, nz, n_zb)
    left_z[...] = 0.0
    rows_i = np.arange(nz)
    left_z[:, rows_i, :, rows_i, :] = np.moveaxis(zpart, 1, 0)
    hy, f_diag = left4[:, :, :nr], left4[:, :, nr:]

    # left rows times Psi, as one (rows x basis) @ (basis x basis) product per bin: the
    # shared block once for all rows, then each row's own Z block
    left = left4.reshape(nb, nz * n_left, n_all)
    pl = (left[:, :, :n_sh] @ psi[:, :n_sh, :]).reshape(nb, nz, n_left, n_all)
    pl += zpart @ psi[:, n_sh:, :].reshape(nb, nz, n_zb, n_all)
    py, pf = pl[:, :, :nr], pl[:, :, nr:]

    # ---- expected residual energies tau_ij = tr(D_j^H P_j P_i D_i) (first order)
    u_max = 2 * rd
    cw = np.zeros((nb, nz, nz, u_max + 1), dtype=complex)  # c_ij,u
    for s in range(rd + 1):
        for t in range(rd + 1):
            cw[..., s + t] += dl[:, :, None, s] * np.conj(dl[:, None, :, t])
    # tr(H_A P^u) = tr(Gaa^-1 Gaa^(u)) for every u (shared by the rows), unscaled Gaa^(u)
    gu = tab.gather(sl.gu_index)  # (B, U, q, q)
    # the scaling D~ of the Gram goes onto ginv once (not onto all U moment matrices)
    g_un = (ginv * (ds[:, :, None] * ds[:, None, :])).swapaxes(-1, -2)
    t_u = (gu.reshape(nb, u_max + 1, q * q) @ g_un.reshape(nb, q * q, 1))[..., 0]
    tr_w = cw @ tab.data[0, 0, sl.one_index]  # the constant-column moments
    tr_ha = np.einsum("biju,bu->bij", cw, t_u)
    # f_ii^H f_ij = sum_t conj(delta_jt) f_ii^H (rho^t Q B~_i): Q B~_i's basis shifted by t
    # all shifts t at once: the A part with one gather and one product per row i ...
    qa_h = np.conj(np.swapaxes(qa, -1, -2))  # (B, nz, q, rd)
    pf_a = np.take(pf, sl.a_at_all, axis=-1).reshape(nb, nz, rd, rd + 1, q)
    pf_a = pf_a.transpose(0, 1, 3, 2, 4).reshape(nb, nz, (rd + 1) * rd, q)
    shifted = (pf_a @ qa_h).reshape(nb, nz, rd + 1, rd, rd)
    # ... and the own Z block (powers 1..2 Rd) as windows of length Rd at offsets t
    pf_z = np.moveaxis(pf[..., n_sh:].reshape(nb, nz, rd, nz, n_zb)[:, rows_i, :, rows_i], 0, 1)
    pf_zw = np.lib.stride_tricks.sliding_window_view(pf_z, rd, axis=-1)  # (B, nz, s, t, u)
    shifted -= pf_zw.transpose(0, 1, 3, 2, 4) * ts[:, :, None, None, :]
    gam = np.einsum("bitsu,bjt->bijsu", shifted, np.conj(dl))
    phi_f = (pf.reshape(nb, nz * rd, n_all)
             @ np.conj(f_diag.reshape(nb, nz * rd, n_all)).swapaxes(-1, -2))
    phi_f = phi_f.reshape(nb, nz, rd, nz, rd).transpose(0, 1, 3, 2, 4)  # f_ii^H f_jj
    term3 = np.einsum("bist,bijts->bij", sinv, gam)  # tr(S_i^-1 f_ii^H f_ij)
    term4 = np.conj(np.swapaxes(term3, 1, 2))  # tr(S_j^-1 f_ji^H f_jj)
    # tr(S_j^-1 (B_j^H Q B_i) S_i^-1 f_ii^H f_jj)
    # tr(H_QBj H_QBi W_ij) with orthonormal U_i = Q B~_i L_i^-H:
    # tr[(L_j^-1 B_j^H Q B_i L_i^-H) (L_i^-1 f_ii^H f_jj L_j^-H)]
    lsinv_h = np.conj(np.swapaxes(lsinv, -1, -2))
    uu_ji = lsinv[:, :, None] @ bqb_bf @ lsinv_h[:, None, :]  # [b, j, i]
    vv_ij = lsinv[:, :, None] @ phi_f @ lsinv_h[:, None, :]  # [b, i, j]
    term5 = np.einsum("bjist,bijts->bij", uu_ji, vv_ij)
    tau = tr_w - tr_ha - term3 - term4 + term5
    s_ij = raw / tau  # (B, nz, nz)

    out = {"noise_covariance": s_ij}
    out["noise_variance"] = np.maximum(np.real(s_ij[:, np.arange(nz), np.arange(nz)]), 0.0)
    if covariance == "diag":
        own = np.sum(py * np.conj(hy), axis=-1)  # (B, nz, nr); hy_i is 0 off its basis
        var = np.real(own) * np.real(s_ij[:, np.arange(nz), np.arange(nz)])[:, :, None]
        out["G_cov"] = var
        return out
    sig = (py.reshape(nb, nz * nr, n_all)
           @ np.conj(hy.reshape(nb, nz * nr, n_all)).swapaxes(-1, -2))
    sig = sig.reshape(nb, nz, nr, nz, nr)
    cov = sig * s_ij[:, :, None, :, None]
    out["G_cov"] = cov
    return out
