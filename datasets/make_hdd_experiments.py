"""Regenerate the bundled HDD benchmark experiments, bit for bit, from fixed seeds.

    python datasets/make_hdd_experiments.py

writes, next to this script:

* ``hdd_case2_N3600.nc``  - the paper's experiment: case 2 (room temperature, nominal PZT
  gain), N = 3600 fast samples, excitation rms (8.0e-8, 3.6e-9), disturbances on, seed 0;
* ``hdd_case2_N36000.nc`` - the same settings with N = 36000 fast samples, seed 1.

Each file is re-read and compared with a fresh simulation, so a file that does not match
its seed is never left behind silently.
"""

from __future__ import annotations

from pathlib import Path

import xarray as xr

import lcmr_xr.hdd as hdd
from lcmr_xr.io import open_experiment, save

HERE = Path(__file__).resolve().parent
EXPERIMENTS = {
    "hdd_case2_N3600.nc": dict(n_samples=3600, case=2, noise=True, seed=0, rms=hdd.PAPER_RMS),
    "hdd_case2_N36000.nc": dict(n_samples=36000, case=2, noise=True, seed=1, rms=hdd.PAPER_RMS),
}


def main() -> None:
    for name, settings in EXPERIMENTS.items():
        path = HERE / name
        ds = hdd.simulate(**settings)
        save(ds, path)
        again = open_experiment(path).load()
        xr.testing.assert_equal(again, hdd.simulate(**settings))
        size_mb = path.stat().st_size / 1e6
        print(f"wrote {path.relative_to(HERE.parent)} ({size_mb:.2f} MB): {settings}")


if __name__ == "__main__":
    main()
