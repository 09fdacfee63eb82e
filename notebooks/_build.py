"""Write the tutorial notebooks of ``notebooks/`` from the cell sources below.

The notebooks are generated so that a review reads plain Python, not JSON, and so
that they are committed with their outputs cleared.  Run from anywhere::

    .venv/bin/python notebooks/_build.py

``tests/test_notebooks.py`` executes the written notebooks and checks that they are
the ones this script writes (so an edit of the ``.ipynb`` alone is caught).
"""

from __future__ import annotations

import sys
import textwrap
from pathlib import Path

import nbformat
from nbformat.v4 import new_code_cell, new_markdown_cell, new_notebook

HERE = Path(__file__).resolve().parent


def _cells(spec):
    """``[("md" | "py", source or tuple of sources), ...]`` -> cells; each part is dedented."""
    cells = []
    for i, (kind, source) in enumerate(spec):
        parts = source if isinstance(source, tuple) else (source,)
        text = "\n\n".join(textwrap.dedent(part).strip("\n") for part in parts)
        make = new_markdown_cell if kind == "md" else new_code_cell
        # fixed ids: nbformat would draw random ones, and every rebuild would show a diff
        cells.append(make(text, id=f"cell-{i:02d}"))
    return cells


# Shared first cell: imports and the few settings every notebook states up front.
SETUP = """
    import os
    import tempfile

    import matplotlib.pyplot as plt
    import numpy as np
    import xarray as xr

    import pandas as pd

    import lcmr_xr
    from lcmr_xr import hdd, plot
    from lcmr_xr.demo import relative_error_table, resonance_peaks

    xr.set_options(display_expand_data=False)
    plt.rcParams["figure.dpi"] = 80
"""

# Median relative error per frequency band; defined in the notebooks that need it so each
# notebook reads on its own.
BAND_ERRORS = """
    def band_median(x, slow_nyquist, low=500.0):
        \"\"\"Median of ``x`` over ``frequency`` in three bands (DC and fast Nyquist left out).\"\"\"
        f = x.frequency
        bands = {
            f"{f[1].item():.0f}-{low:.0f} Hz": (f > 0) & (f < low),
            f"{low:.0f} Hz-slow Nyquist": (f >= low) & (f < slow_nyquist),
            "slow-fast Nyquist": (f > slow_nyquist) & (f < f.max()),
        }
        out = xr.concat([x.where(sel).median("frequency") for sel in bands.values()],
                        dim=xr.DataArray(list(bands), dims="band", name="band"))
        return out.isel(output=0, drop=True)


    def band_errors(frf, truth, low=500.0):
        \"\"\"Median relative error |P_hat - P| / |P| per input in three bands.\"\"\"
        out = band_median(abs(frf.P - truth) / abs(truth), frf.attrs["slow_nyquist"], low)
        return out.assign_attrs(units="1", long_name="median relative error")
"""

