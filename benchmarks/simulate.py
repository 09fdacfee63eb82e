"""Speed of the fast multirate simulator against the sample-by-sample oracle (HDD loop).

Prints times and the ratio measured in this process (no absolute thresholds): the goal is a
ratio of at least 100 and less than 1 s for 2**20 fast samples.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from _multirate_oracle import simulate_multirate_oracle  # noqa: E402

import lcmr_xr.hdd as hdd  # noqa: E402
from lcmr_xr.kernels.lti import simulate_multirate  # noqa: E402


def best_of(repeats, func):
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        result = func()
        times.append(time.perf_counter() - start)
    return min(times), result


def main():
    rng = np.random.default_rng(0)
    loop = hdd.closed_loop()
    parts = (hdd.plant(), hdd.controller(), hdd.notch_filters(), hdd.FACTOR)

    n = 2**14
    r = rng.standard_normal((n, 2)) * hdd.PAPER_RMS
    d_y = hdd.fan_vibration(n, rng)[:, None]
    t_oracle, slow = best_of(1, lambda: simulate_multirate_oracle(*parts, r, d_y=d_y))
    # the first call also builds the block matrices of the loop (memoised per loop object)
    t_cold, _ = best_of(1, lambda: simulate_multirate(loop, r, d_y=d_y))
    t_fast, fast = best_of(3, lambda: simulate_multirate(loop, r, d_y=d_y))
    err = max(np.max(np.abs(a - b)) / np.max(np.abs(b)) for a, b in zip(fast, slow))
    print(f"HDD multirate loop, N = 2**14 fast samples ({loop.system.n_states} states)")
    print(f"  oracle (sample by sample): {t_oracle:8.4f} s")
    print(f"  fast simulator, first call:{t_cold:8.4f} s   (speed-up {t_oracle / t_cold:6.1f} x)")
    print(f"  fast simulator, repeated:  {t_fast:8.4f} s")
    print(f"  speed-up (repeated runs):  {t_oracle / t_fast:8.1f} x   (goal >= 100 x)")
    print(f"  max relative difference:   {err:8.1e}")

    n = 2**20
    r = rng.standard_normal((n, 2)) * hdd.PAPER_RMS
    t_big, _ = best_of(3, lambda: simulate_multirate(loop, r))
    print(f"fast simulator, N = 2**20:   {t_big:8.4f} s   (goal < 1 s)")


if __name__ == "__main__":
    main()
