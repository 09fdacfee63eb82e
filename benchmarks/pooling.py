"""Issue 14 goals that pooling periods and window 0 can measure today (phase 1).

Prints, on the HDD benchmark (case 2, N = 3600, F = 2, the paper's LRM window 30,
degrees 3-3-3):

1. Variance of ``P`` in 500-25 200 Hz against the number of averaged steady-state periods
   ``K = 1, 2, 4, 8`` (noise on the output only, white or the benchmark's fan vibration;
   the same multisine in every run, new noise per seed; one period dropped as transient):
   the slope of log(variance) against log(K) (goal -1 within 20 %), with the variance
   summarised over the band's bins by the mean and by the median.
2. The nonparametric noise variance (spread over periods) against the residual one of
   the local model, in the same band (goal: within 20 %): ratio of the band means and
   median over bins of the ratio.
3. Window 0: ``E = F nu = 4`` noiseless periodic experiments with different multisines,
   ``G = Z R^+`` bin by bin: the largest relative error of ``P`` at every bin the
   experiments determine (goal 1e-9), and the time against identifying the experiments
   one by one with the local model (same process, shared machine: ratios only).

4. Experiments with different multisines pooled in ONE local model
   (``combine="experiment"``, shared ``G``, a transient each; one transient-laden period
   each, white output noise): the variance slope over ``E = 1, 2, 4, 8`` in the same band
   (goal -1 within 20 %).
5. The benchmark disturbances (``hdd.simulate`` with noise), ``window="auto"``: median
   relative error below 500 Hz of 8 experiments pooled against one experiment (goal: 2.5x
   lower) and the coverage of the 95 % discs per band (goal 90-99 % in every band; a
   flagged bin, whose band is unbounded, counts as covered), with the fraction of bins
   flagged undetermined and the median factor the split halves put on the pooled
   covariance (``spread_calibration``) and the median factor of the halves' ``P`` on its band
   (``P_spread_calibration``, VCM/PZT); the goal lines say met or NOT met.
   ``--first-group g`` starts at group ``g`` (seeds ``500 + 8 g + e``);
   ``--band-forms`` prints instead the pooled coverage per form of the ``S^-1`` factor
   (:data:`BAND_FORMS`), each from the same pooled fit per group (:func:`pooled_band_forms`);
   ``--decompose`` the coverage of the band built from each of its ingredients at
   production's window choice (:func:`pooled_band_decomposition`), with the error the split
   halves share against the truth and the candidate bias terms ``b2_W`` (chosen window
   against the pilot) and, with ``--hausman``, ``b2_H`` (pooled least squares against IV);
   ``--circular-fan`` measures a variant of the decomposition;
   ``--instruments-without-own-transient``, ``--second-order-c-s`` and
   ``--noise-covariance-as-estimated`` variants of the estimator and band (with or without
   ``--decompose``).
6. Window 0 exactness for F = 3 (a SISO loop, E = F nu + 1 = 4 experiments).
7. Cost: 64 experiments of N = 3600 pooled in one local model against identifying them
   one by one (one call over the experiment dim, and a loop of calls), window 30.

Run: ``python benchmarks/pooling.py [--seeds 12] [--noise white fan]`` (about 3 minutes
per noise kind on one core, a few more for 4-7).
"""

from __future__ import annotations

import argparse
import contextlib
import sys
import time
import warnings

import numpy as np
import xarray as xr

import lcmr_xr
from lcmr_xr import conventions as cv, hdd
from lcmr_xr.kernels.adaptive import (K95, UNDETERMINED_LIMIT, denominator_bias,
                                      noise_share, nonlinearity_factor, second_order_variance,
                                      select_windows,
                                      small_sample_factor, weak_direction)
from lcmr_xr.kernels.closed_loop import frf_variance_from_first_row, indirect_first_row
from lcmr_xr.kernels.lifting import frf_from_first_block_row
from lcmr_xr.kernels.pooling import half_variances, p_spread_factor, spread_calibration
from lcmr_xr.simulation import simulate_closed_loop

N, CASE, WINDOW, DEGREES = 3600, 2, 30, (3, 3, 3)
BAND = (500.0, 25200.0)
COUNTS = (1, 2, 4, 8)
#: white output noise with the standard deviation of the fan vibration (3.0 nm)
WHITE_STD = 3.0e-9


def _output_noise(kind: str, n: int, rng) -> np.ndarray:
    if kind == "fan":  # the benchmark's output disturbance: lightly damped modes (tau ~ 20 ms)
        return hdd.fan_vibration(n, rng)
    return WHITE_STD * rng.standard_normal(n)


def _hdd_periods(r: xr.DataArray, periods: int, seed: int, kind: str) -> xr.Dataset:
    """The HDD loop, ``periods`` periods of ``r``, noise on the output (one record)."""
    d_y = _output_noise(kind, periods * N, np.random.default_rng(seed))
    d_y = xr.DataArray(d_y.reshape(periods, N, 1), dims=("period", "time", "output"),
                       attrs={"units": "m"})
    return simulate_closed_loop(hdd.plant(CASE), hdd.controller(), hdd.notch_filters(), hdd.FACTOR,
                                r, d_y=d_y, outputs=list(hdd.OUTPUTS), periods=periods)


def variance_against_periods(seeds: int, kind: str):
    """Per-bin variance of P over seeds for each K, and the noise estimates at K = 8."""
    r = hdd.simulate(N, noise=False, seed=0).r  # one multisine for every run
    estimates = {k: [] for k in COUNTS}
    noise = {"np_y": [], "res_y": [], "np_u": [], "res_u": []}
    band = slow_band = None
    for seed in range(seeds):
        # the first 1 + K periods of one 9-period run are a (1 + K)-period experiment
        ds = _hdd_periods(r, 1 + max(COUNTS), 100 + seed, kind)
        for k in COUNTS:
            frf = lcmr_xr.identify(ds.isel(period=slice(0, 1 + k)), window=WINDOW,
                                   degrees=DEGREES, transient_periods=1)
            if band is None:
                f, sf = frf.frequency.values, frf.slow_frequency.values
                band = (f >= BAND[0]) & (f <= BAND[1])
                slow_band = (sf >= BAND[0]) & (sf <= BAND[1])
            estimates[k].append(frf.P.values[band])
            if k == max(COUNTS):
                noise["np_y"].append(frf.period_noise_variance_y.values[slow_band])
                noise["res_y"].append(frf.noise_variance_y.values[slow_band])
                noise["np_u"].append(frf.period_noise_variance_u.values[slow_band])
                noise["res_u"].append(frf.noise_variance_u.values[slow_band])
        print(f"  {kind}: seed {seed + 1}/{seeds}", flush=True)
    var = {k: np.var(np.array(v), axis=0, ddof=1)[:, 0, :] for k, v in estimates.items()}
    return var, {name: np.array(v) for name, v in noise.items()}


def print_slopes(var, what: str):
    """Slope of log(variance) against log(count), per input and summary over bins."""
    k = np.log(np.array(COUNTS, dtype=float))
    for i, name in enumerate(hdd.INPUTS):
        for label, summary in (("mean over bins", np.mean), ("median over bins", np.median)):
            v = np.array([summary(var[c][:, i]) for c in COUNTS])
            slope = np.polyfit(k, np.log(v), 1)[0]
            cells = " ".join(f"{v[j] / v[0]:.3f}" for j in range(len(COUNTS)))
            print(f"   {name} {label:17s}: slope {slope:+.3f};  var({what})/var(1) = {cells}  "
                  f"(1/{what} = {' '.join(f'{1 / c:.3f}' for c in COUNTS)})")


def report_variance(kind: str, var, noise):
    print(f"\n1. [{kind} output noise] variance of P in {BAND[0]:g}-{BAND[1]:g} Hz against "
          f"averaged periods K = {COUNTS} (goal: slope -1 +- 0.2)")
    print_slopes(var, "K")
    print(f"2. [{kind} output noise] nonparametric / residual noise variance in the band, "
          f"K = {max(COUNTS)} (goal 0.8-1.2)")
    for rows in ("y", "u"):
        np_v, res_v = noise[f"np_{rows}"], noise[f"res_{rows}"]
        of_means = np_v.mean() / res_v.mean()
        per_bin = np.median(np_v.mean(axis=0) / res_v.mean(axis=0))
        print(f"   {rows}: ratio of band means {of_means:.3f};  median over bins of the ratio "
              f"{per_bin:.3f}")


def window0_exactness():
    exps = xr.concat([hdd.simulate(N, noise=False, seed=s, periods=5) for s in range(4)],
                     "experiment")
    start = time.perf_counter()
    frf = lcmr_xr.identify(exps, window=0, combine="experiment", transient_periods=3,
                           covariance=False)
    t_pooled = time.perf_counter() - start
    start = time.perf_counter()
    lcmr_xr.identify(exps.isel(period=-1, drop=True), window=WINDOW, degrees=DEGREES)
    t_one_by_one = time.perf_counter() - start
    ok = ~frf.P_flag.values
    k = np.flatnonzero(ok)
    m = N // hdd.FACTOR
    truth = hdd.true_frf(k / (N * hdd.FAST_PERIOD), case=CASE).values
    partner = hdd.true_frf(np.where(k < m, k + m, k - m) / (N * hdd.FAST_PERIOD), case=CASE).values
    err = np.abs(frf.P.values[ok] - truth)
    rel = err / np.abs(truth)
    # the recovery combines bins k and k +- M (they alias onto one slow bin): an error
    # relative to the larger of the two is what double precision can promise
    normwise = err / np.maximum(np.abs(truth), np.abs(partner))
    return rel, normwise, frf.frequency.values[ok], frf.sizes["frequency"], t_pooled, t_one_by_one