NB01 = [
    ("md", """
        # 01 - The dual-stage HDD benchmark: from simulation to the fast-rate FRF

        This notebook repeats the experiment of van Haren, Mae, Blanken and Oomen,
        *Lifted frequency-domain identification of closed-loop multirate systems*
        (Mechatronics 108:103311) on the simulated IEEJ dual-stage hard-disk-drive
        benchmark: two actuators (VCM and PZT) are excited at the fast rate
        `Th = 1/100800 s`, the head position is measured at the slow rate `Tl = 2 Th`
        (factor `F = 2`), and the loop runs through slow controllers.  The goal is the
        fast-rate FRF of both actuators **up to the fast Nyquist frequency (50.4 kHz)**,
        twice as far as the slow output alone allows (25.2 kHz).

        Every number printed below is measured here, in this run.
    """),
    ("py", (SETUP, """
        N, SEED = 3600, 0  # the paper's record: N fast samples = 1800 slow samples, one period
    """)),
    ("md", """
        ## 1. The experiment dataset

        `hdd.simulate` returns an *experiment dataset* (data contract `lcmr-xr-1`): fast
        excitation `r` and measured plant input `u` on (`time`, `input`), slow measured
        output `y` on (`slow_time`, `output`), attribute `factor`.  The noiseless twin has
        the same excitation and no disturbances (rotational vibration, fan vibration,
        repeatable run-out).
    """),
    ("py", """
        exp = hdd.simulate(n_samples=N, case=2, noise=True, seed=SEED)
        exp_clean = hdd.simulate(n_samples=N, case=2, noise=False, seed=SEED)
        assert np.array_equal(exp.r.values, exp_clean.r.values)  # same excitation

        F = exp.attrs["factor"]
        Th = float(exp.time[1] - exp.time[0])
        print(f"F = {F}, Th = {Th:.4e} s, Tl = {F * Th:.4e} s")
        print(f"slow Nyquist {1 / (2 * F * Th):.0f} Hz, fast Nyquist {1 / (2 * Th):.0f} Hz, "
              f"bin spacing {1 / (N * Th):.0f} Hz")
        exp
    """),
    ("py", """
        for name in ("r", "u", "y"):
            da = exp[name]
            print(f"{name}: dims {da.dims}, units {da.attrs['units']!r}, {da.attrs['long_name']}")

        fig, axes = plt.subplots(3, 1, figsize=(8, 6), sharex=True)
        window = dict(time=slice(0, 2e-3))
        exp.r.sel(input="vcm").sel(**window).plot(ax=axes[0], label="r")
        exp.u.sel(input="vcm").sel(**window).plot(ax=axes[0], label="u")
        exp.u.sel(input="pzt").sel(**window).plot(ax=axes[1], label="u")
        exp.y.sel(output="position", slow_time=slice(0, 2e-3)).plot(ax=axes[2], marker=".")
        for ax in axes[:2]:
            ax.legend()
        for ax in axes:
            ax.set_title("")
        fig.tight_layout()
        plt.show()
    """),
    ("md", """
        ## 2. Lifting and the DFT identity

        Lifting by `F` cuts the fast record into `M = N/F` blocks: element `[l, j]` of the
        lifted signal is `x(l F + j)`, so a fast signal becomes an `F`-channel slow signal
        (dim `lift_phase`).  The closed loop is linear time-invariant in these slow
        signals, which is what makes identification at the slow rate possible.
    """),
    ("py", """
        r_lifted = lcmr_xr.lift(exp.r, factor=F)  # time (N) -> slow_time (M) x lift_phase (F)
        print(dict(r_lifted.sizes))

        l, j = 7, 1
        assert np.array_equal(r_lifted.isel(slow_time=l, lift_phase=j).values,
                              exp.r.isel(time=l * F + j).values)
        xr.testing.assert_identical(lcmr_xr.unlift(r_lifted), exp.r)  # exact inverse
        print("lift: element [l, j] is x(l F + j); unlift(lift(r)) is identical to r")
    """),
    ("md", """
        The fast spectrum follows from the slow spectra of the lifted phases:
        `X(k) = sum_j exp(-2j pi k j / N) X_j(k mod M)`.  Fast bins `k` and `k + M` fold
        onto the same slow bin; the phase factors keep them apart, which is how the
        lifted estimate reaches beyond the slow Nyquist frequency.
    """),
    ("py", """
        R_fast = lcmr_xr.dft(exp.r)                              # N bins on `frequency`
        R_phases = lcmr_xr.dft(r_lifted, dim="slow_time")         # M bins per lift phase
        R_rebuilt = lcmr_xr.fast_spectrum_from_lifted(R_phases)   # back to N fast bins
        identity_error = float(abs(R_rebuilt - R_fast).max() / abs(R_fast).max())
        print(f"R_fast: dims {R_fast.dims}, scaling {R_fast.attrs['dft_scaling']!r}")
        print(f"max |X(k) - sum_j exp(-2j pi k j/N) X_j(k mod M)| / max |X| = {identity_error:.1e}")
        assert identity_error < 1e-12
    """),
    ("md", """
        ## 3. Identification with the paper's settings

        Local rational model (LRM), window `n = 30` (61 slow bins), degrees
        `(Rn, Rm, Rd) = (3, 3, 3)`, indirect closed-loop estimate `P_1 = PS_1 S^-1`.
        The exact FRF of the (ZOH-discretised) benchmark plant is the truth; the VCM's
        rigid-body mode makes it infinite at DC, so DC is left out.
    """),
    ("py", """
        settings = dict(method="lrm", window=30, degrees=(3, 3, 3))
        frf = lcmr_xr.identify(exp, **settings)
        frf_clean = lcmr_xr.identify(exp_clean, **settings)
        truth = hdd.true_frf(frf.frequency[1:], case=2).reindex(frequency=frf.frequency)
        frf
    """),
    ("py", """
        result = plot.bode(frf, truth=truth, band=0.95)
        result.figure.set_size_inches(11, 6)
        result.figure.suptitle("with disturbances: lifted indirect LRM (window 30, degrees 3, 3, 3)")
        plt.show()
    """),
    ("md", """
        ### The PZT resonances beyond the slow Nyquist frequency

        The PZT's main resonances lie between 40 and 47 kHz, above the slow Nyquist
        frequency (25.2 kHz): a slow-rate identification cannot see them at their true
        frequency.  The lifted estimate recovers them.
    """),
    ("py", """
        zoom = plot.bode(frf.sel(input=["pzt"]), truth=truth.sel(input=["pzt"]), band=0.95,
                         xlim=(38e3, 50.4e3))
        zoom.figure.suptitle("PZT around 44 kHz")
        plt.show()

        bin_hz = float(frf.frequency[1])
        print("largest PZT resonance peaks, true -> estimated (offset in bins of 28 Hz):")
        for name, estimate in (("noiseless", frf_clean), ("with disturbances", frf)):
            peaks = resonance_peaks(estimate, truth, input="pzt")
            print(f"  {name}: " + ", ".join(
                f"{t:.0f} -> {e:.0f} Hz ({(e - t) / bin_hz:+.0f})" for t, e in peaks))
        # without disturbances every peak must sit on its true bin
        assert all(t == e for t, e in resonance_peaks(frf_clean, truth, input="pzt"))
    """),
    ("md", """
        ### What the estimator saw: the lifted sensitivity `S` and process sensitivity `PS`

        The identification first estimates the lifted (slow-rate, `F nu`-channel) closed-loop
        maps from the lifted excitation: `S` (`lift_phase`, `input` <- `lift_phase2`,
        `input2`) and the first block row of `PS`.  The residual noise variance of each row
        shows where the disturbances act.
    """),
    ("py", """
        plot.lifted(frf, which="S").figure.set_size_inches(11, 8)
        plt.show()
        plot.lifted(frf, which="PS").figure.set_size_inches(11, 3)
        plt.show()
        plot.noise(frf)
        plt.show()
    """),
    ("md", """
        ## 4. How accurate? Noiseless against noisy

        Median relative error `|P_hat - P| / |P|` per actuator, below and above the slow
        Nyquist frequency (`lcmr_xr.demo.relative_error_table`), and in three bands.
    """),
    ("py", (BAND_ERRORS, """

        for name, estimate in (("noiseless", frf_clean), ("with disturbances", frf)):
            table = relative_error_table(estimate, truth).isel(output=0)
            print(f"{name}:")
            for actuator in table.input.values:
                row = table.sel(input=actuator)
                print(f"  {actuator}: below slow Nyquist {float(row.below):.2e}, "
                      f"above {float(row.above):.2e}")
            print("  " + band_errors(estimate, truth).to_pandas().to_string().replace("\\n", "\\n  "))
    """)),
    ("md", """
        Without disturbances the error is the local models' approximation error only.
        With the benchmark disturbances the estimate below a few hundred hertz is poor:
        rotational vibration and run-out dominate there.  `P_std` is the standard
        deviation of the complex estimate, `sqrt(E|P_hat - P|^2)`; for a circular Gaussian
        error the 95 % region is `|P_hat - P| <= sqrt(ln 20) P_std`.  How often does it
        contain the truth?
    """),
    ("py", """
        radius = np.sqrt(np.log(20.0)) * frf.P_std
        f = frf.frequency
        interior = (f > 0) & (f < f.max())
        inside = (abs(frf.P - truth) <= radius).where(interior)
        coverage = inside.mean("frequency").isel(output=0)
        for actuator in coverage.input.values:
            print(f"{actuator}: truth inside the 95 % region at "
                  f"{100 * float(coverage.sel(input=actuator)):.0f} % of the bins")
    """),
    ("py", """
        overlay = plot.bode(frf_clean, truth=truth, band=None, label="noiseless")
        plot.bode(frf, ax=overlay.axes, band=None, label="with disturbances")
        overlay.figure.set_size_inches(11, 6)
        plt.show()
    """),
    ("md", """
        ## 5. Save and open again (NetCDF)

        Experiments and FRF datasets are written with `lcmr_xr.save` (atomic; complex values
        round-trip exactly) and read with `lcmr_xr.open_experiment` / `lcmr_xr.open_frf`,
        which check the data contract.
    """),
    ("py", """
        with tempfile.TemporaryDirectory() as tmp:
            exp_path = lcmr_xr.save(exp, os.path.join(tmp, "hdd_experiment.nc"))
            frf_path = lcmr_xr.save(frf, os.path.join(tmp, "hdd_frf.nc"))
            print(f"{exp_path.name}: {exp_path.stat().st_size / 1e3:.0f} kB, "
                  f"{frf_path.name}: {frf_path.stat().st_size / 1e3:.0f} kB")
            exp_back = lcmr_xr.open_experiment(exp_path).load()
            frf_back = lcmr_xr.open_frf(frf_path).load()
        xr.testing.assert_identical(exp_back, exp)
        xr.testing.assert_identical(frf_back, frf)
        print("round trip: experiment and FRF datasets identical (values, coordinates, attributes)")
    """),
]

