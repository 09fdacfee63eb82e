"""Benchmark of the instrumental-variable local model (run as a script; prints a table).

``local_model(..., instruments=)`` against least squares on the HDD experiment (N = 3600:
M = 1800 slow bins, nz = 5, nr = 4, n = 30, degrees (3, 3, 3)), with the instruments a
first fit's prediction ``G_hat R + T_hat`` (least squares, the same window, made
conjugate-symmetric as the data, so that both fit half the bins and mirror): kernel
times with covariance "full" and None (best of a few repeats, wall / CPU, ratios in the
same process); the IV fit at window n = 120 against n = 12; and the first call of each
compiled version in a new process with an empty numba cache (least squares, IV on one
record, IV pooled: each compiled version on its own; ``--no-compile`` skips it).
Default thread settings, as users run it.

The noise-induced bias (issue 14), at the kernel level: 8 HDD experiments (case 2, the
benchmark disturbances), ``dG = G(disturbances) - G(none)`` with the same excitations,
slow bins of 5-25.2 kHz, one record and the 8 pooled, least squares against IV with the
ideal instruments (the disturbance-free outputs): mean and median ``|dG|^2`` and
``|dG|^2 / G_var`` (1 on average, median ln 2 = 0.69, for a calibrated variance).
"""

import argparse
import os
import subprocess
import sys
import tempfile

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from local_models import best_time, hdd_spectra  # noqa: E402  (the kernel benchmark's)

from lcmr_xr import hdd  # noqa: E402
from lcmr_xr.kernels.identification import experiment_spectra  # noqa: E402
from lcmr_xr.kernels.local_models import local_model  # noqa: E402

KW = {"half_width": 30, "degrees": (3, 3, 3)}

_COLD = """
import time, numpy as np
from lcmr_xr.kernels.local_models import local_model
rng = np.random.default_rng(0)
R = np.exp(2j * np.pi * rng.random((2, 200, 4)))
Z = rng.standard_normal((2, 200, 5)) + 0j
kw = dict(half_width=30, degrees=(3, 3, 3), covariance="full")
which = {which!r}
if which == "iv":
    R, Z, kw["instruments"] = R[0], Z[0], 1.1 * Z[0]
elif which == "iv pooled":
    kw.update(instruments=1.1 * Z, experiment_axis=0)
else:
    R, Z = R[0], Z[0]
t0 = time.perf_counter()
local_model(R, Z, **kw)
print(time.perf_counter() - t0)
"""


def cold_compile(which):
    """First call of one compiled version in a new process, empty numba cache [s]: the
    compile work itself, in one process (no second process compiling the helpers,
    ``lcmr_xr.kernels.compile_ahead``, whose CPU would not be counted and which could
    still be writing into the cache directory when it is removed)."""
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache, LCMR_XR_COMPILE_AHEAD="0")
        out = subprocess.run([sys.executable, "-c", _COLD.format(which=which)], env=env,
                             check=True, capture_output=True, text=True)
    return float(out.stdout.split()[-1])


def _spectra(seed, noise):
    exp = hdd.simulate(n_samples=3600, case=2, noise=noise, seed=seed)
    arrays = [np.asarray(exp[v].transpose(..., d, "input" if v != "y" else "output"))
              for v, d in (("r", "time"), ("u", "time"), ("y", "slow_time"))]
    return experiment_spectra(*arrays, factor=int(exp.attrs["factor"]))


