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

Run: ``python benchmarks/pooling.py [--seeds 12] [--noise white fan]`` (about 3 minutes
per noise kind on one core).
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


def report_variance(kind: str, var, noise):
    k = np.log(np.array(COUNTS, dtype=float))
    print(f"\n1. [{kind} output noise] variance of P in {BAND[0]:g}-{BAND[1]:g} Hz against "
          f"averaged periods K = {COUNTS} (goal: slope -1 +- 0.2)")
    for i, name in enumerate(hdd.INPUTS):
        for label, summary in (("mean over bins", np.mean), ("median over bins", np.median)):
            v = np.array([summary(var[c][:, i]) for c in COUNTS])
            slope = np.polyfit(k, np.log(v), 1)[0]
            cells = " ".join(f"{v[j] / v[0]:.3f}" for j in range(len(COUNTS)))
            print(f"   {name} {label:17s}: slope {slope:+.3f};  var(K)/var(1) = {cells}  "
                  f"(1/K = {' '.join(f'{1 / c:.3f}' for c in COUNTS)})")
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


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=12,
                        help="noise realisations per noise kind (default 12)")
    parser.add_argument("--noise", nargs="+", default=["white", "fan"], choices=["white", "fan"],
                        help="output noise kinds to run (default: white fan)")
    args = parser.parse_args(argv)
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


if __name__ == "__main__":
    main()
