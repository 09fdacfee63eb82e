"""``identify(..., denominator="iv")``: instrumental variables for the LRM's denominator.

Against truth: noiseless loops are recovered as well as by least squares (the instruments
change nothing where the model is exact), and with pooled noisy experiments, where least
squares' errors-in-variables bias dominates, the IV band covers while least squares' does not.
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

from lcmr_xr import settings
from lcmr_xr.experiment import experiment
from lcmr_xr.identification import identify
from lcmr_xr.kernels import identification as kid
from lcmr_xr.kernels.excitation import random_phase_multisine
from lcmr_xr.kernels.local_models import local_model
from _closed_loop_fd import matrix_frf, periodic_experiment
from test_identify import (CONTROLLER, FILTER, PLANT, TH, _median_rel, _siso_loop, _simulate,
                           _true_frf, assert_same_result)


def test_kernel_denominator_methods_equal_the_settings_table():
    assert tuple(settings.DENOMINATOR) == kid.DENOMINATOR_METHODS


@pytest.mark.parametrize("factor", [2, 3, 4])
def test_noiseless_siso_is_recovered_with_iv(factor):
    """Time-domain loop from rest (F = 2, 3, 4): IV as accurate as least squares."""
    n = 240 * factor
    r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, np.random.default_rng(factor))
    exp = _simulate(_siso_loop(factor), r, factor)
    truth = _true_frf(PLANT, n)
    errs = {}
    for den in ("ls", "iv"):
        frf = identify(exp, window=15, degrees=(3, 3, 3), denominator=den)
        assert frf.attrs["denominator"] == den
        errs[den] = _median_rel(frf.P.values[:, 0, 0], truth)
    assert errs["iv"] < 1e-4 and errs["iv"] < 2 * errs["ls"], errs


def test_noiseless_periodic_lifted_g_is_exact_with_iv():
    """Steady-state periodic data (no transient, frequency-domain construction, F = 3):
    IV gives the same S, PS and P as least squares to rounding of the model error."""
    factor, n = 3, 600
    P = matrix_frf([[PLANT]], n)
    C = matrix_frf([[CONTROLLER]], n // factor)
    Fi = matrix_frf([[FILTER]], n)
    r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, np.random.default_rng(7))
    u, y = periodic_experiment(P, C, Fi, factor, r)
    exp = experiment(r, u, y, factor=factor, sampling_period=TH)
    ls, iv = (identify(exp, window=12, denominator=d) for d in ("ls", "iv"))
    # spectra of real signals: the instruments are conjugate-symmetric exactly (the main
    # fit then fits half the bins and mirrors them)
    R, Z = kid.experiment_spectra(exp.r.values, exp.u.values, exp.y.values, factor=factor)
    zhat = kid.denominator_instruments(R, Z, degrees=(3, 3, 3))
    np.testing.assert_array_equal(zhat[(-np.arange(n // factor)) % (n // factor)], zhat.conj())
    assert _median_rel(iv.P.values[:, 0, 0], P[: n // 2 + 1, 0, 0]) < 1e-4
    assert _median_rel(iv.P.values[:, 0, 0], ls.P.values[:, 0, 0]) < 1e-6


def test_exactly_rational_data_give_g_to_rounding():
    """Kernel layer: data exactly of the local model's form (a rational G and transient
    in the bin index, no noise) are fitted exactly with the first fit's instruments."""
    from _lrm_oracle import continuous_resonance

    m, nz, nr = 200, 2, 2
    k = np.arange(m)
    G, T = continuous_resonance(k, nz, nr, seed=3, width=25.0)
    R = np.exp(2j * np.pi * np.random.default_rng(4).random((m, nr)))
    Z = np.einsum("kip,kp->ki", G, R) + T
    inst = kid.denominator_instruments(R, Z, degrees=(2, 2, 2), circular=False)
    fit = local_model(R, Z, half_width=10, degrees=(2, 2, 2), circular=False, instruments=inst)
    inner = slice(10 + kid.first_fit_window(nr, (2, 2, 2)), m - 10 - kid.first_fit_window(nr, (2, 2, 2)))
    assert np.max(np.abs(fit.G[inner] - G[inner])) / np.max(np.abs(G)) < 1e-9