def variance_against_experiments(seeds: int):
    """Per-bin variance of P over seeds for E experiments pooled in one local model."""
    counts = COUNTS
    rs = [hdd.simulate(N, noise=False, seed=e).r for e in range(max(counts))]  # E multisines
    estimates = {e: [] for e in counts}
    band = None
    for seed in range(seeds):
        runs = [_hdd_periods(r, 1, 1000 * seed + e, "white").isel(period=0, drop=True)
                for e, r in enumerate(rs)]
        for e in counts:
            ds = xr.concat(runs[:e], "experiment") if e > 1 else runs[0]
            frf = lcmr_xr.identify(ds, window=WINDOW, degrees=DEGREES,
                                   combine="experiment" if e > 1 else None)
            if band is None:
                f = frf.frequency.values
                band = (f >= BAND[0]) & (f <= BAND[1])
            estimates[e].append(frf.P.values[band])
        print(f"  experiments: seed {seed + 1}/{seeds}", flush=True)
    return {e: np.var(np.array(v), axis=0, ddof=1)[:, 0, :] for e, v in estimates.items()}


def report_experiments(var):
    print(f"\n4. [white output noise] variance of P in {BAND[0]:g}-{BAND[1]:g} Hz against E = "
          f"{COUNTS} experiments (different multisines) in one local model (goal: slope -1 +- 0.2)")
    print_slopes(var, "E")


def disturbances_pooled(groups: int, n_exp: int = 8, denominators=("ls", "iv"),
                        first_group: int = 0):
    """Median relative error per band and coverage: ``n_exp`` pooled against one, for each
    way of estimating the LRM's denominator (least squares, instrumental variables)."""
    from lcmr_xr.demo import BANDS_HZ, band_table

    stats = {(name, d): [] for d in denominators for name in ("pooled", "one")}
    for g in range(first_group, first_group + groups):
        exps = [hdd.simulate(N, case=CASE, seed=500 + n_exp * g + e) for e in range(n_exp)]
        for d in denominators:
            pooled = lcmr_xr.identify(xr.concat(exps, "experiment"), combine="experiment",
                                      errors="ignore", denominator=d)
            truth = hdd.true_frf(pooled.frequency[1:], case=CASE).reindex(frequency=pooled.frequency)
            one = lcmr_xr.identify(exps[0], errors="ignore", denominator=d)
            for name, frf in (("pooled", pooled), ("one", one)):
                t = band_table(frf, truth).isel(output=0).transpose("band", "input")
                f = frf.frequency.values
                # per band: bins flagged undetermined, and the pooled covariance's factor
                # from the split halves (median over the band's slow bins; 1 for one record)
                extra = []
                for lo, hi in BANDS_HZ:
                    sel = (f >= lo) & (f < hi) & (f > 0)
                    flagged = frf.P_undetermined.values[sel].mean()
                    cal = frf.get("spread_calibration")
                    sf = frf.slow_frequency.values
                    c = 1.0 if cal is None else np.median(cal.values[(sf >= lo) & (sf < hi) & (sf > 0)])
                    # the halves' factor on the band of P, median per input (1 for one record)
                    pcal = frf.get(cv.P_SPREAD_CALIBRATION)
                    pc = [1.0, 1.0] if pcal is None else np.median(pcal.values[sel, 0], axis=0)
                    extra.append([[flagged, c, pc[0]], [flagged, c, pc[1]]])
                stats[name, d].append(np.concatenate(
                    [np.stack([t.median_error.values, t.coverage.values], axis=-1),
                     np.array(extra)], axis=-1))
        print(f"  disturbances: group {g} ({g - first_group + 1}/{groups})", flush=True)
    return BANDS_HZ, {k: np.array(v) for k, v in stats.items()}


def report_disturbances(bands, stats, n_exp=8):
    denominators = list(dict.fromkeys(d for _, d in stats))
    groups = stats["pooled", denominators[0]].shape[0]
    print(f"\n5. benchmark disturbances, window 'auto': {n_exp} experiments pooled vs one "
          f"({groups} groups; goal: error below 500 Hz >= 2.5x lower, coverage 0.90-0.99 per band)")
    for d in denominators:
        print(f"   denominator={d!r}")
        print(f"   {'band (Hz)':<15}" + "".join(f"{h:>11}" for h in (
            "err 1 VCM", "err 8 VCM", "ratio", "err 1 PZT", "err 8 PZT", "ratio", "cov 8 VCM",
            "cov 8 PZT", "cov 1 VCM", "cov 1 PZT")))
        for b, (lo, hi) in enumerate(bands):
            e1 = np.median(stats["one", d][:, b, :, 0], axis=0)
            e8 = np.median(stats["pooled", d][:, b, :, 0], axis=0)
            c8 = stats["pooled", d][:, b, :, 1].mean(axis=0)
            c1 = stats["one", d][:, b, :, 1].mean(axis=0)
            cells = [e1[0], e8[0], e1[0] / e8[0], e1[1], e8[1], e1[1] / e8[1], c8[0], c8[1],
                     c1[0], c1[1]]
            print(f"   {f'{lo:g}-{hi:g}':<15}" + "".join(f"{c:>11.3g}" for c in cells)
                  + f"   flagged {stats['pooled', d][:, b, 0, 2].mean():.2f}, spread "
                    f"calibration {np.median(stats['pooled', d][:, b, 0, 3]):.2f}, factor on P "
                    f"{np.median(stats['pooled', d][:, b, 0, 4]):.2f}/"
                    f"{np.median(stats['pooled', d][:, b, 1, 4]):.2f}")
        cover = stats["pooled", d][:, :, :, 1].mean(axis=0)  # (band, input)
        misses = [f"{lo:g}-{hi:g} Hz {name} {cover[b, i]:.3f}" for b, (lo, hi) in enumerate(bands)
                  for i, name in enumerate(hdd.INPUTS) if not 0.90 <= cover[b, i] <= 0.99]
        print(f"   goal, pooled coverage 0.90-0.99 in every band and actuator: "
              f"{'met' if not misses else 'NOT met: ' + '; '.join(misses)}")
        low = [np.median(stats["one", d][:, 0, i, 0]) / np.median(stats["pooled", d][:, 0, i, 0])
               for i in range(len(hdd.INPUTS))]
        print(f"   goal, error below 500 Hz one / pooled >= 2.5: VCM {low[0]:.2f}, PZT {low[1]:.2f} "
              f"({'met' if min(low) >= 2.5 else 'NOT met'})")


#: Forms of the pooled band's variance (before the model-error term and the small-sample
#: factor) from the first-order variance ``v``, the exact second-order variance ``v2``
#: (:func:`lcmr_xr.kernels.adaptive.second_order_variance`), ``q = K95 rho`` and
#: ``rho_v``: today's bound form of ``c_S`` and the candidates that model the
#: nonlinearity of ``S^-1`` instead (docs/uncertainty.md, "Pooled bands").
BAND_FORMS = {
    "bound c_S": lambda v, v2, q, rv: v * (1 + K95 * rv / (1 - q)) ** 2,
    "exact 2nd order": lambda v, v2, q, rv: v + v2 / (1 - q) ** 2,
    "variance form": lambda v, v2, q, rv: v * (1 + (rv / (1 - q)) ** 2),
    "1/(1 - k rho)": lambda v, v2, q, rv: v / (1 - q) ** 2,
    "2nd-order factor": lambda v, v2, q, rv: v * (1 + 2 * (q / K95 / (1 - q)) ** 2),
    "no c_S": lambda v, v2, q, rv: v,
}
#: The form ``identify`` uses for pooled fits calibrated by their halves (on top of the
#: halves' factor on ``P``, ``P_spread_calibration``); single records keep the bound form.
PRODUCTION_FORM = "1/(1 - k rho)"


def _halves(R, Z, kw, covariance):
    """The two halves' local models of :func:`lcmr_xr.kernels.identification.split_half_spread`
    (same window, degrees, denominator and instruments), with ``covariance``."""
    from lcmr_xr.kernels import identification as kid
    from lcmr_xr.kernels.local_models import local_model
    from lcmr_xr.kernels.pooling import split_halves

    R, Z = kid._broadcast_leading(R, Z)
    ax = kw["experiment_axis"]
    zhats = kw.get("instruments")
    if zhats is None:
        zhats = kid.half_instruments(R, Z, degrees=kw["degrees"], circular=kw["circular"],
                                     experiment_axis=ax, denominator=kw["denominator"])
    halves = split_halves(R.shape[ax])
    fits = [local_model(np.take(R, idx, axis=ax), np.take(Z, idx, axis=ax),
                        half_width=kw["half_width"], degrees=tuple(kw["degrees"]),
                        circular=kw["circular"], covariance=covariance, experiment_axis=ax,
                        instruments=zhat) for idx, zhat in zip(halves, zhats)]
    G = [np.where(f.ill_posed[..., None, None], np.nan, f.G) for f in fits]
    V = [half_variances(np.moveaxis(np.take(R, idx, axis=ax), ax, -3), kw["half_width"],
                        circular=kw["circular"])[..., None, :] for idx in halves]
    return fits, G, V