def pooled_bias(rows, n_exp=8):
    """Least squares vs IV, one record and ``n_exp`` pooled (see the module notes)."""
    R, Z, Zc = [], [], []
    for seed in range(n_exp):
        r, z = _spectra(seed, True)
        R.append(r)
        Z.append(z)
        Zc.append(_spectra(seed, False)[1])
    R, Z, Zc = (np.array(x) for x in (R, Z, Zc))
    kw = {"half_width": 30, "degrees": (3, 3, 3), "covariance": "diag"}
    band = slice(round(5000 / 28), 901)  # slow bins of 28 Hz: 5-25.2 kHz
    ref1 = local_model(R, Zc, **kw).G[:, band]
    ref8 = local_model(R, Zc, experiment_axis=0, **kw).G[band]
    for name, extra in (("least squares", {}), ("IV", {"instruments": Zc})):
        one = local_model(R, Z, **kw, **extra)
        pool = local_model(R, Z, experiment_axis=0, **kw, **extra)
        d1 = np.abs(one.G[:, band] - ref1) ** 2
        d8 = np.abs(pool.G[band] - ref8) ** 2
        z8 = d8 / pool.G_cov[band]
        rows.append((f"HDD {n_exp} experiments, {name}: mean |dG|^2 one / pooled (ratio)",
                     f"{d1.mean():.2e} / {d8.mean():.2e} ({d8.mean() / d1.mean():.3f})"))
        rows.append((f"HDD {n_exp} experiments, {name}: median |dG|^2 one / pooled",
                     f"{np.median(d1):.2e} / {np.median(d8):.2e}"))
        rows.append((f"HDD {n_exp} experiments, {name}: pooled |dG|^2 / G_var mean / median",
                     f"{z8.mean():.2f} / {np.median(z8):.2f}"))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--no-compile", action="store_true",
                        help="skip the empty-cache first calls (about a minute each)")
    args = parser.parse_args(argv)
    rows = []
    _, R, Z = hdd_spectra()
    first = local_model(R, Z, covariance=None, **KW)
    Zhat = np.einsum("...kip,...kp->...ki", first.G, R) + first.T
    Zhat = np.where(np.isfinite(Zhat), Zhat, Z)  # flagged bins: the data themselves
    # conjugate-symmetric as the data (a fitted G R + T is so only to the fit's rounding,
    # looser than the mirror test's): the fit then runs on half the bins, as for Z
    Zhat = 0.5 * (Zhat + np.conj(Zhat[(-np.arange(Zhat.shape[0])) % Zhat.shape[0]]))
    local_model(R, Z, instruments=Zhat, **KW)  # compile / load before timing
    for cov in ("full", None):
        ls = best_time(lambda: local_model(R, Z, covariance=cov, **KW))
        iv = best_time(lambda: local_model(R, Z, covariance=cov, instruments=Zhat, **KW))
        rows.append((f"HDD kernel, covariance={cov}: least squares [s]", f"{ls[0]:.3f} / {ls[1]:.3f}"))
        rows.append((f"HDD kernel, covariance={cov}: IV [s]", f"{iv[0]:.3f} / {iv[1]:.3f}"))
        rows.append((f"HDD kernel, covariance={cov}: IV / least squares",
                     f"{iv[0] / ls[0]:.2f} / {iv[1] / ls[1]:.2f}"))
    wide = {}
    for n in (12, 120):  # the fit's cost must not grow with the window (moments by recurrence)
        kw = {"half_width": n, "degrees": KW["degrees"], "covariance": None}
        local_model(R, Z, instruments=Zhat, **kw)
        wide[n] = best_time(lambda: local_model(R, Z, instruments=Zhat, **kw))
    rows.append(("HDD IV fit (covariance None), window n = 120 / n = 12",
                 f"{wide[120][0] / wide[12][0]:.2f} / {wide[120][1] / wide[12][1]:.2f}"))
    fit = local_model(R, Z, instruments=Zhat, **KW)
    ls = local_model(R, Z, **KW)
    rows.append(("HDD flagged bins: least squares / IV",
                 f"{int(ls.ill_posed.sum())} / {int(fit.ill_posed.sum())}"))
    pooled_bias(rows)
    if not args.no_compile:
        for which in ("ls", "iv", "iv pooled"):
            rows.append((f"first call, empty cache: {which} [s]", f"{cold_compile(which):.1f}"))
    width = max(len(r[0]) for r in rows)
    print("(wall / CPU; machine load at start: %.1f)" % os.getloadavg()[0])
    for name, value in rows:
        print(f"{name:<{width}}  {value}")


if __name__ == "__main__":
    main()
