"""Output-error (maximum-likelihood) local rational model: a measurement prototype.

The production local rational model (:func:`lcmr_xr.kernels.local_models.local_model`)
solves the linearised problem ``D_i(r) Z_i(k + r) = N_i(r) R(k + r) + M_i(r) + e`` by least
squares, so the noisy ``Z_i`` sits among its regressors (the denominator columns ``-rho^s
Z_i``) and the estimate has an errors-in-variables bias (docs/uncertainty.md, "The local
model's covariance is right; the excess is a bias of its denominator").  This prototype
fits, per slow bin ``k`` and output row ``i``, the output-error criterion

    V_i(k) = sum_{r=-n..n} |Z_i(k + r) - (N_i(r) R(k + r) + M_i(r)) / D_i(r)|^2

(``D_i(r) = 1 + sum_s d_s rho^s``, ``rho = r / n``, the production basis and degrees), the
maximum-likelihood criterion for circular white noise on ``Z`` (Pintelon & Schoukens,
System Identification: A Frequency Domain Approach, 2nd ed. 2012), by Levenberg-Marquardt
steps started from the least-squares solution (optionally after Sanathanan-Koerner
re-weighting, which is not the output-error minimiser).  The noise then enters only
through the residual, not through the regressors.  ``G`` is ``N_i(0)``
(``D_i(0) = 1``), its covariance the first-order ``s_ij J_i^+ J_j^{+H}`` from the
Jacobians at the optimum (cross-row terms from the residual covariance).

Batched over bins (stacked small matrices, numpy linear algebra; chunks of bins, no loop
over single bins), a loop over the few output rows.  Spectra of real signals are fitted
on bins ``0..M/2`` and mirrored.  A measurement, not production code: it is not used by
the package.

What it measures (``--decomposition``, ``--coverage``, ``--cost``): the bias and variance
of ``G`` at a fixed excitation (as ``benchmarks/accuracy.py --decomposition``), the error
and the coverage of ``P``'s 95 % disc through the project's indirect step and band
(first-order band with the small-sample factor, and production's bound-form ``c_S``), and
the cost of one fit against one production ``local_model`` call.

Usage: ``python benchmarks/output_error_lrm.py [--decomposition] [--coverage] [--cost]
[--cases 1 2 5 9] [--seeds 4] [--half-width 30] [--records 30] [--iterations 20]
[--start ls|sk] [--noise disturbances|white]``; the numbers in docs/uncertainty.md ("The
output-error (maximum-likelihood) local rational model") are these defaults (``--seeds 2
--cases 2`` for ``--decomposition``).
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
import time
from pathlib import Path

import numpy as np

from lcmr_xr import hdd
from lcmr_xr.hdd.plants import FAST_PERIOD
from lcmr_xr.kernels.adaptive import K95, nonlinearity_factor, small_sample_factor
from lcmr_xr.kernels.identification import (_finish, _fit_blocks, experiment_spectra,
                                            slow_bin_terms, window_dof)
from lcmr_xr.kernels.local_models import hermitian, local_model

BANDS = ((0, 500), (500, 5000), (5000, 25200), (25200, 50400))
#: bins per chunk of the batched algebra (memory: chunk x nz x (2n+1) x p complex)
CHUNK = 256


def _accuracy():
    """benchmarks/accuracy.py as a module (read-only use of its helpers)."""
    spec = importlib.util.spec_from_file_location(
        "bench_accuracy", Path(__file__).resolve().parent / "accuracy.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


# --------------------------------------------------------------------------- the fit


def _windows(R, Z, bins, n):
    """Windowed data of ``bins``: ``Rw`` (B, w, nr), ``Zw`` (B, w, nz) (circular)."""
    m = R.shape[-2]
    idx = (np.asarray(bins)[:, None] + np.arange(-n, n + 1)) % m
    return R[idx, :], Z[idx, :]


def _basis(Rw, n, degrees):
    """Linear regressors ``Phi`` (B, w, nr (Rn+1) + Rm + 1) (``G`` = the first ``nr``
    columns' coefficients) and the denominator powers ``X`` (w, Rd)."""
    rn, rm, rd = degrees
    x = np.arange(-n, n + 1) / n
    cols = [Rw * (x ** s)[:, None] for s in range(rn + 1)]
    if rm >= 0:
        cols.append(np.broadcast_to(x[:, None] ** np.arange(rm + 1),
                                    Rw.shape[:-1] + (rm + 1,)).astype(complex))
    return np.concatenate(cols, axis=-1), x[:, None] ** np.arange(1, rd + 1)


def _lstsq(K, y):
    """Batched least squares ``min ||K t - y||`` for K (..., w, p), y (..., w) (QR with
    column scaling)."""
    c = np.linalg.norm(K, axis=-2)
    c = np.where(c > 0, c, 1.0)
    q, r = np.linalg.qr(K / c[..., None, :])
    t = np.linalg.solve(r, np.swapaxes(q, -1, -2).conj() @ y[..., None])[..., 0]
    return t / c


def _model(Phi, X, b, d):
    """``D`` (B, w) and the model ``(Phi b) / D``."""
    D = 1 + np.einsum("ws,bs->bw", X, d)
    return D, (Phi @ b[..., None])[..., 0] / D


def _jacobian(Phi, X, D, model):
    """d model / d theta (B, w, p + Rd): ``Phi / D`` and ``-rho^s model / D``."""
    return np.concatenate([Phi / D[..., None], -X[None] * (model / D)[..., None]], axis=-1)


def _reduced(Phi, X, z, d):
    """The linear parameters eliminated for a denominator ``d`` (B, Rd): ``D`` (B, w),
    the orthonormal basis ``Q`` of ``Phi / D``, ``b`` (B, p), the model and the residual."""
    D = 1 + np.einsum("ws,bs->bw", X, d)
    Q, Rr = np.linalg.qr(Phi / D[..., None])
    c = (np.swapaxes(Q, -1, -2).conj() @ z[..., None])
    model = (Q @ c)[..., 0]
    b = np.linalg.solve(Rr, c)[..., 0]
    return D, Q, b, model, z - model


def _oe_row(Phi, X, z, *, iterations, start="ls", sk_iterations=3, tol=1e-12):
    """Output-error fit of one output row on a chunk of bins.

    Variable projection (Golub & Pereyra 1973, with Kaufman's 1975 Jacobian): for a
    denominator ``d`` the numerator and transient coefficients are the linear least-squares
    solution of ``Phi / D``, and Levenberg-Marquardt steps act on ``d`` alone (``Rd``
    complex parameters) with the Jacobian ``P_perp (rho^s model / D)``; a step is kept
    only where it lowers the cost (per bin), the damping falls tenfold after a kept step
    and rises tenfold otherwise.  Stops after ``iterations`` steps or when no bin's cost
    falls by more than ``tol`` relative.  Returns ``theta`` (B, p + Rd), the residual
    (B, w), the least-squares start's ``theta``, its OE cost, and the number of steps."""
    nb, w, p = Phi.shape
    rd = X.shape[-1]
    K = np.concatenate([Phi, -X[None] * z[..., None]], axis=-1)
    theta_ls = _lstsq(K, z)  # the production linearised fit (equation error)
    d = theta_ls[:, p:]
    if start == "sk":  # Sanathanan-Koerner: weight by 1 / |D_prev|
        for _ in range(sk_iterations):
            D = 1 + np.einsum("ws,bs->bw", X, d)
            d = _lstsq(K / D[..., None], z / D)[:, p:]
    D_ls, _, _, _, e_ls = _reduced(Phi, X, z, theta_ls[:, p:])
    # the OE cost of the least-squares solution itself (its own b, not the projected one)
    mod_ls = (Phi @ theta_ls[:, :p, None])[..., 0] / D_ls
    cost_ls = np.sum(np.abs(z - mod_ls) ** 2, axis=-1)
    D, Q, b, model, e = _reduced(Phi, X, z, d)
    cost = np.sum(np.abs(e) ** 2, axis=-1)
    lam = np.full(nb, 1e-3)
    steps = 0
    for steps in range(1, iterations + 1):
        if rd == 0:
            break
        Mc = X[None] * (model / D)[..., None]  # d model / d d_s at fixed b, sign flipped
        Jr = Mc - Q @ (np.swapaxes(Q, -1, -2).conj() @ Mc)
        Jh = np.swapaxes(Jr, -1, -2).conj()
        A = Jh @ Jr
        g = (Jh @ e[..., None])[..., 0]
        c = np.sqrt(np.real(np.einsum("bii->bi", A)))
        c = np.where(c > 0, c, 1.0)
        As = A / (c[:, :, None] * c[:, None, :])
        step = -np.linalg.solve(As + lam[:, None, None] * np.eye(rd), (g / c)[..., None])[..., 0] / c
        t = _reduced(Phi, X, z, d + step)
        cost_t = np.sum(np.abs(t[4]) ** 2, axis=-1)
        ok = np.isfinite(cost_t) & (cost_t <= cost)
        gain = np.where(ok, (cost - cost_t) / np.where(cost > 0, cost, 1.0), 0.0)
        d = np.where(ok[:, None], d + step, d)
        D, Q, b, model, e = (np.where(ok.reshape((nb,) + (1,) * (x.ndim - 1)), x_t, x)
                             for x, x_t in zip((D, Q, b, model, e), t))
        cost = np.where(ok, cost_t, cost)
        lam = np.where(ok, lam / 10, lam * 10).clip(1e-12, 1e10)
        if np.all(gain < tol) and np.all(ok | (lam > 1e6)):
            break
    return np.concatenate([b, d], axis=-1), e, theta_ls, cost_ls, steps


def _d_min(X, theta, p):
    """min over the window of ``|D(r)|`` (B,)."""
    return np.min(np.abs(1 + np.einsum("ws,bs->bw", X, theta[:, p:])), axis=-1)


class OEFit(dict):
    """``G`` (M, nz, nr), ``G_cov`` (M, nz nr, nz nr) or None, ``T`` (M, nz),
    ``noise_covariance`` (M, nz, nz), ``cost`` and ``cost_ls`` (M, nz) (the OE criterion at
    the optimum and at the least-squares solution), ``d_min`` and ``d_min_ls`` (M, nz) (the
    smallest ``|D(r)|`` over the window, OE and least squares), ``G_ls`` (M, nz, nr) (the
    least-squares start, equal to production's ``local_model``)."""


def oe_local_model(R, Z, *, half_width, degrees=(3, 3, 3), iterations=60, start="ls",
                   covariance=True, chunk=CHUNK) -> OEFit:
    """Output-error local rational model at every slow bin (see the module docstring).

    ``R`` (M, nr), ``Z`` (M, nz), one record.  Spectra of real signals (``hermitian``) are
    fitted on bins ``0..M/2`` and mirrored, as ``local_model`` does.  ``iterations``
    Levenberg-Marquardt steps (a step is kept only where it lowers the cost, per bin and
    row); ``start``: ``"ls"`` (the least-squares solution) or ``"sk"`` (three
    Sanathanan-Koerner re-weightings of it first).  ``covariance``: the first-order
    ``cov(vec G)`` with cross-row terms, ``s_ij (J_i^+ J_j^{+H})`` restricted to ``G``'s
    coefficients, ``s_ij = sum_r e_i conj(e_j) / tr(P_i P_j)`` (``P`` the residual
    projector ``I - J J^+``: ``w - 2 p + ||Q_i^H Q_j||_F^2``).
    """
    R, Z = np.asarray(R, complex), np.asarray(Z, complex)
    m, nr = R.shape
    nz = Z.shape[-1]
    n = int(half_width)
    degrees = tuple(int(d) for d in degrees)
    half = hermitian(R[None]) and hermitian(Z[None])
    last = m // 2 + 1 if half else m
    p = nr * (degrees[0] + 1) + degrees[1] + 1
    q = p + degrees[2]
    out = OEFit(G=np.empty((m, nz, nr), complex), T=np.empty((m, nz), complex),
                G_ls=np.empty((m, nz, nr), complex), cost=np.empty((m, nz)),
                cost_ls=np.empty((m, nz)), d_min=np.empty((m, nz)), d_min_ls=np.empty((m, nz)),
                noise_covariance=np.empty((m, nz, nz), complex),
                G_cov=np.empty((m, nz * nr, nz * nr), complex) if covariance else None)
    w = 2 * n + 1
    for a in range(0, last, chunk):
        bins = np.arange(a, min(a + chunk, last))
        Rw, Zw = _windows(R, Z, bins, n)
        Phi, X = _basis(Rw, n, degrees)
        E = np.empty((bins.size, nz, w), complex)
        L = np.empty((bins.size, nz, nr, w), complex)
        Qs = []
        for i in range(nz):  # a few output rows
            theta, e, theta_ls, cost_ls, steps = _oe_row(Phi, X, Zw[..., i],
                                                         iterations=iterations, start=start)
            out["steps"] = max(out.get("steps", 0), steps)
            out["G"][bins, i] = theta[:, :nr]
            out["T"][bins, i] = theta[:, nr * (degrees[0] + 1)] if degrees[1] >= 0 else 0
            out["G_ls"][bins, i] = theta_ls[:, :nr]
            out["cost"][bins, i] = np.sum(np.abs(e) ** 2, axis=-1)
            out["cost_ls"][bins, i] = cost_ls
            out["d_min"][bins, i] = _d_min(X, theta, p)
            out["d_min_ls"][bins, i] = _d_min(X, theta_ls, p)
            E[:, i] = e
            if covariance:
                D, mod = _model(Phi, X, theta[:, :p], theta[:, p:])
                J = _jacobian(Phi, X, D, mod)
                Q, Rr = np.linalg.qr(J)
                pinv = np.linalg.solve(Rr, np.swapaxes(Q.conj(), -1, -2))  # (B, q, w)
                L[:, i] = pinv[:, :nr, :]
                Qs.append(Q)
        if covariance:
            tau = np.empty((bins.size, nz, nz))
            for i in range(nz):
                for j in range(nz):
                    tau[:, i, j] = w - 2 * q + np.sum(
                        np.abs(np.swapaxes(Qs[i], -1, -2).conj() @ Qs[j]) ** 2, axis=(-2, -1))
            s = (E @ np.swapaxes(E, -1, -2).conj()) / tau
            Lf = L.reshape(bins.size, nz * nr, w)
            C = (Lf @ np.swapaxes(Lf, -1, -2).conj()).reshape(bins.size, nz, nr, nz, nr)
            C = s[:, :, None, :, None] * C
            out["G_cov"][bins] = C.reshape(bins.size, nz * nr, nz * nr)
            out["noise_covariance"][bins] = s
        else:
            out["noise_covariance"][bins] = (E @ np.swapaxes(E, -1, -2).conj()) / (w - q)
    if half:  # bins M/2+1..M-1 mirrored
        src = np.arange((m - 1) // 2, 0, -1)
        dst = np.arange(m // 2 + 1, m)
        for k, v in out.items():
            if isinstance(v, np.ndarray):
                v[dst] = np.conj(v[src]) if v.dtype.kind == "c" else v[src]
    return out


# --------------------------------------------------------------------------- measurements


def _slow_band_masks(m, n_samples):
    f = np.arange(m) * hdd.FACTOR / (n_samples * FAST_PERIOD)
    fs = m * f[1]
    return [((f > lo) & (f < hi)) | ((f > fs - hi) & (f < fs - lo)) for lo, hi in BANDS[:3]]


def decomposition(*, case=2, excitation_seeds=(0, 1), records=30, n_samples=3600,
                  half_width=30, degrees=(3, 3, 3), iterations=60, start="ls", noise="disturbances"):
    """Bias and variance of ``G`` at a FIXED excitation for least squares and the OE fit,
    as ``benchmarks/accuracy.py --decomposition`` (``dG_j = G(Z0 + V_j) - G(Z0)`` over
    ``records`` disturbance records ``V_j``, simulation seeds ``1000 + j``; ``noise="white"``:
    circular white noise, per row the median over bins of the records' variance).  Returns
    ``{method: (seeds, band, 6)}`` medians over the band's bins and entries of
    ``[|dG|^2/G_var, var/G_var, bias^2/G_var, mse/G_var, mse/mse_LS, bias^2/G_var_LS]``
    (each method's own mean reported ``G_var``; the last column over least squares')."""
    m = n_samples // hdd.FACTOR
    acc = _accuracy()
    V = acc.disturbance_records(case=case, records=records, n_samples=n_samples)
    if noise == "white":
        nz = V.shape[-1]
        sd = np.sqrt(np.median(np.mean(np.abs(V) ** 2, axis=0), axis=0))
        g = np.random.default_rng(0).standard_normal((2,) + V.shape)
        V = acc._mirror(sd * (g[0] + 1j * g[1]) / np.sqrt(2))
        assert V.shape[-1] == nz
    sel = _slow_band_masks(m, n_samples)
    stats = {"least squares": [], "output error": []}
    for es in excitation_seeds:
        clean = hdd.simulate(n_samples, case=case, noise=False, seed=es)
        R, Z0 = experiment_spectra(clean.r.values, clean.u.values, clean.y.values,
                                   factor=hdd.FACTOR)
        ref = {"least squares": local_model(R, Z0, half_width=half_width, degrees=degrees,
                                            covariance=None).G,
               "output error": oe_local_model(R, Z0, half_width=half_width, degrees=degrees,
                                              iterations=iterations, start=start,
                                              covariance=False)["G"]}
        dG = {k: [] for k in stats}
        var_rep = {k: [] for k in stats}
        for v in V:
            ls = local_model(R, Z0 + v, half_width=half_width, degrees=degrees, covariance="diag")
            oe = oe_local_model(R, Z0 + v, half_width=half_width, degrees=degrees,
                                iterations=iterations, start=start)
            dG["least squares"].append(ls.G - ref["least squares"])
            var_rep["least squares"].append(ls.G_cov)
            dG["output error"].append(oe["G"] - ref["output error"])
            var_rep["output error"].append(
                np.real(np.einsum("kii->ki", oe["G_cov"])).reshape(oe["G"].shape))
        mse_ls = (np.abs(np.array(dG["least squares"])) ** 2).mean(axis=0)
        vr_ls = np.array(var_rep["least squares"]).mean(axis=0)
        for k in stats:
            d = np.array(dG[k])
            vr = np.array(var_rep[k]).mean(axis=0)
            z = np.abs(d) ** 2 / np.array(var_rep[k])
            bias, var = d.mean(axis=0), d.var(axis=0)
            b2 = np.abs(bias) ** 2 - var / records
            mse = (np.abs(d) ** 2).mean(axis=0)
            terms = [var / vr, b2 / vr, mse / vr, mse / mse_ls, b2 / vr_ls]
            stats[k].append([[np.median(z[:, s])] + [np.median(t[s]) for t in terms]
                             for s in sel])
        print(f"  excitation seed {es} done", file=sys.stderr, flush=True)
    return {k: np.array(v) for k, v in stats.items()}


def _terms_from_g(G, G_cov, *, nr, ill_posed):
    """The fitted terms ``_finish`` reads, from ``G`` and its full covariance (one record,
    all slow bins): as the kernel's block fit produces them."""
    t = slow_bin_terms(G, G_cov, nr=nr)
    m, nz = G.shape[0], G.shape[1]
    t.update({"G": G, "T": np.zeros((m, nz), complex), "noise_variance": np.zeros((m, nz)),
              "condition": np.ones(m), "ill_posed": ill_posed})
    return t


def coverage(*, cases=(1, 2, 5, 9), seeds=4, n_samples=3600, half_width=30, degrees=(3, 3, 3),
             iterations=60, start="ls"):
    """Median relative error of ``P`` and coverage of its 95 % disc per band and actuator
    for least squares (production's block fit) and the OE fit (its ``G`` and covariance
    through production's indirect step and band, :func:`_finish`): band forms ``"first
    order"`` (``c_dof^2 P_var_linear``, ``c_S = 1``) and ``"bound c_S"`` (production's
    ``P_var``); a flagged bin counts as covered, a bin whose ``P`` is not finite as missed
    (its fraction is returned; the error is the median over the finite ones).  Returns ``{method: {form or "error" or
    "flagged": (case, seed, band, input)}}``."""
    methods = ("least squares", "output error")
    keys = ("first order", "bound c_S", "error", "flagged", "P not finite")
    out = {k: {f: np.zeros((len(cases), seeds, len(BANDS), 2)) for f in keys} for k in methods}
    dof = window_dof(half_width, 4, degrees)
    c = small_sample_factor(dof)
    for ci, case in enumerate(cases):
        for seed in range(seeds):
            exp = hdd.simulate(n_samples, case=case, noise=True, seed=seed)
            R, Z = experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=hdd.FACTOR)
            nr = R.shape[-1]
            k = np.arange(n_samples // 2 + 1)
            f = k / (n_samples * float(exp.time[1] - exp.time[0]))
            truth = np.full((k.size, 1, nr // hdd.FACTOR), np.nan, dtype=complex)
            truth[1:] = hdd.true_frf(f[1:], case=case).values
            fit = _fit_blocks(R, Z, half_width=half_width, degrees=degrees, covariance=True,
                              noise_covariance=None, experiment_axis=None,
                              closed_loop="indirect")
            kw = dict(n_fast=n_samples, factor=hdd.FACTOR, nu=nr // hdd.FACTOR, ny=1,
                      closed_loop="indirect", dof=dof)
            res = {"least squares": _finish(fit, **kw)}
            oe = oe_local_model(R, Z, half_width=half_width, degrees=degrees,
                                iterations=iterations, start=start)
            res["output error"] = _finish(_terms_from_g(oe["G"], oe["G_cov"], nr=nr,
                                                        ill_posed=fit["ill_posed"]), **kw)
            for name, r in res.items():
                und = r["P_undetermined"][:, None, None]
                err2 = np.abs(r["P"] - truth) ** 2
                with np.errstate(divide="ignore", invalid="ignore"):
                    rel = np.sqrt(err2) / np.abs(truth)
                    forms = {"first order": np.where(und, np.inf, c ** 2 * r["P_var_linear"]),
                             "bound c_S": r["P_var"]}
                    for b, (lo, hi) in enumerate(BANDS):
                        sel = (f > max(lo, 0)) & (f < hi) & (k < k[-1])
                        for form, var in forms.items():
                            hit = (err2 <= K95 ** 2 * var)[:, 0]
                            out[name][form][ci, seed, b] = hit[sel].mean(axis=0)
                        out[name]["error"][ci, seed, b] = np.nanmedian(rel[sel, 0], axis=0)
                        out[name]["P not finite"][ci, seed, b] = np.mean(
                            ~np.isfinite(r["P"][sel, 0]), axis=0)
                        out[name]["flagged"][ci, seed, b] = und[sel, 0, 0].mean()
            print(f"  case {case} seed {seed} done", file=sys.stderr, flush=True)
    return out


def cost(*, windows=(12, 30, 45), n_samples=3600, repeats=1, iterations=60):
    """CPU time of one OE fit with covariance (``iterations`` steps, and 0 steps: the
    least-squares start, the Jacobian and the covariance alone) over one production
    ``local_model`` call (``covariance="full"``), alternating in this process; per window.
    Returns ``{window: (oe seconds, oe seconds at 0 steps, production seconds)}`` (minimum
    over ``repeats``; CPU time of all threads)."""
    exp = hdd.simulate(n_samples, case=2, noise=True, seed=0)
    R, Z = experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=hdd.FACTOR)
    local_model(R, Z, half_width=30)  # compile / load
    out = {}
    for w in windows:
        t = {"oe": [], "oe0": [], "lm": []}
        for _ in range(repeats):
            for key, fn in (("lm", lambda: local_model(R, Z, half_width=w, covariance="full")),
                            ("oe", lambda: oe_local_model(R, Z, half_width=w,
                                                          iterations=iterations)),
                            ("oe0", lambda: oe_local_model(R, Z, half_width=w, iterations=0))):
                t0 = time.process_time()
                fn()
                t[key].append(time.process_time() - t0)
        out[w] = (min(t["oe"]), min(t["oe0"]), min(t["lm"]))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--decomposition", action="store_true")
    ap.add_argument("--coverage", action="store_true")
    ap.add_argument("--cost", action="store_true")
    ap.add_argument("--cases", type=int, nargs="+", default=[1, 2, 5, 9])
    ap.add_argument("--seeds", type=int, default=4)
    ap.add_argument("--half-width", type=int, default=30)
    ap.add_argument("--records", type=int, default=30)
    ap.add_argument("--iterations", type=int, default=20)
    ap.add_argument("--start", default="ls", choices=["ls", "sk"])
    ap.add_argument("--noise", default="disturbances", choices=["disturbances", "white"])
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    if args.decomposition:
        st = decomposition(case=args.cases[0], excitation_seeds=range(args.seeds),
                           records=args.records, half_width=args.half_width,
                           iterations=args.iterations, start=args.start, noise=args.noise)
        print(f"G at a fixed excitation, case {args.cases[0]}, window {args.half_width}, "
              f"{args.records} records ({args.noise}), start {args.start}, {args.iterations} "
              "LM steps; medians over bins and entries, one column per excitation seed: "
              "z = |dG|^2/G_var, var, bias^2, mse over the method's G_var; mse/LS; "
              "bias^2 over least squares' G_var")
        for name, s in st.items():
            print(f"- {name}")
            for b, (lo, hi) in enumerate(BANDS[:3]):
                print(f"  {f'{lo}-{hi}':<12}" + "   ".join(
                    f"z {r[b, 0]:.2f} var {r[b, 1]:.2f} bias2 {r[b, 2]:.3f} mse {r[b, 3]:.2f} "
                    f"mse/LS {r[b, 4]:.2f} bias2/GvarLS {r[b, 5]:.3f}" for r in s))
    if args.coverage:
        cv = coverage(cases=args.cases, seeds=args.seeds, half_width=args.half_width,
                      iterations=args.iterations, start=args.start)
        print(f"P through the indirect step, cases {args.cases}, {args.seeds} seeds, window "
              f"{args.half_width}: coverage VCM/PZT mean (worst case); error: median; flagged")
        print(f"  {'method, form':<30}" + "".join(f"{f'{lo}-{hi} Hz':>26}" for lo, hi in BANDS))
        _accuracy().print_cover_forms(cv, 30)
    if args.cost:
        print(f"cost per fit, CPU s (load {open('/proc/loadavg').read().split()[0]})")
        for w, (a, a0, b) in cost(iterations=args.iterations).items():
            print(f"  window {w}: OE {args.iterations} steps {a:.2f} s, 0 steps {a0:.2f} s, "
                  f"local_model {b:.3f} s; ratios {a / b:.0f}x, {a0 / b:.0f}x")
    print(f"({time.perf_counter() - t0:.0f} s)")


if __name__ == "__main__":
    main()