def _mean_ratio(num, den):
    """Per bin, the mean over the entries of ``num / den`` (finite, ``den > 0``; NaN if none)."""
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        ok = np.isfinite(num) & np.isfinite(den) & (den > 0)
        total = np.where(ok, num / np.where(ok, den, 1.0), 0.0).sum(axis=(-2, -1))
        count = ok.sum(axis=(-2, -1))
        return np.where(count > 0, total / np.maximum(count, 1), np.nan)


def _ratio_gram(R, Z, terms, kw, noise="pool"):
    """``w |G_a - G_b|^2 / G_var`` with the halves' Gram weight (the random-group variance
    of the pooled estimate); ``noise``: the noise levels in the weight, the pool's for both
    halves (``"pool"``: ``V_a V_b / (V_a + V_b)^2``) or each half's own residual estimate
    (``"none"``: of the fit without covariance, ``"diag"``: with its exact ``tau``):
    ``s_p V_a V_b / ((V_a + V_b) (s_a V_a + s_b V_b))``."""
    fits, G, V = _halves(R, Z, kw, None if noise in ("pool", "none") else "diag")
    G_var = np.where(terms["ill_posed"][..., None, None], np.nan, terms["G_var"])
    d2 = np.abs(G[0] - G[1]) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        if noise == "pool":
            w = V[0] * V[1] / (V[0] + V[1]) ** 2
        else:
            s = [f.noise_variance[..., :, None] for f in fits]
            s_p = terms["noise_variance"][..., :, None]
            w = s_p * V[0] * V[1] / ((V[0] + V[1]) * (s[0] * V[0] + s[1] * V[1]))
    return _mean_ratio(w * d2, G_var)


def _ratio_own(R, Z, terms, kw):
    """``|G_a - G_b|^2 / (var_a + var_b)``: the halves' own reported variances (their local
    models with ``covariance="diag"``); no ratio where the pool is ill-posed."""
    fits, G, _ = _halves(R, Z, kw, "diag")
    den = fits[0].G_cov + fits[1].G_cov
    den = np.where(terms["ill_posed"][..., None, None], np.nan, den)
    return _mean_ratio(np.abs(G[0] - G[1]) ** 2, den)


#: The calibrations compared by ``--band-forms`` (each from the same pooled fits):
#: name -> ``(R, Z, terms, kw) -> ratio`` (``terms``: the pooled fit's
#: :func:`lcmr_xr.kernels.identification._fit_terms`; ``kw``: those of ``split_half_spread``).
CALIBRATIONS = {
    "gram (pool noise)": lambda R, Z, t, kw: _ratio_gram(R, Z, t, kw, "pool"),
    "gram (halves' noise)": lambda R, Z, t, kw: _ratio_gram(R, Z, t, kw, "none"),
    "gram (halves' tau)": lambda R, Z, t, kw: _ratio_gram(R, Z, t, kw, "diag"),
    "own (diag halves)": _ratio_own,
}


#: Calibrations of ``P``'s own band from the split halves, on top of production's (measured
#: by ``--band-forms``, not used by ``identify``): each half's ``P`` (its ``G`` through the
#: indirect step and the recovery), ``|P_a - P_b|^2 / 4`` (equal halves of one design) over
#: the calibrated first-order variance of the pooled ``P`` per fast bin and entry, not at
#: undetermined bins, over +-6 fast bins by the mean or by the median / ln 2 (a robust
#: mean of ``Exp(1)`` terms), never below 1, multiplies every form's variance.
P_CALIBRATIONS = {"P halves (mean)": "mean", "P halves (median)": "median"}


