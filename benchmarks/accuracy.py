"""Accuracy and honesty of the FRF estimate on the HDD benchmark (issue 13's table).

Per band and actuator: median relative error ``|P_hat - P| / |P|`` (median over bins,
then over seeds), coverage of the 95 % disc ``|P_hat - P| <= sqrt(ln 20) P_std`` (a bin
flagged ``P_undetermined``, whose band is unbounded, counts as covered) and the flagged
fraction, for fixed window 30 and the default ``window="auto"``, each with the LRM's
denominator by least squares and by instrumental variables (``--denominator``); then the noiseless case
against the fixed-window sweep 12..60 (best fixed window per band); then the calibration of
the local model's own covariance (:func:`covariance_check`).

Usage: ``python benchmarks/accuracy.py [--seeds 10] [--cases 1-9] [--n-samples 3600]
[--denominator ls iv] [--band-forms] [--decomposition [--records 30] [--half-width 30]
[--degrees 3 3 3] [--denominator ls] [--instruments narrow] [--first-window 30]
[--noise VARIANT ...]] [--instrument-coverage [--first-window 30]] [--attribution]
[--cost [--repeats 5]] [--per-window] [--windows 30 12 auto]``.
``--band-forms`` prints only the coverage of candidate forms of the ``S^-1`` nonlinearity
factor (:func:`band_forms`); ``--decomposition`` only the bias / variance decomposition of
the local model's error at fixed excitations (:func:`covariance_decomposition`; with
``--denominator iv`` the instruments of ``--instruments``, :func:`build_instruments`);
``--instrument-coverage`` only the coverage of ``P``'s band per instrument kind and band
form at a fixed window (:func:`instrument_coverage`); ``--attribution`` only the error with
each disturbance alone (:func:`attribution`); ``--cost`` only the cost of ``window="auto"``
against one fixed-window fit (:func:`cost`, issue 13's bound 3x; the full run prints it last);
``--per-window`` only ``window="auto"``'s band table and, per band and chosen window, the
count of bins, flagged and unflagged, and the coverage of the unflagged bins
(:func:`window_tally`: a flagged bin counts as covered in the band table, so a small class
of released bins whose band lies hides in it; the full run prints this table too).
``--windows`` (half-widths or ``auto``) replaces the windows of the band tables (fixed 30
and auto; ``--per-window``: auto) and tallies each of them per window.
Prints progress to stderr; takes minutes (one identification per seed, case and setting).
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from lcmr_xr import hdd, identify
from lcmr_xr.demo import BANDS_HZ as BANDS, band_table
from lcmr_xr.hdd.plants import FAST_PERIOD
from lcmr_xr.kernels.adaptive import (K95, candidate_windows,
                                      second_order_factor, second_order_variance,
                                      small_sample_factor, weak_direction)
from lcmr_xr.kernels.closed_loop import frf_variance_from_first_row, indirect_first_row
from lcmr_xr.kernels.identification import (_block_plan, _positive_semidefinite,
                                            denominator_instruments,
                                            experiment_spectra, identify_spectra,
                                            identify_spectra_auto, twin_bins, window_dof)
from lcmr_xr.kernels.local_models import CovarianceBuffer, hermitian, local_model
from lcmr_xr.settings import auto_window_range
SWEEP = (12, 16, 20, 24, 30, 40, 60)


def band_stats(frf, truth):
    """(band, input, [median rel. error, coverage, flagged fraction]) for one estimate."""
    t = band_table(frf, truth).isel(output=0).transpose("band", "input")
    return np.stack([t.median_error.values, t.coverage.values, t.flagged.values], axis=-1)


def window_tally(frf, truth, tally=None) -> dict:
    """Add ``frf``'s bins per (band, chosen window) to ``tally`` (a new dict if None).

    Per key ``(band index, half-width)`` (the window chosen at each fast bin's slow bin,
    ``local_window``; DC and the fast Nyquist bin left out, as in the band table): ``bins``,
    ``flagged``, ``unflagged`` and ``covered`` (the unflagged bins whose 95 % disc holds the
    truth, per input).  The band table's coverage counts a flagged bin as covered; this
    shows what the released bins of each window promise.  Returns ``tally``.
    """
    tally = {} if tally is None else tally
    f = frf.frequency.values
    t = truth.values if hasattr(truth, "values") else np.asarray(truth)
    hit = (np.abs(frf.P.values - t) <= K95 * frf.P_std.values)[:, 0, :]
    flag = frf.P_undetermined.values
    m = frf.sizes["slow_frequency"]
    if "local_window" in frf:
        window = frf.local_window.values[np.arange(f.size) % m]
    else:  # a fixed window: the same at every bin
        window = np.full(f.size, int(frf.attrs["window"]))
    interior = (f > 0) & (f < f.max())
    for b, (lo, hi) in enumerate(BANDS):
        sel = interior & (f > lo) & (f < hi)
        for w in np.unique(window[sel]):
            at = sel & (window == w)
            row = tally.setdefault((b, int(w)), {"bins": 0, "flagged": 0, "unflagged": 0,
                                                 "covered": np.zeros(hit.shape[1], int)})
            row["bins"] += int(at.sum())
            row["flagged"] += int(flag[at].sum())
            row["unflagged"] += int((at & ~flag).sum())
            row["covered"] += hit[at & ~flag].sum(axis=0)
    return tally


def print_window_tally(title, tally):
    """Print :func:`window_tally`'s counts and the coverage of the unflagged bins."""
    print(title)
    print(f"  {'band (Hz)':<16}{'window':>7}{'bins':>8}{'flagged':>9}{'unflagged':>11}"
          f"{'cover unflagged VCM/PZT':>25}")
    for (b, w), r in sorted(tally.items()):
        c = r["covered"] / r["unflagged"] if r["unflagged"] else np.full(2, np.nan)
        print(f"  {f'{BANDS[b][0]:.0f}-{BANDS[b][1]:.0f}':<16}{w:>7}{r['bins']:>8}{r['flagged']:>9}"
              f"{r['unflagged']:>11}{f'{c[0]:.3f}/{c[1]:.3f}':>25}")


