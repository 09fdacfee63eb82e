"""Issue 14 goals that pooling periods and window 0 can measure today (phase 1).

Prints, on the HDD benchmark (case 2, N = 3600, F = 2, the paper's LRM window 30,
degrees 3-3-3):

1. Variance of ``P`` in 500-25 200 Hz against the number of averaged steady-state periods
   ``K = 1, 2, 4, 8`` (noise on the output only: the benchmark's fan vibration; the same
   multisine in every run, new noise per seed; one period dropped as transient): the
   measured slope of log(variance) against log(K) (goal -1 within 20 %) and each
   variance ratio against ``1/K``.
2. The nonparametric noise variance (spread over periods) against the residual one of
   the local model, in the same band (goal: within 20 %).
3. Window 0: ``E = F nu = 4`` noiseless periodic experiments with different multisines,
   ``G = Z R^+`` bin by bin: the largest relative error of ``P`` at every bin the
   experiments determine (goal 1e-9), and the time against identifying the experiments
   one by one with the local model (same process, shared machine: ratios only).

Run: ``python benchmarks/pooling.py [--seeds 20]`` (about 3 minutes on one core).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import xarray as xr

import lcmr_xr
from lcmr_xr import hdd
from lcmr_xr.simulation import simulate_closed_loop

N, CASE, WINDOW, DEGREES = 3600, 2, 30, (3, 3, 3)
BAND = (500.0, 25200.0)
COUNTS = (1, 2, 4, 8)


def _hdd_periods(r: xr.DataArray, periods: int, seed: int) -> xr.Dataset:
    """The HDD loop, ``periods`` periods of ``r``, fan vibration on the output (one record)."""
    d_y = hdd.fan_vibration(periods * N, np.random.default_rng(seed))
    d_y = xr.DataArray(d_y.reshape(periods, N, 1), dims=("period", "time", "output"),
                       attrs={"units": "m"})
    return simulate_closed_loop(hdd.plant(CASE), hdd.controller(), hdd.notch_filters(), hdd.FACTOR,
                                r, d_y=d_y, outputs=list(hdd.OUTPUTS), periods=periods)


def variance_against_periods(seeds: int):
    r = hdd.simulate(N, noise=False, seed=0).r  # one multisine for every run
    estimates = {k: [] for k in COUNTS}
    noise_ratio = []
    band = None
    for seed in range(seeds):
        ds = _hdd_periods(r, 1 + max(COUNTS), 100 + seed)
        for k in COUNTS:
            frf = lcmr_xr.identify(ds.isel(period=slice(0, 1 + k)), window=WINDOW,
                                   degrees=DEGREES, transient_periods=1)
            if band is None:
                f = frf.frequency.values
                band = (f >= BAND[0]) & (f <= BAND[1])
                sf = frf.slow_frequency.values
                slow_band = (sf >= BAND[0]) & (sf <= BAND[1])
            estimates[k].append(frf.P.values[band])
            if k == max(COUNTS):
                np_y = frf.period_noise_variance_y.values[slow_band].mean()
                res_y = frf.noise_variance_y.values[slow_band].mean()
                np_u = frf.period_noise_variance_u.values[slow_band].mean()
                res_u = frf.noise_variance_u.values[slow_band].mean()
                noise_ratio.append((np_y / res_y, np_u / res_u))
        print(f"  seed {seed + 1}/{seeds} done", flush=True)
    var = {k: np.mean(np.var(np.array(v), axis=0, ddof=1), axis=0) for k, v in estimates.items()}
    return var, np.array(noise_ratio)


def window0_exactness():
    exps = xr.concat([hdd.simulate(N, noise=False, seed=s, periods=5) for s in range(4)],
                     "experiment")
    start = time.perf_counter()
    frf = lcmr_xr.identify(exps, window=0, combine="experiment", transient_periods=3,
                           covariance=False)
    t_pooled = time.perf_counter() - start
    one_period = exps.isel(period=-1, drop=True)
    start = time.perf_counter()
    lcmr_xr.identify(one_period, window=WINDOW, degrees=DEGREES)
    t_one_by_one = time.perf_counter() - start
    ok = ~frf.P_flag.values
    truth = hdd.true_frf(frf.frequency.values[ok], case=CASE).values
    rel = np.abs(frf.P.values[ok] - truth) / np.abs(truth)
    return rel.max(axis=0)[0], int(ok.sum()), frf.sizes["frequency"], t_pooled, t_one_by_one


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20,
                        help="noise realisations per number of periods (default 20)")
    args = parser.parse_args(argv)
    if args.seeds < 3:
        parser.error(f"--seeds must be at least 3 to estimate a variance, got {args.seeds}")

    print(f"HDD benchmark case {CASE}, N = {N}, LRM window {WINDOW}, degrees {DEGREES}; "
          f"{args.seeds} noise seeds (fan vibration on the output)")
    var, ratios = variance_against_periods(args.seeds)
    k = np.array(COUNTS, dtype=float)
    print(f"\n1. variance of P in {BAND[0]:g}-{BAND[1]:g} Hz against averaged periods K")
    for i, name in enumerate(hdd.INPUTS):
        v = np.array([var[c][0, i] for c in COUNTS])
        slope = np.polyfit(np.log(k), np.log(v), 1)[0]
        cells = "  ".join(f"K={c}: {v[j] / v[0]:.3f} (1/K = {1 / c:.3f})" for j, c in enumerate(COUNTS))
        print(f"   {name}: slope {slope:+.3f} (goal -1 +- 0.2)   var(K)/var(1): {cells}")
    print(f"\n2. nonparametric / residual noise variance, mean over {BAND[0]:g}-{BAND[1]:g} Hz, "
          f"K = {max(COUNTS)} (median over seeds; goal 0.8-1.2)")
    med = np.median(ratios, axis=0)
    print(f"   output y: {med[0]:.3f}   lifted input u: {med[1]:.3f}")
    worst, n_ok, n_all, t_pooled, t_one = window0_exactness()
    print(f"\n3. window 0, E = 4 noiseless periodic experiments (5 periods, 3 dropped): "
          f"{n_ok} of {n_all} fast bins determined")
    print("   largest relative error: " + ", ".join(
        f"{name} {w:.1e}" for name, w in zip(hdd.INPUTS, worst)) + "   (goal 1e-9)")
    print(f"   time: window 0 over 4 experiments x 2 periods {t_pooled:.3f} s; LRM window "
          f"{WINDOW} on the 4 experiments one by one {t_one:.3f} s (ratio {t_pooled / t_one:.2f})")


if __name__ == "__main__":
    main()