NB02 = [
    ("md", """
        # 02 - Methods compared on the same data

        Why the paper's method (lifted, indirect, local rational model) is needed:

        1. **LRM vs LPM** - local rational vs local polynomial models near lightly damped
           resonances;
        2. **indirect vs direct** - the direct estimate `U -> Y` is biased under feedback
           because `u` is correlated with the disturbances; shown by averaging over seeds;
        3. **lifted vs single-rate** - a single-rate estimate reaches only the slow Nyquist
           frequency, and the fast dynamics alias onto it.

        All numbers are measured in this run.
    """),
    ("py", (SETUP, BAND_ERRORS, """

        N = 3600
        exp = hdd.simulate(n_samples=N, case=2, noise=True, seed=0)
        exp_clean = hdd.simulate(n_samples=N, case=2, noise=False, seed=0)
        truth = hdd.true_frf(np.arange(1, N // 2 + 1) / (N * hdd.FAST_PERIOD), case=2)
        # align on the estimate's grid, with DC (where the VCM's FRF is infinite) as NaN
        truth = truth.reindex(frequency=np.arange(N // 2 + 1) / (N * hdd.FAST_PERIOD),
                              method="nearest", tolerance=1e-6)
    """)),
    ("md", """
        ## 1. LRM against LPM

        Same window (`n = 30`, 61 slow bins): LRM with degrees (3, 3, 3), LPM with (3, 3, 0).
        A polynomial in the local frequency variable bends poorly around a lightly damped
        resonance; a rational model has poles of its own.  A narrower window helps the LPM
        (and the LRM near DC) at the price of more noise.
    """),
    ("py", """
        candidates = {
            "LRM n=30 (3,3,3)": dict(method="lrm", window=30, degrees=(3, 3, 3)),
            "LPM n=30 (3,3,0)": dict(method="lpm", window=30, degrees=(3, 3, 0)),
            "LRM n=15 (3,3,3)": dict(method="lrm", window=15, degrees=(3, 3, 3)),
            "LPM n=15 (3,3,0)": dict(method="lpm", window=15, degrees=(3, 3, 0)),
        }
        estimates = {}
        for data_name, data in (("noiseless", exp_clean), ("noisy", exp)):
            for name, settings in candidates.items():
                estimates[data_name, name] = lcmr_xr.identify(data, **settings)
        rows = {key: band_errors(e, truth).to_pandas().T for key, e in estimates.items()}
        table = pd.concat(rows, names=["data", "estimator"])
        print(table.round(4).to_string())
    """),
    ("md", """
        Near the PZT resonances (40-47 kHz, beyond the slow Nyquist frequency), the error of
        the peak magnitude at each true resonance bin:
    """),
    ("py", """
        peaks = resonance_peaks(estimates["noiseless", "LRM n=30 (3,3,3)"], truth, input="pzt")
        true_hz = [t for t, _ in peaks]
        peak_truth = abs(truth.sel(input="pzt", frequency=true_hz).isel(output=0))
        print("true peaks (Hz):", ", ".join(f"{t:.0f}" for t in true_hz))
        for (data_name, name), e in estimates.items():
            peak_est = abs(e.P.sel(input="pzt", frequency=true_hz).isel(output=0))
            err_db = 20 * np.log10(peak_est / peak_truth)
            print(f"{data_name:>9} {name}: peak magnitude error (dB) "
                  + " ".join(f"{v:+6.2f}" for v in err_db.values))

        zoom = dict(xlim=(38e3, 50.4e3), band=None)
        view = plot.bode(estimates["noiseless", "LRM n=30 (3,3,3)"].sel(input=["pzt"]),
                         truth=truth.sel(input=["pzt"]), label="LRM n=30", **zoom)
        plot.bode(estimates["noiseless", "LPM n=30 (3,3,0)"].sel(input=["pzt"]), ax=view.axes,
                  label="LPM n=30", **zoom)
        view.figure.suptitle("noiseless data, PZT resonances")
        plt.show()
    """),
    ("md", """
        ## 2. Indirect against direct, averaged over seeds

        The direct estimate fits a local model from the lifted *measured* input `u` to `y`.
        In closed loop `u` contains the controller's response to the disturbances, so the
        error does not average out: the mean over many experiments converges to something
        other than `P`.  The indirect estimate uses only the excitation `r`, which is
        independent of the disturbances.

        Eight experiments with independent disturbances (seeds 0-7, same excitation
        spectrum), stacked on an `experiment` dim and identified in one call (every function
        broadcasts over leading dims).  For each bin, the mean over the seeds is compared
        with the truth in units of its own standard error
        `sem = sqrt(sum_s |P_s - mean|^2 / ((S - 1) S))`: without bias this ratio is of
        order one (median about 0.8 for a circular Gaussian error), with a bias it grows
        like `sqrt(S)`.
    """),
    ("py", """
        seeds = list(range(8))
        stack = xr.concat([hdd.simulate(n_samples=N, case=2, noise=True, seed=s) for s in seeds],
                          dim="experiment")
        stack = stack.assign_coords(experiment=("experiment", seeds, {"units": "1", "long_name": "seed"}))
        by_method = {
            cl: lcmr_xr.identify(stack, window=30, degrees=(3, 3, 3), closed_loop=cl)
            for cl in ("indirect", "direct")
        }
        noiseless_direct = lcmr_xr.identify(exp_clean, window=30, degrees=(3, 3, 3), closed_loop="direct")
        print(dict(by_method["direct"].P.sizes))
    """),
    ("py", """
        def bias_in_standard_errors(frf_stack):
            \"\"\"Median over each band of |mean_seeds(P_hat) - P| / sem and of |mean - P| / |P|.\"\"\"
            n = frf_stack.sizes["experiment"]
            mean = frf_stack.P.mean("experiment")
            sem = np.sqrt((abs(frf_stack.P - mean) ** 2).sum("experiment") / ((n - 1) * n))
            nyquist = frf_stack.attrs["slow_nyquist"]
            relative = band_median(abs(mean - truth) / abs(truth), nyquist)
            z = band_median(abs(mean - truth) / sem, nyquist)
            return relative, z

        rows = {}
        for name, frf_stack in by_method.items():
            relative, z = bias_in_standard_errors(frf_stack)
            rows[name, "|mean - P| / |P|"] = relative.to_pandas().T
            rows[name, "|mean - P| / sem"] = z.to_pandas().T
        print(pd.concat(rows, names=["estimate", "statistic"]).round(3).to_string())
        print()
        print("noiseless data, direct estimate:")
        print(band_errors(noiseless_direct, truth).to_pandas().T.round(4).to_string())
    """),
    ("md", """
        Without disturbances the direct estimate is accurate (near DC even more than the
        indirect one, whose closed-loop maps `S` and `PS` vary faster there than `P`): the
        bias comes from the feedback of the disturbances, not from the method as such.
        Above 500 Hz, where the excitation dominates, both means sit within about two
        standard errors of the truth.  Below 500 Hz, where rotational vibration and run-out dominate, the
        direct mean is many standard errors away: it converges to the wrong FRF.  The
        indirect estimate is also off there at this signal-to-disturbance ratio (a ratio of
        noisy local estimates), but much less.
    """),
    ("py", """
        low = (30.0, 3000.0)
        view = plot.bode(by_method["indirect"].mean("experiment").sel(input=["vcm"]),
                         truth=truth.sel(input=["vcm"]), band=None, label="indirect, mean of 8", xlim=low)
        plot.bode(by_method["direct"].mean("experiment").sel(input=["vcm"]), ax=view.axes,
                  band=None, label="direct, mean of 8", xlim=low)
        view.figure.suptitle("VCM at low frequency, where the disturbances act")
        plt.show()
    """),
    ("md", """
        ## 3. Lifted against single-rate

        `identify_single_rate` ignores the multirate structure: it samples `r` and `u` at
        the slow rate and forms an ordinary closed-loop estimate on the slow DFT grid.  It
        ends at the slow Nyquist frequency (25.2 kHz), and the fast dynamics above it fold
        back: a resonance at `f` shows up at `1/Tl - f`.
    """),
    ("py", """
        single = lcmr_xr.identify_single_rate(exp_clean, window=30, degrees=(3, 3, 3))
        lifted = estimates["noiseless", "LRM n=30 (3,3,3)"]
        print(f"single-rate: {single.sizes['frequency']} bins up to {float(single.frequency.max()):.0f} Hz; "
              f"lifted: {lifted.sizes['frequency']} bins up to {float(lifted.frequency.max()):.0f} Hz")

        below = truth.sel(frequency=single.frequency)
        for name, estimate in (("lifted", lifted.sel(frequency=single.frequency)), ("single-rate", single)):
            estimate = estimate.assign_attrs(slow_nyquist=float(single.frequency.max()) + 1.0)
            errors = band_errors(estimate, below).isel(band=[0, 1])
            print(f"{name:>12}: " + "; ".join(
                f"{a} " + ", ".join(f"{b} {float(v):.3g}" for b, v in zip(errors.band.values, errors.sel(input=a).values))
                for a in errors.input.values))
    """),
    ("py", """
        slow_rate = 1 / (hdd.FACTOR * hdd.FAST_PERIOD)  # 1/Tl = 50.4 kHz
        print("PZT resonance -> alias in the single-rate band; |P_single| vs |P_true| there (dB)")
        for t in true_hz:
            alias = single.frequency.sel(frequency=slow_rate - t, method="nearest").item()
            at_alias_single = abs(single.P.sel(input="pzt", frequency=alias).item())
            at_alias_truth = abs(truth.sel(input="pzt", frequency=alias).item())
            print(f"  {t:8.0f} Hz -> {alias:8.0f} Hz: "
                  f"{20 * np.log10(at_alias_single / at_alias_truth):+6.1f} dB")

        view = plot.bode(lifted.sel(input=["pzt"]), truth=truth.sel(input=["pzt"]), band=None,
                         label="lifted (this library)")
        plot.bode(single.sel(input=["pzt"]), ax=view.axes, band=None, label="single-rate")
        for t in true_hz:
            view.axes[0, 0].axvline(slow_rate - t, color="tab:red", linewidth=0.5, alpha=0.6)
        view.figure.set_size_inches(9, 6)
        view.figure.suptitle("PZT: single-rate estimate; red lines: aliases of the resonances")
        plt.show()
    """),
    ("md", """
        ## Summary

        * The LRM follows the resonances where the LPM with the same window does not;
          near DC a narrower window is better for both.
        * Under feedback, where the disturbances dominate, the direct estimate converges to
          the wrong FRF; the indirect estimate is far less affected and, where the
          excitation dominates, its mean over seeds sits within its standard error.
        * A single-rate estimate stops at the slow Nyquist frequency and shows the PZT
          resonances at their aliases; the lifted estimate places them correctly, up to
          the fast Nyquist frequency.
    """),
]

