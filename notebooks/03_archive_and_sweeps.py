# %% [markdown]
# # 03 - An archive of experiments, a parallel sweep of settings, and their selection
#
# Many experiments (re-measurements, several drives) are kept as an **archive**: one
# consolidated NetCDF file (or a directory with one file per experiment), opened as one
# lazy dataset with an `experiment` dim.  A **sweep** identifies every experiment for every combination of
# window and degrees as dask tasks, in parallel.  **select_settings** then picks, per
# experiment, the settings that best predict the *other* experiments' measured
# spectra: no true FRF needed.  Small here: 4 experiments x 3 windows x 2 degrees.

# %%
import os
import tempfile

import matplotlib.pyplot as plt
import numpy as np
import xarray as xr

import pandas as pd

import lcmr_xr
from lcmr_xr import hdd, plot
from lcmr_xr.demo import band_errors, band_table, relative_error_table, resonance_peaks

xr.set_options(display_expand_data=False)
plt.rcParams["figure.dpi"] = 80

import dask
from dask.diagnostics import ProgressBar

from lcmr_xr.scaleout import open_archive, save_archive, select_settings, sweep

N = 3600
workdir = tempfile.TemporaryDirectory()
archive_path = os.path.join(workdir.name, "hdd_archive.nc")

# %% [markdown]
# ## 1. Write and open an archive
#
# Four simulated experiments with independent disturbances (seeds 0-3), labelled by
# seed; `save_archive` writes them into one consolidated NetCDF file (`experiment` along an
# unlimited dim, metadata such as `seed` as coordinates; `layout="files"` would write a
# directory of one file each), `open_archive` opens it lazily.

# %%
seeds = [0, 1, 2, 3]
experiments = xr.concat([hdd.simulate(n_samples=N, case=2, noise=True, seed=s) for s in seeds],
                        dim="experiment")
experiments = experiments.assign_coords(
    experiment=("experiment", [f"seed{s}" for s in seeds], {"units": "1", "long_name": "experiment"}))
files = save_archive(experiments, archive_path)
print([f.name for f in files])

archive = open_archive(archive_path)
assert archive.r.chunks is not None  # lazy: nothing read yet beyond metadata
assert np.array_equal(archive.y.values, experiments.y.values)
archive

# %% [markdown]
# ## 2. Sweep window and degrees in parallel
#
# `sweep` returns a lazy FRF dataset with dims `method`, `degrees`, `window` in front of
# the experiment's; computing it runs one task per (setting, experiment) on the
# current dask scheduler (threads here; a `distributed.Client` works the same).

# %%
result = sweep(archive, window=[15, 30, 45], degrees=["2-2-2", "3-3-3"], method="lrm")
print(dict(result.P.sizes))
with dask.config.set(scheduler="threads", num_workers=2), ProgressBar(dt=1.0):
    result = result.compute()
print("flagged bins per setting:", int(result.P_flag.sum()))

# %% [markdown]
# ## 3. Select the settings
#
# With several experiments, the criterion is cross-validation: each experiment's lifted
# estimates predict the other experiments' measured lifted spectra from their
# excitation; the score is the median relative prediction error.

# %%
choice = select_settings(result, archive)
print("criterion:", choice.attrs["criterion"])
print(choice.score.isel(method=0).to_dataframe(name="score").score.unstack("window").round(4).to_string())
for e in choice.experiment.values:
    c = choice.sel(experiment=e)
    print(f"{e}: best method {c.best_method.item()}, degrees {c.best_degrees.item()}, "
          f"window {int(c.best_window)}, score {float(c.best_score):.4f}")

# %% [markdown]
# ## 4. Does the selection agree with the truth?
#
# The simulation gives what a measurement does not: the exact FRF.  The median
# relative error above 500 Hz of every setting, averaged over the experiments, next
# to the validation score:

