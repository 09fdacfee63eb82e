"""Compiled per-bin algebra of the local model (numba): factorisations, solves, covariance.

:func:`lcmr_xr.kernels.local_models.local_model` computes the windowed moments of a chunk
of bins (FFT, window-independent) and hands them here; :func:`fit_bins` then runs one
plain loop over the chunk's bins.  Everything per bin is written as explicit loops on
small matrices: no BLAS call (threaded BLAS on thousands of 20 x 20 matrices spins and
fights for the cores), no temporaries per bin (scratch is allocated once per call).
Compiled once with ``cache=True`` (the first call of a new install compiles, later
processes load the cache) and ``nogil=True``, so chunks run in parallel threads.  Sums
may be reassociated and multiply-adds fused (``fastmath`` ``reassoc``, ``contract``;
not ``nnan``/``ninf``, NaN checks keep working) so that the loops vectorise: results are
reproducible bit for bit for one build on one CPU, and agree across builds and CPUs to
rounding (what the oracle tests check).

Per bin and output row ``i`` the model's regressors are the shared block ``A`` (columns
``rho^b R_p`` and ``rho^c``, ordered so that ``T`` and then ``G`` come last) and the row's
own block ``B_i`` (``-rho^s Z_i``, ``s = 1..Rd``).  All columns are scaled to unit norm
(Jacobi), so pivots are squared sines of angles between columns and the condition
estimate is scale-free:

1. Cholesky of ``A^H A`` with all rows' right-hand sides ``A^H rho^s Z_i`` carried
   along (``Y = L^-1 A^H X``: the forward substitution for free), two pivots at a time.
   It runs on the unscaled Gram: the factor of the scaled one is ``D L``
   (``D = diag(1/||a_c||)``), so its pivots and rows follow by scaling, and ``Y`` is the
   same for both.
2. Per row, the ``Rd x Rd`` Schur complement ``S_i = B~_i^H (I - P_A) B~_i`` is factored
   with diagonal pivoting.  A column whose pivot (its squared distance from the span of
   all other columns) is below ``drop_tol`` is dropped in that bin: the data do not
   determine its coefficient (noiseless, exactly modelled data: numerator and
   denominator share a factor), the fit continues with a reduced denominator degree.
   ``G`` is unaffected when the dropped direction has no ``G`` component, which is
   checked (``g_sensitivity``); only bins where it has one are flagged.
3. ``G`` and ``T`` from the trailing block of ``L^H``; residual cross products from
   ``v_i = Y_i delta_i``.
4. Covariance (optional): explicit over the window (cost ``O(W)`` per bin, the fit
   itself stays window independent).  With orthonormal bases ``Q_A = A~ L^-H`` and
   ``U_i`` of ``(I - P_A) B~_i``, the G-rows of ``K_i^+`` are ``w^H [Q_A, U_i]^H`` where
   ``w`` has only ``nr + Rd`` non-zero entries (G is last in ``A``), so the gains
   ``h_i = g_i D_i`` cost ``(nr + Rd) W`` per row and ``Cov(G_i, G_j) = s_ij h_i h_j^H``
   is one Hermitian product.  ``tau_ij = tr(D_j^H P_j P_i D_i)`` with
   ``P_i = I - Q_A Q_A^H - U_i U_i^H``::

       tau_ij = sum_r c_ij(r) (1 - lev(r) - nu_i(r) - nu_j(r))
                + tr((U_j^H U_i)(U_i^H diag(c_ij) U_j)),   c_ij = d_i conj(d_j)

   (``lev``, ``nu_i`` the squared row norms of ``Q_A``, ``U_i``).  Least squares and
   instrumental variables share the code over the window (:func:`_row_gains` for the
   columns and gains, :func:`_iv_tau` for ``tau``: least squares is its form with ``Y =
   U``, whose weights are real), one copy to compile.

Instrumental variables (``iv`` not None; ``local_model(..., instruments=)``): the
denominator columns ``B_i`` get the instruments ``W_i = -rho^s Zhat_i`` (``A`` is its
own instrument), the normal equations become ``[A, W_i]^H [A, B_i] theta = [A, W_i]^H
Z_i``.  ``Zhat`` is ``nz`` more bases of the moment table (``zt`` holds ``[Z, Zhat]``):
``A^H W`` rides through the shared Cholesky as more right-hand sides (``Y_W =
L^-1 A~^H W``), and per row the IV Schur complement ``S_i = W~_i^H B~_i = W^H X - Y_W^H
Y_X`` (non-Hermitian) is solved by LU with partial pivoting on the columns that the
least-squares factorisation of step 2 keeps (so rank decisions, dropped terms and the
``G`` sensitivity check are those of least squares, and exactly modelled noiseless data
still give ``G``).  An instrument within ``drop_tol`` of the span of the shared columns
fails the bin; a geometric-mean canonical correlation between projected instruments and
regressors below ``weak_limit`` flags it.  ``G``, ``T`` and the residual cross products
follow from ``delta_i`` as in steps 3 (``v_i = Y_i delta_i``: ``A`` given ``D`` is least
squares either way).  Covariance: ``delta theta_A = Gaa^-1 A^H (I - B S^-1 W~^H) e``,
so the gains are ``h_i = ds_g wa^H (Q_A^H - Y_B Y_i^H) D_i`` with ``Y_i = W~_i S_i^-H``,
and the residual projector ``Pi_i = P - X_i Y_i^H`` (``P = I - Q_A Q_A^H``, ``X_i = P
B~_i``, ``Y_i^H X_i = I``) is oblique::

    tau_ij = sum_r c_ij(r) (1 - lev(r) - x_i(r) - conj(x_j(r)))
             + tr((X_j^H X_i)(Y_i^H diag(c_ij) Y_j)),   x_i(r) = sum_t conj(Y_i(r,t)) X_i(r,t)

(least squares: ``Y = X S^-1``, ``x_i = nu_i``).  Pooled: the instruments' moments are
projected off each experiment's transient columns like the others.
"""

from __future__ import annotations

import math

import numba
import numpy as np

#: ``fit_bins`` modes: which covariance of ``G`` to compute.
COV_NONE, COV_DIAG, COV_FULL = 0, 1, 2

_JIT = {"cache": True, "nogil": True, "error_model": "numpy", "boundscheck": False,
        "fastmath": {"reassoc", "contract"}, "no_cfunc_wrapper": True}
#: (No C-callback wrapper for anything: Python calls through the CPython wrapper.)
#: Helpers only called from compiled code: built without the CPython and C-callback
#: wrappers that numba otherwise compiles for every function (measured: about a tenth of
#: the first call's compile time).  Such a function must NOT be called from Python (numba
#: then jumps into a missing wrapper and the interpreter crashes): whatever Python calls,
#: tests included, is decorated with ``_JIT``.
_INNER = dict(_JIT, no_cpython_wrapper=True, no_cfunc_wrapper=True)


@numba.njit(**_INNER)
def cholesky_planes(mr, mi, q, piv, rb):
    """In place: ``mr + 1j mi`` (q, c), real and imaginary parts in separate arrays, holds
    a Hermitian positive definite ``G`` (upper triangle of the first ``q`` columns read)
    and right-hand sides ``X`` after it; its rows become ``[L^H | L^-1 X]``.  ``piv`` (q)
    receives the pivots (squared diagonal of ``L``); the first non-positive pivot stops
    the factorisation (that and later pivots are NaN).  ``rb`` (4, c) is scratch.
    Returns the number of positive pivots.

    Two pivots at a time: rows ``j`` and ``j + 1`` of ``L^H`` are formed, then every
    later row takes both updates in one pass (a rank-2 update), which halves the passes
    over the rows and their loads and stores (measured 5.2 -> 4.8 us for the HDD's
    20 x 40).  Separate real and imaginary parts, the pivot rows copied out (so the
    compiler need not assume that the rows alias) and row views indexed from 0 (so that
    it need not guard against negative indices): the inner loops vectorise.
    """
    c = mr.shape[1]
    for j in range(q):
        piv[j] = np.nan
    r0r = rb[0]
    r0i = rb[1]
    r1r = rb[2]
    r1i = rb[3]
    j = 0
    while j < q:
        for u in range(2):  # the pair's pivot rows j and j + 1, into rb[2 u], rb[2 u + 1]
            jj = j + u
            if u == 1:
                if jj == q:
                    return q
                fr = r0r[jj]  # row j + 1 -= conj(l_j,j+1) row j, l = fr + 1j fi
                fi = r0i[jj]
                ar = mr[jj, jj:]
                ai = mi[jj, jj:]
                br = r0r[jj:]
                bi = r0i[jj:]
                for t in range(c - jj):
                    ar[t] -= fr * br[t] + fi * bi[t]
                    ai[t] -= fr * bi[t] - fi * br[t]
            p = mr[jj, jj]
            if not p > 0.0:
                return jj
            piv[jj] = p
            # row jj of L^H in place, and a copy of it (from column jj + 1 on) in rb
            # (written here, not in a helper: a call per pivot cost more than the row)
            d = math.sqrt(p)
            mr[jj, jj] = d
            mi[jj, jj] = 0.0
            inv = 1.0 / d
            ar = mr[jj]
            ai = mi[jj]
            br = rb[2 * u]
            bi = rb[2 * u + 1]
            for col in range(jj + 1, c):
                x = ar[col] * inv
                y = ai[col] * inv
                ar[col] = x
                ai[col] = y
                br[col] = x
                bi[col] = y
        for i in range(j + 2, q):  # the later rows: both pivots at once
            f0r = r0r[i]
            f0i = r0i[i]
            f1r = r1r[i]
            f1i = r1i[i]
            ar = mr[i, i:]
            ai = mi[i, i:]
            b0r = r0r[i:]
            b0i = r0i[i:]
            b1r = r1r[i:]
            b1i = r1i[i:]
            for t in range(c - i):  # (the pivot rows' values loaded once: measured 6 %)
                x0r = b0r[t]
                x0i = b0i[t]
                x1r = b1r[t]
                x1i = b1i[t]
                ar[t] = ar[t] - ((f0r * x0r + f0i * x0i) + (f1r * x1r + f1i * x1i))
                ai[t] = ai[t] - ((f0r * x0i - f0i * x0r) + (f1r * x1i - f1i * x1r))
        j += 2
    return q