def _p_factor(G_halves, kw, v, und, how, smoothing=6):
    """The factor of :data:`P_CALIBRATIONS` per fast bin and entry of one candidate."""
    nr, f_, k = kw["factor"] * kw["nu"], kw["factor"], kw["n_fast"] // 2 + 1
    with np.errstate(all="ignore"):
        P = [frf_from_first_block_row(indirect_first_row(g, nr).first_row, f_)[..., :k, :, :]
             for g in G_halves]
        r = 0.25 * np.abs(P[0] - P[1]) ** 2 / v
    r = np.where(und | ~np.isfinite(r), np.nan, r)
    pad = np.full((smoothing,) + r.shape[1:], np.nan)
    windows = np.lib.stride_tricks.sliding_window_view(np.concatenate([pad, r, pad]),
                                                       2 * smoothing + 1, axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN windows: factor 1
        local = (np.nanmean(windows, axis=-1) if how == "mean"
                 else np.nanmedian(windows, axis=-1) / np.log(2.0))
    return np.maximum(np.where(np.isfinite(local), local, 1.0), 1.0)


@contextlib.contextmanager
def _captured_candidates(calibrations=None):
    """Record every candidate window's fit as ``identify`` finishes it (the production
    path: the kernels' ``_finish``, with its inputs and outputs, and the local model's
    ``G_cov`` that its terms were reduced from), so that the pieces of the band can be
    recombined without fitting again.  The local models are fitted in one block of bins
    meanwhile (``BLOCK_BYTES``); ``G_cov`` is completed over the circle as production
    completes its terms (bins above ``M/2`` the conjugates of those below, for real
    signals).  ``calibrations`` (name -> function, :data:`CALIBRATIONS`): each candidate's
    ratio by each of them too (``fit["ratios"]``)."""
    from lcmr_xr.kernels import identification as kid
    from lcmr_xr.kernels.closed_loop import mirror_source

    calls, blocks, ratios = [], [], []
    original, terms, nbytes, spread = kid._finish, kid.slow_bin_terms, kid.BLOCK_BYTES, kid._spread_ratio

    def reducing(G, G_cov, **kw):
        blocks.append(G_cov)
        return terms(G, G_cov, **kw)

    def spreading(R, Z, t, **kw):
        ratios.append({name: fn(R, Z, t, kw) for name, fn in (calibrations or {}).items()})
        return spread(R, Z, t, **kw)

    def recording(fit, **kw):
        out = original(fit, **kw)
        # one block per candidate (the last: before it, window="auto" may have refitted
        # the bins a narrower candidate won, without finishing them)
        C = blocks[-1]
        blocks.clear()
        m = fit["G"].shape[-3]
        src = mirror_source(fit["G"])
        if src is not None:  # mirrored: bin k > M/2 is the conjugate of bin M - k
            C = np.take(C, src, axis=-3)
            C[..., m // 2 + 1:, :, :] = np.conj(C[..., m // 2 + 1:, :, :])
        # (copies: the window choice empties the candidates' dicts and writes the chosen
        # values into the widest candidate's arrays)
        extra = {"ratios": ratios.pop()} if ratios else {}
        copy = lambda d: {k: v.copy() if isinstance(v, np.ndarray) else v  # noqa: E731
                          for k, v in d.items()}
        calls.append(({**copy(fit), "G_cov": C[..., :m, :, :], **extra}, kw, copy(out)))
        return out

    kid._finish, kid.slow_bin_terms, kid.BLOCK_BYTES = recording, reducing, 1 << 62
    kid._spread_ratio = spreading
    try:
        yield calls
    finally:
        kid._finish, kid.slow_bin_terms, kid.BLOCK_BYTES = original, terms, nbytes
        kid._spread_ratio = spread


@contextlib.contextmanager
def _variant(circular_fan: bool = False, own_transient: bool = True, psd: bool = True,
             second_order: bool = False):
    """Measurement variants of :func:`pooled_band_decomposition` and
    :func:`disturbances_pooled` (not production):
    ``circular_fan``: the fan vibration as the periodic steady state of its filter (the
    noise's DFT times the filter's FRF at the fast bins: no transient, no leakage in its
    spectrum); ``own_transient=False``: the pooled IV's instruments ``G1 R`` without each
    experiment's own first-fit transient ``T1`` (which is fitted to that experiment's
    noise); ``psd=False``: every pooled fit's ``G_cov`` from its residual noise covariance
    as estimated, entry by entry (production up to session 14; now mended by
    :func:`lcmr_xr.kernels.pooling.nearest_correlation`); ``second_order``: the pooled
    band's nonlinearity factor :func:`lcmr_xr.kernels.adaptive.second_order_factor`
    instead of ``1 / (1 - k rho)`` (pooled fits calibrated by their halves only)."""
    from lcmr_xr.hdd import benchmark as hb, disturbances as hd
    from lcmr_xr.kernels import identification as kid
    from lcmr_xr.kernels.adaptive import second_order_factor
    from lcmr_xr.kernels.lti import frequency_response

    fan, prediction = hb.fan_vibration, kid._prediction
    nearest, pooled_factor = kid.nearest_correlation, kid.pooled_nonlinearity_factor

    def circular(n, rng):
        e = hd.NOISE_SCALE * rng.uniform(-0.5, 0.5, size=int(n))
        H = frequency_response(hd.fan_filter(), np.fft.rfftfreq(int(n), d=hd.FAST_PERIOD))
        return np.fft.irfft(np.fft.rfft(e) * H[:, 0, 0], n=int(n))

    def without_own_transient(G, T, R, Z, *, circular=True, experiment_axis=None):
        if experiment_axis is not None:
            T = np.zeros_like(T)
        return prediction(G, T, R, Z, circular=circular, experiment_axis=experiment_axis)

    if circular_fan:
        hb.fan_vibration = circular
    if not own_transient:
        kid._prediction = without_own_transient
    if not psd:
        kid.nearest_correlation = lambda s: s
    if second_order:
        kid.pooled_nonlinearity_factor = second_order_factor
    try:
        yield
    finally:
        hb.fan_vibration, kid._prediction = fan, prediction
        kid.nearest_correlation, kid.pooled_nonlinearity_factor = nearest, pooled_factor


def _widest_flag_kept(calls, q_widest, choice):
    """Where ``identify`` carries the widest candidate's flag over (fast bins; as
    ``kernels.identification._finish_choice``): its test with ``rho`` (``q_widest = K95
    rho``, per fast bin) scaled to the share of its residual variance of the rows of ``S``
    that can be noise (:func:`lcmr_xr.kernels.adaptive.noise_share`) against the chosen
    candidate's (``choice`` per slow bin)."""
    nr = calls[0][1]["factor"] * calls[0][1]["nu"]
    m = choice.shape[-1]
    var = np.stack([out["noise_variance"][..., :nr].sum(-1) for _, _, out in calls])
    dof = np.stack([np.broadcast_to(kw["dof"], (m,)) for _, kw, _ in calls])
    bins = np.arange(m)
    share = noise_share(var[-1], var[choice, bins], dof[-1], dof[choice, bins])
    q = np.asarray(q_widest).reshape(q_widest.shape[0], -1)[:, 0]
    k = np.arange(q.size)
    return ~(q * np.sqrt(share[k % m]) <= UNDETERMINED_LIMIT)


def _band_pieces(fit, kw, out, ratio=None, production_form=PRODUCTION_FORM):
    """Per fast bin of one candidate: ``v``, ``v2``, ``q``, ``rho_v`` (broadcast to ``P``),
    the small-sample factor, and the calibration and undetermined flag it used.
    ``ratio``: another split-half ratio than production's (the pieces are then those
    ``identify`` would compute with it: the undetermined flag recomputed)."""
    production = ratio is None
    cal = spread_calibration(fit["spread_ratio"] if production else ratio)
    pf = 1.0
    G, C = fit["G"], fit["G_cov"] * cal[..., None, None]
    n_fast, f_, nu, ny = kw["n_fast"], kw["factor"], kw["nu"], kw["ny"]
    nr = f_ * nu
    ind = indirect_first_row(G, nr, C)
    m = G.shape[-3]
    bins = np.arange(n_fast // 2 + 1)
    slow = bins % m
    v = frf_variance_from_first_row(ind.first_row_cov, n_fast, f_, bins, ny, nu)
    rho, rho_v = weak_direction(G[..., :nr, :], C[..., : nr * nr, : nr * nr])
    S_inv = np.linalg.inv(np.where(ind.singular[..., None, None], np.eye(nr), G[..., :nr, :]))
    start = time.process_time()
    v2 = second_order_variance(S_inv, ind.first_row, C, ind.first_row_cov, n_fast=n_fast,
                               factor=f_, bins=bins)
    t2 = time.process_time() - start
    dof = np.broadcast_to(small_sample_factor(kw["dof"]), (m,))[slow, None, None]
    und_slow = nonlinearity_factor(rho, rho_v)[1] & ~fit["s_singular"]
    und = und_slow[slow][:, None, None]
    if production:
        # the pieces are production's: its form times the halves' factor on P gives
        # identify's P_var (and v its P_var_linear), the flag is identify's
        np.testing.assert_array_equal(und[:, 0, 0], out["P_undetermined"])
        P_h = [frf_from_first_block_row(fit[h], f_)[..., : bins.size, :, :]
               for h in ("P1_half_a", "P1_half_b")]
        pf = p_spread_factor(*P_h, v, und[:, 0, 0], weight=fit["half_weight"][slow])
        np.testing.assert_allclose(pf, out["P_spread_calibration"], rtol=1e-9)
        with np.errstate(divide="ignore", invalid="ignore"):
            check = np.where(und, np.inf,
                             dof ** 2 * pf * BAND_FORMS[production_form](
                                 v, v2, K95 * rho[slow, None, None], rho_v[slow, None, None]))
        ok = np.isfinite(out["P_var"])
        np.testing.assert_allclose(check[ok], out["P_var"][ok], rtol=1e-9)
        np.testing.assert_allclose(v, out["P_var_linear"], rtol=1e-7)
    return dict(v=v, v2=v2, q=K95 * rho[slow, None, None], rho_v=rho_v[slow, None, None],
                dof=dof, und=und, P=out["P"], cal=cal, t2=t2, pf=pf)


def pooled_band_forms(groups: int, first_group: int = 0, n_exp: int = 8, denominator="iv",
                      calibrations=None):
    """Coverage per band of the pooled 95 % discs for every form of :data:`BAND_FORMS`
    and every split-half calibration of ``calibrations`` (names of :data:`CALIBRATIONS`;
    default: production's alone, named ``"production"``).

    One pooled ``identify`` (``window="auto"``) per group of ``n_exp`` experiments (the
    groups of :func:`disturbances_pooled`); its candidate windows' fits are recorded and
    each form's band is rebuilt per candidate (``c_dof^2 form``, ``inf`` where
    undetermined), the window is chosen per slow bin by
    :func:`lcmr_xr.kernels.adaptive.select_windows` on that form's band (as ``identify``
    would choose it) and the chosen window's model-error term added.  Checks that the bound
    form with production's calibration reproduces ``identify``'s ``P_std`` and flag (so
    every form is what ``identify`` would return with it).  Returns (calibration, form) ->
    (group, band, input) coverage, and per calibration the flagged fraction (group, band)
    and the median factor (group, band); for production's: the median ``c_S`` and
    ``E|e2|^2 / var_lin`` of the chosen windows (band, input) and the CPU seconds of
    ``second_order_variance`` per candidate.
    """
    from lcmr_xr.demo import BANDS_HZ

    names = ["production"] + list(calibrations or [])
    cover = {(c, name): np.zeros((groups, len(BANDS_HZ), 2)) for c in names for name in BAND_FORMS}
    flagged = {c: np.zeros((groups, len(BANDS_HZ))) for c in names}
    factor = {c: np.zeros((groups, len(BANDS_HZ))) for c in names}
    c_s, ratio2, zlin, t2 = [[] for _ in BANDS_HZ], [[] for _ in BANDS_HZ], [[] for _ in BANDS_HZ], []
    for gi, g in enumerate(range(first_group, first_group + groups)):
        exps = [hdd.simulate(N, case=CASE, seed=500 + n_exp * g + e) for e in range(n_exp)]
        capture = {c: CALIBRATIONS[c] for c in names[1:] if c in CALIBRATIONS}
        if any(c in P_CALIBRATIONS for c in names):
            capture["_halves_G"] = lambda R, Z, t, kw: _halves(R, Z, kw, None)[1]
        with _captured_candidates(capture) as calls:
            pooled = lcmr_xr.identify(xr.concat(exps, "experiment"), combine="experiment",
                                      errors="ignore", denominator=denominator)
        windows = pooled.attrs.get(cv.CANDIDATE_WINDOWS)
        f = pooled.frequency.values
        sf = pooled.slow_frequency.values
        truth = np.full(calls[0][2]["P"].shape, np.nan, dtype=complex)
        truth[1:] = hdd.true_frf(f[1:], case=CASE).values
        m = pooled.sizes["slow_frequency"]
        k = np.arange(f.size)
        for cal_name in names:
            if cal_name in P_CALIBRATIONS:  # production's pieces, the factor on P on top
                pieces = [{**p, "pf": _p_factor(fit["ratios"]["_halves_G"], kw, p["v"], p["und"],
                                                P_CALIBRATIONS[cal_name])}
                          for p, (fit, kw, out) in zip(base, calls)]
            else:
                pieces = [_band_pieces(fit, kw, out, None if cal_name == "production"
                                       else fit["ratios"][cal_name]) for fit, kw, out in calls]
            if cal_name == "production":
                t2 += [p["t2"] for p in pieces]
                base = pieces
            P = np.stack([p["P"] for p in pieces])
            v = np.stack([p["v"] for p in pieces])
            und = np.stack([p["und"] for p in pieces])
            for name, form in BAND_FORMS.items():
                with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
                    var = np.stack([np.where(p["und"], np.inf,
                                             p["dof"] ** 2 * p.get("pf", 1.0)
                                             * form(p["v"], p["v2"], p["q"], p["rho_v"]))
                                    for p in pieces])
                choice, bias2 = select_windows(P, var, v, m)
                pick = choice[k % m][None, :, None, None]
                chosen = lambda a: np.take_along_axis(a, np.broadcast_to(pick, (1,) + a.shape[1:]),
                                                      axis=0)[0]
                kept = _widest_flag_kept(calls, pieces[-1]["q"], choice)[:, None, None]
                undetermined = chosen(und) | (und[-1] & kept)
                var_c = np.where(undetermined, np.inf, chosen(var) + chosen(bias2))
                P_c = chosen(P)
                first = cal_name == "production" and name == PRODUCTION_FORM
                if first:  # identify's own result
                    np.testing.assert_allclose(np.sqrt(var_c), pooled.P_std.values, rtol=1e-9)
                    np.testing.assert_array_equal(P_c, pooled.P.values)
                    q = np.stack([np.broadcast_to(p["q"], p["v"].shape) for p in pieces])
                    rv = np.stack([np.broadcast_to(p["rho_v"], p["v"].shape) for p in pieces])
                    v2 = np.stack([p["v2"] for p in pieces])
                    dof = np.stack([np.broadcast_to(p["dof"], p["v"].shape) for p in pieces])
                    with np.errstate(divide="ignore", invalid="ignore"):
                        cs = chosen(1 / (1 - q))
                        r2 = chosen(v2 / v)
                        # the error over the calibrated first-order variance (ln 2 = 0.69 if right)
                        z = np.abs(P_c - truth) ** 2 / (chosen(dof) ** 2 * chosen(v))
                hit = (np.abs(P_c - truth) ** 2 <= K95 ** 2 * var_c) | undetermined
                for b, (lo, hi) in enumerate(BANDS_HZ):
                    sel = (f > lo) & (f < hi) & (f > 0) & (f < f.max())
                    cover[cal_name, name][gi, b] = hit[sel, 0].mean(axis=0)
                    if name == "bound c_S":
                        flagged[cal_name][gi, b] = undetermined[sel, 0, 0].mean()
                        # median factor of the widest candidate over the band's slow bins
                        # (fast bins, both inputs, for the factors on P)
                        ssel = (sf > lo) & (sf < hi)
                        factor[cal_name][gi, b] = (np.median(pieces[-1]["pf"][sel])
                                                   if cal_name in P_CALIBRATIONS else
                                                   np.median(pieces[-1]["cal"][ssel]))
                    if first:
                        keep = sel & ~undetermined[:, 0, 0]
                        c_s[b].append(cs[keep, 0])
                        ratio2[b].append(r2[keep, 0])
                        zlin[b].append(z[keep, 0])
        print(f"  band forms: group {g} done ({len(calls)} candidates"
              f"{'' if windows is None else f' {windows}'})", file=sys.stderr, flush=True)

    def med(parts_per_band):
        # over the finite values (a bin whose S is singular has a NaN P and is no
        # undetermined bin); a band whose bins are all flagged (0-500 Hz) has nothing to
        # take a median of: NaN (np.median of an empty slice would warn "Mean of empty slice")
        out = []
        for parts in parts_per_band:
            x = np.concatenate(parts) if parts else np.empty((0, 2))
            out.append([np.median(c[np.isfinite(c)]) if np.isfinite(c).any() else np.nan
                        for c in x.T])
        return np.array(out)

    return (BANDS_HZ, cover, flagged, factor, med(c_s), med(ratio2), med(zlin),
            np.array(t2))


def report_band_forms(bands, cover, flagged, factor, c_s, ratio2, zlin, t2, *, first_group,
                      denominator):
    groups = next(iter(flagged.values())).shape[0]
    print(f"\n5b. benchmark disturbances, 8 experiments pooled, window 'auto', denominator "
          f"{denominator!r}, groups {first_group}-{first_group + groups - 1}: coverage of the "
          f"pooled 95 % discs VCM/PZT per split-half calibration and form of the S^-1 factor "
          f"(window chosen per form)")
    print(f"   {'calibration / form':<40}" + "".join(f"{f'{lo:g}-{hi:g} Hz':>17}" for lo, hi in bands))
    for (cal, name), c in cover.items():
        mean = c.mean(axis=0)
        print(f"   {f'{cal}: {name}':<40}" + "".join(f"{f'{mean[b, 0]:.3f}/{mean[b, 1]:.3f}':>17}"
                                                 for b in range(len(bands))))
    for cal in flagged:
        print(f"   {f'{cal}: flagged':<40}" + "".join(f"{flagged[cal][:, b].mean():>17.3f}"
                                                     for b in range(len(bands))))
        print(f"   {f'{cal}: median factor':<40}" + "".join(
            f"{np.median(factor[cal][:, b]):>17.2f}" for b in range(len(bands))))
    print(f"   {'production: median c_S':<40}" + "".join(f"{f'{c_s[b, 0]:.3g}/{c_s[b, 1]:.3g}':>17}"
                                                     for b in range(len(bands))))
    print(f"   {'production: med. var2/var':<40}" + "".join(
        f"{f'{ratio2[b, 0]:.2g}/{ratio2[b, 1]:.2g}':>17}" for b in range(len(bands))))
    print(f"   {'production: med. err2/var':<40}" + "".join(
        f"{f'{zlin[b, 0]:.2f}/{zlin[b, 1]:.2f}':>17}" for b in range(len(bands))))
    print(f"   second_order_variance: {1e3 * np.median(t2):.0f} ms CPU per candidate "
          f"(median of {t2.size})")


def weak_direction_quantile_factor(rho):
    """Factor on the first-order standard deviation that gives the exact 95 % region of
    ``alpha / (1 - z)`` (``alpha ~ CN(0, 1)``, ``z ~ CN(0, rho^2)`` independent): the error of
    ``P`` when the weakest direction of ``S`` carries all of it (``e_lin ~ alpha u^H``, the
    geometric series ``(I - dS S^-1)^-1`` along ``u``, docs/uncertainty.md "The mechanism").
    ``P(|alpha|^2 > t |1 - z|^2) = E exp(-t |1 - z|^2) = exp(-t / (1 + t rho^2)) / (1 + t
    rho^2)`` (the moment generating function of a non-central complex Gaussian), solved for
    0.05 by Newton's method; the factor is ``sqrt(t / ln 20)``.  For comparison with the
    forms of ``c_S`` (it is at most ``second_order_factor``: 1.013, 1.031, 1.055, 1.088 at
    ``K95 rho`` = 0.2, 0.3, 0.4, 0.5 against 1.25-2.0 for ``1 / (1 - K95 rho)``)."""
    rho = np.asarray(rho, dtype=float)
    s2 = np.where(np.isfinite(rho), rho, 0.0) ** 2
    t = np.full(s2.shape, np.log(20.0))
    for _ in range(30):  # g(t) = ln 20 - t / a - ln a decreases in t; Newton from ln 20 (t at rho = 0)
        a = 1.0 + t * s2
        g = -t / a - np.log(a) + np.log(20.0)
        t = t - g / (-1.0 / a ** 2 - s2 / a)
    return np.where(np.isfinite(rho), np.sqrt(t / np.log(20.0)), np.nan)


def _floored_mean(ratio, floor: bool):
    """:func:`spread_calibration` with or without its floor at 1."""
    from lcmr_xr.kernels.pooling import SPREAD_SMOOTHING, window_mean

    ok = np.isfinite(ratio)
    total = window_mean(np.where(ok, ratio, 0.0), SPREAD_SMOOTHING, axis=-1)
    count = window_mean(ok.astype(float), SPREAD_SMOOTHING, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / np.where(count > 0, count, 1.0), 1.0)
    return np.maximum(mean, 1.0) if floor else mean


def _p_factor_raw(P_a, P_b, v, und, weight, floor: bool, smoothing=6):
    """:func:`lcmr_xr.kernels.pooling.p_spread_factor`, with or without its floor at 1."""
    with np.errstate(all="ignore"):
        r = weight[:, None, None] * np.abs(P_a - P_b) ** 2 / v
    r = np.where(und[:, None, None] | ~np.isfinite(r), np.nan, r)
    windows = np.lib.stride_tricks.sliding_window_view(
        np.pad(r, [(smoothing, smoothing), (0, 0), (0, 0)], constant_values=np.nan),
        2 * smoothing + 1, axis=0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        local = np.nanmedian(windows, axis=-1) / np.log(2.0)
    local = np.where(np.isfinite(local), local, 1.0)
    return np.maximum(local, 1.0) if floor else local


#: Bands of the decomposition (:func:`pooled_band_decomposition`), each from the pieces of
#: the chosen candidate: ``v`` the first-order variance calibrated by ``spread_calibration``
#: (``cal``), ``raw`` that calibration without its floor, ``dof`` = ``c_dof``, ``pf`` =
#: ``P_spread_calibration`` (``pf_nf`` unfloored, ``pf_raw`` / ``pf_raw_nf`` recomputed on
#: the band with the unfloored ``raw``), ``cs`` = production's ``1 / (1 - K95 rho)``,
#: ``cs2`` = ``second_order_factor``, ``csq`` = :func:`weak_direction_quantile_factor`,
#: ``b2`` = ``P_bias^2``.
DECOMPOSITION = {
    "P_std_linear, uncalibrated": lambda x: x["v"] / x["cal"],
    "P_std_linear": lambda x: x["v"],
    "c_dof": lambda x: x["dof"] ** 2 * x["v"],
    "c_dof c_S": lambda x: x["dof"] ** 2 * x["v"] * x["cs"] ** 2,
    "c_dof c_P": lambda x: x["dof"] ** 2 * x["v"] * x["pf"],
    "c_dof c_P c_S": lambda x: x["dof"] ** 2 * x["v"] * x["pf"] * x["cs"] ** 2,
    "c_dof c_P + P_bias": lambda x: x["dof"] ** 2 * x["v"] * x["pf"] + x["b2"],
    "production (all)": lambda x: x["dof"] ** 2 * x["v"] * x["pf"] * x["cs"] ** 2 + x["b2"],
    "prod., no spread_calibration": lambda x: (x["dof"] ** 2 * x["v"] / x["cal"] * x["pf"]
                                               * x["cs"] ** 2 + x["b2"]),
    "prod., spread_cal. unfloored": lambda x: (x["dof"] ** 2 * x["v"] / x["cal"] * x["raw"]
                                               * x["pf_raw"] * x["cs"] ** 2 + x["b2"]),
    "prod., c_P unfloored": lambda x: x["dof"] ** 2 * x["v"] * x["pf_nf"] * x["cs"] ** 2 + x["b2"],
    "prod., c_S 2nd order": lambda x: x["dof"] ** 2 * x["v"] * x["pf"] * x["cs2"] ** 2 + x["b2"],
    "prod., c_S exact quantile": lambda x: x["dof"] ** 2 * x["v"] * x["pf"] * x["csq"] ** 2 + x["b2"],
    "prod., c_S 2nd, no floors": lambda x: (x["dof"] ** 2 * x["v"] / x["cal"] * x["raw"]
                                            * x["pf_raw_nf"] * x["cs2"] ** 2 + x["b2"]),
}
#: Rows with ``b2W``: the squared difference between the chosen window's ``P`` and the
#: narrowest candidate's (the pilot), less the variance of that difference measured by the
#: split halves (``|d_a - d_b|^2 / 4``), averaged over the neighbours as
#: :func:`lcmr_xr.kernels.adaptive.denominator_bias` does: the noise-induced bias that
#: grows with the window, if the pilot's own is small (:func:`pooled_band_decomposition`).
WINDOW_BIAS_ROWS = {
    "prod. + b2_W": lambda x: DECOMPOSITION["production (all)"](x) + x["b2W"],
    "prod., c_S exact quantile + b2_W": lambda x: (DECOMPOSITION["prod., c_S exact quantile"](x)
                                                   + x["b2W"]),
    "c_dof c_P + P_bias + b2_W": lambda x: DECOMPOSITION["c_dof c_P + P_bias"](x) + x["b2W"],
}
#: Rows with the Hausman term ``b2H`` of the pooled least-squares fit against the pooled IV
#: fit at the widest window (:func:`lcmr_xr.kernels.adaptive.denominator_bias`), added by
#: ``--hausman`` (:func:`pooled_band_decomposition`).
HAUSMAN_ROWS = {
    "prod. + b2_H": lambda x: DECOMPOSITION["production (all)"](x) + x["b2H"],
    "prod., c_S exact quantile + b2_H": lambda x: (DECOMPOSITION["prod., c_S exact quantile"](x)
                                                   + x["b2H"]),
    "prod., c_S 2nd order + b2_H": lambda x: DECOMPOSITION["prod., c_S 2nd order"](x) + x["b2H"],
    "c_dof c_P + P_bias + b2_H": lambda x: DECOMPOSITION["c_dof c_P + P_bias"](x) + x["b2H"],
    "prod. + b2_H halves": lambda x: DECOMPOSITION["production (all)"](x) + x["b2Hh"],
    "prod., c_S exact quantile + b2_H halves": lambda x: (
        DECOMPOSITION["prod., c_S exact quantile"](x) + x["b2Hh"]),
    "c_dof c_P + P_bias + b2_H halves": lambda x: DECOMPOSITION["c_dof c_P + P_bias"](x) + x["b2Hh"],
}


def pooled_band_decomposition(groups: int, first_group: int = 0, n_exp: int = 8,
                              denominator="iv", disturbances=None, hausman: bool = False,
                              circular_fan: bool = False, own_transient: bool = True,
                              psd: bool = True, second_order: bool = False):
    """Coverage of the pooled 95 % discs per band with the band built from some of its
    ingredients (:data:`DECOMPOSITION`), at production's window choice and flag (so every
    row has ``identify``'s ``P``; a flagged bin counts as covered).  One pooled
    ``identify`` (``window="auto"``) per group of :func:`disturbances_pooled`, its
    candidates recorded (:func:`_captured_candidates`); checks that the pieces reproduce
    ``identify``'s ``P_std`` and ``P``.  Returns the bands, row -> (group, band, input)
    coverage, the flagged fraction (group, band), and medians over the unflagged bins
    (name -> (group, band, input)) of the factors and of the error over the calibrated
    first-order variance (``ln 2`` if that variance is right); rows marked ``(mean)`` are
    means over those bins: the error the two halves share against the truth, ``Re(e_a
    conj(e_b))`` (``|B|^2`` for a bias ``B`` common to both, 0 on average for independent
    noise), next to the halves' difference ``|e_a - e_b|^2 / 4`` (the pooled noise
    variance for equal halves) and the pooled error.  ``disturbances``: names
    for :func:`lcmr_xr.hdd.simulate` (default: all of them, the benchmark's).
    ``hausman``: also the rows of :data:`HAUSMAN_ROWS`, with ``b2H`` from two more pooled
    fits per group at the widest window (least squares and IV), whose difference bounds
    least squares' errors-in-variables bias (an upper term for IV's).  ``circular_fan``,
    ``own_transient``, ``psd``, ``second_order``: measurement variants (:func:`_variant`;
    with ``second_order`` the row "production (all)" is that variant's band).  Also
    reported: the fraction of unflagged bins whose first-order variance is exactly 0 (a
    negative variance of a covariance that is not positive semidefinite, clipped)."""
    from lcmr_xr.demo import BANDS_HZ
    from lcmr_xr.kernels.adaptive import second_order_factor

    which = {} if disturbances is None else {"disturbances": tuple(disturbances)}
    rows = {**DECOMPOSITION, **WINDOW_BIAS_ROWS, **(HAUSMAN_ROWS if hausman else {})}

    cover = {name: np.zeros((groups, len(BANDS_HZ), 2)) for name in rows}
    flagged = np.zeros((groups, len(BANDS_HZ)))
    medians = {}
    for gi, g in enumerate(range(first_group, first_group + groups)):
        with _variant(circular_fan, own_transient, psd, second_order):
            exps = [hdd.simulate(N, case=CASE, seed=500 + n_exp * g + e, **which)
                    for e in range(n_exp)]
        with _captured_candidates({}) as calls, _variant(circular_fan, own_transient, psd, second_order):
            pooled = lcmr_xr.identify(xr.concat(exps, "experiment"), combine="experiment",
                                      errors="ignore", denominator=denominator)
        form = "2nd-order factor" if second_order else PRODUCTION_FORM
        pieces = [_band_pieces(fit, kw, out, production_form=form) for fit, kw, out in calls]
        f = pooled.frequency.values
        m = pooled.sizes["slow_frequency"]
        slow = np.arange(f.size) % m
        truth = np.full(pieces[0]["P"].shape, np.nan, dtype=complex)
        truth[1:] = hdd.true_frf(f[1:], case=CASE).values
        full = lambda a: np.broadcast_to(a, pieces[0]["v"].shape)  # noqa: E731
        x = {key: [] for key in ("v", "cal", "raw", "dof", "pf", "pf_nf", "pf_raw", "pf_raw_nf",
                                 "cs", "cs2", "csq", "jk", "Pa", "Pb")}
        for p, (fit, kw, out) in zip(pieces, calls):
            P_h = [frf_from_first_block_row(fit[h], kw["factor"])[: f.size]
                   for h in ("P1_half_a", "P1_half_b")]
            w, und = fit["half_weight"][slow], p["und"][:, 0, 0]
            cal = p["cal"][slow][:, None, None]
            raw = _floored_mean(fit["spread_ratio"], False)[slow][:, None, None]
            v_raw = p["v"] / cal * raw
            rho = p["q"] / K95
            with np.errstate(all="ignore"):
                cs2 = np.where(und[:, None, None], 1.0, second_order_factor(rho)[0])
                jk = np.abs(0.5 * (P_h[0] + P_h[1]) - p["P"]) ** 2
            for key, val in (("v", p["v"]), ("cal", cal), ("raw", raw), ("dof", p["dof"]),
                             ("pf", p["pf"]), ("pf_nf", _p_factor_raw(*P_h, p["v"], und, w, False)),
                             ("pf_raw", _p_factor_raw(*P_h, v_raw, und, w, True)),
                             ("pf_raw_nf", _p_factor_raw(*P_h, v_raw, und, w, False)),
                             ("cs", np.where(und[:, None, None], 1.0, cs2 if second_order
                                             else 1.0 / (1.0 - p["q"]))),
                             ("cs2", cs2),
                             ("csq", weak_direction_quantile_factor(np.where(und[:, None, None], 0.0, rho))),
                             ("jk", jk), ("Pa", P_h[0]), ("Pb", P_h[1])):
                x[key].append(full(val))
        x = {key: np.stack(val) for key, val in x.items()}
        P = np.stack([p["P"] for p in pieces])
        und = np.stack([p["und"] for p in pieces])
        with np.errstate(divide="ignore", invalid="ignore"):
            var = np.where(und, np.inf, x["dof"] ** 2 * x["pf"] * x["v"] * x["cs"] ** 2)
        choice, bias2 = select_windows(P, var, x["v"], m)
        pick = np.broadcast_to(choice[slow][None, :, None, None], (1,) + P.shape[1:])
        chosen = lambda a: np.take_along_axis(np.broadcast_to(a, P.shape), pick, axis=0)[0]  # noqa: E731
        undetermined = chosen(und) | (und[-1] & _widest_flag_kept(calls, pieces[-1]["q"],
                                                                  choice)[:, None, None])
        c = {key: chosen(val) for key, val in x.items()}
        c["b2"] = chosen(bias2)
        assert np.all(np.diff([np.min(kw["dof"]) for _, kw, _ in calls]) > 0)  # narrowest first
        # the chosen window against the pilot (the narrowest candidate, first fitted), the
        # variance of the difference from the halves' own difference
        with np.errstate(invalid="ignore"):
            spread = 0.25 * np.abs((c["Pa"] - x["Pa"][0]) - (c["Pb"] - x["Pb"][0])) ** 2
        c["b2W"] = denominator_bias(chosen(P), P[0], np.zeros(spread.shape), spread,
                                    determined=~undetermined & np.isfinite(spread))
        if hausman:  # pooled least squares against pooled IV, both at the widest window
            with _variant(circular_fan, own_transient, psd, second_order):
                twins = [lcmr_xr.identify(xr.concat(exps, "experiment"), combine="experiment",
                                          errors="ignore", denominator=d, window=WINDOW)
                         for d in ("ls", "iv")]
            var = [t.P_std_linear.values ** 2 for t in twins]
            determined = np.isfinite(twins[1].P_std.values)
            c["b2H"] = denominator_bias(twins[0].P.values, twins[1].P.values, *var,
                                        determined=determined)
            # the same comparison with the variance of the difference measured by the
            # split halves (random groups, equal halves: w = 1/4) instead of the fits'
            # reported variances: mean over the neighbours of |d|^2 - |d_a - d_b|^2 / 4
            with _variant(circular_fan, own_transient, psd, second_order):
                d_h = [lcmr_xr.identify(xr.concat(exps[h::2], "experiment"),
                                        combine="experiment", errors="ignore", denominator="ls",
                                        window=WINDOW).P.values
                       - lcmr_xr.identify(xr.concat(exps[h::2], "experiment"),
                                          combine="experiment", errors="ignore",
                                          denominator="iv", window=WINDOW).P.values
                       for h in (0, 1)]
            with np.errstate(invalid="ignore"):
                spread = 0.25 * np.abs(d_h[0] - d_h[1]) ** 2
            c["b2Hh"] = denominator_bias(twins[0].P.values, twins[1].P.values,
                                         np.zeros(spread.shape), spread,
                                         determined=determined & np.isfinite(spread))
        P_c = chosen(P)
        np.testing.assert_array_equal(P_c, pooled.P.values)
        with np.errstate(all="ignore"):
            np.testing.assert_allclose(np.sqrt(np.where(undetermined, np.inf,
                                                        DECOMPOSITION["production (all)"](c))),
                                       pooled.P_std.values, rtol=1e-9)
            err2 = np.abs(P_c - truth) ** 2
            extra = {"spread_calibration": c["cal"], "c_P": c["pf"], "c_P unfloored": c["pf_nf"],
                     "c_S = 1/(1 - k rho)": c["cs"], "c_S 2nd order": c["cs2"], "c_dof": c["dof"],
                     "P_bias > 0": (c["b2"] > 0).astype(float),
                     "err^2 / (c_dof^2 v)": err2 / (c["dof"] ** 2 * c["v"]),
                     "err^2 / production": err2 / DECOMPOSITION["production (all)"](c),
                     "jackknife bias^2 / (c_dof^2 v)": c["jk"] / (c["dof"] ** 2 * c["v"]),
                     # the error the halves share, against the truth: Re(e_a conj(e_b)) is
                     # |B|^2 for a bias B common to both (independent halves' noise: 0 on average)
                     "shared Re(e_a e_b*) / (c_dof^2 v) (mean)":
                         np.real((c["Pa"] - truth) * np.conj(c["Pb"] - truth)) / (c["dof"] ** 2 * c["v"]),
                     "w |e_a - e_b|^2 / (c_dof^2 v) (mean)":
                         0.25 * np.abs(c["Pa"] - c["Pb"]) ** 2 / (c["dof"] ** 2 * c["v"]),
                     "err^2 / (c_dof^2 v) (mean)": err2 / (c["dof"] ** 2 * c["v"]),
                     "first-order variance 0 (mean)": (c["v"] == 0).astype(float)}
        for b, (lo, hi) in enumerate(BANDS_HZ):
            sel = (f > lo) & (f < hi) & (f < f.max())
            flagged[gi, b] = undetermined[sel, 0, 0].mean()
            for name, form in rows.items():
                with np.errstate(all="ignore"):
                    hit = (err2 <= K95 ** 2 * np.where(undetermined, np.inf, form(c))) | undetermined
                cover[name][gi, b] = hit[sel, 0].mean(axis=0)
            keep = sel & ~undetermined[:, 0, 0]
            for name, val in extra.items():
                medians.setdefault(name, np.full((groups, len(BANDS_HZ), 2), np.nan))
                if keep.any():
                    how = np.nanmean if name.endswith("(mean)") else np.nanmedian
                    medians[name][gi, b] = how(val[keep, 0], axis=0)
        print(f"  decomposition: group {g} done", file=sys.stderr, flush=True)
    return BANDS_HZ, cover, flagged, medians


def report_band_decomposition(bands, cover, flagged, medians, *, first_group, denominator):
    groups = flagged.shape[0]
    print(f"\n5c. benchmark disturbances, 8 experiments pooled, window 'auto', denominator "
          f"{denominator!r}, groups {first_group}-{first_group + groups - 1}: coverage of the "
          f"pooled 95 % discs VCM/PZT with the band built from the named ingredients "
          f"(production's window choice, flag and P; a flagged bin counts as covered)")
    print(f"   {'band from':<32}" + "".join(f"{f'{lo:g}-{hi:g} Hz':>17}" for lo, hi in bands))
    for name, c in cover.items():
        mean = c.mean(axis=0)
        print(f"   {name:<32}" + "".join(f"{f'{mean[b, 0]:.3f}/{mean[b, 1]:.3f}':>17}"
                                         for b in range(len(bands))))
    print(f"   {'flagged':<32}" + "".join(f"{flagged[:, b].mean():>17.3f}" for b in range(len(bands))))
    print("   medians over the unflagged bins of the chosen windows (means where marked; "
          "median over groups):")
    for name, v in medians.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            med = np.nanmedian(v, axis=0)
        print(f"   {name:<32}" + "".join(f"{f'{med[b, 0]:.3g}/{med[b, 1]:.3g}':>17}"
                                         for b in range(len(bands))))


def window0_exactness_f3():
    """Window 0 on a SISO loop at F = 3 (the HDD benchmark has F = 2)."""
    from scipy import signal

    from lcmr_xr.kernels import ltisim
    from lcmr_xr.kernels.excitation import random_phase_multisine

    factor, n, th = 3, 720, 1e-3
    plant, ctrl, filt = ([0.0, 0.10, 0.06], [1.0, -1.6, 0.89]), ([0.25, -0.15], [1.0, -0.3]), \
        ([0.6, 0.0], [1.0, -0.4])
    blocks = (ltisim.tf_q_inverse(*plant, th), ltisim.tf_q_inverse(*ctrl, factor * th),
              ltisim.tf_q_inverse(*filt, th))
    runs = []
    for e in range(factor + 1):
        x = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, np.random.default_rng(e))
        r = xr.DataArray(x, dims=("time", "input"), coords={"time": np.arange(n) * th})
        runs.append(simulate_closed_loop(*blocks, factor, r, periods=3))
    frf = lcmr_xr.identify(xr.concat(runs, "experiment"), window=0, combine="experiment",
                           transient_periods=2, covariance=False)
    truth = signal.freqz(*plant, worN=2 * np.pi * np.arange(n // 2 + 1) / n)[1]
    ok = ~frf.P_flag.values
    rel = np.abs(frf.P.values[ok, 0, 0] - truth[ok]) / np.abs(truth[ok])
    return rel.max(), int(ok.sum()), ok.size


def pooling_cost(n_exp: int = 64, repeat: int = 3, calibrations=(), loop: bool = True,
                 window=WINDOW):
    """Seconds (best of ``repeat``, the variants run in turn each round so that a change
    of load hits them alike): ``n_exp`` experiments pooled, with production's split-half
    calibration and with each of ``calibrations`` (names of :data:`CALIBRATIONS`, swapped
    in for production's ratio), with the calibration of ``G_cov`` alone (``"G calibration
    only"``: no factor on ``P``, the band as before it) and without any (``"no
    calibration"``), against
    identifying them one by one in one call and (``loop``) in a loop of calls."""
    from lcmr_xr.kernels import identification as kid

    exps = xr.concat([hdd.simulate(N, case=CASE, seed=700 + e) for e in range(n_exp)],
                     "experiment")
    kw = dict(window=window, degrees=DEGREES, errors="ignore")

    @contextlib.contextmanager
    def variant(name):
        spread, limit = kid._spread_ratio, kid.MIN_SPLIT_EXPERIMENTS
        if name == "no calibration":
            kid.MIN_SPLIT_EXPERIMENTS = n_exp + 1
        elif name == "G calibration only":  # no factor on P (the halves' P not formed)
            def ratio_only(R, Z, t, **k):
                G_var = np.where(t["ill_posed"][..., None, None], np.nan, t["G_var"])
                k.pop("closed_loop", None)
                return {"spread_ratio": kid.split_half_spread(R, Z, G_var, **k)}
            kid._spread_ratio = ratio_only
        elif name != "pooled":
            fn = CALIBRATIONS[name]
            kid._spread_ratio = lambda R, Z, t, **k: {"spread_ratio": fn(R, Z, t, k)}
        try:
            yield
        finally:
            kid._spread_ratio, kid.MIN_SPLIT_EXPERIMENTS = spread, limit

    def pooled(name):
        with variant(name):
            return lcmr_xr.identify(exps, combine="experiment", **kw)

    runs = {"pooled": lambda: pooled("pooled")}
    runs.update({name: (lambda name=name: pooled(name))
                 for name in ("G calibration only", "no calibration", *calibrations)})
    runs["one by one, one call"] = lambda: lcmr_xr.identify(exps, **kw)
    if loop:
        runs["one by one, loop"] = lambda: [lcmr_xr.identify(exps.isel(experiment=e), **kw)
                                            for e in range(n_exp)]
    lcmr_xr.identify(exps.isel(experiment=slice(0, 4)), combine="experiment", **kw)  # warm up
    times = {name: [] for name in runs}
    for _ in range(repeat):
        for name, fn in runs.items():
            start = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - start)
    return {name: min(t) for name, t in times.items()}


def report_cost(times, n_exp=64, window=WINDOW, repeat=3):
    one = times["one by one, one call"]
    print(f"\n7. cost, {n_exp} experiments of N = {N}, window {window!r}, degrees {DEGREES} "
          f"(best of {repeat}, variants in turn; shared machine), goal: pooled / one by one <= 1.5")
    for name, t in times.items():
        loop = times.get("one by one, loop")
        print(f"   {name:<28} {t:8.2f} s   / one call {t / one:5.2f}"
              + ("" if loop is None else f"   / loop {t / loop:5.2f}"))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12,
                        help="noise realisations per noise kind (default 12)")
    parser.add_argument("--noise", nargs="+", default=["white", "fan"], choices=["white", "fan"],
                        help="output noise kinds to run (default: white fan)")
    parser.add_argument("--groups", type=int, default=6,
                        help="groups of 8 experiments with the benchmark disturbances (default 6)")
    parser.add_argument("--skip-experiments", action="store_true",
                        help="skip goals 4 and 5 (the longest)")
    parser.add_argument("--denominator", nargs="+", default=["ls", "iv"], choices=["ls", "iv"],
                        help="how the LRM denominator is estimated in goal 5 (default: both)")
    parser.add_argument("--only-disturbances", action="store_true",
                        help="run goal 5 alone")
    parser.add_argument("--first-group", type=int, default=0,
                        help="first group of 8 experiments in goal 5 (seeds 500 + 8 g + e)")
    parser.add_argument("--band-forms", action="store_true",
                        help="with --only-disturbances: the pooled coverage per form of the "
                             "S^-1 factor from one pooled fit per group (not the error table)")
    parser.add_argument("--decompose", action="store_true",
                        help="with --only-disturbances: the pooled coverage of the band built "
                             "from each of its ingredients (production's window choice)")
    parser.add_argument("--hausman", action="store_true",
                        help="with --decompose: also the bands with the Hausman term of pooled "
                             "least squares against pooled IV at the widest window")
    parser.add_argument("--circular-fan", action="store_true",
                        help="with --decompose: the fan vibration as its filter's periodic "
                             "steady state (no leakage; a measurement variant)")
    parser.add_argument("--instruments-without-own-transient", action="store_true",
                        help="with --only-disturbances: pooled IV instruments G1 R without each "
                             "experiment's own first-fit transient (a measurement variant)")
    parser.add_argument("--noise-covariance-as-estimated", action="store_true",
                        help="with --only-disturbances: pooled fits' G_cov from the residual noise "
                             "covariance entry by entry, not mended to a covariance (session 14's "
                             "production; a measurement variant)")
    parser.add_argument("--second-order-c-s", action="store_true",
                        help="with --only-disturbances: the pooled band's nonlinearity factor "
                             "second_order_factor instead of 1/(1 - k rho) (a measurement variant)")
    parser.add_argument("--disturbances", nargs="+", default=None,
                        choices=["rotational", "fan", "runout"],
                        help="with --decompose: only these disturbances (default: all)")
    parser.add_argument("--calibrations", nargs="*", default=[],
                        choices=list(CALIBRATIONS) + list(P_CALIBRATIONS),
                        help="with --band-forms: also these split-half calibrations "
                             "(each from the same pooled fits)")
    parser.add_argument("--only-cost", action="store_true",
                        help="run goal 7 alone (with --calibrations timed too)")
    parser.add_argument("--cost-window", default=str(WINDOW),
                        help="window of goal 7 with --only-cost (an int or 'auto')")
    parser.add_argument("--repeat", type=int, default=3, help="best of how many, goal 7")
    parser.add_argument("--no-loop", action="store_true",
                        help="goal 7 without the loop of one call per experiment")
    args = parser.parse_args(argv)
    if args.only_cost:
        if set(args.calibrations) & set(P_CALIBRATIONS):
            parser.error("--only-cost times the calibrations of the pooled covariance "
                         f"({', '.join(CALIBRATIONS)}), not {', '.join(P_CALIBRATIONS)}")
        window = args.cost_window if args.cost_window == "auto" else int(args.cost_window)
        report_cost(pooling_cost(repeat=args.repeat, calibrations=args.calibrations,
                                 loop=not args.no_loop, window=window),
                    window=window, repeat=args.repeat)
        return
    if args.only_disturbances:
        if args.decompose:
            for d in args.denominator:
                report_band_decomposition(*pooled_band_decomposition(
                    args.groups, args.first_group, denominator=d,
                    disturbances=args.disturbances, hausman=args.hausman,
                    circular_fan=args.circular_fan,
                    own_transient=not args.instruments_without_own_transient,
                    psd=not args.noise_covariance_as_estimated,
                    second_order=args.second_order_c_s),
                    first_group=args.first_group, denominator=d)
            return
        if args.band_forms:
            for d in args.denominator:
                report_band_forms(*pooled_band_forms(args.groups, args.first_group,
                                                     denominator=d,
                                                     calibrations=args.calibrations),
                                  first_group=args.first_group, denominator=d)
            return
        with _variant(own_transient=not args.instruments_without_own_transient,
                      psd=not args.noise_covariance_as_estimated,
                      second_order=args.second_order_c_s):
            report_disturbances(*disturbances_pooled(args.groups, first_group=args.first_group,
                                                     denominators=args.denominator))
        return
    if args.seeds < 3:
        parser.error(f"--seeds must be at least 3 to estimate a variance, got {args.seeds}")

    print(f"HDD benchmark case {CASE}, N = {N}, LRM window {WINDOW}, degrees {DEGREES}; "
          f"{args.seeds} noise seeds per kind; the same multisine in every run")
    results = {kind: variance_against_periods(args.seeds, kind) for kind in args.noise}
    for kind, (var, noise) in results.items():
        report_variance(kind, var, noise)
    rel, normwise, freq, n_all, t_pooled, t_one = window0_exactness()
    print(f"\n3. window 0, E = F nu = 4 noiseless periodic experiments, different multisines "
          f"(5 periods, 3 dropped): {rel.shape[0]} of {n_all} fast bins determined (goal: "
          f"1e-9 relative)")
    for i, name in enumerate(hdd.INPUTS):
        bad = rel[:, 0, i] > 1e-9
        where = f" at {freq[bad].min():.0f}-{freq[bad].max():.0f} Hz" if bad.any() else ""
        print(f"   {name}: largest relative error {rel[:, 0, i].max():.1e}; {int(bad.sum())} bins "
              f"above 1e-9{where}; largest error / max(|P(k)|, |P(k +- M)|) "
              f"{normwise[:, 0, i].max():.1e}")
    print(f"   time: window 0 over 4 experiments x 2 periods {t_pooled:.3f} s; LRM window "
          f"{WINDOW} on the 4 experiments one by one {t_one:.3f} s (ratio {t_pooled / t_one:.2f})")

    if not args.skip_experiments:
        report_experiments(variance_against_experiments(args.seeds))
        bands, stats = disturbances_pooled(args.groups, denominators=args.denominator)
        report_disturbances(bands, stats)
    worst, n_ok, n_all = window0_exactness_f3()
    print(f"\n6. window 0 at F = 3 (SISO loop, E = 4 noiseless periodic experiments): largest "
          f"relative error {worst:.1e} over {n_ok} of {n_all} fast bins determined (goal 1e-9)")
    report_cost(pooling_cost())


if __name__ == "__main__":
    main()
