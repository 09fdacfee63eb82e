"""Moving means over bins spanning many decades: error and time against one cumulative sum.

``lcmr_xr.kernels.adaptive._running_mean`` (windows cut at the ends) sums every window
from its own bins (``lcmr_xr.kernels.moving.window_sums``).  The baseline here is what it
was before session 17: one cumulative sum over all bins, each window the difference of
two of its values.  Both run on HDD-like terms (magnitudes falling over 14 decades, as
``|P|^2`` of the VCM plant from about 60 dB to -80 dB) and on flat ones; the error is
relative to the exactly rounded window means (``math.fsum``), the times are the best of
several calls alternating in this process (ratios only, no thresholds).

Usage: ``python benchmarks/moving.py [--bins 1801 18001 90001] [--half 6 60]``.
"""

from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from lcmr_xr.kernels.adaptive import _running_mean


def one_cumulative_sum(x, half, axis):
    """The running mean before session 17 (baseline)."""
    x = np.moveaxis(x, axis, 0)
    c = np.concatenate([np.zeros((1,) + x.shape[1:]), np.cumsum(x, axis=0)])
    n = x.shape[0]
    lo, hi = np.clip(np.arange(n) - half, 0, n), np.clip(np.arange(n) + half + 1, 0, n)
    return np.moveaxis((c[hi] - c[lo]) / (hi - lo).reshape((-1,) + (1,) * (x.ndim - 1)), 0, axis)


def exact(x, half):
    """Window means along axis 0 from math.fsum (truth)."""
    n = x.shape[0]
    flat = x.reshape(n, -1)
    out = np.array([[math.fsum(flat[max(k - half, 0):k + half + 1, j]) / (min(k + half + 1, n) - max(k - half, 0))
                     for j in range(flat.shape[1])] for k in range(n)])
    return out.reshape(x.shape)


def best(func, repeats=7, number=10):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for _ in range(number):
            func()
        times.append((time.perf_counter() - start) / number)
    return min(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--bins", type=int, nargs="+", default=[1801, 18001, 90001])
    ap.add_argument("--half", type=int, nargs="+", default=[6, 60])
    args = ap.parse_args(argv)
    rng = np.random.default_rng(0)
    print(f"load average {os.getloadavg()[0]:.1f}")
    for k in args.bins:
        magnitude = np.logspace(6, -8, k)[:, None, None]
        terms = {"HDD-like (1e6..1e-8)": magnitude * rng.random((k, 1, 2)),
                 "flat": rng.random((k, 1, 2))}
        for label, x in terms.items():
            for half in args.half:
                truth = exact(x, half) if k <= 20000 else None
                row = f"bins {k:6d} half {half:3d} {label:22s}"
                if truth is not None:
                    err = [np.max(np.abs(f(x, half, 0) - truth) / np.abs(truth))
                           for f in (one_cumulative_sum, _running_mean)]
                    row += f" max rel error: one sum {err[0]:.1e}, window sums {err[1]:.1e};"
                t_old, t_new = [], []
                for _ in range(3):  # alternating
                    t_old.append(best(lambda: one_cumulative_sum(x, half, 0)))
                    t_new.append(best(lambda: _running_mean(x, half, 0)))
                row += f" time {min(t_new) * 1e6:.0f} us vs {min(t_old) * 1e6:.0f} us ({min(t_new) / min(t_old):.2f}x)"
                print(row, flush=True)
    print(f"load average {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
