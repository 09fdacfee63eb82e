"""Plain per-bin least-squares oracle of the local rational / polynomial model.

Obviously-correct and slow on purpose: a Python loop over bins and rows, the regression
matrix written literally from the model equations, solved by ``numpy.linalg.lstsq``.
The tests compare :func:`lcmr_xr.kernels.local_models.local_model` with it, and
``benchmarks/local_models.py`` imports it (one copy only).
"""

from __future__ import annotations

import numpy as np


def oracle_local_model(R, Z, half_width, degrees, circular=True, bins=None, covariance=True,
                       instruments=None):
    """Per-bin ``lstsq`` fit of ``D(r) Z_i(k+r) - N_i(r) R(k+r) - Mt_i(r) = e_i(r)``.

    ``covariance=False`` stops after ``G``, ``T`` and the residual covariance (a plain
    per-bin fit, the speed baseline of ``benchmarks/local_models.py``).

    ``R`` (M, nr), ``Z`` (M, nz) (no batch dims).  Returns a dict with ``G`` (M, nz, nr),
    ``T`` (M, nz), ``noise_covariance`` (M, nz, nz) and ``noise_variance`` (M, nz) (its
    diagonal), ``G_cov`` (M, nz nr, nz nr), ``residual_covariance`` (M, nz, nz), ``tau``
    (M, nz, nz) and ``singular`` values of the column-scaled regression (M, nz, p).  Bins
    without a full window (non-circular) or not in ``bins`` are NaN.

    Everything is written literally from first-order perturbation theory, with explicit
    matrices over the window (``W`` = 2n+1 bins):

    * equation error at the true parameters ``e_i = D_i V_i``, ``D_i = diag(d_i(r))``,
      ``d_i(r) = 1 + sum_s d_is rho^s`` (``V_i`` the noise on ``Z_i``, white over bins,
      ``E[V_i V_j^H] = s_ij I``); ``d`` is taken at its estimate;
    * ``theta_i - theta_i0 = K_i^+ e_i``, so the sandwich
      ``Cov(G_i, G_j) = s_ij g_i D_i D_j^H g_j^H`` with ``g_i`` the G-rows of ``K_i^+``;
    * the residual ``r_i = P_i D_i V_i`` (``P_i = I - K_i K_i^+``), so
      ``E[r_j^H r_i] = s_ij tau_ij`` with ``tau_ij = tr(D_j^H P_j P_i D_i)`` and the noise
      estimate ``s_ij = (sum_r r_i conj(r_j)) / tau_ij`` (``residual_covariance`` holds the
      plain ``sum_r r_i conj(r_j) / dof``).  For the LPM ``D = I``, ``tau = dof``.

    ``instruments`` (M, nz): instrumental variables for the denominator columns: ``Phi_i``
    is ``K_i`` with ``-rho^s Z_i`` replaced by ``-rho^s Zhat_i``, ``theta = (Phi^H K)^-1
    Phi^H z`` (``numpy.linalg.solve``), ``K_i^+`` above becomes ``(Phi^H K)^-1 Phi^H`` and
    ``P_i = I - K (Phi^H K)^-1 Phi^H`` an oblique projector (the same formulas otherwise).
    """
    R = np.asarray(R, dtype=complex)
    Z = np.asarray(Z, dtype=complex)
    m, nr = R.shape
    nz = Z.shape[1]
    rn, rm, rd = degrees
    n = half_width
    r = np.arange(-n, n + 1)
    rho = r / n
    p_row = nr * (rn + 1) + rm + 1 + rd
    dof = 2 * n + 1 - p_row
    nan_c = complex(np.nan, np.nan)
    out = {
        "G": np.full((m, nz, nr), nan_c),
        "T": np.full((m, nz), nan_c),
        "noise_variance": np.full((m, nz), np.nan),
        "noise_covariance": np.full((m, nz, nz), nan_c),
        "residual_covariance": np.full((m, nz, nz), nan_c),
        "tau": np.full((m, nz, nz), nan_c),
        "G_cov": np.full((m, nz * nr, nz * nr), nan_c),
        "singular": np.full((m, nz, p_row), np.nan),
        "dof": dof,
    }
    if bins is None:
        bins = range(m) if circular else range(n, m - n)
    for k in bins:
        idx = (k + r) % m if circular else k + r
        Rw, Zw = R[idx], Z[idx]
        resid = np.empty((nz, 2 * n + 1), dtype=complex)
        gain = []  # rows of K_i^+ that give G_i
        proj = []  # P_i = I - K_i K_i^+
        dwin = []  # D_i = diag(d_i(r))
        for i in range(nz):
            columns = []
            for p in range(nr):  # N(r) R(k+r): G_p + sum_s N_s,p rho^s
                for b in range(rn + 1):
                    columns.append(Rw[:, p] * rho**b)
            for c in range(rm + 1):  # Mt(r): T + sum_s M_s rho^s
                columns.append(rho**c + 0j)
            for s in range(1, rd + 1):  # D(r) Z_i = Z_i + sum_s d_s rho^s Z_i, moved right
                columns.append(-(rho**s) * Zw[:, i])
            K = np.stack(columns, axis=1)
            if instruments is None:
                theta, *_ = np.linalg.lstsq(K, Zw[:, i], rcond=None)
                pinv_of = np.linalg.pinv
            else:
                Phi = K.copy()
                for s in range(1, rd + 1):
                    Phi[:, p_row - rd + s - 1] = -(rho**s) * instruments[idx, i]
                theta = np.linalg.solve(Phi.conj().T @ K, Phi.conj().T @ Zw[:, i])
                pinv_of = lambda K, Phi=Phi: np.linalg.solve(Phi.conj().T @ K, Phi.conj().T)  # noqa: E731
            out["G"][k, i] = theta[0 : nr * (rn + 1) : rn + 1]
            out["T"][k, i] = theta[nr * (rn + 1)] if rm >= 0 else 0.0  # Rm = -1: no T
            resid[i] = Zw[:, i] - K @ theta
            if not covariance:
                continue
            pinv = pinv_of(K)
            gain.append(pinv[0 : nr * (rn + 1) : rn + 1])
            proj.append(np.eye(2 * n + 1) - K @ pinv)
            d_coef = theta[p_row - rd :]  # d(r) = 1 + sum_s d_s rho^s (empty for the LPM)
            d_r = np.ones(2 * n + 1, dtype=complex)
            for s in range(1, rd + 1):
                d_r = d_r + d_coef[s - 1] * rho**s
            dwin.append(np.diag(d_r))
            Ks = K / np.linalg.norm(K, axis=0)
            out["singular"][k, i] = np.linalg.svd(Ks, compute_uv=False)
        raw = resid @ resid.conj().T  # raw[i, j] = sum_r r_i conj(r_j)
        out["residual_covariance"][k] = raw / dof
        if not covariance:
            continue
        # tau_ij = tr(D_j^H P_j^H P_i D_i) = sum of conj(P_j D_j) * (P_i D_i)
        pd = [proj[i] @ dwin[i] for i in range(nz)]
        tau = np.array([[np.sum(np.conj(pd[j]) * pd[i]) for j in range(nz)] for i in range(nz)])
        s = raw / tau
        out["residual_covariance"][k] = raw / dof
        out["tau"][k] = tau
        out["noise_covariance"][k] = s
        out["noise_variance"][k] = np.real(np.diag(s))
        gd = [gain[i] @ dwin[i] for i in range(nz)]  # g_i D_i
        for i in range(nz):
            for j in range(nz):
                out["G_cov"][k, i * nr : (i + 1) * nr, j * nr : (j + 1) * nr] = (
                    s[i, j] * gd[i] @ gd[j].conj().T
                )
    return out