def run(settings, *, cases, seeds, n_samples, noise, disturbances=hdd.DISTURBANCES,
        tallies=None):
    """stats[setting] -> array (case, seed, band, input, 3).

    ``tallies``: a dict whose keys are settings; each gets the :func:`window_tally` of
    that setting's results over every case and seed."""
    stats = {name: [] for name in settings}
    for case in cases:
        per = {name: [] for name in settings}
        for seed in range(seeds):
            exp = hdd.simulate(n_samples, case=case, noise=noise, seed=seed,
                               disturbances=disturbances if noise else ())
            truth = None
            for name, setting in settings.items():
                window, denominator = setting if isinstance(setting, tuple) else (setting, None)
                frf = identify(exp, window=window, errors="ignore", denominator=denominator)
                if truth is None:  # DC left out: the VCM's double integrator is inf there
                    truth = hdd.true_frf(frf.frequency[1:], case=case).reindex(frequency=frf.frequency)
                per[name].append(band_stats(frf, truth))
                if tallies is not None and name in tallies:
                    tallies[name] = window_tally(frf, truth, tallies[name])
        for name in settings:
            stats[name].append(per[name])
        print(f"  case {case} done", file=sys.stderr, flush=True)
    return {k: np.array(v) for k, v in stats.items()}


def covariance_check(*, case, seeds, n_samples, half_width=30, degrees=(3, 3, 3),
                     denominator="ls"):
    """Median of ``|dG|^2 / G_var`` per slow band and entry of ``G`` (ln 2 = 0.69 if calibrated).

    ``dG = G(disturbances on) - G(disturbances off)`` with the same excitation (``hdd.simulate``
    keeps it when ``noise`` is switched): the error the disturbances cause in the local-model
    estimate, the noiseless model error cancelling to first order (it is 1e-3 of the noise
    error above 500 Hz).  ``G_var`` is the kernel's first-order variance from the residuals.
    For a circular Gaussian error with a correct variance the ratio is ``Exp(1)``, median
    ``ln 2``; above ``ln 2`` the local model understates its own noise.  Slow bins ``m`` and
    ``M - m`` (the same fast frequencies folded) are pooled; band edges in fast Hz below the
    slow Nyquist frequency.  ``denominator``: ``"ls"`` or ``"iv"`` (identify's).  Returns
    (band, nz, nr) medians.
    """
    ratios = {b: [] for b in BANDS[:3]}
    for seed in range(seeds):
        noisy = hdd.simulate(n_samples, case=case, noise=True, seed=seed)
        clean = hdd.simulate(n_samples, case=case, noise=False, seed=seed)
        fits = [identify_spectra(*experiment_spectra(e.r.values, e.u.values, e.y.values,
                                                     factor=hdd.FACTOR),
                                 n_fast=e.sizes["time"], factor=hdd.FACTOR, nu=e.sizes["input"],
                                 half_width=half_width, degrees=degrees, denominator=denominator)
                for e in (noisy, clean)]
        z = np.abs(fits[0]["G"] - fits[1]["G"]) ** 2 / fits[0]["G_var"]
        m = z.shape[0]
        f = np.arange(m) / (m * float(noisy.slow_time[1] - noisy.slow_time[0]))
        fs = m * f[1]
        for lo, hi in ratios:
            sel = ((f > lo) & (f < hi)) | ((f > fs - hi) & (f < fs - lo))
            ratios[(lo, hi)].append(z[sel])
    return np.array([np.median(np.concatenate(v), axis=0) for v in ratios.values()])


def _slow_bands(m, n_samples):
    """Masks of the slow bins per band of ``BANDS[:3]`` (bins ``m`` and ``M - m`` pooled)."""
    f = np.arange(m) * hdd.FACTOR / (n_samples * FAST_PERIOD)
    fs = m * f[1]
    return [((f > lo) & (f < hi)) | ((f > fs - hi) & (f < fs - lo)) for lo, hi in BANDS[:3]]