@numba.njit(**_JIT)
def cholesky_augmented(m, q):
    """:func:`cholesky_planes` on a complex ``m`` (q, c), in place; returns the pivots."""
    c = m.shape[1]
    mr = np.empty((q, c))
    mi = np.empty((q, c))
    for a in range(q):
        for col in range(c):
            mr[a, col] = m[a, col].real
            mi[a, col] = m[a, col].imag
    piv = np.empty(q)
    cholesky_planes(mr, mi, q, piv, np.empty((4, c)))
    for a in range(q):
        for col in range(c):
            m[a, col] = complex(mr[a, col], mi[a, col])
    return piv


@numba.njit(**_JIT)
def pivoted_cholesky(s, drop_tol, low, perm, piv):
    """Cholesky with diagonal pivoting of the small Hermitian ``s`` (k, k), stopped when
    the largest remaining pivot is below ``drop_tol``.

    ``s`` is overwritten.  ``low`` receives ``L`` of the kept columns in pivot order
    (``s[perm][:, perm] = L L^H`` on the kept block), ``perm`` the pivot order, ``piv``
    the pivots in that order (the first dropped one included; later ones NaN).  Returns
    the number of kept columns.
    """
    k = s.shape[0]
    for j in range(k):
        perm[j] = j
        piv[j] = np.nan
    for j in range(k):
        best = j
        for t in range(j + 1, k):
            if s[perm[t], perm[t]].real > s[perm[best], perm[best]].real:
                best = t
        perm[j], perm[best] = perm[best], perm[j]
        for c in range(j):  # the rows of L computed so far follow the permutation
            low[j, c], low[best, c] = low[best, c], low[j, c]
        pj = perm[j]
        p = s[pj, pj].real
        piv[j] = p
        if not p >= drop_tol:
            return j
        d = math.sqrt(p)
        low[j, j] = d
        inv = 1.0 / d  # (complex / real compiles to a complex division: 3x slower)
        for t in range(j + 1, k):
            low[t, j] = s[perm[t], pj] * inv
        for t in range(j + 1, k):
            pt = perm[t]
            for u in range(j + 1, k):
                pu = perm[u]
                s[pt, pu] -= low[t, j] * low[u, j].conjugate()
    return k


@numba.njit(**_JIT)  # (called by the tests)
def _natural_min_pivot(s, scratch):
    """Smallest pivot of the unpivoted Cholesky of the small Hermitian ``s`` (0 when one
    is not positive); ``s`` is kept, ``scratch`` (k, k) overwritten."""
    k = s.shape[0]
    for a in range(k):
        for c in range(k):
            scratch[a, c] = s[a, c]
    best = np.inf
    for j in range(k):
        p = scratch[j, j].real
        if not p > 0.0:
            return 0.0
        best = min(best, p)
        inv = 1.0 / p
        for a in range(j + 1, k):  # lower triangle: s[a, c] -= s[a, j] conj(s[c, j]) / p
            f = scratch[a, j] * inv
            for c in range(j + 1, a + 1):
                scratch[a, c] -= f * scratch[c, j].conjugate()
    return best


@numba.njit(**_JIT)  # (called by the tests)
def _chol_solve(low, rank, b, x):
    """``x = (L L^H)^-1 b`` on the leading ``rank`` entries (``b``, ``x`` may alias)."""
    for j in range(rank):
        acc = b[j]
        for c in range(j):
            acc -= low[j, c] * x[c]
        x[j] = acc * (1.0 / low[j, j].real)
    for j in range(rank - 1, -1, -1):
        acc = x[j]
        for c in range(j + 1, rank):
            acc -= low[c, j].conjugate() * x[c]
        x[j] = acc * (1.0 / low[j, j].real)


@numba.njit(**_INNER)
def _lu_solve(a, k, ipiv, x):
    """``x = A^-1 x`` in place from the LU factors of ``A`` that :func:`_iv_row` makes
    (leading ``k`` entries; ``ipiv[j]`` the row swapped with row ``j``)."""
    for j in range(k):
        t = ipiv[j]
        if t != j:
            x[j], x[t] = x[t], x[j]
    for j in range(k):
        acc = x[j]
        for c in range(j):
            acc -= a[j, c] * x[c]
        x[j] = acc
    for j in range(k - 1, -1, -1):
        acc = x[j]
        for c in range(j + 1, k):
            acc -= a[j, c] * x[c]
        x[j] = acc / a[j, j]


@numba.njit(**_INNER)
def _iv_row(m, q, nx, i, rk, perm, low, tsc, wx, ww, twc, siv, ipiv, gw, scratch, dsol,
            delta, drop_tol):
    """Instrumental-variable denominator of row ``i`` on its kept columns (``perm[:rk]``).

    ``m`` holds ``[L^H | Y_X | Y_W]`` after the shared Cholesky (``Y_W = L^-1 A~^H W``,
    the instruments' columns ``rho^s Zhat_i`` at ``q + nx + i (Rd+1) + s``), ``wx``, ``ww``
    (nz, Rd+1, Rd+1) the moments ``W_s^H X_t``, ``W_s^H W_t``.  The IV Schur complement
    ``S = W~^H X~`` (``~``: projected off ``A``; rows scaled by ``twc = 1/||W_s||``,
    columns by ``tsc``) is factored by LU with partial pivoting into ``siv``, ``ipiv``
    (kept for the covariance), and ``delta[s + 1]`` of the kept columns overwritten by
    the IV solution.  Returns ``log`` of the geometric mean of the squared canonical
    correlations between the projected instruments and regressors,
    ``|det S|^2 / (det W~^H W~ det X~^H X~)`` to the power ``1 / rk`` (scale-free, 0 for
    ``W = X``; ``-inf`` when ``S`` is singular or an instrument is within ``drop_tol``
    (squared sine, unit-norm columns) of the span of the shared columns and the other
    instruments: numerically in it, as least squares drops such a column).
    """
    rd1 = wx.shape[1]
    c0 = i * rd1
    cw = q + nx + c0  # the W columns of m (s = 0..Rd)
    cx = q + c0
    for s in range(1, rd1):
        e = ww[i, s, s].real
        twc[s - 1] = 1.0 / math.sqrt(e) if e > 0.0 else 0.0
    if rk == 0:
        return 0.0
    for j1 in range(rk):
        s1 = perm[j1] + 1
        for j2 in range(rk):  # (W~^H X~)[s1, s2] = W^H X - Y_W^H Y_X
            s2 = perm[j2] + 1
            acc = wx[i, s1, s2]
            for a in range(q):
                acc -= m[a, cw + s1].conjugate() * m[a, cx + s2]
            siv[j1, j2] = acc * (twc[s1 - 1] * tsc[s2 - 1])
        for j2 in range(j1, rk):  # W~^H W~, Hermitian
            s2 = perm[j2] + 1
            acc = ww[i, s1, s2]
            for a in range(q):
                acc -= m[a, cw + s1].conjugate() * m[a, cw + s2]
            gw[j1, j2] = acc * (twc[s1 - 1] * twc[s2 - 1])
            gw[j2, j1] = gw[j1, j2].conjugate()
        acc = wx[i, s1, 0]  # right-hand side -W~^H X~_0 (the B columns are -rho^s Z_i)
        for a in range(q):
            acc -= m[a, cw + s1].conjugate() * m[a, cx]
        dsol[j1] = -acc * twc[s1 - 1]
    # log det W~^H W~ by an unpivoted Cholesky in scratch (-inf when a pivot is not
    # above drop_tol)
    for a in range(rk):
        for c in range(rk):
            scratch[a, c] = gw[a, c]
    log_w = 0.0
    for j in range(rk):
        p = scratch[j, j].real
        if not p > drop_tol:
            log_w = -np.inf
            break
        log_w += math.log(p)
        for a in range(j + 1, rk):
            f = scratch[a, j] / p
            for c in range(j + 1, a + 1):
                scratch[a, c] -= f * scratch[c, j].conjugate()
    log_x = 0.0
    for j in range(rk):
        log_x += 2.0 * math.log(low[j, j].real)
    # LU with partial (row) pivoting of S in place (L unit lower below the diagonal, U on
    # and above; ipiv[j] the row swapped with row j); log_iv = sum_j log|u_jj|, -inf at
    # the first zero pivot, which stops the factorisation
    log_iv = 0.0
    for j in range(rk):
        best = j
        for t in range(j + 1, rk):
            if abs(siv[t, j]) > abs(siv[best, j]):
                best = t
        ipiv[j] = best
        if best != j:
            for c in range(rk):
                siv[j, c], siv[best, c] = siv[best, c], siv[j, c]
        pv = siv[j, j]
        if not abs(pv) > 0.0:
            log_iv = -np.inf
            break
        log_iv += math.log(abs(pv))
        for t in range(j + 1, rk):
            f = siv[t, j] / pv
            siv[t, j] = f
            for c in range(j + 1, rk):
                siv[t, c] -= f * siv[j, c]
    if not (log_iv > -np.inf and log_w > -np.inf):
        return -np.inf
    _lu_solve(siv, rk, ipiv, dsol)
    for j in range(rk):
        s = perm[j]
        delta[s + 1] = dsol[j] * tsc[s]
    return (2.0 * log_iv - log_w - log_x) / rk