def oracle_pooled_local_model(R, Z, half_width, degrees, bins=None, instruments=None):
    """Per-bin ``lstsq`` fit of ``E`` experiments stacked: shared ``G``, numerator and
    denominator, one transient term per experiment (block columns), written literally.

    ``R`` (E, M, nr), ``Z`` (E, M, nz), circular windows.  Returns ``G`` (M, nz, nr), ``T``
    (E, M, nz), ``noise_covariance`` (M, nz, nz), ``G_cov`` (M, nz nr, nz nr) and ``dof``
    ``E (2n + 1) - p`` with the same first-order formulas as :func:`oracle_local_model`
    over the stacked windows; ``instruments`` (E, M, nz) as in :func:`oracle_local_model`.
    """
    R = np.asarray(R, dtype=complex)
    Z = np.asarray(Z, dtype=complex)
    n_exp, m, nr = R.shape
    nz = Z.shape[2]
    rn, rm, rd = degrees
    n = half_width
    r = np.arange(-n, n + 1)
    rho = r / n
    w = 2 * n + 1
    p = nr * (rn + 1) + n_exp * (rm + 1) + rd
    dof = n_exp * w - p
    nan_c = complex(np.nan, np.nan)
    out = {"G": np.full((m, nz, nr), nan_c), "T": np.full((n_exp, m, nz), nan_c),
           "noise_covariance": np.full((m, nz, nz), nan_c),
           "G_cov": np.full((m, nz * nr, nz * nr), nan_c), "dof": dof}
    for k in range(m) if bins is None else bins:
        idx = (k + r) % m
        resid, gain, proj, dwin = [], [], [], []
        for i in range(nz):
            blocks = []
            for e in range(n_exp):
                cols = [R[e, idx, q] * rho**b for q in range(nr) for b in range(rn + 1)]
                for e2 in range(n_exp):  # experiment e2's transient: zero outside its rows
                    cols += [(rho**c + 0j) * (e2 == e) for c in range(rm + 1)]
                cols += [-(rho**s) * Z[e, idx, i] for s in range(1, rd + 1)]
                blocks.append(np.stack(cols, axis=1))
            K = np.concatenate(blocks, axis=0)
            zi = np.concatenate([Z[e, idx, i] for e in range(n_exp)])
            if instruments is None:
                theta, *_ = np.linalg.lstsq(K, zi, rcond=None)
                pinv = np.linalg.pinv(K)
            else:
                Phi = K.copy()
                zh = np.concatenate([instruments[e, idx, i] for e in range(n_exp)])
                rho_all = np.tile(rho, n_exp)
                for s in range(1, rd + 1):
                    Phi[:, p - rd + s - 1] = -(rho_all**s) * zh
                theta = np.linalg.solve(Phi.conj().T @ K, Phi.conj().T @ zi)
                pinv = np.linalg.solve(Phi.conj().T @ K, Phi.conj().T)
            out["G"][k, i] = theta[0: nr * (rn + 1): rn + 1]
            if rm >= 0:
                out["T"][:, k, i] = theta[nr * (rn + 1): nr * (rn + 1) + n_exp * (rm + 1)] \
                    .reshape(n_exp, rm + 1)[:, 0]
            resid.append(zi - K @ theta)
            gain.append(pinv[0: nr * (rn + 1): rn + 1])
            proj.append(np.eye(n_exp * w) - K @ pinv)
            d_r = np.ones(w, dtype=complex)
            for s in range(1, rd + 1):
                d_r = d_r + theta[p - rd + s - 1] * rho**s
            dwin.append(np.diag(np.tile(d_r, n_exp)))
        resid = np.array(resid)
        raw = resid @ resid.conj().T
        pd = [proj[i] @ dwin[i] for i in range(nz)]
        tau = np.array([[np.sum(np.conj(pd[j]) * pd[i]) for j in range(nz)] for i in range(nz)])
        sc = raw / tau
        out["noise_covariance"][k] = sc
        gd = [gain[i] @ dwin[i] for i in range(nz)]
        for i in range(nz):
            for j in range(nz):
                out["G_cov"][k, i * nr:(i + 1) * nr, j * nr:(j + 1) * nr] = \
                    sc[i, j] * gd[i] @ gd[j].conj().T
    return out