def test_pooled_instruments_use_the_pooled_first_fit():
    """Pooled: Zhat_e = G1 R_e + T1_e with the pooled G1 and each experiment's T1, for an
    experiment axis anywhere in front."""
    rng = np.random.default_rng(5)
    E, m, nr, nz = 3, 120, 2, 3
    R = rng.standard_normal((E, m, nr)) + 1j * rng.standard_normal((E, m, nr))
    Z = rng.standard_normal((E, m, nz)) + 1j * rng.standard_normal((E, m, nz))
    zhat = kid.denominator_instruments(R, Z, degrees=(1, 1, 1), experiment_axis=0)
    first = local_model(R, Z, half_width=kid.first_fit_window(nr, (1, 1, 1)), degrees=(1, 1, 1),
                        covariance=None, experiment_axis=0)
    expected = np.einsum("mip,emp->emi", first.G, R) + first.T
    np.testing.assert_allclose(zhat, expected, rtol=1e-12, atol=0)
    # experiments in front of a batch axis (E, 2, M, c): each batch its own pooled fit
    both = kid.denominator_instruments(np.stack([R, R]).swapaxes(0, 1),
                                       np.stack([Z, 2 * Z]).swapaxes(0, 1),
                                       degrees=(1, 1, 1), experiment_axis=0)
    np.testing.assert_allclose(both[:, 0], zhat, rtol=1e-12, atol=0)
    np.testing.assert_allclose(both[:, 1], 2 * zhat, rtol=1e-9, atol=0)


def _pooled_noisy(seed, n_exp=8, n=960, noise=0.2, factor=2):
    exps = []
    for e in range(n_exp):
        rng = np.random.default_rng(1000 * seed + e)
        r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, rng)
        exps.append(_simulate(_siso_loop(factor), r, factor, d_y=noise * rng.standard_normal((n, 1))))
    return xr.concat(exps, "experiment")


@pytest.mark.slow
def test_pooled_iv_band_covers_where_least_squares_is_biased():
    """8 pooled experiments, white output noise 0.2, window 30 (SISO, F = 2): least squares'
    errors-in-variables bias does not shrink with pooling, so its band is too narrow; the
    IV band is calibrated.  Measured (these 4 seeds): coverage LS 0.878, IV 0.938; mean squared
    error over band variance (median over seeds) LS 1.88, IV 1.04; mse LS 6.3e-4, IV 3.7e-4.
    With the halves' factor on the band of ``P`` (``P_spread_calibration``, a median over
    13 fast bins whose errors the 61-bin window correlates, floored at 1: about 1.7 in the
    mean where the band is right) the IV band is wider: mse over band variance 0.57,
    coverage 0.956-0.962 (seeds 0, 1)."""
    n = 960
    truth = _true_frf(PLANT, n)[1:-1]
    k95 = np.sqrt(np.log(20.0))
    stats = {"ls": [], "iv": []}
    for seed in range(4):
        ds = _pooled_noisy(seed, n=n)
        for den in stats:
            frf = identify(ds, window=30, combine="experiment", denominator=den, errors="ignore")
            err = np.abs(frf.P.values[1:-1, 0, 0] - truth)
            std = frf.P_std.values[1:-1, 0, 0]
            stats[den].append((np.mean(err <= k95 * std), np.mean(err ** 2), np.mean(std ** 2)))
    ls, iv = (np.array(stats[d]) for d in ("ls", "iv"))
    assert 0.90 <= iv[:, 0].mean() <= 0.99, iv[:, 0]
    assert ls[:, 0].mean() < iv[:, 0].mean() - 0.03, (ls[:, 0], iv[:, 0])
    assert iv[:, 1].mean() < 0.8 * ls[:, 1].mean()  # the bias is gone from the error
    assert 0.45 < iv[:, 1].mean() / iv[:, 2].mean() < 1.4  # mse / band variance


def test_frequency_chunked_iv_equals_eager():
    """The chunks' halo grows by the first fit's window: chunked == eager to rounding, for
    every variable (noisy data, two experiments)."""
    from test_identify import _noisy_siso

    stacked = xr.concat([_noisy_siso(2, 480, s, noise_std=0.01) for s in (3, 4)], "experiment")
    eager = identify(stacked, window=15, denominator="iv")
    lazy = identify(stacked.chunk({"experiment": 1}), window=15, denominator="iv",
                    frequency_chunks=40)
    assert lazy.P.chunks is not None
    # 1e-6: the moments of a haloed block are summed in another order, and the IV normal
    # equations (not Hermitian) amplify that more than least squares'
    assert_same_result(lazy.compute(), eager, rtol=1e-6)
    halo = 15 + kid.first_fit_window(2, (3, 3, 3))
    with pytest.raises(ValueError, match=f"plus 8 for the first fit of denominator='iv'.*"
                                         f"frequency_chunks >= {halo}"):
        identify(stacked, window=15, denominator="iv", frequency_chunks=20)