NB03 = [
    ("md", """
        # 03 - An archive of experiments, a parallel sweep of settings, and their selection

        Many experiments (re-measurements, several drives) are kept as an **archive**: a
        directory with one NetCDF file per experiment, opened as one lazy dataset with an
        `experiment` dim.  A **sweep** identifies every experiment for every combination of
        window and degrees as dask tasks, in parallel.  **select_settings** then picks, per
        experiment, the settings that best predict the *other* experiments' measured
        spectra: no true FRF needed.  Small here: 4 experiments x 3 windows x 2 degrees.
    """),
    ("py", (SETUP, BAND_ERRORS, """
        import dask
        from dask.diagnostics import ProgressBar

        from lcmr_xr.scaleout import open_archive, save_archive, select_settings, sweep

        N = 3600
        workdir = tempfile.TemporaryDirectory()
        archive_dir = os.path.join(workdir.name, "hdd_archive")
    """)),
    ("md", """
        ## 1. Write and open an archive

        Four simulated experiments with independent disturbances (seeds 0-3), labelled by
        seed; `save_archive` writes one file each, `open_archive` opens them lazily.
    """),
    ("py", """
        seeds = [0, 1, 2, 3]
        experiments = xr.concat([hdd.simulate(n_samples=N, case=2, noise=True, seed=s) for s in seeds],
                                dim="experiment")
        experiments = experiments.assign_coords(
            experiment=("experiment", [f"seed{s}" for s in seeds], {"units": "1", "long_name": "experiment"}))
        files = save_archive(experiments, archive_dir)
        print([f.name for f in files])

        archive = open_archive(archive_dir)
        assert archive.r.chunks is not None  # lazy: nothing read yet beyond metadata
        assert np.array_equal(archive.y.values, experiments.y.values)
        archive
    """),
    ("md", """
        ## 2. Sweep window and degrees in parallel

        `sweep` returns a lazy FRF dataset with dims `method`, `degrees`, `window` in front of
        the experiment's; computing it runs one task per (setting, experiment) on the
        current dask scheduler (threads here; a `distributed.Client` works the same).
    """),
    ("py", """
        result = sweep(archive, window=[15, 30, 45], degrees=["2-2-2", "3-3-3"], method="lrm")
        print(dict(result.P.sizes))
        with dask.config.set(scheduler="threads", num_workers=2), ProgressBar(dt=1.0):
            result = result.compute()
        print("flagged bins per setting:", int(result.P_flag.sum()))
    """),
    ("md", """
        ## 3. Select the settings

        With several experiments, the criterion is cross-validation: each experiment's lifted
        estimates predict the other experiments' measured lifted spectra from their
        excitation; the score is the median relative prediction error.
    """),
    ("py", """
        choice = select_settings(result, archive)
        print("criterion:", choice.attrs["criterion"])
        print(choice.score.isel(method=0).to_dataframe(name="score").score.unstack("window").round(4).to_string())
        for e in choice.experiment.values:
            c = choice.sel(experiment=e)
            print(f"{e}: best method {c.best_method.item()}, degrees {c.best_degrees.item()}, "
                  f"window {int(c.best_window)}, score {float(c.best_score):.4f}")
    """),
    ("md", """
        ## 4. Does the selection agree with the truth?

        The simulation gives what a measurement does not: the exact FRF.  The median
        relative error above 500 Hz of every setting, averaged over the experiments, next
        to the validation score:
    """),
    ("py", """
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
    """),
    ("py", """
        workdir.cleanup()  # the archive lived in a temporary directory
    """),
]