# %%
truth = hdd.true_frf(result.frequency[1:], case=2).reindex(frequency=result.frequency)
f = result.frequency
useful = (f >= 500.0) & (f < f.max())
true_error = (abs(result.P - truth) / abs(truth)).where(useful).median(["frequency", "output"])
true_error = true_error.mean(["experiment", "input"]).isel(method=0)
mean_score = choice.score.mean("experiment").isel(method=0)
table = xr.Dataset({"true error": true_error, "validation score": mean_score}).reset_coords(drop=True)
print(table.to_dataframe().round(4).to_string())
for name, values in (("lowest true error", true_error), ("lowest mean score", mean_score)):
    best = values.isel(values.argmin(...))
    print(f"{name}: degrees {best.degrees.item()}, window {best.window.item()}")

# %%
workdir.cleanup()  # the archive lived in a temporary directory

# %% [markdown]
# ## 5. Pooling: more periods, more experiments, one better FRF
#
# Engineers rarely stop at one 36 ms record: they
# apply the multisine for several periods (the robust method of Pintelon and Schoukens,
# *System Identification: A Frequency Domain Approach*, 2nd ed., 2012, ch. 2 and 7) and
# repeat experiments.  `hdd.simulate(..., periods=P)` runs `P` periods of one multisine
# from rest; the loop and the disturbances run on across periods, so period 0 carries
# the transient.  `identify` drops it (`transient_periods=1`), averages the rest and
# estimates the noise of the average from the period-to-period spread.

# %%
long_run = hdd.simulate(n_samples=3600, case=2, noise=True, seed=0, periods=9)
print(dict(long_run.y.sizes))  # period, slow_time, output

# %% [markdown]
# The same record, averaged over 1, 2, 4 and 8 steady-state periods: the error falls
# and the band narrows with the number of periods (the noise variance of the average
# falls as 1/K; the local model's approximation error does not).

# %%
f_band = (500.0, 25200.0)
rows = []
for k in (1, 2, 4, 8):
    frf_k = lcmr_xr.identify(long_run.isel(period=slice(0, 1 + k)), window=30,
                             transient_periods=1)
    truth_k = hdd.true_frf(frf_k.frequency[1:], case=2).reindex(frequency=frf_k.frequency)
    in_band = (frf_k.frequency >= f_band[0]) & (frf_k.frequency <= f_band[1])
    rel = (abs(frf_k.P - truth_k) / abs(truth_k)).where(in_band)
    rows.append((k, float(rel.sel(input="vcm").median()), float(rel.sel(input="pzt").median()),
                 float((frf_k.P_std / abs(truth_k)).where(in_band).median()),
                 frf_k.attrs["noise_estimate"]))
print(" K   median rel. error vcm   pzt     median P_std/|P|   noise estimate")
for k, ev, ep, sd, how in rows:
    print(f"{k:2d}   {ev:10.2e}        {ep:8.2e}   {sd:10.2e}        {how}")

# %% [markdown]
# Two estimates of the same noise: from the spread over the periods (model-free,
# `period_noise_variance_y`) and from the residuals of the local model
# (`noise_variance_y`).  Where they agree the local model explains the data; where the
# residual one is larger, the model misses something (or the run-out, which is not
# periodic with the multisine, shows up in both).

# %%
frf8 = lcmr_xr.identify(long_run, window=30, transient_periods=1)
in_slow_band = (frf8.slow_frequency >= f_band[0]) & (frf8.slow_frequency <= f_band[1])
ratio = (frf8.period_noise_variance_y.where(in_slow_band).mean()
         / frf8.noise_variance_y.where(in_slow_band).mean())
print(f"nonparametric / residual noise variance of y, {f_band[0]:g}-{f_band[1]:g} Hz: "
      f"{float(ratio):.2f}")

# %% [markdown]
# **Window 0.**  With `E >= F nu = 4` periodic experiments using *different* multisines,
# the lifted excitations have full rank at every slow bin and determine `G` bin by bin:
# no local model at all.  On noiseless data the estimate is exact; the only
# undetermined bins are those on the slow DC bin, which a multisine without DC does not
# excite.

# %%
exps = xr.concat([hdd.simulate(n_samples=3600, case=2, noise=False, seed=s, periods=5)
                  for s in range(4)], dim="experiment")