def _mirror(X):
    """Spectra of a real signal from bins ``0..M/2`` of ``X`` (..., M, c): ``X(M - k) =
    conj(X(k))``, bins 0 and ``M/2`` real (as the lifted spectra of real records are)."""
    m = X.shape[-2]
    k = np.arange(m)
    out = np.where((k <= m // 2)[:, None], X, np.conj(X[..., (m - k) % m, :]))
    out[..., 0, :] = out[..., 0, :].real
    if m % 2 == 0:
        out[..., m // 2, :] = out[..., m // 2, :].real
    return out


#: Instrument builders of the decomposition's ``denominator="iv"``: ``"narrow"``, today's
#: :func:`denominator_instruments` (the same LRM fitted in the narrow window
#: :func:`first_fit_window`); ``"lrm"``, the same with the first fit in the window
#: ``first_window``; ``"lpm"``, the prediction of an LPM first stage (degrees ``(Rn, Rm,
#: 0)``) in the window ``first_window``; ``"jackknife"``, that prediction with its own bin
#: left out (:func:`jackknife_instruments`); ``"jackknife lrm"``, the same with the LRM
#: first stage (per-row leverage).
INSTRUMENTS = ("narrow", "lrm", "lpm", "jackknife", "jackknife lrm")


def build_instruments(R, Z, kind, *, degrees=(3, 3, 3), first_window=30):
    """The instruments ``kind`` of :data:`INSTRUMENTS` (None: least squares)."""
    if kind is None:
        return None
    if kind in ("narrow", "lrm"):
        return denominator_instruments(R, Z, degrees=degrees,
                                       half_width=None if kind == "narrow" else first_window)
    return jackknife_instruments(R, Z, degrees=degrees, first_window=first_window,
                                 jackknife=kind.startswith("jackknife"),
                                 first="lrm" if kind == "jackknife lrm" else "lpm")


def centre_leverage(R, half_width, degrees=(3, 3), Z=None):
    """Leverage ``h(k) = a_0^T (A^H A)^-1 conj(a_0)`` of the centre bin of the local
    regression at every bin ``k`` (circular windows ``r = -n..n``), the diagonal entry of
    the hat matrix ``A (A^H A)^-1 A^H`` at ``r = 0``: ``A`` has the rows ``[R(k + r)^T x^s,
    x^t]``, ``x = r / n``, ``s = 0..Rn``, ``t = 0..Rm`` (the LPM, the same for every output
    row), and with ``Rd = degrees[2] > 0`` and ``Z`` the LRM's denominator columns ``-x^d
    Z_i(k + r)``, ``d = 1..Rd`` (one regression per output row ``i``; they vanish at ``r =
    0``, so ``a_0`` holds no ``Z``).  The leverage does not depend on the polynomial basis
    (only on the span).  ``R`` (M, nr), ``Z`` (M, nz); returns (M,) for the LPM, (M, nz)
    for the LRM, batched over bins (reduced QR, ``h = |Q[r = 0]|^2``)."""
    R = np.asarray(R)
    m, nr = R.shape[-2:]
    n = int(half_width)
    rn, rm = tuple(degrees)[:2]
    rd = tuple(degrees)[2] if len(tuple(degrees)) > 2 else 0
    x = np.arange(-n, n + 1) / n
    idx = (np.arange(m)[:, None] + np.arange(-n, n + 1)) % m
    Rw = R[idx, :]  # (M, w, nr)
    A = (Rw[..., None] * (x[:, None] ** np.arange(rn + 1))[:, None, :]).reshape(
        Rw.shape[:-1] + (nr * (rn + 1),))
    if rm >= 0:
        A = np.concatenate([A, np.broadcast_to(x[:, None] ** np.arange(rm + 1),
                                               A.shape[:-1] + (rm + 1,)).astype(A.dtype)], axis=-1)
    if rd < 1:
        return (np.abs(np.linalg.qr(A)[0][..., n, :]) ** 2).sum(axis=-1)
    Zw = np.asarray(Z)[idx, :]  # (M, w, nz)
    h = np.empty(Zw.shape[::2])
    for i in range(Zw.shape[-1]):  # one regression per output row (a few rows)
        D = -Zw[..., i, None] * x[:, None] ** np.arange(1, rd + 1)
        Q = np.linalg.qr(np.concatenate([A, D], axis=-1))[0]
        h[:, i] = (np.abs(Q[..., n, :]) ** 2).sum(axis=-1)
    return h


def jackknife_instruments(R, Z, *, degrees=(3, 3, 3), first_window=30, jackknife=True,
                          first="lpm"):
    """Instruments for the denominator from a first stage in the window ``first_window``:
    ``first="lpm"`` an LPM (degrees ``(Rn, Rm, 0)``), ``"lrm"`` the LRM ``degrees``; its
    prediction ``Zhat(k) = G1(k) R(k) + T1(k)`` at the centre bin, and with ``jackknife``
    the leave-one-out prediction ``(Zhat(k) - h(k) Z(k)) / (1 - h(k))``
    (:func:`centre_leverage`), which does not contain the noise of bin ``k`` (jackknife IV:
    Phillips & Hale 1977; Angrist, Imbens & Krueger 1999).  The first fit is linear least
    squares in its regressors and the centre row ``a_0`` holds no ``Z`` (the LRM's
    denominator columns vanish at ``r = 0``), so the leave-one-out identity is exact (for
    the LRM with the other bins' ``Z`` in the regressors, per output row).
    Conjugate-symmetrised like :func:`denominator_instruments` when ``Z`` is the spectrum
    of real signals; non-finite predictions fall back to ``Z``.  ``R`` (M, nr), ``Z`` (M,
    nz) (no batch dims)."""
    R, Z = np.asarray(R), np.asarray(Z)
    deg = (degrees[0], degrees[1], 0) if first == "lpm" else tuple(degrees)
    fit = local_model(R, Z, half_width=first_window, degrees=deg, covariance=None)
    zhat = np.einsum("...mip,...mp->...mi", fit.G, R) + fit.T
    if jackknife:
        h = centre_leverage(R, first_window, deg, Z=Z)
        h = h[..., None] if h.ndim == 1 else h
        zhat = (zhat - h * Z) / (1 - h)
    zhat = np.where(np.isfinite(zhat), zhat, Z)
    m = zhat.shape[-2]
    if not hermitian(Z.reshape(-1, m, Z.shape[-1])):
        return zhat
    return (zhat + np.conj(np.take(zhat, (-np.arange(m)) % m, axis=-2))) / 2


#: Noise of the decomposition (:func:`covariance_decomposition`): the benchmark's
#: disturbances themselves, and circular Gaussian noise with their per-bin covariance, with
#: that covariance averaged over the local window, and white (per row constant).
NOISE_VARIANTS = ("disturbances", "Gaussian, per-bin covariance",
                  "Gaussian, window-averaged covariance", "white")


def disturbance_records(*, case, records, n_samples):
    """(records, M, nz) lifted spectra ``Z`` of the benchmark's disturbances alone: the
    difference of a record with and without them (simulation seeds ``1000 + j``).  They do
    not depend on the excitation (the loop is linear), so one set serves every excitation."""
    V = []
    for j in range(records):
        on = hdd.simulate(n_samples, case=case, noise=True, seed=1000 + j)
        off = hdd.simulate(n_samples, case=case, noise=False, seed=1000 + j)
        V.append(experiment_spectra(on.r.values, on.u.values, on.y.values, factor=hdd.FACTOR)[1]
                 - experiment_spectra(off.r.values, off.u.values, off.y.values,
                                      factor=hdd.FACTOR)[1])
    return np.array(V)


def covariance_decomposition(*, case=2, excitation_seeds=(0,), records=30, n_samples=3600,
                             half_width=30, degrees=(3, 3, 3), variants=NOISE_VARIANTS,
                             seed=0, denominator="ls", instruments="narrow", first_window=30):
    """Bias and variance of the local model's error at a FIXED excitation.

    The loop is linear, so the disturbances' part of the lifted output spectra, ``V = Z(on)
    - Z(off)`` (``hdd.simulate`` with and without disturbances, same seed), does not depend
    on the excitation: ``records`` independent disturbance records (simulation seeds
    ``1000 + j``) are added to the noiseless spectra ``Z0`` of each excitation seed, and
    ``dG_j = G(Z0 + V_j) - G(Z0)`` is the error the disturbances cause (``denominator``:
    ``"ls"``, least squares, the one-record default, or ``"iv"``, instrumental variables
    from each fit's own data: ``instruments`` one of :data:`INSTRUMENTS`, ``first_window``
    the LPM first stage's half-width).  Per slow bin and entry of ``G``, over the records: the bias
    ``mean_j dG_j`` (its square less ``var / records``, the sampling part), the variance
    ``var_j dG_j`` and the mean squared error, each over the kernel's mean reported
    variance ``G_var``; and ``|dG|^2 / G_var`` (median ``ln 2`` if calibrated).  The other
    noise variants (:data:`NOISE_VARIANTS`) replace ``V_j`` by circular Gaussian draws
    with the records' own per-bin covariance across the lifted rows (no inter-bin
    correlation, no leakage), with that covariance averaged over ``2 n + 1`` bins (no
    heteroscedasticity within the window), or white with per row the median over bins
    of its variance.  Returns ``{variant: (seeds, band, 4)}`` medians over the band's bins
    and entries of ``[|dG|^2/G_var, var/G_var, bias^2/G_var, mse/G_var, mse/mse_LS]`` and
    ``{variant: (seeds, M, nz, nr)}`` biases (for their agreement across excitations).
    """
    m = n_samples // hdd.FACTOR
    V = disturbance_records(case=case, records=records, n_samples=n_samples)
    nz = V.shape[-1]
    C = np.einsum("jki,jkl->kil", V, V.conj()) / records  # per-bin covariance (M, nz, nz)
    w = 2 * half_width + 1
    Cw = sum(np.roll(C, s, axis=0) for s in range(-half_width, half_width + 1)) / w

    def factor(Cm):
        lam, U = np.linalg.eigh(Cm)
        return U * np.sqrt(np.clip(lam, 0, None))[..., None, :]

    Ls = {"Gaussian, per-bin covariance": factor(C),
          "Gaussian, window-averaged covariance": factor(Cw),
          "white": np.sqrt(np.median(np.einsum("kii->ki", C).real, axis=0))[None, :, None]
          * np.eye(nz)}
    rng = np.random.default_rng(seed)
    draws = {"disturbances": V}
    for name in variants:
        if name != "disturbances":
            g = (rng.standard_normal((records, m, nz)) + 1j * rng.standard_normal((records, m, nz)))
            draws[name] = _mirror(np.einsum("kil,jkl->jki", np.broadcast_to(Ls[name], C.shape),
                                            g / np.sqrt(2)))
    sel = _slow_bands(m, n_samples)
    stats = {name: [] for name in variants}
    biases = {name: [] for name in variants}
    for es in excitation_seeds:
        clean = hdd.simulate(n_samples, case=case, noise=False, seed=es)
        R, Z0 = experiment_spectra(clean.r.values, clean.u.values, clean.y.values, factor=hdd.FACTOR)
        def fit(Z, covariance):
            iv = build_instruments(R, Z, instruments if denominator == "iv" else None,
                                   degrees=degrees, first_window=first_window)
            return local_model(R, Z, half_width=half_width, degrees=degrees,
                               covariance=covariance, instruments=iv)

        G0 = fit(Z0, None).G
        G0_ls = local_model(R, Z0, half_width=half_width, degrees=degrees, covariance=None).G
        for name in variants:
            fits = [fit(Z0 + v, "diag") for v in draws[name]]
            dG = np.array([fit.G for fit in fits]) - G0
            mse_ls = np.mean([np.abs(local_model(R, Z0 + v, half_width=half_width,
                                                 degrees=degrees, covariance=None).G - G0_ls) ** 2
                              for v in draws[name]], axis=0) if denominator == "iv" else None
            var_rep = np.array([fit.G_cov for fit in fits])
            z = np.abs(dG) ** 2 / var_rep
            bias, var = dG.mean(axis=0), dG.var(axis=0)
            vr = var_rep.mean(axis=0)
            terms = [var / vr, (np.abs(bias) ** 2 - var / records) / vr,
                     (np.abs(dG) ** 2).mean(axis=0) / vr]
            ls = (np.ones_like(vr) if mse_ls is None
                  else (np.abs(dG) ** 2).mean(axis=0) / mse_ls)
            stats[name].append([[np.median(z[:, s])] + [np.median(t[s]) for t in terms]
                                + [np.median(ls[s])] for s in sel])
            biases[name].append(bias)
    return ({k: np.array(v) for k, v in stats.items()},
            {k: np.array(v) for k, v in biases.items()})


def print_decomposition(stats, biases, *, case, records, half_width, degrees, n_samples,
                        denominator="ls"):
    print(f"local-model error at a fixed excitation, case {case}, window {half_width}, degrees "
          f"{tuple(degrees)}, denominator {denominator}, {records} records per excitation seed: medians over "
          "bins and entries of |dG|^2/G_var (ln 2 = 0.69 if calibrated) and of var, bias^2, "
          "mse over G_var (1, 0, 1 if calibrated and unbiased); iv: median of mse / least squares' mse")
    for name, s in stats.items():
        print(f"- {name} (one column per excitation seed)")
        b = biases[name]
        for i, ((lo, hi), sel) in enumerate(zip(BANDS[:3], _slow_bands(b.shape[1], n_samples))):
            line = f"  {f'{lo:.0f}-{hi:.0f}':<12}" + "   ".join(
                f"z {row[i, 0]:.2f} var {row[i, 1]:.2f} bias2 {row[i, 2]:.2f} mse {row[i, 3]:.2f}"
                + (f" mse/LS {row[i, 4]:.2f}" if row[i, 4] != 1 else "")
                for row in s)
            if len(b) > 1:  # two excitations of one design: the same bias?
                x, y = b[0][sel].ravel(), b[1][sel].ravel()
                line += (f"   bias correlation seeds 0/1 "
                         f"{abs(np.vdot(x, y)) / np.linalg.norm(x) / np.linalg.norm(y):.2f}")
            print(line)


def _band_terms(R, Z, *, half_width, n_fast, degrees=(3, 3, 3)):
    """Per fast bin ``0..N/2`` of one window's least-squares fit: first-order variance,
    exact second-order variance (:func:`second_order_variance`), ``rho``, ``rho_v`` and
    the small-sample factor (the pieces ``recover_frf`` combines)."""
    nr, nu = R.shape[-1], R.shape[-1] // hdd.FACTOR
    fit = local_model(R, Z, half_width=half_width, degrees=degrees, covariance="full")
    G, C = fit.G, fit.G_cov
    ind = indirect_first_row(G, nr, C)
    # as production (kernels.identification._mend_indefinite): where cov(P_1) is not a
    # covariance, G_cov from the noise covariance mended
    V = ind.first_row_cov
    ok = np.all(np.isfinite(V), axis=(-2, -1))
    bad = ok & (np.linalg.eigvalsh(np.where(ok[..., None, None], V, np.eye(V.shape[-1])))[..., 0] < 0)
    if bad.any():
        C = np.where(bad[..., None, None], _positive_semidefinite(C, fit.noise_covariance), C)
        ind = indirect_first_row(G, nr, C)
    m = G.shape[-3]
    bins = np.arange(n_fast // 2 + 1)
    var_lin = frf_variance_from_first_row(ind.first_row_cov, n_fast, hdd.FACTOR, bins,
                                          Z.shape[-1] - nr, nu)
    rho, rho_v = weak_direction(G[..., :nr, :], C[..., : nr * nr, : nr * nr])
    S_inv = np.linalg.inv(np.where(ind.singular[..., None, None], np.eye(nr), G[..., :nr, :]))
    var2 = second_order_variance(S_inv, ind.first_row, C, ind.first_row_cov, n_fast=n_fast,
                                 factor=hdd.FACTOR, bins=bins)
    dof = small_sample_factor(window_dof(half_width, nr, degrees))
    slow = bins % m
    return var_lin, var2, rho[slow, None, None], rho_v[slow, None, None], dof


#: Forms of the band's variance (before the model-error term) from the pieces of
#: :func:`_band_terms`: production's second-order factor of ``window="auto"`` with a
#: least-squares denominator (:func:`lcmr_xr.kernels.adaptive.second_order_factor`), the
#: bound form of ``c_S`` (production before session 12, and of fixed windows) and the
#: measured alternatives (docs/uncertainty.md, "Why 5-25 kHz needs the conservative c_S",
#: "The denominator's bias from a Hausman comparison").  Every form gets production's
#: ``P_bias``, which holds the denominator's bias.
BAND_FORMS = {
    "second order (production)": lambda v, v2, q, rv: v * (1 + 2 * (q / K95 / (1 - q)) ** 2),
    "bound c_S": lambda v, v2, q, rv: v * (1 + K95 * rv / (1 - q)) ** 2,
    "no c_S": lambda v, v2, q, rv: v,
    "variance form": lambda v, v2, q, rv: v * (1 + (rv / (1 - q)) ** 2),
    "exact 2nd order": lambda v, v2, q, rv: v + v2 / (1 - q) ** 2,
    "bound, exact 2nd": lambda v, v2, q, rv: (np.sqrt(v) + K95 * np.sqrt(v2) / (1 - q)) ** 2,
}


def band_forms(*, cases, seeds, n_samples, degrees=(3, 3, 3)):
    """Coverage of the 95 % disc per band for every form of :data:`BAND_FORMS`.

    ``window="auto"`` (least squares): the production choice of window and its model-error
    term ``P_bias`` are kept; each candidate window is refitted with the kernels to get the
    pieces of the band, gathered per slow bin at the chosen window, and the band
    ``c_dof^2 form + P_bias^2`` is evaluated (``inf`` where undetermined).  Checks on the
    way that the second-order form reproduces the production ``P_var`` (so the pieces are
    the production ones).  Returns form -> (case, seed, band, input) coverage.
    """
    out = {name: np.zeros((len(cases), seeds, len(BANDS), 2)) for name in BAND_FORMS}
    for ci, case in enumerate(cases):
        for seed in range(seeds):
            exp = hdd.simulate(n_samples, case=case, noise=True, seed=seed)
            R, Z = experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=hdd.FACTOR)
            nr, m = R.shape[-1], R.shape[-2]
            windows = candidate_windows(*auto_window_range(degrees, nr, m))
            auto = identify_spectra_auto(R, Z, n_fast=n_samples, factor=hdd.FACTOR,
                                         nu=nr // hdd.FACTOR, windows=windows, degrees=degrees)
            k = np.arange(n_samples // 2 + 1)
            pick = np.searchsorted(windows, auto["window"])[k % m]
            terms = [_band_terms(R, Z, half_width=w, n_fast=n_samples, degrees=degrees)
                     for w in windows]
            v, v2, rho, rho_v, dof = (np.take_along_axis(
                np.stack([np.broadcast_to(t[i], terms[0][0].shape) for t in terms]),
                pick[None, :, None, None], axis=0)[0] for i in range(5))
            und = auto["P_undetermined"][:, None, None]
            bias2 = auto["P_bias"] ** 2
            with np.errstate(divide="ignore", invalid="ignore"):
                q = K95 * rho
                check = np.where(und, np.inf,
                                 dof ** 2 * v * second_order_factor(rho)[0] ** 2 + bias2)
                ok = np.isfinite(auto["P_var"])
                np.testing.assert_allclose(check[ok], auto["P_var"][ok], rtol=1e-6)
                f = k / (n_samples * float(exp.time[1] - exp.time[0]))
                truth = np.full(auto["P"].shape, np.nan, dtype=complex)
                truth[1:] = hdd.true_frf(f[1:], case=case).values
                err2 = np.abs(auto["P"] - truth) ** 2
                for name, form in BAND_FORMS.items():
                    var = np.where(und, np.inf, dof ** 2 * form(v, v2, q, rho_v) + bias2)
                    hit = (err2 <= K95 ** 2 * var)[:, 0]
                    for b, (lo, hi) in enumerate(BANDS):
                        sel = (f > max(lo, 0)) & (f < hi) & (k < k[-1])
                        out[name][ci, seed, b] = hit[sel].mean(axis=0)
        print(f"  case {case} done", file=sys.stderr, flush=True)
    return out


#: Instrument settings of :func:`instrument_coverage`: (denominator, instruments).
IV_SETTINGS = {"ls": ("ls", None), "iv narrow": ("iv", "narrow"), "iv lrm": ("iv", "lrm"),
               "iv lpm": ("iv", "lpm"), "iv jackknife": ("iv", "jackknife"),
               "iv jackknife lrm": ("iv", "jackknife lrm")}
#: Band forms of :func:`instrument_coverage` from the fit's pieces (``v`` the linear
#: variance, ``q = K95 rho``, ``rv = rho_v``, ``c`` the small-sample factor).
IV_BAND_FORMS = {
    "linear (P_var_linear)": lambda v, q, rv, c: v,
    "c_dof^2 linear": lambda v, q, rv, c: c ** 2 * v,
    "variance form c_S": lambda v, q, rv, c: c ** 2 * v * (1 + (rv / (1 - q)) ** 2),
    "bound c_S (P_var)": lambda v, q, rv, c: c ** 2 * v * (1 + K95 * rv / (1 - q)) ** 2,
}


def instrument_coverage(*, cases, seeds, n_samples, half_width=30, degrees=(3, 3, 3),
                        first_window=30, settings=tuple(IV_SETTINGS)):
    """Coverage of the 95 % disc of ``P`` at a fixed window for each denominator estimate
    of :data:`IV_SETTINGS` (least squares and the instruments of :func:`build_instruments`,
    the first stages in ``first_window``) and each band form of
    :data:`IV_BAND_FORMS`, the median relative error, and the flagged fraction (the
    production flag; a flagged bin counts as covered).  Fits through the kernel's own
    pipeline (``_fit_blocks`` / ``_finish``, the instruments passed in).  Returns
    ``{setting: {form or "error" or "flagged": (case, seed, band, input)}}``."""
    from lcmr_xr.kernels.identification import _finish, _fit_blocks
    out = {k: {f: np.zeros((len(cases), seeds, len(BANDS), 2))
               for f in (*IV_BAND_FORMS, "error", "flagged")} for k in settings}
    for ci, case in enumerate(cases):
        for seed in range(seeds):
            exp = hdd.simulate(n_samples, case=case, noise=True, seed=seed)
            R, Z = experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=hdd.FACTOR)
            nr, m = R.shape[-1], R.shape[-2]
            k = np.arange(n_samples // 2 + 1)
            f = k / (n_samples * float(exp.time[1] - exp.time[0]))
            truth = np.full((k.size, 1, nr // hdd.FACTOR), np.nan, dtype=complex)
            truth[1:] = hdd.true_frf(f[1:], case=case).values
            c = small_sample_factor(window_dof(half_width, nr, degrees))
            for name in settings:
                denominator, kind = IV_SETTINGS[name]
                iv = build_instruments(R, Z, kind, degrees=degrees, first_window=first_window)
                fit = _fit_blocks(R, Z, half_width=half_width, degrees=degrees, covariance=True,
                                  noise_covariance=None, experiment_axis=None,
                                  closed_loop="indirect", denominator=denominator,
                                  instruments=iv)
                res = _finish(fit, n_fast=n_samples, factor=hdd.FACTOR, nu=nr // hdd.FACTOR,
                              ny=1, closed_loop="indirect", dof=window_dof(half_width, nr, degrees))
                und = res["P_undetermined"][:, None, None]
                q = K95 * fit["rho"][k % m, None, None]
                rv = fit["rho_v"][k % m, None, None]
                v = res["P_var_linear"]
                err2 = np.abs(res["P"] - truth) ** 2
                with np.errstate(divide="ignore", invalid="ignore"):
                    check = np.where(und, np.inf, IV_BAND_FORMS["bound c_S (P_var)"](v, q, rv, c))
                    ok = np.isfinite(res["P_var"])
                    np.testing.assert_allclose(check[ok], res["P_var"][ok], rtol=1e-6)
                    rel = np.sqrt(err2) / np.abs(truth)
                    for form, fn in IV_BAND_FORMS.items():
                        hit = (err2 <= K95 ** 2 * np.where(und, np.inf, fn(v, q, rv, c)))[:, 0]
                        for b, (lo, hi) in enumerate(BANDS):
                            sel = (f > max(lo, 0)) & (f < hi) & (k < k[-1])
                            out[name][form][ci, seed, b] = hit[sel].mean(axis=0)
                            out[name]["error"][ci, seed, b] = np.median(rel[sel, 0], axis=0)
                            out[name]["flagged"][ci, seed, b] = und[sel, 0, 0].mean()
        print(f"  case {case} done", file=sys.stderr, flush=True)
    return out


def attribution(*, cases, seeds, n_samples, windows=(30, "auto")):
    """stats[(disturbances, window)] -> (case, seed, band, input, 3): each disturbance alone.

    The benchmark's disturbances switched on one at a time (same realisations as the full
    benchmark, ``hdd.simulate(..., disturbances=[...])``), none and all, for each of
    ``windows`` (default 30 and ``auto``): which of them makes the estimate wrong in which band.
    """
    subsets = [(), *[(d,) for d in hdd.DISTURBANCES], hdd.DISTURBANCES]
    out = {}
    for sub in subsets:
        label = " + ".join(sub) if sub else "none"
        stats = run({w: w for w in windows}, cases=cases, seeds=seeds, n_samples=n_samples,
                    noise=bool(sub), disturbances=sub)
        for window, st in stats.items():
            out[(label, window)] = st
    return out


def print_table(title, s):
    """s: (case, seed, band, input, 3)."""
    print(title)
    print(f"  {'band (Hz)':<15}{'VCM err':>9}{'PZT err':>9}{'cover VCM':>11}{'cover PZT':>11}"
          f"{'worst case VCM/PZT':>20}{'best case VCM/PZT':>19}{'flagged':>9}")
    for b, (lo, hi) in enumerate(BANDS):
        med = np.median(s[:, :, b, :, 0], axis=(0, 1))
        cov = s[:, :, b, :, 1].mean(axis=(0, 1))
        per_case = s[:, :, b, :, 1].mean(axis=1)
        worst, best = per_case.min(axis=0), per_case.max(axis=0)  # over plant cases
        flag = s[:, :, b, 0, 2].mean()
        print(f"  {f'{lo:.0f}-{hi:.0f}':<15}{med[0]:>9.3g}{med[1]:>9.3g}{cov[0]:>11.3f}{cov[1]:>11.3f}"
              f"{f'{worst[0]:.3f}/{worst[1]:.3f}':>20}{f'{best[0]:.3f}/{best[1]:.3f}':>19}"
              f"{flag:>9.3f}")



def _print_cover_row(label: str, width: int, mean, worst) -> None:
    """One row of a per-band table: ``VCM/PZT mean (worst case)`` for each band."""
    print(f"  {label:<{width}}" + "".join(
        f"{f'{mean[b, 0]:.3f}/{mean[b, 1]:.3f} ({worst[b, 0]:.3f}/{worst[b, 1]:.3f})':>26}"
        for b in range(len(BANDS))))

def print_cover_forms(cover, width: int) -> None:
    """Rows of ``{setting: {form: (case, seed, band, input)}}``: coverage mean (worst case)
    per form, and for the form ``"error"`` the median (both columns)."""
    for name, forms in cover.items():
        for form, c in forms.items():
            if form == "error":
                mean = worst = np.median(c, axis=(0, 1))
            else:
                mean, worst = c.mean(axis=(0, 1)), c.mean(axis=1).min(axis=0)
            _print_cover_row(f"{name}, {form}", width, mean, worst)


def cost(*, n_samples=3600, case=2, seed=0, repeats=5, denominators=("ls", "iv")):
    """Cost of ``identify(window="auto")`` against ``identify(window=30)`` (both with
    ``P_std``, the default covariance), timed alternately in this process: best of
    ``repeats`` in CPU seconds (``time.process_time``, every thread of the process) and
    wall seconds, per ``denominators``.  Also the floor set by the local-model fits that
    ``auto`` (least squares) needs whatever else it does: each candidate window fitted
    with its covariance on the bins the blocks fit, and the widest window again by IV with
    that candidate's own prediction as instruments at the slow bins of ``twin_bins`` (the
    Hausman comparison), their covariance in one ``CovarianceBuffer`` as ``auto`` has it,
    against the same ``identify(window=30)``.

    Returns
    -------
    dict
        ``(setting, denominator) -> (cpu, wall)`` best times, settings ``30``, ``"auto"``
        and, for least squares, ``"fits"`` (the sum of those local-model fits).
    """
    exp = hdd.simulate(n_samples, case=case, seed=seed)
    R, Z = experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=hdd.FACTOR)
    nr, m = R.shape[-1], R.shape[-2]
    windows = candidate_windows(*auto_window_range((3, 3, 3), nr, m))
    zhat = denominator_instruments(R, Z, half_width=windows[-1])

    def fits():  # (their covariance in one buffer, as auto fits them)
        buffers = CovarianceBuffer()
        for w in windows:
            stop = _block_plan(R, Z, half_width=w, degrees=(3, 3, 3), covariance=True,
                               noise_covariance=None, experiment_axis=None,
                               instruments=None)["edges"][-1]
            local_model(R, Z, half_width=w, covariance="full", bins=(0, stop), buffers=buffers)
        local_model(R, Z, half_width=windows[-1], covariance="full", instruments=zhat,
                    bins=(0, stop), select=twin_bins(m), buffers=buffers)

    calls = {(w, d): (lambda w=w, d=d: identify(exp, window=w, errors="ignore", denominator=d))
             for w in (30, "auto") for d in denominators}
    if "ls" in denominators:
        calls["fits", "ls"] = fits
    for f in calls.values():  # first calls (compiled code loaded)
        f()
    times = {k: [] for k in calls}
    for _ in range(repeats):
        for k, f in calls.items():
            c, w = time.process_time(), time.perf_counter()
            f()
            times[k].append((time.process_time() - c, time.perf_counter() - w))
    return {k: tuple(np.min(v, axis=0)) for k, v in times.items()}


def print_cost(best, repeats):
    """Print :func:`cost`'s ratios."""
    import os

    for d in sorted({d for _, d in best}):
        a, f = best["auto", d], best[30, d]
        print(f"cost, denominator {d}: auto / fixed window 30 = {a[0] / f[0]:.2f}x CPU "
              f"({a[0] * 1e3:.0f} ms vs {f[0] * 1e3:.0f} ms), {a[1] / f[1]:.2f}x wall "
              f"(best of {repeats}, alternating; issue 13's bound 3x)")
        if ("fits", d) in best:
            k = best["fits", d]
            print(f"  of which the local-model fits auto needs (candidates with covariance, "
                  f"the widest by IV) alone: {k[0] / f[0]:.2f}x CPU ({k[0] * 1e3:.0f} ms)")
    if ("auto", "iv") in best and ("auto", "ls") in best:
        print(f"  denominator iv / ls: window 30 {best[30, 'iv'][0] / best[30, 'ls'][0]:.2f}x, "
              f"auto {best['auto', 'iv'][0] / best['auto', 'ls'][0]:.2f}x CPU")
    print(f"  load average {os.getloadavg()[0]:.1f} (2 cores shared: compare within the run)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--cases", default="1-9", help="plant cases, e.g. 1-9 or 2")
    ap.add_argument("--n-samples", type=int, default=3600)
    ap.add_argument("--noiseless-seeds", type=int, default=3)
    ap.add_argument("--band-forms", action="store_true",
                    help="only the coverage of the candidate forms of the S^-1 factor")
    ap.add_argument("--decomposition", action="store_true",
                    help="only the bias / variance decomposition of the local model's error at "
                         "fixed excitations (case: the first of --cases; --seeds excitation seeds)")
    ap.add_argument("--records", type=int, default=30,
                    help="disturbance records per excitation for --decomposition")
    ap.add_argument("--half-width", type=int, default=30,
                    help="local window half-width n for --decomposition")
    ap.add_argument("--degrees", type=int, nargs=3, default=[3, 3, 3],
                    help="local-model degrees Rn Rm Rd for --decomposition")
    ap.add_argument("--denominator", nargs="+", default=["ls", "iv"], choices=["ls", "iv"],
                    help="how the LRM denominator is estimated (default: both, one table each; "
                         "--decomposition takes the first)")
    ap.add_argument("--instruments", default="narrow", choices=INSTRUMENTS,
                    help="instruments of --decomposition --denominator iv (and rows of "
                         "--instrument-coverage): today's narrow LRM first fit, an LRM or LPM "
                         "first stage in --first-window, or their leave-one-out (jackknife) forms")
    ap.add_argument("--first-window", type=int, default=30,
                    help="half-width of the first stage of --instruments lrm / lpm / jackknife")
    ap.add_argument("--instrument-coverage", action="store_true",
                    help="only the coverage of P's band at window --half-width for least squares "
                         "and every kind of --instruments (first stages in --first-window)")
    ap.add_argument("--noise", nargs="+", default=list(NOISE_VARIANTS), choices=NOISE_VARIANTS,
                    metavar="VARIANT", help="noise variants of --decomposition (default: all; "
                    f"of {NOISE_VARIANTS})")
    ap.add_argument("--attribution", action="store_true",
                    help="only the error per band with each disturbance alone (none, each, all) "
                         "for window 30 and auto")
    ap.add_argument("--cost", action="store_true",
                    help="only the cost of window='auto' against one fixed-window fit (CPU and "
                         "wall, alternating in this process)")
    ap.add_argument("--repeats", type=int, default=5, help="timings per setting of --cost")
    ap.add_argument("--cost-seeds", type=int, nargs="+", default=[0],
                    help="seeds of hdd.simulate for --cost, one measurement each (default: 0)")
    ap.add_argument("--per-window", action="store_true",
                    help="only window='auto' with the disturbances: the band table, then per "
                         "band and chosen window the number of bins, flagged and unflagged, and "
                         "the coverage of the unflagged bins (the full run prints it too)")
    ap.add_argument("--windows", nargs="+", default=[],
                    help="the windows of the band tables and the per-window tallies "
                         "(half-widths or auto; default: 30 and auto, --per-window: auto)")
    args = ap.parse_args(argv)
    if args.cost:
        for seed in args.cost_seeds:
            print(f"seed {seed}:")
            print_cost(cost(n_samples=args.n_samples, seed=seed, repeats=args.repeats,
                            denominators=tuple(args.denominator)), args.repeats)
        return
    lo, _, hi = args.cases.partition("-")
    cases = list(range(int(lo), int(hi or lo) + 1))
    t0 = time.perf_counter()
    if args.attribution:
        table = attribution(cases=cases, seeds=args.seeds, n_samples=args.n_samples)
        print(f"HDD benchmark, N = {args.n_samples}, cases {args.cases}, {args.seeds} seeds, "
              "disturbances one at a time: median relative error VCM/PZT per band; coverage "
              "of the 95 % disc VCM/PZT (flagged = covered) and the flagged fraction below 500 Hz")
        print(f"  {'disturbances, window':<34}" + "".join(
            f"{f'{lo:.0f}-{hi:.0f} Hz':>18}" for lo, hi in BANDS) + f"{'cover <500':>14}{'flag':>7}")
        for (label, window), s in table.items():
            med = np.median(s[..., 0], axis=(0, 1))
            cover = s[:, :, 0, :, 1].mean(axis=(0, 1))
            print(f"  {f'{label}, {window}':<34}" + "".join(
                f"{f'{med[b, 0]:.3g}/{med[b, 1]:.3g}':>18}" for b in range(len(BANDS)))
                + f"{f'{cover[0]:.2f}/{cover[1]:.2f}':>14}{s[:, :, 0, 0, 2].mean():>7.2f}")
        print(f"({time.perf_counter() - t0:.0f} s; machine shared with other jobs)")
        return
    if args.decomposition:
        stats, biases = covariance_decomposition(
            case=cases[0], excitation_seeds=range(args.seeds), records=args.records,
            n_samples=args.n_samples, half_width=args.half_width, degrees=tuple(args.degrees),
            denominator=args.denominator[0], instruments=args.instruments,
            first_window=args.first_window, variants=tuple(args.noise))
        iv = "" if args.denominator[0] == "ls" else (
            f" ({args.instruments}" + ("" if args.instruments == "narrow"
                                       else f", first window {args.first_window}") + ")")
        print_decomposition(stats, biases, case=cases[0], records=args.records,
                            half_width=args.half_width, denominator=args.denominator[0] + iv,
                            degrees=args.degrees, n_samples=args.n_samples)
        print(f"({time.perf_counter() - t0:.0f} s; machine shared with other jobs)")
        return
    if args.instrument_coverage:
        cover = instrument_coverage(cases=cases, seeds=args.seeds, n_samples=args.n_samples,
                                    half_width=args.half_width, degrees=tuple(args.degrees),
                                    first_window=args.first_window)
        print(f"HDD benchmark, N = {args.n_samples}, disturbances on, cases {args.cases}, "
              f"{args.seeds} seeds, window {args.half_width}, first-stage window "
              f"{args.first_window}: coverage of the 95 % disc VCM/PZT per band form (flagged = "
              "covered), mean (worst case); median relative error; flagged fraction")
        print(f"  {'setting / form':<32}" + "".join(f"{f'{lo:.0f}-{hi:.0f} Hz':>26}"
                                                    for lo, hi in BANDS))
        print_cover_forms(cover, 32)
        print(f"({time.perf_counter() - t0:.0f} s; machine shared with other jobs)")
        return
    if args.band_forms:
        cover = band_forms(cases=cases, seeds=args.seeds, n_samples=args.n_samples)
        print(f"HDD benchmark, N = {args.n_samples}, disturbances on, cases {args.cases}, "
              f"{args.seeds} seeds, window auto (least squares): coverage of the 95 % disc "
              "VCM/PZT per form of the S^-1 factor, mean (worst case)")
        print(f"  {'form':<20}" + "".join(f"{f'{lo:.0f}-{hi:.0f} Hz':>26}" for lo, hi in BANDS))
        for name, c in cover.items():
            mean, worst = c.mean(axis=(0, 1)), c.mean(axis=1).min(axis=0)
            _print_cover_row(name, 20, mean, worst)
        print(f"({time.perf_counter() - t0:.0f} s; machine shared with other jobs)")
        return
    named = [("auto", "auto") if w == "auto" else (f"fixed window {w}", int(w))
             for w in args.windows]
    windows = tuple(named) if args.windows else (
        (("auto", "auto"),) if args.per_window else (("fixed window 30", 30), ("auto", "auto")))
    tallies = {f"{name}, denominator {d}": None for d in args.denominator
               for name, _ in windows if args.windows or name == "auto"}
    noisy = run({f"{name}, denominator {d}": (w, d) for d in args.denominator
                 for name, w in windows}, cases=cases,
                seeds=args.seeds, n_samples=args.n_samples, noise=True, tallies=tallies)
    print(f"HDD benchmark, N = {args.n_samples}, disturbances on, cases {args.cases}, "
          f"{args.seeds} seeds; coverage of the 95 % disc (flagged = covered)")
    for name, s in noisy.items():
        print_table(f"- {name}", s)
    for name, tally in tallies.items():
        print_window_tally(f"- {name}, per chosen window: bins, flagged, unflagged, and the "
                           "coverage of the unflagged bins", tally)
    if args.per_window:
        print(f"({time.perf_counter() - t0:.0f} s; machine shared with other jobs)")
        return
    clean = run({**{f"fixed {w}": w for w in SWEEP}, "auto": "auto"}, cases=[2],
                seeds=args.noiseless_seeds, n_samples=args.n_samples, noise=False)
    print(f"noiseless, case 2, {args.noiseless_seeds} seeds: median relative error per band "
          "(VCM/PZT), and auto / best fixed window")
    med = {k: np.median(v[..., 0], axis=(0, 1)) for k, v in clean.items()}
    best = np.min([med[f"fixed {w}"] for w in SWEEP], axis=0)
    for k, m in med.items():
        print(f"  {k:<10}" + "".join(f"{m[b, 0]:>10.2g}/{m[b, 1]:<8.2g}" for b in range(len(BANDS))))
    ratio = med["auto"] / best
    print("  auto/best " + "".join(f"{ratio[b, 0]:>10.2f}/{ratio[b, 1]:<8.2f}" for b in range(len(BANDS))))
    for d in args.denominator:
        ratio = covariance_check(case=2, seeds=args.seeds, n_samples=args.n_samples, denominator=d)
        print(f"local-model covariance, denominator {d}, case 2, window 30, {args.seeds} seeds: "
              "median |dG|^2/G_var (ln 2 = 0.69 when calibrated), rows S then PS, over the 4 "
              "lifted inputs")
        for (lo, hi), r in zip(BANDS, ratio):
            print(f"  {f'{lo:.0f}-{hi:.0f}':<12}" + "  ".join(
                "/".join(f"{x:.2f}" for x in row) for row in r))
    print(f"({time.perf_counter() - t0:.0f} s; machine shared with other jobs)")
    # cost: auto against one fixed-window fit, same process
    print_cost(cost(n_samples=args.n_samples, repeats=args.repeats,
                    denominators=tuple(args.denominator)), args.repeats)


if __name__ == "__main__":
    main()
