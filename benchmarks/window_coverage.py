"""Coverage of ``window="auto"``'s band per band and per chosen window (HDD benchmark).

The band tables of ``benchmarks/accuracy.py`` average over every bin; the bins where a
rare window is chosen (0.2 % choose the pilot, ``n = 12``) hide in them.  Per band: mean,
worst and best per-case coverage of the 95 % disc ``|P_hat - P| <= sqrt(ln 20) P_std``
(flagged bins counting as covered, as in ``accuracy.py``), then per chosen window the
number of bins, the flagged ones, and the coverage over all and over the unflagged bins,
VCM / PZT (docs/uncertainty.md, "The pilot's band").

Usage: ``python benchmarks/window_coverage.py [--seeds 10] [--cases 1-9] [--n-samples 3600]
[--denominator ls]``.  Prints progress to stderr; about a minute per 40 records.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from lcmr_xr import hdd, identify
from lcmr_xr.demo import BANDS_HZ as BANDS
from lcmr_xr.kernels.adaptive import K95


def record_coverage(frf, truth, tally) -> np.ndarray:
    """Coverage (band, input) of one result; adds its bins per (band, window) to ``tally``."""
    f = frf.frequency.values
    err = np.abs(frf.P.values - truth)[:, 0, :]
    flag = frf.P_undetermined.values
    covered = (err <= K95 * frf.P_std.values[:, 0, :]) | flag[:, None]
    m = frf.sizes["slow_frequency"]
    window = frf.local_window.values[np.arange(f.size) % m]
    interior = (f > 0) & (f < f.max())
    out = []
    for b, (lo, hi) in enumerate(BANDS):
        sel = interior & (f > lo) & (f < hi)
        out.append(covered[sel].mean(axis=0))
        for w in np.unique(window[sel]):
            at = sel & (window == w)
            row = tally.setdefault((b, int(w)), {"n": 0, "flagged": 0, "covered": np.zeros(2),
                                                 "unflagged": 0, "covered_unflagged": np.zeros(2)})
            row["n"] += int(at.sum())
            row["flagged"] += int(flag[at].sum())
            row["covered"] += covered[at].sum(axis=0)
            row["unflagged"] += int((at & ~flag).sum())
            row["covered_unflagged"] += covered[at & ~flag].sum(axis=0)
    return np.array(out)


def run(*, cases, seeds, n_samples, denominator):
    """(per-record coverage (case, seed, band, input), tally per (band, window))."""
    tally, cover = {}, []
    for case in cases:
        for seed in range(seeds):
            exp = hdd.simulate(n_samples, case=case, noise=True, seed=seed,
                               disturbances=hdd.DISTURBANCES)
            frf = identify(exp, window="auto", errors="ignore", denominator=denominator)
            truth = np.full(frf.P.shape, np.nan, complex)
            truth[1:] = hdd.true_frf(frf.frequency.values[1:], case=case).values
            cover.append(record_coverage(frf, truth, tally))
        print(f"  case {case} done", file=sys.stderr, flush=True)
    return np.array(cover).reshape((len(cases), seeds) + cover[0].shape), tally


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--cases", default="1-9", help="plant cases, e.g. 1-9 or 2")
    ap.add_argument("--n-samples", type=int, default=3600)
    ap.add_argument("--denominator", default="ls", choices=["ls", "iv"])
    args = ap.parse_args(argv)
    lo, _, hi = args.cases.partition("-")
    cases = list(range(int(lo), int(hi or lo) + 1))
    t0 = time.perf_counter()
    cover, tally = run(cases=cases, seeds=args.seeds, n_samples=args.n_samples,
                       denominator=args.denominator)
    per_case = cover.mean(axis=1)
    mean, worst, best = cover.mean(axis=(0, 1)), per_case.min(axis=0), per_case.max(axis=0)
    print(f"HDD benchmark, N = {args.n_samples}, disturbances on, cases {args.cases}, "
          f"{args.seeds} seeds, window auto, denominator {args.denominator}: coverage of the "
          "95 % disc VCM/PZT (flagged = covered)")
    for b, (lo_, hi_) in enumerate(BANDS):
        print(f"  {f'{lo_:.0f}-{hi_:.0f} Hz':<14} mean {mean[b, 0]:.3f}/{mean[b, 1]:.3f}  worst case "
              f"{worst[b, 0]:.3f}/{worst[b, 1]:.3f}  best case {best[b, 0]:.3f}/{best[b, 1]:.3f}")
    print("  per chosen window: bins, flagged, coverage of all / of the unflagged bins")
    for (b, w), r in sorted(tally.items()):
        c = r["covered"] / max(r["n"], 1)
        cu = r["covered_unflagged"] / max(r["unflagged"], 1)
        print(f"  {f'{BANDS[b][0]:.0f}-{BANDS[b][1]:.0f} Hz':<14} window {w:>3}: {r['n']:>6} bins, "
              f"{r['flagged']:>5} flagged, {c[0]:.3f}/{c[1]:.3f}; unflagged {r['unflagged']:>6}: "
              f"{cu[0]:.3f}/{cu[1]:.3f}")
    print(f"({time.perf_counter() - t0:.0f} s; machine shared with other jobs)")


if __name__ == "__main__":
    main()
