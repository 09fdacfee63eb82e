"""Pooled experiments: the covariance calibrated by the spread between two halves.

``combine="experiment"`` fits the even- and odd-numbered experiments apart as well, and
scales the pooled local model's covariance per slow bin by the random-group variance
over the reported one (never below 1).  Against truth: the ratio is 1 where the reported
variances are right (unit Monte Carlo, white noise on a loop), it finds the bins where
the local model understates its noise (a noise resonance narrower than the window) and
there restores the band; on the HDD benchmark the pooled band below 500 Hz covers again.
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
from scipy import signal

from lcmr_xr import conventions as cv
from lcmr_xr.identification import identify
from lcmr_xr.kernels import identification as kid
from lcmr_xr.kernels.excitation import random_phase_multisine
from lcmr_xr.kernels.pooling import split_halves, spread_calibration, spread_ratio
from test_identify import PLANT, _siso_loop, _simulate, _true_frf

K95 = np.sqrt(np.log(20.0))


@pytest.mark.parametrize("n_a, n_b, understated", [(4, 4, 1.0), (3, 5, 1.0), (4, 4, 2.0)])
def test_spread_ratio_is_the_variance_misstatement(n_a, n_b, understated):
    """Two independent group estimates around a common (biased) value: the ratio is the
    true variance of the pooled estimate over the reported one, 1 when calibrated."""
    rng = np.random.default_rng(n_a + int(10 * understated))
    shape, n = (4000, 3, 2), n_a + n_b
    v = rng.uniform(0.5, 2.0, shape)  # true variance of the pooled estimate, per entry

    def draw(k):  # a group of k experiments: variance n / k times the pool's
        return np.sqrt(v * n / k / 2) * (rng.standard_normal(shape) + 1j * rng.standard_normal(shape))

    bias = 3.0 + 1.0j  # common to both groups: cancels
    ratio = spread_ratio(bias + draw(n_a), bias + draw(n_b), v / understated, n_a * n_b / n ** 2)
    assert ratio.shape == (4000,)
    assert abs(ratio.mean() / understated - 1) < 0.05, ratio.mean()


def test_spread_calibration_is_a_smoothed_floor_at_one():
    ratio = np.full(100, 0.5)
    ratio[40:60] = 3.0
    ratio[10] = np.nan
    cal = spread_calibration(ratio, 2)
    assert np.all(cal >= 1) and np.all(np.isfinite(cal))
    assert np.allclose(cal[44:56], 3.0) and np.allclose(cal[:5], 1.0)
    assert np.allclose(spread_calibration(np.full(9, np.nan)), 1.0)
    assert [h.tolist() for h in split_halves(3)] == [[0, 2], [1]]
    with pytest.raises(ValueError, match="at least 2"):
        split_halves(1)


def _pooled(seed, resonance, n_exp=8, n=960, factor=2):
    """8 experiments on the SISO loop of test_identify, output noise white (0.2) or through
    a resonance at 0.1 cycles per sample, a few bins wide (window 30 spans 61 slow bins)."""
    exps = []
    for e in range(n_exp):
        rng = np.random.default_rng(1000 * seed + e)
        r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, rng)
        v = 0.2 * rng.standard_normal((n, 1))
        if resonance:
            rad, w0 = 0.995, 2 * np.pi * 0.1
            v = signal.lfilter([1 - rad], [1, -2 * rad * np.cos(w0), rad ** 2], v, axis=0)
        exps.append(_simulate(_siso_loop(factor), r, factor, d_y=v))
    return xr.concat(exps, "experiment")


def _with_and_without(ds, n=960):
    """The pooled IV fit (window 30) finished with and without the calibration."""
    R, Z = kid.experiment_spectra(ds.r.values, ds.u.values, ds.y.values, factor=2)
    fit = kid._fit(R, Z, half_width=30, degrees=(3, 3, 3), circular=True, covariance=True,
                   noise_covariance=None, experiment_axis=-3, denominator="iv")
    fit["T"] = np.moveaxis(fit["T"], -3, -2)
    kw = dict(n_fast=n, factor=2, nu=1, ny=1, closed_loop="indirect",
              dof=kid.window_dof(30, 2, (3, 3, 3), ds.sizes["experiment"]))
    calibrated = kid._finish(fit, **kw)
    raw = kid._finish({k: v for k, v in fit.items() if k != "spread_ratio"}, **kw)
    assert "spread_calibration" not in raw
    return raw, calibrated


@pytest.mark.slow
@pytest.mark.parametrize("resonance", [False, True])
def test_calibration_keeps_calibrated_bands_and_restores_understated_ones(resonance):
    """Size: white noise, where the kernel's covariance is right, the factor stays near 1
    and the band keeps its coverage.  Power: a noise resonance narrower than the window
    (the local model takes the noise as constant over the window, so it understates it at
    the peak): measured over these 3 seeds, coverage within 12 bins of the peak 0.41
    without, 0.91 with the calibration (median factor there 2.6-9.7; whole band 0.79 ->
    0.88); white noise: factor 1.10 (median), coverage 0.946 -> 0.953."""
    n = 960
    truth = _true_frf(PLANT, n)[1:-1]
    near = np.abs(np.arange(1, n // 2) - 96) <= 12
    stats = []
    for seed in range(3):
        raw, cal = _with_and_without(_pooled(seed, resonance))
        assert np.all(cal["spread_calibration"] >= 1)
        assert np.array_equal(cal["P"], raw["P"], equal_nan=True)  # the estimate is untouched
        err = np.abs(cal["P"][1:-1, 0, 0] - truth)

        def covered(o, sel=slice(None)):
            ok = (err <= K95 * np.sqrt(o["P_var"][1:-1, 0, 0])) | o["P_undetermined"][1:-1]
            return ok[sel].mean()

        c = cal["spread_calibration"]
        stats.append((covered(raw), covered(cal), covered(raw, near), covered(cal, near),
                      np.median(c), np.median(c[np.arange(1, n // 2)[near] % (n // 2)])))
    cov_raw, cov_cal, near_raw, near_cal, median_c, peak_c = np.mean(stats, axis=0)
    if not resonance:
        assert median_c < 1.2, stats
        assert 0.90 <= cov_raw <= 0.99 and 0.90 <= cov_cal <= 0.99, stats
        assert cov_cal - cov_raw < 0.03, stats
    else:
        assert peak_c > 1.8, stats
        assert near_raw < 0.7 and near_cal >= 0.85, stats
        assert cov_cal > cov_raw, stats


def test_identify_pooled_returns_the_factor_with_odd_counts_and_in_chunks():
    """Five experiments (halves of 3 and 2): finite factors >= 1 on every slow bin, the
    same in frequency chunks as eager; fewer than MIN_SPLIT_EXPERIMENTS (halves of one
    record), no covariance or one record: no factor (NaN, or no variable)."""
    from lcmr_xr.kernels.pooling import MIN_SPLIT_EXPERIMENTS

    ds = _pooled(7, True, n_exp=5, n=480)
    frf = identify(ds, window=20, combine="experiment")
    c = frf[cv.SPREAD_CALIBRATION]
    assert c.dims == (cv.SLOW_FREQUENCY,) and c.attrs["units"] == "1"
    assert np.all(np.isfinite(c.values)) and np.all(c.values >= 1) and c.values.max() > 1
    chunked = identify(ds.chunk({"experiment": 1}), window=20, combine="experiment",
                       frequency_chunks=40).compute()
    # 1e-6 as test_denominator_iv's chunked test: the moments of a haloed block are summed
    # in another order and the IV normal equations (of the pool and of each half) amplify it
    for name in (cv.SPREAD_CALIBRATION, "P_std"):
        np.testing.assert_allclose(chunked[name].values, frf[name].values, rtol=1e-6)
    few = identify(ds.isel(experiment=slice(0, MIN_SPLIT_EXPERIMENTS - 1)), window=20,
                   combine="experiment")
    assert np.all(np.isnan(few[cv.SPREAD_CALIBRATION].values))
    assert cv.SPREAD_CALIBRATION not in identify(ds.isel(experiment=0), window=20)
    none = identify(ds, window=20, combine="experiment", covariance=False)
    assert np.all(np.isnan(none[cv.SPREAD_CALIBRATION].values))


@pytest.mark.slow
@pytest.mark.parametrize("group", [2, 3])
def test_hdd_pooled_band_below_500_hz_covers(group):
    """HDD case 2, 8 experiments pooled (``benchmarks/pooling.py`` goal 5's groups 2 and 3,
    whose IV bands covered 0.71 / 0.71 and 0.76 / 0.82 of the bins below 500 Hz before the
    calibration): the factor there is about 2, and with it the 95 % regions (flagged bins
    unbounded) cover >= 90 %.  Group 5 still misses (0.12 / 0.18 -> 0.65 / 0.71; its error
    along the weak direction of ``S`` is common to both halves, docs/uncertainty.md)."""
    from lcmr_xr import hdd

    exps = xr.concat([hdd.simulate(3600, case=2, seed=500 + 8 * group + e) for e in range(8)],
                     "experiment")
    frf = identify(exps, combine="experiment", errors="ignore")
    f = frf.frequency.values
    sel = (f > 0) & (f < 500)
    truth = hdd.true_frf(f[sel], case=2).values[:, 0]
    err = np.abs(frf.P.values[sel, 0] - truth)
    ok = (err <= K95 * frf.P_std.values[sel, 0]) | frf.P_undetermined.values[sel, None]
    assert ok.mean(axis=0).min() >= 0.9, ok.mean(axis=0)
    sf = frf.slow_frequency.values
    assert np.median(frf[cv.SPREAD_CALIBRATION].values[(sf > 0) & (sf < 500)]) > 1.3