def resonant_system(m, nz, nr, *, damping=0.01, seed=0, noise=1e-3, bins_per_pole=None):
    """Spectra of a lightly damped, rational, MIMO system with a transient, on ``m`` bins.

    ``Z = G R + T + V``: ``G_ip(z) = b_ip(z) / a(z)``, ``T_i(z) = t_i(z) / a(z)`` (a real
    transient shares the system's denominator), ``z = exp(2j pi k / m)`` on the DFT grid,
    ``R`` random-phase with unit modulus, ``V`` circular complex Gaussian noise with
    standard deviation ``noise`` relative to the RMS of ``G R``.  Two resonances of the
    given damping make ``|Z|`` span about four decades.

    Returns ``R`` (m, nr), ``Z`` (m, nz), ``G`` (m, nz, nr) and ``T`` (m, nz) (noise-free).
    """
    rng = np.random.default_rng(seed)
    zk = np.exp(2j * np.pi * np.arange(m) / m)
    poles = []
    for w0 in (0.05 * 2 * np.pi, 0.21 * 2 * np.pi):
        rad = np.exp(-damping * w0)
        poles += [rad * np.exp(1j * w0), rad * np.exp(-1j * w0)]
    a = np.real(np.poly(poles))  # denominator coefficients in z^-1 (monic)
    zinv = zk[:, None] ** -np.arange(len(a))[None, :]
    den = zinv @ a
    nb = 3
    b = rng.standard_normal((nz, nr, nb)) * 0.05
    G = np.einsum("ipj,kj->kip", b, zinv[:, :nb]) / den[:, None, None]
    t = rng.standard_normal((nz, nb)) * 0.05
    T = np.einsum("ij,kj->ki", t, zinv[:, :nb]) / den[:, None] * np.sqrt(m)
    R = np.exp(2j * np.pi * rng.random((m, nr))) * np.sqrt(m)
    clean = np.einsum("kip,kp->ki", G, R) + T
    scale = noise * np.sqrt(np.mean(np.abs(clean) ** 2))
    V = scale * (rng.standard_normal((m, nz)) + 1j * rng.standard_normal((m, nz))) / np.sqrt(2)
    return R, clean + V, G, T