@numba.njit(**_INNER)
def _pooled_iv_blocks(moms, n_flat, wx_index, ww_index, txe, wtx, q_all, nx, wx, ww):
    """Pooled ``W^H X`` and ``W^H W`` (nz, Rd+1, Rd+1): every experiment's moments
    projected off its transient columns (``txe``, ``wtx`` from :func:`_gather_pooled`,
    whose columns hold ``[A | X | W]``) and summed."""
    nz = wx_index.shape[0]
    rd1 = wx_index.shape[1]
    qt = txe.shape[1]
    for i in range(nz):
        for s in range(rd1):
            for t in range(rd1):
                wx[i, s, t] = 0j
                ww[i, s, t] = 0j
    for e in range(moms.shape[0]):
        mom = moms[e]
        for i in range(nz):
            for s in range(rd1):
                cw = q_all + nx + i * rd1 + s
                for t in range(rd1):
                    cx = q_all + i * rd1 + t
                    cw2 = q_all + nx + i * rd1 + t
                    ax = _moment(mom, n_flat, wx_index[i, s, t])
                    aw = _moment(mom, n_flat, ww_index[i, s, t])
                    for t1 in range(qt):
                        ax -= txe[e, t1, cw].conjugate() * wtx[e, t1, cx]
                        aw -= txe[e, t1, cw].conjugate() * wtx[e, t1, cw2]
                    wx[i, s, t] += ax
                    ww[i, s, t] += aw


@numba.njit(**_INNER)
def _gram_rows(ar, ai, r0, out):
    """``out[s, t] = sum_a conj(a[r0 + s, a]) a[r0 + t, a]`` (``out`` (k, k), Hermitian):
    the Gram of rows ``r0 .. r0 + k - 1`` of a complex matrix held as real and imaginary
    planes, in one call (a call per entry cost more than its 20 multiply-adds: numba
    passes every array argument field by field)."""
    k = out.shape[0]
    for s in range(k):
        xr = ar[r0 + s]
        xi = ai[r0 + s]
        for t in range(s, k):
            yr = ar[r0 + t]
            yi = ai[r0 + t]
            accr = 0.0
            acci = 0.0
            for a in range(xr.shape[0]):
                accr += xr[a] * yr[a] + xi[a] * yi[a]
                acci += xr[a] * yi[a] - xi[a] * yr[a]
            out[s, t] = complex(accr, acci)
            out[t, s] = complex(accr, -acci)


@numba.njit(**_INNER)
def _tail_solve(u, q, nt, v, x):
    """``x = U22^-1 v[q-nt:]`` for the trailing ``nt x nt`` block of upper-triangular
    ``u`` (``x`` has length ``nt``)."""
    off = q - nt
    for j in range(nt - 1, -1, -1):
        acc = v[off + j]
        for c in range(j + 1, nt):
            acc -= u[off + j, off + c] * x[c]
        x[j] = acc * (1.0 / u[off + j, off + j].real)


@numba.njit(**_INNER)
def _products(rt, zt, b, j, slot_i, slot_j, base, x):
    """``x[s] = conj(base_i) base_j`` at padded sample ``j`` for every slot ``(i, j)``;
    the bases are ``R_0..R_{nr-1}``, ``1``, ``Z_0..`` (``base`` is scratch)."""
    nr = rt.shape[2]
    for c in range(nr):
        base[c] = rt[b, j, c]
    base[nr] = 1.0
    for c in range(zt.shape[2]):
        base[nr + 1 + c] = zt[b, j, c]
    for s in range(slot_i.shape[0]):
        x[s] = base[slot_i[s]].conjugate() * base[slot_j[s]]


@numba.njit(**_INNER)
def _moment(mom, n_flat, f):
    """Table entry ``f``: the moments, then (``f >= n_flat``) their conjugates."""
    if f >= n_flat:
        return mom[f - n_flat].conjugate()
    return mom[f]


@numba.njit(**_JIT)
def moments_and_floor(rt, zt, n, sel, restart, k_base, slot_i, slot_j, p1, mom_out,
                      floor_out):
    """All moments and R-energy rounding floors of the selected bins, exactly as
    :func:`fit_bins` computes them (for tests): ``mom_out`` (nbat, K, n_slots p1) slot
    major (``s p1 + a``), ``floor_out`` (nbat, K, nr); ``k_base`` the global index of the
    first bin (see ``_advance``)."""
    nr = rt.shape[2]
    ns = slot_i.shape[0]
    rho_pow, shift, lead = _recurrence(n, p1)
    mom = np.empty(ns * p1, dtype=np.complex128)
    floor = np.empty(nr)
    scratch = np.empty((4, max(ns, nr + 1 + zt.shape[2])), dtype=np.complex128)
    for b in range(sel.shape[0]):
        valid = np.bool_(False)  # not the literal False: one compiled _advance, not two
        for k in range(sel.shape[1]):
            valid = _advance(rt, zt, b, k, valid, sel[b], restart, k_base, n, slot_i,
                             slot_j, rho_pow, shift, lead, mom, floor, scratch)
            if sel[b, k]:
                for s in range(ns):
                    for a in range(p1):
                        mom_out[b, k, s * p1 + a] = mom[a * ns + s]
                for p in range(nr):
                    floor_out[b, k, p] = floor[p]
    return 0


@numba.njit(**_INNER)
def _recurrence(n, p1):
    """``rho^a`` over the window, and the coefficients of the step in :func:`_advance`:
    ``shift`` (2, p1) the weights ``((n+1)/n)^c`` of the sample entering the window and
    ``(-1)^c`` of the one leaving it, ``lead`` (3,) the coordinate step ``h = -1/n``,
    ``2 h`` and ``h^2``."""
    width = 2 * n + 1
    rho_pow = np.empty((width, p1))
    for r in range(width):
        rho = (r - n) / n
        for a in range(p1):
            rho_pow[r, a] = rho**a
    shift = np.empty((2, p1))
    for c in range(p1):
        shift[0, c] = ((n + 1.0) / n) ** c
        shift[1, c] = (-1.0) ** c
    lead = np.empty(3)
    lead[0] = -1.0 / n
    lead[1] = 2.0 * lead[0]
    lead[2] = lead[0] * lead[0]
    return rho_pow, shift, lead


@numba.njit(**_INNER)
def _advance(rt, zt, b, k, valid, sel_b, restart, k_base, n, slot_i, slot_j, rho_pow, shift,
             lead, mom, floor, scratch):
    """Bring ``mom`` to output bin ``k`` and return whether it holds valid moments.

    Segments of ``restart`` bins start at global bins ``k_base + k`` that are multiples
    of ``restart`` (so results do not depend on how the bins are chunked): direct sums
    at a segment's start when one of its bins is wanted, then one step per bin (the
    recurrence's rounding grows with the distance, by at most ``2^p`` within ``n``
    bins).  A chunk starting inside a segment starts with direct sums.  ``floor``:
    ``2 eps (W + 2 restart)`` times the R energy of the samples the segment's windows
    cover, a bound of the absolute rounding of the windowed ``sum |R_p|^2``.
    ``scratch`` (>= 3, >= max(n_slots, n_bases)) complex.

    Moments are power-major (``mom[a n_slots + s]``), so that the inner loops run over
    the slots; every weight is real, so the sums run over the real and imaginary parts
    alike (float views: in compiled code a real times a complex128 is a full complex
    product), and over views whose indices start at 0 (an offset index might be negative
    to the compiler: wraparound), which vectorise.

    One step (``k - 1`` to ``k``): with ``x`` a product series and the window moved by
    one bin, first the window's samples change in bin ``k - 1``'s coordinates, ``S_c +=
    ((n+1)/n)^c x(k+n) - (-1)^c x(k-1-n)`` (``shift[0, c]``, ``shift[1, c]``), then the
    coordinates move by ``h = 1/n``: ``S_a <- sum_c C(a, c) (-h)^(a-c) S_c``, a Taylor
    shift, applied as ``p (p - 1) / 2`` bidiagonal steps ``S_(j+1) += -h S_j``
    (``lead[0] = -h``; sweeps ``i = 0..p-2``, each over ``j = p-2..i`` descending so that
    it reads the sweep's old ``S_j``), two sweeps per pass over the moments.  ``O(p^2)``
    per product whatever the width, and fewer than half the passes over the moments of
    forming each new power as a sum over the old ones (19 instead of 49 for ``p = 7``).

    Direct sums: ``mom[a n_slots + s] = sum_r rho^a conj(base_i) base_j`` over the window
    of bin ``k`` (padded samples ``k .. k + 2n``), ``(i, j) = (slot_i[s], slot_j[s])``;
    the samples at ``rho = +-u/n`` summed in pairs, ``rho^a (x(+u) + (-1)^a x(-u))``,
    half the multiply-adds of a sum sample by sample.

    (The step and the direct sums are written here, not as functions of their own: a
    compiled function is optimised and made machine code alone and again in every
    caller's linked module.)
    """
    nr = rt.shape[2]
    ns = slot_i.shape[0]
    n2 = 2 * ns
    mf = mom.view(np.float64)
    base = scratch[0]
    phase = (k_base + k) % restart
    if phase != 0 and (valid or k > 0):
        if valid:  # one step of the recurrence
            x_out = scratch[1]
            x_in = scratch[2]
            _products(rt, zt, b, k - 1, slot_i, slot_j, base, x_out)
            _products(rt, zt, b, k + 2 * n, slot_i, slot_j, base, x_in)
            xo = x_out.view(np.float64)
            xi = x_in.view(np.float64)
            p1 = shift.shape[1]
            for c in range(p1):
                w_in = shift[0, c]
                w_out = shift[1, c]
                row = mf[c * n2: (c + 1) * n2]
                for s in range(n2):
                    row[s] += w_in * xi[s] - w_out * xo[s]
            # the sweeps two at a time: sweeps i, i + 1 make S_r += 2 h S_(r-1) + h^2
            # S_(r-2) (r = p-1..i+2, descending: old values) and S_(i+1) += h S_i; a last
            # single sweep S_(p-1) += h S_(p-2)
            h = lead[0]
            h2 = lead[1]
            hh = lead[2]
            i = 0
            while i < p1 - 1:
                pair = i + 2 < p1
                if pair:
                    for r in range(p1 - 1, i + 1, -1):
                        row = mf[r * n2: (r + 1) * n2]
                        r1 = mf[(r - 1) * n2: r * n2]
                        r2 = mf[(r - 2) * n2: (r - 1) * n2]
                        for s in range(n2):
                            row[s] += h2 * r1[s] + hh * r2[s]
                row = mf[(i + 1) * n2: (i + 2) * n2]
                r1 = mf[i * n2: (i + 1) * n2]
                for s in range(n2):
                    row[s] += h * r1[s]
                i += 2 if pair else 1
        return valid
    end = min(k + restart - phase, sel_b.shape[0])
    want = False
    for kk in range(k, end):
        want = want or sel_b[kk]
    if not want:
        return False
    # direct sums over the window
    x = scratch[1]
    y = scratch[2]
    p1 = rho_pow.shape[1]
    xf = x.view(np.float64)
    yf = y.view(np.float64)
    for f in range(mf.shape[0]):
        mf[f] = 0.0
    _products(rt, zt, b, k + n, slot_i, slot_j, base, x)  # rho = 0: the power 0 only
    for s in range(n2):
        mf[s] = xf[s]
    for u in range(1, n + 1):
        _products(rt, zt, b, k + n + u, slot_i, slot_j, base, x)
        _products(rt, zt, b, k + n - u, slot_i, slot_j, base, y)
        for s in range(n2):  # x <- x(+u) + x(-u), y <- x(+u) - x(-u)
            xp = xf[s]
            xm = yf[s]
            xf[s] = xp + xm
            yf[s] = xp - xm
        for a in range(p1):
            w = rho_pow[n + u, a]
            row = mf[a * n2: (a + 1) * n2]
            src = xf if a % 2 == 0 else yf
            for s in range(n2):
                row[s] += w * src[s]
    width = rho_pow.shape[0]
    hi = min(end + width - 1, rt.shape[1])
    for p in range(nr):
        e = 0.0
        for j in range(k, hi):
            e += rt[b, j, p].real ** 2 + rt[b, j, p].imag ** 2
        floor[p] = 2.0 * 2.220446049250313e-16 * (width + 2 * restart) * e
    return True