pooled = lcmr_xr.identify(exps, window=0, combine="experiment", transient_periods=3,
                          covariance=False)
ok = ~pooled.P_flag
truth_p = hdd.true_frf(pooled.frequency[ok], case=2)
worst = (abs(pooled.P.sel(frequency=truth_p.frequency) - truth_p) / abs(truth_p)).max("frequency")
print("largest relative error:", {k: f"{float(v):.1e}" for k, v in
                                  zip(worst.input.values, worst.isel(output=0).values)})
print(int((~ok).sum()), "undetermined bins at", pooled.frequency[~ok].values, "Hz")

# %% [markdown]
# **Experiments with different multisines, one local model.**  Eight records of one
# period each (each with its own multisine, transient and disturbances) fitted as ONE
# local model: `G` and the denominator shared, a transient term per experiment, one
# noise estimate with `8 (2n + 1) - p` degrees of freedom.  Against one record: the
# error and the band shrink where noise dominates; below 500 Hz the run-out and the
# local model's approximation error shrink less.

# %%
eight = xr.concat([hdd.simulate(n_samples=3600, case=2, noise=True, seed=40 + s)
                   for s in range(8)], dim="experiment")
frf_pooled = lcmr_xr.identify(eight, combine="experiment", errors="ignore")
frf_one = lcmr_xr.identify(eight.isel(experiment=0), errors="ignore")
truth_e = hdd.true_frf(frf_one.frequency[1:], case=2).reindex(frequency=frf_one.frequency)
print(frf_pooled.attrs["pooled_experiments"], "experiments pooled;",
      dict(frf_pooled.transient_y.sizes), "(a transient per experiment)")
table = xr.concat([band_errors(frf_one, truth_e), band_errors(frf_pooled, truth_e)],
                  dim=xr.DataArray(["1 experiment", "8 pooled"], dims="data"))
print(table.to_dataframe(name="median relative error")["median relative error"].unstack("input"))

# %% [markdown]
# **Is the pooled band honest?**  Coverage of the 95 % discs (a flagged bin counts as
# covered).  Pooling shrinks the noise scatter as `1/E`, but least squares gives the LRM a
# noise-induced bias that all experiments share (its denominator regressors carry the
# noise).  So pooled fits estimate the denominator by instrumental variables by default
# (`denominator="iv"`, recorded in `attrs["denominator"]`).  Below 500 Hz, where the data
# barely determine `S`, the local model's own covariance is 2-3x too small; pooled fits
# therefore also fit the even- and odd-numbered experiments apart and scale the covariance
# by their spread (`spread_calibration`), and the halves' own `P` put a factor on the band
# of `P` (`P_spread_calibration`).  Measured over 6 groups of 8: IV coverage 0.94 below
# 500 Hz (0.77-0.78 without the halves) and 0.905-0.967 per band above (least squares:
# 0.93-0.96 and 0.77-0.93); the last cell compares the two denominators.
# `docs/uncertainty.md` ("Pooled bands: the covariance checked by split halves", "The band
# of `P` from the halves' `P`") has the numbers.

# %%
coverage = xr.concat([band_table(frf_one, truth_e).coverage, band_table(frf_pooled, truth_e).coverage],
                     dim=xr.DataArray(["1 experiment", "8 pooled"], dims="data"))
print(coverage.isel(output=0, drop=True).to_dataframe(name="coverage")["coverage"].unstack("input"))
print("denominator of the pooled fit:", frf_pooled.attrs["denominator"])

# %%
frf_pooled_ls = lcmr_xr.identify(eight, combine="experiment", errors="ignore", denominator="ls")
coverage = xr.concat([band_table(frf_pooled_ls, truth_e).coverage,
                      band_table(frf_pooled, truth_e).coverage],
                     dim=xr.DataArray(["8 pooled, least squares", "8 pooled, IV"], dims="data"))
print(coverage.isel(output=0, drop=True).to_dataframe(name="coverage")["coverage"].unstack("input"))