NOTEBOOKS = {
    "01_hdd_benchmark.ipynb": NB01,
    "02_methods_compared.ipynb": NB02,
    "03_archive_and_sweeps.ipynb": NB03,
}


def build_notebooks() -> dict:
    """Build every tutorial notebook in memory, with empty outputs and fixed cell ids.

    Returns
    -------
    dict
        ``{file name: nbformat.NotebookNode}`` in the order of ``NOTEBOOKS``; kernel
        spec ``python3``.

    Examples
    --------
    >>> nbs = build_notebooks()
    >>> sorted(nbs)[0], nbs["01_hdd_benchmark.ipynb"].cells[0].cell_type
    ('01_hdd_benchmark.ipynb', 'markdown')
    """
    out = {}
    for name, spec in NOTEBOOKS.items():
        nb = new_notebook(cells=_cells(spec))
        nb.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
        nb.metadata["language_info"] = {"name": "python"}
        out[name] = nb
    return out


def main(argv=None) -> int:
    """Write the notebooks next to this script.

    Parameters
    ----------
    argv : list of str, optional
        Notebook file names to write; default (None) ``sys.argv[1:]``, and when that is
        empty every notebook.

    Returns
    -------
    int
        Exit status: 0, or 2 (nothing written) when a name is not a known notebook.

    Examples
    --------
    >>> main(["no_such.ipynb"])
    2
    """
    names = list(argv if argv is not None else sys.argv[1:]) or list(NOTEBOOKS)
    unknown = sorted(set(names) - set(NOTEBOOKS))
    if unknown:
        print(f"unknown notebook(s) {unknown}; choose from {sorted(NOTEBOOKS)}", file=sys.stderr)
        return 2
    for name, nb in build_notebooks().items():
        if name in names:
            nbformat.validate(nb)
            nbformat.write(nb, HERE / name)
            print(f"wrote {HERE / name}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