@numba.njit(**_INNER)
def _failed_bin(o, mode, out_g, out_t, out_ncov, out_cond, out_ill, out_reduced, out_gcov,
                out_gvar):
    """Output row ``o`` of a bin whose ``G`` is undetermined: NaN, flagged (the outputs
    are not prefilled: every fitted bin writes all of its row)."""
    nan_c = complex(np.nan, np.nan)
    for i in range(out_g.shape[1]):
        for p in range(out_g.shape[2]):
            out_g[o, i, p] = nan_c
    for e in range(out_t.shape[1]):
        for i in range(out_t.shape[2]):
            out_t[o, e, i] = nan_c
    for i in range(out_ncov.shape[1]):
        for j in range(out_ncov.shape[2]):
            out_ncov[o, i, j] = nan_c
    out_cond[o] = np.inf
    out_ill[o] = True
    out_reduced[o] = 0
    if mode == 2:
        for x in range(out_gcov.shape[1]):
            for y in range(out_gcov.shape[2]):
                out_gcov[o, x, y] = nan_c
    elif mode == 1:
        for i in range(out_gvar.shape[1]):
            for p in range(out_gvar.shape[2]):
                out_gvar[o, i, p] = np.nan


@numba.njit(**_JIT)
def fit_bins(rt, zt, n, sel, out_offset, m_out, restart, slot_i, slot_j, p1,
             aug_index, zz_index, gather, a_base, a_pow, mean_pow, dof, mode, drop_tol,
             pivot_limit, sens_limit, out_g, out_t, out_ncov, out_cond, out_ill,
             out_reduced, out_gcov, out_gvar, pool, iv):
    """Fit the local model at the selected bins of one chunk (see the module notes).

    ``rt``, ``zt`` (nbat, K + 2n, nr / nz): the chunk with its ``n``-bin halo on each
    side; ``sel`` (nbat, K) the bins to fit, whose flat output row is
    ``out_offset + b m_out + k`` (``out_offset mod m_out`` is the chunk's first bin, which
    aligns the moment restarts, see ``_advance``).  Windowed moments of the product pairs ``(slot_i,
    slot_j)``, ``p1`` powers each, power-major (entry ``a n_slots + s``), read through
    ``aug_index`` (q, q + nx) and ``zz_index`` (nz, nz, Rd+1, Rd+1) (entries from
    ``n_slots p1`` on are conjugates); ``gather`` the same tables decoded for the one-record
    gathers (``local_models._gather_tables``: positions of the real parts
    in the moments' float view and the signs of the imaginary parts, ``aug_index``'s then
    ``zz_index``'s).  ``mode`` is ``COV_*``.  Outputs: ``G`` (., nz,
    nr), ``T`` (., nz), noise covariance (., nz, nz), condition estimate, ill-posed flag,
    number of dropped denominator columns, ``G`` covariance (., nz nr, nz nr; mode full)
    or variances (., nz, nr; mode diag).

    ``pool``: None for one record per output row of ``sel``; pooled experiments
    (``pool = E > 1``, an int): rows ``b E .. b E + E - 1`` of ``rt``, ``zt``
    are the ``E`` experiments of output group ``b`` (``sel`` has ``nbat / E`` rows), fitted
    with ``G`` and ``D`` shared and a transient per experiment.  Each experiment keeps its
    own moment vector (same recurrence); per bin its Gram and right-hand sides are
    projected off its transient columns (whose Gram ``sum_r rho^(c+c')`` is the same for
    every experiment and bin: inverted once) and summed into the shared block, which then
    goes through the unchanged solve (as a model without transient).  Each experiment's
    ``T`` is back-substituted from its own projected moments (``out_t`` (., E, nz)); the
    covariance stacks the experiments' windows (``E W`` rows, transient leverage added).
    One experiment is the single-record path (``pool=None``).

    ``iv``: ``(wx_index, ww_index, weak_limit)``; empty index tables (shape
    ``(0, 1, 1)``) for least squares, else instrumental variables for the denominator
    columns.  ``zt`` then holds ``Z`` and after it the
    instruments ``Zhat`` (nbat, K + 2n, 2 nz); ``aug_index`` (q, q + nx + nw) indexes
    ``[Gaa | A^H X | A^H W]`` (``W`` columns ``rho^s Zhat_i`` at ``i (Rd+1) + s``, ``nw =
    nx``), ``wx_index``, ``ww_index`` (nz, Rd+1, Rd+1) the moments ``W_s^H X_t``,
    ``W_s^H W_t``.  Rows whose geometric-mean canonical correlation between projected
    instruments and regressors is below ``weak_limit`` flag the bin (weak instruments);
    a singular IV system fails it.  Least squares and instrumental variables are one
    compiled version (the same argument types, the branches taken at run time):
    ``identify``'s default fits both (the IV twin of the widest window), and one version
    with both compiles in much less than two versions with one each (measured:
    ``docs/architecture.md``, "A new process to its first result").
    """
    q = aug_index.shape[0]
    nz = zz_index.shape[0]
    rd1 = zz_index.shape[2]
    # instruments: their columns follow X in [Gaa | A^H X | A^H W] (nw = 0 without)
    has_iv = iv[0].shape[0] > 0
    nw = nz * rd1 if has_iv else 0
    nx = aug_index.shape[1] - q - nw
    rd = rd1 - 1
    nr = out_g.shape[2]
    # T (the constant column rho^0) precedes G at the end of A, unless Rm = -1 (no
    # transient term: periodic data)
    has_t = q > nr and a_base[q - nr - 1] == nr
    nt = nr + 1 if has_t else nr
    width = 2 * n + 1
    # ---- pooled experiments: the transient columns (base nr) are eliminated per
    # experiment; the shared solve below sees the other qs columns only (indices sh)
    # ``pool is None`` / ``pool is not None`` on the argument itself: numba then drops
    # the pooled branches when compiling for one record (pool=None), which keeps that
    # version (everybody's first call) free of the pooled code: less to compile (one
    # version with the pooled branches as well took about as long as both: measured)
    if pool is None:
        n_exp = 1
    else:
        n_exp = pool
    q_all = q
    qt = 0
    for a in range(q):
        if a_base[a] == nr:
            qt += 1
    sh = np.empty(q - qt, dtype=np.int64)
    tr = np.empty(qt, dtype=np.int64)
    c = 0
    for a in range(q):
        if a_base[a] == nr:
            tr[a - c] = a
        else:
            sh[c] = a
            c += 1
    rho_pow, shift, lead = _recurrence(n, p1)
    # inverse of the transient basis Gram sum_r rho^(c+c') (every experiment, every bin)
    tinv = np.empty((qt, qt))  # (written below when pooled; read only then)
    if pool is not None and qt > 0:
        tg = np.zeros((qt, 2 * qt), dtype=np.complex128)
        for t1 in range(qt):
            for t2 in range(qt):
                acc = 0.0
                for r in range(width):
                    acc += rho_pow[r, a_pow[tr[t1]]] * rho_pow[r, a_pow[tr[t2]]]
                tg[t1, t2] = acc
            tg[t1, qt + t1] = 1.0
        # rows [L^H | L^-1]: inverse = L^-H L^-1 (qt not a literal: one compiled version)
        cholesky_augmented(tg, np.int64(qt))
        for t1 in range(qt):
            for t2 in range(qt):
                acc = 0.0
                for t3 in range(qt):
                    acc += (tg[t3, qt + t1].conjugate() * tg[t3, qt + t2]).real
                tinv[t1, t2] = acc
    nxw = nx + nw
    ge = np.empty((q_all, q_all + nxw), dtype=np.complex128)  # one experiment's [Gaa | A^H X]
    wtx = np.empty((max(n_exp, 1), qt, q_all + nxw), dtype=np.complex128)  # Winv T^H [A | X]
    txe = np.empty((max(n_exp, 1), qt, q_all + nxw), dtype=np.complex128)  # T^H [A | X]
    xxe = np.empty((nz, nz, zz_index.shape[2], zz_index.shape[2]), dtype=np.complex128)
    tpow = np.empty(qt, dtype=np.int64)
    for t1 in range(qt):
        tpow[t1] = a_pow[tr[t1]]
    if pool is not None:
        q = q_all - qt
        a_base = a_base[sh].copy()
        a_pow = a_pow[sh].copy()
        has_t = False
        nt = nr
        width = n_exp * (2 * n + 1)
    wn = 2 * n + 1  # one experiment's window
    nan_c = complex(np.nan, np.nan)
    m = np.empty((q, q + nxw), dtype=np.complex128)
    mr = np.empty((q, q + nxw))  # m's real and imaginary planes for the Cholesky
    mi = np.empty((q, q + nxw))
    piv_a = np.empty(q)
    rb_c = np.empty((4, q + nxw))
    # Y = L^-1 A~^H X transposed (nx, q) and v_i = Y_i delta_i (nz, q), real and imaginary
    # planes: the per-row products over the q shared coordinates run on contiguous rows
    ytr = np.empty((nx, q))
    yti = np.empty((nx, q))
    vpr = np.empty((nz, q))
    vpi = np.empty((nz, q))
    # tau of covariance=None: u_i(t) = sum_s delta_i(s) mean_pow(s + t)
    upow = np.empty((nz, rd1), dtype=np.complex128)
    ds = np.empty(q)
    xx = np.empty((nz, nz, rd1, rd1), dtype=np.complex128)
    delta = np.empty((nz, rd1), dtype=np.complex128)
    v = np.empty((nz, q), dtype=np.complex128)
    schur = np.empty((max(rd, 1), max(rd, 1)), dtype=np.complex128)
    low = np.empty((nz, max(rd, 1), max(rd, 1)), dtype=np.complex128)
    perm = np.empty((nz, max(rd, 1)), dtype=np.int64)
    spiv = np.empty(max(rd, 1))
    rank = np.empty(nz, dtype=np.int64)
    tsc = np.empty((nz, max(rd, 1)))
    rhs = np.empty(max(rd, 1), dtype=np.complex128)
    dsol = np.empty(max(rd, 1), dtype=np.complex128)
    tail = np.empty(nt, dtype=np.complex128)
    ehe = np.empty((nz, nz), dtype=np.complex128)
    yy = np.empty((rd1, rd1), dtype=np.complex128)  # Y_i^H Y_i of a row's X columns
    vv = np.empty((nz, nz), dtype=np.complex128)  # v_i^H v_j
    wa = np.empty(q, dtype=np.complex128)
    # covariance scratch (window-sized)
    cov = mode != 0
    wc = width if cov else 0
    qhr = np.empty((q, wc))
    qhi = np.empty((q, wc))
    lev = np.empty(wc)
    umr = np.empty((nz, max(rd, 1), wc))
    umi = np.empty((nz, max(rd, 1), wc))
    dwr = np.empty((nz, wc))
    dwi = np.empty((nz, wc))
    vmr = np.empty((nz, max(rd, 1), wc))
    vmi = np.empty((nz, max(rd, 1), wc))
    ncr = np.empty((nz, wc))  # x_i(r) of the residual projector (_iv_tau)
    nci = np.empty((nz, wc))
    hgr = np.empty((nz * nr, wc))
    hgi = np.empty((nz * nr, wc))
    crow = np.empty(wc, dtype=np.complex128)
    ybk = np.empty((q, max(rd, 1)), dtype=np.complex128)
    wb = np.empty(max(rd, 1), dtype=np.complex128)
    tau = np.empty((nz, nz), dtype=np.complex128)
    scov = np.empty((nz, nz), dtype=np.complex128)
    # instrumental variables (sized 0 without: the least-squares build allocates nothing)
    rdv = max(rd, 1) if nw > 0 else 0
    wcv = wc if nw > 0 else 0
    wxm = np.empty((nz, rd1, rd1) if nw > 0 else (0, 0, 0), dtype=np.complex128)
    wwm = np.empty((nz, rd1, rd1) if nw > 0 else (0, 0, 0), dtype=np.complex128)
    twc = np.empty((nz, rdv))
    siv = np.empty((nz, rdv, rdv), dtype=np.complex128)
    ipiv = np.empty((nz, rdv), dtype=np.int64)
    gwv = np.empty((rdv, rdv), dtype=np.complex128)
    gws = np.empty((rdv, rdv), dtype=np.complex128)
    sinv = np.empty((rdv, rdv), dtype=np.complex128)
    ybw = np.empty((q, rdv), dtype=np.complex128)
    wmr = np.empty((rdv, wcv))
    wmi = np.empty((rdv, wcv))
    ymr = np.empty((nz, rdv, wcv))
    ymi = np.empty((nz, rdv, wcv))

    n_flat = slot_i.shape[0] * p1
    moms = np.empty((n_exp, n_flat), dtype=np.complex128)
    mom = moms[0]
    momf = mom.view(np.float64)
    # the gather of [Gaa | A^H X] and X^H X without a branch per entry (one record only:
    # pooled moments are gathered per experiment)
    gre, gsg, zre, zsg = gather
    floors = np.empty((n_exp, nr))
    floor = np.empty(nr)
    scratch = np.empty((4, max(slot_i.shape[0], nr + 1 + zt.shape[2])), dtype=np.complex128)
    for b in range(sel.shape[0]):
      valid = np.bool_(False)  # not the literal False: one compiled _advance, not two
      for k in range(sel.shape[1]):
        v_all = valid
        for e in range(n_exp):  # one moment vector per experiment, same recurrence
            v_all = _advance(rt, zt, b * n_exp + e, k, valid, sel[b], restart,
                             out_offset % m_out, n, slot_i, slot_j, rho_pow, shift, lead,
                             moms[e], floors[e], scratch)
        valid = v_all
        if not sel[b, k]:
            continue
        o = out_offset + b * m_out + k
        # ---- gather [Gaa | A^H X] into the real and imaginary planes of the Cholesky; an
        # R column within FFT rounding of zero energy is unexcited: the bin fails (NaN,
        # flagged)
        dead = False
        if pool is None:
            for a in range(q):
                ga = gre[a]
                sa = gsg[a]
                ra = mr[a]
                ia = mi[a]
                for c in range(a, q + nxw):
                    ra[c] = momf[ga[c]]
                    ia[c] = sa[c] * momf[ga[c] + 1]
            for p in range(nr):  # (a loop: an array slice assignment compiles numba's
                floor[p] = floors[0, p]  # shape-mismatch message machinery, ~8 s)
        else:
            _gather_pooled(moms, n_flat, aug_index, zz_index, sh, tr, tinv, ge, txe, wtx,
                           xxe, m, xx, q, nxw)
            for a in range(q):
                for c in range(a, q + nxw):
                    mr[a, c] = m[a, c].real
                    mi[a, c] = m[a, c].imag
            for p in range(nr):
                acc_f = 0.0
                for e in range(n_exp):
                    acc_f += floors[e, p]
                floor[p] = acc_f
        for a in range(q):
            dia = mr[a, a]
            if a_base[a] < nr and not dia > floor[a_base[a]]:
                dead = True
            ds[a] = 1.0 / math.sqrt(dia) if dia > 0.0 else np.nan
        if dead:
            _failed_bin(o, mode, out_g, out_t, out_ncov, out_cond, out_ill, out_reduced,
                        out_gcov, out_gvar)
            continue
        # Cholesky of the unscaled Gram: the factor of the Jacobi-scaled Gram D Gaa D
        # (D = diag(ds), unit-norm columns) is D L, so its rows are those of L^H times
        # ds column by column, its pivots those of L times ds^2, and L^-1 A^H X is the
        # same for both (the scaled rows' D cancels); a scaling pass is saved
        cholesky_planes(mr, mi, q, piv_a, rb_c)
        min_a = np.inf
        for a in range(q):
            pa = piv_a[a] * ds[a] ** 2
            if not pa > 0.0:
                min_a = np.nan
                break
            min_a = min(min_a, pa)
        if not min_a > 0.0:  # the shared block (holding G) is singular: G undetermined
            _failed_bin(o, mode, out_g, out_t, out_ncov, out_cond, out_ill, out_reduced,
                        out_gcov, out_gvar)
            continue
        # m: the scaled [L^H | L^-1 A~^H X] for what reads it whole (covariance, pooled
        # transients, instruments); otherwise only the trailing (T, G) block of L^H, which
        # the tail solves read
        whole = cov or pool is not None or has_iv
        for a in range(0 if whole else q - nt, q):
            for c in range(a, q):
                m[a, c] = complex(mr[a, c] * ds[c], mi[a, c] * ds[c])
            if whole:
                for c in range(q, q + nxw):
                    m[a, c] = complex(mr[a, c], mi[a, c])
        for x in range(nx):
            for a in range(q):
                ytr[x, a] = mr[a, q + x]
                yti[x, a] = mi[a, q + x]
        min_piv = min_a
        if pool is None:  # (pooled: xx already holds the projected sums)
            for i in range(nz):
                for j in range(i, nz):  # (j < i is never read)
                    for s in range(rd1):
                        for t in range(rd1):
                            zf = zre[i, j, s, t]
                            xx[i, j, s, t] = complex(momf[zf], zsg[i, j, s, t] * momf[zf + 1])
        if has_iv:  # the instruments' moments W^H X, W^H W (same row only)
            if pool is None:
                for i in range(nz):
                    for s in range(rd1):
                        for t in range(rd1):
                            wxm[i, s, t] = _moment(mom, n_flat, iv[0][i, s, t])
                            wwm[i, s, t] = _moment(mom, n_flat, iv[1][i, s, t])
            else:
                _pooled_iv_blocks(moms, n_flat, iv[0], iv[1], txe, wtx, q_all, nx, wxm, wwm)

        # ---- per row: Schur complement of the D columns, pivoted and rank revealing
        ill = False
        iv_failed = False
        n_drop = 0
        for i in range(nz):
            delta[i, 0] = 1.0
            for s in range(1, rd1):
                delta[i, s] = 0.0
            rank[i] = 0
            c0 = i * rd1
            if rd > 0:
                _gram_rows(ytr, yti, c0, yy)  # Y_i^H Y_i (rd1, rd1)
                for s in range(1, rd1):
                    e = xx[i, i, s, s].real
                    tsc[i, s - 1] = 1.0 / math.sqrt(e) if e > 0.0 else 0.0
                for s in range(1, rd1):
                    for t in range(s, rd1):  # Hermitian: the lower triangle mirrored
                        acc = xx[i, i, s, t] - yy[s, t]
                        schur[s - 1, t - 1] = acc * (tsc[i, s - 1] * tsc[i, t - 1])
                        if t != s:
                            schur[t - 1, s - 1] = schur[s - 1, t - 1].conjugate()
                    acc = xx[i, i, s, 0] - yy[s, 0]
                    rhs[s - 1] = -acc * tsc[i, s - 1]
                # condition estimate from the pivots in natural order (the same lower
                # bound as for the shared block); the pivoted factorisation decides drops
                min_piv = min(min_piv, _natural_min_pivot(schur, low[i]))
                rk = pivoted_cholesky(schur, drop_tol, low[i], perm[i], spiv)
                rank[i] = rk
                for j in range(rk):
                    dsol[j] = rhs[perm[i, j]]
                _chol_solve(low[i], rk, dsol, dsol)
                for j in range(rk):
                    s = perm[i, j]
                    delta[i, s + 1] = dsol[j] * tsc[i, s]
                n_drop += rd - rk
                # a dropped column: its null direction [-Gaa^-1 A^H b~; b~] (kept
                # columns eliminated) must not move G, or G is undetermined here
                for jd in range(rk, rd):
                    sd = perm[i, jd]
                    # kept-column coefficients of the direction: -S_kk^-1 S_k,sd
                    for j in range(rk):
                        sj = perm[i, j]
                        acc = xx[i, i, sj + 1, sd + 1] - yy[sj + 1, sd + 1]
                        dsol[j] = -acc * (tsc[i, sj] * tsc[i, sd])
                    _chol_solve(low[i], rk, dsol, dsol)
                    # Y~_B v_B on the shared rows (scaled B columns are -tsc rho^s Z_i)
                    norm2 = 1.0
                    for j in range(rk):
                        norm2 += abs(dsol[j]) ** 2
                    for a in range(q):
                        acc = -tsc[i, sd] * complex(ytr[c0 + sd + 1, a], yti[c0 + sd + 1, a])
                        for j in range(rk):
                            sj = perm[i, j]
                            acc -= dsol[j] * tsc[i, sj] * complex(ytr[c0 + sj + 1, a],
                                                                  yti[c0 + sj + 1, a])
                        wa[a] = acc
                    _tail_solve(m, q, nt, wa, tail)
                    sens = 0.0
                    for p in range(nr):
                        sens += abs(tail[nt - nr + p]) ** 2
                    if sens > sens_limit**2 * norm2:
                        ill = True
                if has_iv:  # the kept columns' coefficients by IV instead
                    corr = _iv_row(m, q, nx, i, rk, perm[i], low[i], tsc[i], wxm, wwm,
                                   twc[i], siv[i], ipiv[i], gwv, gws, dsol, delta[i],
                                   drop_tol)
                    if not corr > -np.inf:
                        iv_failed = True
                    elif corr < 2.0 * math.log(iv[2]):
                        ill = True
            # v_i = Y_i delta_i (the shared coordinates of D z_i); T, G from its tail
            for a in range(q):
                vpr[i, a] = 0.0
                vpi[i, a] = 0.0
            for s in range(rd1):
                dr = delta[i, s].real
                di = delta[i, s].imag
                yr = ytr[c0 + s]
                yi = yti[c0 + s]
                wr = vpr[i]
                wi = vpi[i]
                for a in range(q):
                    wr[a] += yr[a] * dr - yi[a] * di
                    wi[a] += yr[a] * di + yi[a] * dr
            for a in range(q):
                v[i, a] = complex(vpr[i, a], vpi[i, a])
            _tail_solve(m, q, nt, v[i], tail)
            out_t[o, 0, i] = tail[0] * ds[q - nt] if has_t else 0j
            for p in range(nr):
                out_g[o, i, p] = tail[nt - nr + p] * ds[q - nr + p]
            if pool is not None:
                _pooled_transients(m, q, nx, ds, delta[i], i, rd1, sh, tr, wtx, out_t[o],
                                   v[i], wa)

        if has_iv:
            if iv_failed:  # a singular IV system: the instruments do not determine D
                _failed_bin(o, mode, out_g, out_t, out_ncov, out_cond, out_ill,
                            out_reduced, out_gcov, out_gvar)
                continue

        # ---- residual cross products e_i^H e_j = delta_i^H X_i^H X_j delta_j - v_i^H v_j
        _gram_rows(vpr, vpi, np.int64(0), vv)  # (not the literal 0: one compiled _gram_rows)
        for i in range(nz):
            for j in range(i, nz):
                acc = 0j
                for s in range(rd1):
                    inner = 0j
                    for t in range(rd1):
                        inner += xx[i, j, s, t] * delta[j, t]
                    acc += delta[i, s].conjugate() * inner
                acc -= vv[i, j]
                ehe[i, j] = acc
                ehe[j, i] = acc.conjugate()
        out_cond[o] = math.sqrt(1.0 / min_piv) if min_piv > 0.0 else np.inf
        out_ill[o] = ill or not min_a * pivot_limit**2 >= 1.0
        out_reduced[o] = n_drop

        if not cov:
            # tau_ij ~ dof mean_r d_i(r) conj(d_j(r)) (exact for the LPM; local_model Notes)
            for i in range(nz):
                for t in range(rd1):
                    acc = 0j
                    for s in range(rd1):
                        acc += delta[i, s] * mean_pow[s + t]
                    upow[i, t] = acc
            for i in range(nz):
                for j in range(i, nz):  # Hermitian
                    acc = 0j
                    for t in range(rd1):
                        acc += upow[i, t] * delta[j, t].conjugate()
                    # times 1 / (dof acc) = conj(acc) / (dof |acc|^2): numba's complex
                    # division is a call per entry
                    inv_d = 1.0 / (dof * (acc.real * acc.real + acc.imag * acc.imag))
                    out_ncov[o, i, j] = ehe[i, j].conjugate() * complex(acc.real * inv_d,
                                                                        -acc.imag * inv_d)
                    out_ncov[o, j, i] = out_ncov[o, i, j].conjugate()
            continue

        # ---- covariance, explicit over the window (loops over r innermost, contiguous).
        # Real and imaginary parts live in separate arrays (suffixes r, i): complex128
        # elements interleave them, and the loops over the window then do not vectorise
        # (measured about 2x on these loops).
        # qh = Q_A^H = L^-1 A~^H (q, W) and the leverages lev(r) = ||Q_A(r, :)||^2
        for a in range(q):
            sc = ds[a]
            pw = a_pow[a]
            if pool is not None:  # stacked windows, each projected off its experiment's transient
                _pooled_columns(rt, b, k, a_base[a], pw, sh[a], sc, rho_pow, tpow, wtx,
                                crow)
                for r in range(width):
                    qhr[a, r] = crow[r].real
                    qhi[a, r] = crow[r].imag
            elif a_base[a] < nr:
                col = a_base[a]
                for r in range(width):
                    w = sc * rho_pow[r, pw]
                    qhr[a, r] = rt[b, k + r, col].real * w
                    qhi[a, r] = -rt[b, k + r, col].imag * w
            else:
                for r in range(width):
                    qhr[a, r] = sc * rho_pow[r, pw]
                    qhi[a, r] = 0.0
            for c in range(a):  # qh[a] -= conj(m[c, a]) qh[c]
                fr = m[c, a].real
                fi = -m[c, a].imag
                for r in range(width):
                    qhr[a, r] -= fr * qhr[c, r] - fi * qhi[c, r]
                    qhi[a, r] -= fr * qhi[c, r] + fi * qhr[c, r]
            inv = 1.0 / m[a, a].real
            for r in range(width):
                qhr[a, r] *= inv
                qhi[a, r] *= inv
        for r in range(width):
            lev[r] = 0.0
        for a in range(q):
            for r in range(width):
                lev[r] += qhr[a, r] ** 2 + qhi[a, r] ** 2
        if pool is not None:  # the eliminated transient columns' leverage, the same in every window
            for r in range(wn):
                lt = 0.0
                for t1 in range(qt):
                    for t2 in range(qt):
                        lt += rho_pow[r, tpow[t1]] * tinv[t1, t2] * rho_pow[r, tpow[t2]]
                for e in range(n_exp):
                    lev[e * wn + r] += lt
        for i in range(nz):
            for r in range(width):
                acc = delta[i, 0]
                for s in range(1, rd1):
                    acc += delta[i, s] * rho_pow[r % wn, s]
                dwr[i, r] = acc.real
                dwi[i, r] = acc.imag
            # the row's projected D columns (least squares: whitened, U_i; IV: X~ and
            # Y = W~ S^-H) and the gains of its G entries (_row_gains)
            _row_gains(zt, b, k, i, nz, rd1, rank[i], perm[i], low[i], tsc[i], twc[i], siv[i],
                       ipiv[i], m, nx, q_all, ds, dwr[i], dwi[i], qhr, qhi, rho_pow, tpow,
                       wtx, pool, has_iv, crow, ybk, ybw, wmr, wmi, sinv, dsol, umr[i],
                       umi[i], ymr[i], ymi[i], hgr, hgi, wa, wb)
        # tau_ij and s_ij = raw_ij / tau_ij (least squares: the residual projector is
        # orthogonal, Y = U; IV: oblique)
        _iv_tau(rank, lev, dwr, dwi, umr, umi, ymr if has_iv else umr,
                ymi if has_iv else umi, ncr, nci, vmr, vmi, ehe, tau, scov, has_iv)
        for i in range(nz):
            for j in range(nz):
                out_ncov[o, i, j] = scov[i, j]
        if mode == 1:
            for i in range(nz):
                for p in range(nr):
                    acc_v = 0.0
                    x = i * nr + p
                    for r in range(width):
                        acc_v += hgr[x, r] ** 2 + hgi[x, r] ** 2
                    out_gvar[o, i, p] = acc_v * scov[i, i].real
            continue
        ng = nz * nr
        for x in range(ng):
            for y in range(x, ng):
                accr = 0.0  # h_x conj(h_y)
                acci = 0.0
                for r in range(width):
                    accr += hgr[x, r] * hgr[y, r] + hgi[x, r] * hgi[y, r]
                    acci += hgi[x, r] * hgr[y, r] - hgr[x, r] * hgi[y, r]
                acc = complex(accr, acci) * scov[x // nr, y // nr]
                out_gcov[o, x, y] = acc
                out_gcov[o, y, x] = acc.conjugate()
    return 0


@numba.njit(**_INNER)
def _project_kept(zt, b, k, col, mcol, pcol, scale, rk, perm, m, qhr, qhi, rho_pow, tpow, wtx,
                  pool, crow, yb, ur, ui):
    """The kept denominator columns ``-scale[s] rho^(s+1) zt[:, col]`` (``s = perm[j]``)
    over the window, projected off ``A``: ``yb[a, j] = Y~ = L^-1 A~^H b~`` (the scaled
    column ``mcol + s + 1`` of ``m``) and ``ur``, ``ui`` (rk, W) ``b~ - Q_A Y~`` (pooled:
    each window also off its experiment's transient, column ``pcol + s + 1`` of ``wtx``).
    Least squares calls it for the regressors ``Z_i``, IV also for the instruments."""
    q = qhr.shape[0]
    width = qhr.shape[1]
    for j in range(rk):
        s = perm[j]
        f = -scale[s]
        for a in range(q):
            yb[a, j] = f * m[a, mcol + s + 1]
        if pool is not None:  # (pool None: numba leaves the pooled branch out)
            _pooled_d_column(zt, b, k, col, s + 1, pcol + s + 1, f, rho_pow, tpow, wtx, crow)
            for r in range(width):
                ur[j, r] = crow[r].real
                ui[j, r] = crow[r].imag
        else:
            for r in range(width):
                w = f * rho_pow[r, s + 1]
                ur[j, r] = w * zt[b, k + r, col].real
                ui[j, r] = w * zt[b, k + r, col].imag
        for a in range(q):  # - Q_A Y~: Q_A(r, a) = conj(qh[a, r])
            yr = yb[a, j].real
            yi = yb[a, j].imag
            for r in range(width):
                ur[j, r] -= qhr[a, r] * yr + qhi[a, r] * yi
                ui[j, r] -= qhr[a, r] * yi - qhi[a, r] * yr


@numba.njit(**_INNER)
def _row_gains(zt, b, k, i, nz, rd1, rk, perm, low, tsc, twc, siv, ipiv, m, nx, q_all, ds,
               dwr, dwi, qhr, qhi, rho_pow, tpow, wtx, pool, has_iv, crow, ybk, ybw, wmr,
               wmi, sinv, x, umr, umi, ymr, ymi, hgr, hgi, wa, wb):
    """Covariance pieces of row ``i`` over the window: its projected denominator columns
    and the gains of its ``G`` entries (rows ``i nr + p`` of ``hgr``, ``hgi``), times
    ``d_i(r)`` (the equation error is ``d_i V_i``).

    Least squares: ``U_i`` (rk, W) into ``umr``, ``umi``, the kept scaled columns projected
    off ``A`` (:func:`_project_kept`) and whitened by ``L_s^-H`` (``low``), and the gains
    ``g~(r) = conj(Q_A w_A + U_i w_B)(r)`` with ``w_A = L^-1 e_g`` (non-zero on the trailing
    ``nr`` entries only) and ``w_B = -L_s^-1 Y~_B^H w_A``.

    Instrumental variables: ``X~ = P B~`` (not whitened) into ``umr``, ``umi``; ``Y = W~
    S^-H`` into ``ymr``, ``ymi`` (``W~ = P W'``, the scaled instruments projected off
    ``A``; ``S = W~^H B~`` from the LU in ``siv``), so that the residual projector is ``P
    - X~ Y^H``; gains ``delta G = ds_g wa^H (Q_A^H - Y_B Y^H) e`` with ``Y_B = Q_A^H B~``.
    ``P`` is ``I - Q_A Q_A^H`` (pooled: the columns also off each experiment's transient,
    through ``wtx``).  ``x`` (>= rk) is scratch.
    """
    width = qhr.shape[1]
    q = qhr.shape[0]
    nr = hgr.shape[0] // nz
    c0 = i * rd1
    _project_kept(zt, b, k, i, q + c0, q_all + c0, tsc, rk, perm, m, qhr, qhi, rho_pow, tpow,
                  wtx, pool, crow, ybk, umr, umi)
    if has_iv:
        _project_kept(zt, b, k, nz + i, q + nx + c0, q_all + nx + c0, twc, rk, perm, m, qhr,
                      qhi, rho_pow, tpow, wtx, pool, crow, ybw, wmr, wmi)
        for t in range(rk):  # S^-1, column by column
            for u in range(rk):
                x[u] = 1.0 if u == t else 0.0
            _lu_solve(siv, rk, ipiv, x)
            for u in range(rk):
                sinv[u, t] = x[u]
        for t in range(rk):  # Y(r, t) = sum_u W~(r, u) conj(S^-1[t, u])
            for r in range(width):
                ymr[t, r] = 0.0
                ymi[t, r] = 0.0
            for u in range(rk):
                fr = sinv[t, u].real
                fi = -sinv[t, u].imag
                for r in range(width):
                    ymr[t, r] += wmr[u, r] * fr - wmi[u, r] * fi
                    ymi[t, r] += wmr[u, r] * fi + wmi[u, r] * fr
    else:
        for j in range(rk):  # whitened: um[j] -= um[c] conj(low[j, c]), / low[j, j]
            for c in range(j):
                fr = low[j, c].real
                fi = -low[j, c].imag
                for r in range(width):
                    umr[j, r] -= umr[c, r] * fr - umi[c, r] * fi
                    umi[j, r] -= umr[c, r] * fi + umi[c, r] * fr
            inv = 1.0 / low[j, j].real
            for r in range(width):
                umr[j, r] *= inv
                umi[j, r] *= inv
    for p in range(nr):
        g = q - nr + p
        xg = i * nr + p
        # wa = L^-1 e_g (non-zero from entry g on: G is last in A) and the shared
        # columns' part of the gain: conj(Q_A wa)(r) = sum_a qh[a, r] conj(wa[a])
        for a in range(q):
            wa[a] = 0j
        for a in range(g, q):
            acc = 1.0 + 0j if a == g else 0j
            for c in range(g, a):
                acc -= m[c, a].conjugate() * wa[c]
            wa[a] = acc / m[a, a].real
        for r in range(width):
            hgr[xg, r] = 0.0
            hgi[xg, r] = 0.0
        for a in range(g, q):  # += qh[a] conj(wa[a])
            fr = wa[a].real
            fi = -wa[a].imag
            for r in range(width):
                hgr[xg, r] += qhr[a, r] * fr - qhi[a, r] * fi
                hgi[xg, r] += qhr[a, r] * fi + qhi[a, r] * fr
        if has_iv:
            for j in range(rk):  # wb = Y_B^H wa
                acc = 0j
                for a in range(g, q):
                    acc += ybk[a, j].conjugate() * wa[a]
                wb[j] = acc
            for j in range(rk):  # -= conj(Y(r, j)) conj(wb[j])
                br = wb[j].real
                bi = wb[j].imag
                for r in range(width):
                    hgr[xg, r] -= ymr[j, r] * br - ymi[j, r] * bi
                    hgi[xg, r] += ymr[j, r] * bi + ymi[j, r] * br
        else:
            for j in range(rk):  # w_B = -L_s^-1 Y~_B^H w_A
                acc = 0j
                for a in range(g, q):
                    acc -= ybk[a, j].conjugate() * wa[a]
                for c in range(j):
                    acc -= low[j, c] * wb[c]
                wb[j] = acc / low[j, j].real
            for j in range(rk):  # += conj(um[j]) conj(wb[j])
                fr = wb[j].real
                fi = -wb[j].imag
                for r in range(width):
                    hgr[xg, r] += umr[j, r] * fr + umi[j, r] * fi
                    hgi[xg, r] += umr[j, r] * fi - umi[j, r] * fr
        sc = ds[g]  # times ds_g d(r) (the column scale of G, the equation error d V)
        for r in range(width):
            fr = sc * dwr[r]
            fi = sc * dwi[r]
            hr = hgr[xg, r]
            hgr[xg, r] = hr * fr - hgi[xg, r] * fi
            hgi[xg, r] = hr * fi + hgi[xg, r] * fr


@numba.njit(**_INNER)
def _iv_tau(rank, lev, dwr, dwi, umr, umi, ymr, ymi, ncr, nci, vmr, vmi, ehe, tau, scov,
            oblique):
    """``tau_ij = tr(D_j^H Pi_j^H Pi_i D_i)`` of the residual projector
    ``Pi_i = P - X_i Y_i^H`` (IV: oblique, ``Y_i^H X_i = I``; ``X``, ``Y`` in ``umr``/``ymr``
    from :func:`_row_gains`; least squares, ``oblique`` false: ``X = Y = U_i``,
    orthonormal, ``x_i = nu_i`` real, the weight's imaginary part left out) and ``scov = conj(ehe) / tau``::

        tau_ij = sum_r c(r) (1 - lev(r) - x_i(r) - conj(x_j(r)))
                 + tr((X_j^H X_i)(Y_i^H diag(c) Y_j)),   c = d_i conj(d_j),

    ``x_i(r) = sum_t conj(Y_i(r, t)) X_i(r, t)`` (``||U_i(r, :)||^2`` for least
    squares, where ``Y = X``).  ``O(rk^2 W)`` per pair of rows.
    """
    nz = rank.shape[0]
    width = lev.shape[0]
    for i in range(nz):
        for r in range(width):
            ncr[i, r] = 0.0
            nci[i, r] = 0.0
        for t in range(rank[i]):
            for r in range(width):
                yr = ymr[i, t, r]
                yi = ymi[i, t, r]
                xr = umr[i, t, r]
                xi = umi[i, t, r]
                ncr[i, r] += yr * xr + yi * xi
                nci[i, r] += yr * xi - yi * xr
                vmr[i, t, r] = yr * dwr[i, r] + yi * dwi[i, r]  # V_i = Y_i conj(d_i)
                vmi[i, t, r] = yi * dwr[i, r] - yr * dwi[i, r]
    for i in range(nz):
        for j in range(i, nz):
            accr = 0.0
            acci = 0.0
            if oblique:
                for r in range(width):
                    cr = dwr[i, r] * dwr[j, r] + dwi[i, r] * dwi[j, r]
                    ci = dwi[i, r] * dwr[j, r] - dwr[i, r] * dwi[j, r]
                    wr = 1.0 - lev[r] - ncr[i, r] - ncr[j, r]
                    wi = nci[j, r] - nci[i, r]
                    accr += cr * wr - ci * wi
                    acci += cr * wi + ci * wr
            else:  # least squares: x_i = nu_i is real, d_i conj(d_j) (1 - lev - nu_i - nu_j)
                for r in range(width):
                    wgt = 1.0 - lev[r] - ncr[i, r] - ncr[j, r]
                    accr += (dwr[i, r] * dwr[j, r] + dwi[i, r] * dwi[j, r]) * wgt
                    acci += (dwi[i, r] * dwr[j, r] - dwr[i, r] * dwi[j, r]) * wgt
            # + tr((X_j^H X_i)(V_i^H V_j)) over the kept columns, V = Y conj(d)
            acc = complex(accr, acci)
            for s in range(rank[j]):
                for t in range(rank[i]):
                    ujr = 0.0  # (X_j^H X_i)[s, t]
                    uji = 0.0
                    ucr = 0.0  # (V_i^H V_j)[t, s]
                    uci = 0.0
                    for r in range(width):
                        ujr += umr[j, s, r] * umr[i, t, r] + umi[j, s, r] * umi[i, t, r]
                        uji += umr[j, s, r] * umi[i, t, r] - umi[j, s, r] * umr[i, t, r]
                        ucr += vmr[i, t, r] * vmr[j, s, r] + vmi[i, t, r] * vmi[j, s, r]
                        uci += vmr[i, t, r] * vmi[j, s, r] - vmi[i, t, r] * vmr[j, s, r]
                    acc += complex(ujr, uji) * complex(ucr, uci)
            tau[i, j] = acc
            scov[i, j] = ehe[i, j].conjugate() / acc
            scov[j, i] = scov[i, j].conjugate()


@numba.njit(**_INNER)
def _gather_pooled(moms, n_flat, aug_index, zz_index, sh, tr, tinv, ge, txe, wtx, xxe, m, xx,
                   qs, nx):
    """Pooled ``[Gaa | A^H X]`` (shared columns ``sh``, upper triangle) and ``X^H X`` in
    ``m``, ``xx``: every experiment's moments projected off its transient columns ``tr``
    (``Winv = tinv``) and summed.  Keeps ``txe = T^H [A | X]`` and ``wtx = Winv txe`` per
    experiment for the transients and the covariance."""
    q_all = aug_index.shape[0]
    qt = tr.shape[0]
    nz = zz_index.shape[0]
    rd1 = zz_index.shape[2]
    for a in range(qs):
        for c in range(qs + nx):
            m[a, c] = 0j
    for i in range(nz):
        for j in range(nz):
            for s in range(rd1):
                for t in range(rd1):
                    xx[i, j, s, t] = 0j
    for e in range(moms.shape[0]):
        mom = moms[e]
        for a in range(q_all):
            for c in range(a, q_all + nx):
                ge[a, c] = _moment(mom, n_flat, aug_index[a, c])
            for c in range(a):
                ge[a, c] = ge[c, a].conjugate()
        for t1 in range(qt):
            for c in range(q_all + nx):
                txe[e, t1, c] = ge[tr[t1], c]
        for t1 in range(qt):
            for c in range(q_all + nx):
                acc = 0j
                for t2 in range(qt):
                    acc += tinv[t1, t2] * txe[e, t2, c]
                wtx[e, t1, c] = acc
        for a in range(qs):
            ra = sh[a]
            for c in range(a, qs + nx):
                oc = sh[c] if c < qs else q_all + c - qs
                acc = ge[ra, oc]
                for t1 in range(qt):
                    acc -= txe[e, t1, ra].conjugate() * wtx[e, t1, oc]
                m[a, c] += acc
        for i in range(nz):
            for j in range(nz):
                for s in range(rd1):
                    ci = q_all + i * rd1 + s
                    for t in range(rd1):
                        cj = q_all + j * rd1 + t
                        acc = _moment(mom, n_flat, zz_index[i, j, s, t])
                        for t1 in range(qt):
                            acc -= txe[e, t1, ci].conjugate() * wtx[e, t1, cj]
                        xx[i, j, s, t] += acc


@numba.njit(**_INNER)
def _pooled_transients(m, qs, nx, ds, delta_i, i, rd1, sh, tr, wtx, out_t_o, v_i, x):
    """Every experiment's transient ``T`` (the ``rho^0`` coefficient) of row ``i``:
    ``theta_T,e = Winv T^H (X_e delta_i - A_e theta_S)`` from the shared coefficients
    ``theta_S`` (full back substitution of ``v_i``) and the experiment's own moments."""
    _tail_solve(m, qs, qs, v_i, x)  # x = L^-H v_i: all scaled shared coefficients
    for a in range(qs):
        x[a] *= ds[a]
    q_all = wtx.shape[2] - (m.shape[1] - qs)
    qt = tr.shape[0]
    t0 = qt - 1  # the transient columns run rho^Rm .. rho^0
    for e in range(wtx.shape[0]):
        acc = 0j
        for s in range(rd1):
            acc += wtx[e, t0, q_all + i * rd1 + s] * delta_i[s]
        for a in range(qs):
            acc -= wtx[e, t0, sh[a]] * x[a]
        out_t_o[e, i] = acc


@numba.njit(**_INNER)
def _pooled_columns(rt, b, k, base, pw, orig, sc, rho_pow, tpow, wtx, out):
    """``out`` (E W): ``sc`` times the conjugate of shared column ``orig`` (base ``base``,
    power ``pw``) over the stacked windows, each projected off its transient columns."""
    n_exp = wtx.shape[0]
    nr = rt.shape[2]
    wn = rho_pow.shape[0]
    for e in range(n_exp):
        row = b * n_exp + e
        for r in range(wn):
            val = rho_pow[r, pw] * (rt[row, k + r, base].conjugate() if base < nr else 1.0)
            for t1 in range(tpow.shape[0]):
                val -= rho_pow[r, tpow[t1]] * wtx[e, t1, orig].conjugate()
            out[e * wn + r] = sc * val


@numba.njit(**_INNER)
def _pooled_d_column(zt, b, k, i, pw, orig, f, rho_pow, tpow, wtx, out):
    """``out`` (E W): ``f`` times ``rho^pw Z_i`` over the stacked windows, each projected
    off its experiment's transient columns (``orig``: the column's index in ``wtx``)."""
    n_exp = wtx.shape[0]
    wn = rho_pow.shape[0]
    for e in range(n_exp):
        row = b * n_exp + e
        for r in range(wn):
            val = rho_pow[r, pw] * zt[row, k + r, i]
            for t1 in range(tpow.shape[0]):
                val -= rho_pow[r, tpow[t1]] * wtx[e, t1, orig]
            out[e * wn + r] = f * val


# an empty cache's first fit_bins compile starts a second process that compiles the
# helpers above into the same cache meanwhile (lcmr_xr.kernels.compile_ahead)
from lcmr_xr.kernels import compile_ahead as _compile_ahead  # noqa: E402

_compile_ahead.install(fit_bins)