def continuous_resonance(k, nz, nr, *, seed=0, damping=0.05, center=None, width=None):
    """A system that is exactly rational in the bin index ``k`` (so in ``r``).

    ``G_ip(k) = (b0_ip + b1_ip s) / a(s)``, ``T_i(k) = (t0_i + t1_i s) / a(s)`` with
    ``s = j (k - center) / width`` and ``a(s) = s^2 + 2 zeta s + 1``: a second-order
    resonance (a continuous-time transfer function sampled on a frequency grid).  Over
    any window the local rational model with degrees ``(>=1, >=1, 2)`` is then exact.
    Returns ``G`` (len(k), nz, nr) and ``T`` (len(k), nz).
    """
    rng = np.random.default_rng(seed)
    k = np.asarray(k, dtype=float)
    center = k.mean() if center is None else center
    width = (k.max() - k.min()) / 8 if width is None else width
    s = 1j * (k - center) / width
    a = s**2 + 2 * damping * s + 1
    b = rng.standard_normal((2, nz, nr)) + 1j * rng.standard_normal((2, nz, nr))
    t = rng.standard_normal((2, nz)) + 1j * rng.standard_normal((2, nz))
    G = (b[0] + b[1] * s[:, None, None]) / a[:, None, None]
    T = (t[0] + t[1] * s[:, None]) / a[:, None]
    return G, T