def test_auto_window_and_pooled_record_the_setting():
    ds = _pooled_noisy(0, n_exp=2, n=480, noise=0.01)
    auto = identify(ds.isel(experiment=0), denominator="iv")
    assert auto.attrs["denominator"] == "iv" and auto.attrs["iv_first_window"] == 8
    pooled = identify(ds, window=20, combine="experiment")  # the pooled default
    assert pooled.attrs["denominator"] == settings.POOLED_DEFAULT_DENOMINATOR == "iv"
    assert identify(ds, window=20, combine="experiment", denominator="ls").attrs["denominator"] == "ls"
    assert identify(ds.isel(experiment=0), window=20).attrs["denominator"] == settings.DEFAULT_DENOMINATOR
    assert identify(ds.isel(experiment=0), method="lpm", window=20).attrs["denominator"] == "none"


@pytest.mark.parametrize("kwargs, error, words", [
    (dict(denominator="IV"), ValueError, ("denominator must be 'ls' or 'iv'", "'IV'")),
    (dict(denominator=1), ValueError, ("denominator must be", "(a int)")),
    (dict(method="lpm", denominator="iv"), ValueError, ("Rd = 0", "denominator='ls'")),
    (dict(degrees=(3, 3, 0), denominator="iv"), ValueError, ("Rd = 0", "method='lrm' with Rd > 0")),
])
def test_bad_denominator_is_refused_before_the_data(kwargs, error, words):
    exp = _simulate(_siso_loop(2), random_phase_multisine(240, 1, np.arange(1, 121), 1.0,
                                                           np.random.default_rng(1)), 2)
    with pytest.raises(error) as info:
        identify(exp, window=15, **kwargs)
    for w in words:
        assert w in str(info.value), (w, str(info.value))
    assert identify(exp, method="lpm", window=15, denominator="ls").attrs["denominator"] == "none"


def test_window0_refuses_iv():
    with pytest.raises(ValueError, match="window=0 fits no local model"):
        identify(_pooled_noisy(0, n_exp=2, n=240, noise=0.0), window=0, combine="experiment",
                 denominator="iv")


def test_sweep_passes_and_records_the_denominator():
    from lcmr_xr.scaleout import sweep
    from lcmr_xr.scaleout.sweep import sweep_settings

    ds = _pooled_noisy(0, n_exp=2, n=480, noise=0.01)
    res = sweep(ds, window=[20], method=["lrm", "lpm"], degrees=["2-2-0"]).compute()
    assert res.denominator_fit.values.tolist() == [["none"], ["none"]]
    res = sweep(ds, window=[20], denominator="iv").compute()
    assert res.denominator_fit.values.tolist() == [["iv"]]
    direct = identify(ds.isel(experiment=1), window=20, denominator="iv", errors="ignore")
    np.testing.assert_allclose(res.P.isel(method=0, degrees=0, window=0, experiment=1).values,
                               direct.P.values, rtol=1e-12)
    pooled = sweep(ds, window=[20], pool=[2]).compute()  # pooled: identify's pooled default
    assert pooled.denominator_fit.values.tolist() == [["iv"]]
    with pytest.raises(ValueError, match=r"method=lpm.*denominator='iv'"):
        sweep_settings(window=[20], method=["lrm", "lpm"], degrees=["3-3-0"], denominator="iv")


def test_command_lines_take_the_denominator(tmp_path, capsys):
    from lcmr_xr.cli import _parser, main
    from lcmr_xr.io import open_frf, save

    exp = _pooled_noisy(0, n_exp=1, n=480, noise=0.01).isel(experiment=0, drop=True)
    save(exp, tmp_path / "e.nc")
    assert main(["identify", str(tmp_path / "e.nc"), "-o", str(tmp_path / "f.nc"),
                 "--window", "20", "--denominator", "iv"]) == 0
    assert open_frf(tmp_path / "f.nc").attrs["denominator"] == "iv"
    assert main(["identify", str(tmp_path / "e.nc"), "-o", str(tmp_path / "g.nc"),
                 "--method", "lpm", "--denominator", "iv"]) == 2
    assert "Rd = 0" in capsys.readouterr().err
    args = _parser().parse_args(["sweep", "a.nc", "-o", "r.nc", "--denominator", "ls"])
    assert args.denominator == "ls"
    with pytest.raises(SystemExit):
        _parser().parse_args(["identify", "a.nc", "-o", "r.nc", "--denominator", "tls"])
