"""Benchmark of the batched local-model kernel (run as a script; prints a small table).

* HDD-sized problem (M = 1800, nz = 5, nr = 4, n = 30, degrees (3, 3, 3)): kernel vs the
  per-bin lstsq oracle of the tests (time ratio, max relative difference);
* kernel time for window n = 100 vs n = 10 (cost should not grow with the window);
* time per bin at M = 2**16 with covariance=None (extrapolated to 2**19, the speed goal);
* M = 2**19 bins with covariance=None and 2**16 with "diag" (the LRM sandwich covariance),
  one thread, about a minute in all (skip with ``--no-big``).

Ratios are against baselines measured in the same process, never absolute limits.
"""

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # before numpy is imported: time one core

import argparse
import sys
import time

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests"))
from _lrm_oracle import oracle_local_model, resonant_system

from lcmr_xr.kernels.local_models import local_model


def best_time(fn, repeat=3):
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-big", action="store_true",
                        help="skip the M = 2**19 part (about a minute on one core)")
    args = parser.parse_args(argv)
    rows = []
    R, Z, _, _ = resonant_system(1800, 5, 4, seed=0, noise=1e-3)
    dyn = np.ptp(np.log10(np.abs(Z)))
    kw = {"half_width": 30, "degrees": (3, 3, 3)}
    t_kernel = best_time(lambda: local_model(R, Z, **kw))
    t_diag = best_time(lambda: local_model(R, Z, covariance="diag", **kw))
    bins = np.arange(0, 1800, 10)  # the oracle on every 10th bin, scaled to all bins
    t0 = time.perf_counter()
    ref = oracle_local_model(R, Z, 30, (3, 3, 3), bins=bins)
    t_oracle = (time.perf_counter() - t0) * 1800 / len(bins)
    fit = local_model(R, Z, **kw)

    def rel(a, b):
        return float(np.max(np.abs(a[bins] - b[bins]) / np.abs(b[bins])))

    rows.append(("HDD M=1800 kernel, covariance='full' [s]", f"{t_kernel:.4f}"))
    rows.append(("HDD M=1800 kernel, covariance='diag' [s]", f"{t_diag:.4f}"))
    rows.append(("HDD M=1800 lstsq oracle (all bins) [s]", f"{t_oracle:.3f}"))
    rows.append(("oracle / kernel time ratio (goal >= 100)", f"{t_oracle / t_kernel:.1f}"))
    rows.append(("|Z| dynamic range [decades]", f"{dyn:.1f}"))
    rows.append(("max rel diff G", f"{rel(fit.G, ref['G']):.1e}"))
    rows.append(("max rel diff T", f"{rel(fit.T, ref['T']):.1e}"))
    rows.append(("max rel diff noise variance", f"{rel(fit.noise_variance, ref['noise_variance']):.1e}"))
    rows.append(("ill-posed bins", f"{int(fit.ill_posed.sum())}"))

    # best of 9: this shared machine's timings vary by 30 % from run to run
    t10 = best_time(lambda: local_model(R, Z, half_width=10, degrees=(1, 1, 1)), repeat=9)
    t100 = best_time(lambda: local_model(R, Z, half_width=100, degrees=(1, 1, 1)), repeat=9)
    t30_333 = t_kernel
    t100_333 = best_time(lambda: local_model(R, Z, half_width=100, degrees=(3, 3, 3)))
    rows.append(("time n=100 / n=10, degrees (1,1,1) (goal <= 1.5)", f"{t100 / t10:.2f}"))
    rows.append(("time n=100 / n=30, degrees (3,3,3)", f"{t100_333 / t30_333:.2f}"))

    t_none = best_time(lambda: local_model(R, Z, covariance=None, **kw))
    rows.append(("HDD M=1800 kernel, covariance=None [s]", f"{t_none:.4f}"))
    rows.append(("covariance='full' / None time ratio", f"{t_kernel / t_none:.1f}"))

    rng = np.random.default_rng(1)
    mid = 2**16
    Rb = np.exp(2j * np.pi * rng.random((mid, 4)))
    Zb = rng.standard_normal((mid, 5)) + 1j * rng.standard_normal((mid, 5))
    t_mid = best_time(lambda: local_model(Rb, Zb, covariance=None, **kw), repeat=2)
    rows.append(("M=2**16 covariance=None [us per bin]", f"{t_mid / mid * 1e6:.1f}"))
    rows.append(("  extrapolated to M=2**19 [s] (goal < 4)", f"{t_mid * 8:.1f}"))

    if args.no_big:
        return _print(rows)
    t_diag_mid = best_time(lambda: local_model(Rb, Zb, covariance="diag", **kw), repeat=1)
    rows.append(("M=2**16 covariance='diag' [s]", f"{t_diag_mid:.2f}"))
    big = 2**19
    Rb = np.exp(2j * np.pi * rng.random((big, 4)))
    Zb = rng.standard_normal((big, 5)) + 1j * rng.standard_normal((big, 5))
    t_big = best_time(lambda: local_model(Rb, Zb, covariance=None, **kw), repeat=1)
    rows.append(("M=2**19 nz=5 nr=4 (3,3,3) covariance=None [s] (goal < 4)", f"{t_big:.2f}"))

    _print(rows)


def _print(rows):
    width = max(len(r[0]) for r in rows)
    for name, value in rows:
        print(f"{name:<{width}}  {value}")


if __name__ == "__main__":
    main()
