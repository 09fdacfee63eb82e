"""The benchmark scripts stay runnable (they are not run in full by the suite: minutes each).

Each script is imported as a module and its command line parsed; the reducing sweep task of
the scale-out benchmark is checked against the true HDD FRF.
"""

import importlib.util
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks"


def _load(name):
    spec = importlib.util.spec_from_file_location(f"bench_{name}", BENCH / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("name", ["local_models", "scale_out", "pooling", "accuracy"])
def test_benchmark_command_line_parses(name, capsys):
    module = _load(name)
    with pytest.raises(SystemExit) as exc:
        module.main(["--help"])
    assert exc.value.code == 0
    assert "usage:" in capsys.readouterr().out


def test_simulate_benchmark_imports():
    assert callable(_load("simulate").main)


def test_scale_out_task_reduces_its_experiments_to_their_errors():
    import xarray as xr

    from lcmr_xr import hdd

    module = _load("scale_out")
    exps = xr.concat([hdd.simulate(n_samples=3600, noise=False, seed=3).assign_coords(experiment=e)
                      for e in ("e0", "e1")], "experiment")
    truth = module._truth_of(exps.isel(experiment=0))
    # the truth is the exact FRF on identify's frequency grid
    np.testing.assert_array_equal(truth.values, hdd.true_frf(truth.frequency.values).values)
    out = module.reduced_sweep(exps, truth, per_task=1).compute(scheduler="synchronous")
    assert out.error.dims == ("experiment",) and list(out.experiment.values) == ["e0", "e1"]
    # noiseless benchmark: the paper's settings give ~2e-3 median relative error
    assert np.all((0 < out.error) & (out.error < 1e-2))
    assert np.all(np.isfinite(out.rel_std)) and np.all((0 <= out.flagged) & (out.flagged < 0.05))


def test_accuracy_band_forms_reproduce_identify():
    """The band-form tool (benchmarks/accuracy.py --band-forms) rebuilds the band from its
    pieces; its second-order form (production's, with the denominator's bias in P_bias)
    gives identify's own coverage, bin for bin."""
    from lcmr_xr import hdd, identify

    module = _load("accuracy")
    cover = module.band_forms(cases=[2], seeds=1, n_samples=3600)
    exp = hdd.simulate(3600, case=2, noise=True, seed=0)
    frf = identify(exp, denominator="ls")
    truth = hdd.true_frf(frf.frequency[1:], case=2).reindex(frequency=frf.frequency)
    np.testing.assert_allclose(cover["second order (production)"][0, 0],
                               module.band_stats(frf, truth)[..., 1], atol=1e-12)
    # the forms differ where they should: without c_S fewer bins hold the truth
    assert np.all(cover["no c_S"][0, 0, 1:] <= cover["bound c_S"][0, 0, 1:])
    assert cover["no c_S"][0, 0, 1:].sum() < cover["bound c_S"][0, 0, 1:].sum()


def test_pooling_band_forms_reproduce_identify():
    """The pooled band-form tool (benchmarks/pooling.py --band-forms) rebuilds the pooled
    band from its pieces: it checks inside that production's form (pooled: ``1 / (1 - k
    rho)`` times the halves' factor on P) with production's calibration is identify's own
    P_std (to 1e-9), P and flag; the forms then differ where
    they should, and the other calibrations (of G_cov, and the factor on P) give factors
    of at least 1 and coverages."""
    module = _load("pooling")
    bands, cover, flagged, factor, c_s, ratio2, zlin, t2 = module.pooled_band_forms(
        groups=1, n_exp=4, calibrations=["own (diag halves)", "P halves (median)"])
    bound, none = cover["production", "bound c_S"][0], cover["production", "no c_S"][0]
    assert np.all((0 <= bound) & (bound <= 1)) and np.all(none <= bound + 1e-12)
    assert none.sum() < bound.sum()  # c_S > 1 wherever S^-1 is uncertain
    assert all(np.all((f >= 0) & (f <= 1)) for f in flagged.values()) and t2.size >= 1
    for name in ("own (diag halves)", "P halves (median)"):
        c = cover[name, "bound c_S"][0]
        assert np.all((0 <= c) & (c <= 1)) and np.all(factor[name] >= 1)


def test_accuracy_decomposition_shows_the_lrm_bias_on_white_noise():
    """The decomposition tool (benchmarks/accuracy.py --decomposition) on the HDD loop's
    noiseless spectra plus white circular Gaussian noise, where every assumption of the
    kernel's covariance holds: the LPM (linear in Z) has no bias, the LRM's error at
    5-25.2 kHz is a bias of about 0.2 of the reported variance on top of a variance that
    the kernel does not understate (docs/uncertainty.md, "The local model's covariance is
    right; the excess is the denominator's errors-in-variables bias")."""
    module = _load("accuracy")
    lpm, _ = module.covariance_decomposition(records=8, degrees=(3, 3, 0), variants=("white",))
    lrm, bias = module.covariance_decomposition(records=8, degrees=(3, 3, 3),
                                                variants=("white",))
    z, var, bias2, mse, mse_over_ls = lrm["white"][0, 2]  # excitation seed 0, 5-25.2 kHz
    assert bias2 > 0.1 and var < 1.0 and mse > var + 0.1 and mse_over_ls == 1
    assert np.all(np.abs(lpm["white"][0, :, 2]) < 0.01)  # medians of bias^2 / G_var
    assert bias["white"].shape == (1, 1800, 5, 4)


def test_accuracy_attribution_finds_the_rotational_vibration_below_500_hz():
    """The attribution tool (benchmarks/accuracy.py --attribution): without disturbances the
    adaptive window is right below 500 Hz; the rotational vibration alone (at the VCM input,
    in the controller's direction of the loop) makes the estimate wrong there, and the fan
    vibration and the run-out each cost far less (docs/uncertainty.md, "Lower error below
    500 Hz from one experiment?")."""
    module = _load("accuracy")
    table = module.attribution(cases=[2], seeds=1, n_samples=3600, windows=("auto",))
    assert len(table) == 5 and table[("none", "auto")].shape == (1, 1, 4, 2, 3)
    err = {key: np.median(s[..., 0], axis=(0, 1)) for key, s in table.items()}  # (band, input)
    assert np.all(err[("none", "auto")][0] < 0.02)
    assert np.all(err[("rotational", "auto")][0] > 0.5)
    for other in ("fan", "runout"):
        assert np.all(err[(other, "auto")][0] < 0.5 * err[("rotational", "auto")][0])
    # the flag sees it: below 500 Hz nearly every bin is undetermined with the rotational
    # vibration, few without disturbances
    assert table[("rotational", "auto")][0, 0, 0, 0, 2] > 0.8
    assert table[("none", "auto")][0, 0, 0, 0, 2] < 0.2


@pytest.mark.parametrize("real", [False, True])
def test_accuracy_jackknife_instruments_are_the_leave_one_out_lpm_predictions(real):
    """The prototype instruments of benchmarks/accuracy.py (--instruments lpm / jackknife)
    against a literal per-bin least-squares fit of the LPM (degrees (Rn, Rm, 0)): the
    prediction at the centre bin, and the fit without the centre bin predicting it (the
    leave-one-out identity with the batched leverage); windows wrap around the circle."""
    module = _load("accuracy")
    rng = np.random.default_rng(3)
    m, nr, nz, n, rn, rm = 48, 2, 3, 9, 2, 1
    R = rng.standard_normal((m, nr)) + 1j * rng.standard_normal((m, nr))
    Z = rng.standard_normal((m, nz)) + 1j * rng.standard_normal((m, nz))
    if real:  # spectra of real signals: the instruments are conjugate-symmetric too
        R, Z = (np.fft.fft(rng.standard_normal((m, c)), axis=0) for c in (nr, nz))
    plain = module.jackknife_instruments(R, Z, degrees=(rn, rm, 1), first_window=n,
                                         jackknife=False)
    loo = module.jackknife_instruments(R, Z, degrees=(rn, rm, 1), first_window=n)
    h = module.centre_leverage(R, n, (rn, rm))
    r = np.arange(-n, n + 1)
    x = r / n
    for k in range(m):
        idx = (k + r) % m
        A = np.concatenate([(R[idx][:, :, None] * x[:, None, None] ** np.arange(rn + 1))
                            .reshape(r.size, -1), x[:, None] ** np.arange(rm + 1)], axis=1)
        a0 = A[n]
        theta = np.linalg.lstsq(A, Z[idx], rcond=None)[0]
        keep = r != 0
        theta_loo = np.linalg.lstsq(A[keep], Z[idx][keep], rcond=None)[0]
        np.testing.assert_allclose(h[k], np.real(a0 @ np.linalg.solve(A.conj().T @ A, a0.conj())),
                                   rtol=1e-9)
        if not real:
            np.testing.assert_allclose(plain[k], a0 @ theta, rtol=1e-8, atol=1e-10)
            np.testing.assert_allclose(loo[k], a0 @ theta_loo, rtol=1e-8, atol=1e-10)
    if real:  # symmetrised: equal to the per-bin fits to their rounding, and Hermitian
        k = np.arange(m)
        np.testing.assert_allclose(loo[(-k) % m], np.conj(loo), atol=1e-12)
        idx = (5 + r) % m
        A = np.concatenate([(R[idx][:, :, None] * x[:, None, None] ** np.arange(rn + 1))
                            .reshape(r.size, -1), x[:, None] ** np.arange(rm + 1)], axis=1)
        theta_loo = np.linalg.lstsq(A[r != 0], Z[idx][r != 0], rcond=None)[0]
        np.testing.assert_allclose(loo[5], A[n] @ theta_loo, rtol=1e-8)


def test_accuracy_jackknife_lrm_instruments_leave_the_centre_bin_out_per_row():
    """With the LRM first stage (--instruments "jackknife lrm") the regressors hold the
    other bins' Z (one regression per output row); the centre row holds none (``x^d`` with
    ``d >= 1`` vanishes at ``r = 0``), so the per-row leave-one-out identity is exact:
    against a literal per-bin, per-row least-squares fit without the centre bin."""
    module = _load("accuracy")
    rng = np.random.default_rng(4)
    m, nr, nz, n, rn, rm, rd = 40, 2, 2, 9, 1, 1, 2
    R = rng.standard_normal((m, nr)) + 1j * rng.standard_normal((m, nr))
    Z = rng.standard_normal((m, nz)) + 1j * rng.standard_normal((m, nz))
    loo = module.jackknife_instruments(R, Z, degrees=(rn, rm, rd), first_window=n, first="lrm")
    assert module.centre_leverage(R, n, (rn, rm, rd), Z=Z).shape == (m, nz)
    r = np.arange(-n, n + 1)
    x = r / n
    for k in range(0, m, 3):
        idx = (k + r) % m
        for i in range(nz):
            A = np.concatenate([(R[idx][:, :, None] * x[:, None, None] ** np.arange(rn + 1))
                                .reshape(r.size, -1), x[:, None] ** np.arange(rm + 1),
                                -Z[idx, i, None] * x[:, None] ** np.arange(1, rd + 1)], axis=1)
            theta = np.linalg.lstsq(A[r != 0], Z[idx, i][r != 0], rcond=None)[0]
            np.testing.assert_allclose(loo[k, i], A[n] @ theta, rtol=1e-7)


def test_accuracy_decomposition_wide_first_stage_instruments_trade_bias_for_variance():
    """--decomposition --denominator iv --instruments lrm --first-window 30 on white noise
    (docs/uncertainty.md, "Instruments from a wider or leave-one-out first stage"): the
    LRM first stage in window 30 removes the errors-in-variables bias that least squares
    shows (bias^2 > 0.1 G_var in the test above) and costs more mse than least squares."""
    module = _load("accuracy")
    iv, _ = module.covariance_decomposition(records=8, variants=("white",), denominator="iv",
                                            instruments="lrm", first_window=30)
    z, var, bias2, mse, mse_over_ls = iv["white"][0, 2]  # excitation seed 0, 5-25.2 kHz
    assert abs(bias2) < 0.05 and mse_over_ls > 1.0  # 30 records: 0.00, 1.15-1.16


def test_pooling_decomposition_rebuilds_identify_band():
    """The pooled decomposition tool (benchmarks/pooling.py --decompose) rebuilds the pooled
    band from its ingredients at identify's own window choice: it checks inside that the
    full band reproduces identify's P_std (to 1e-9) and P; the ingredients then order as
    they must (a factor of at least 1 never loses a covered bin)."""
    module = _load("pooling")
    bands, cover, flagged, medians = module.pooled_band_decomposition(groups=1, n_exp=4)
    assert len(bands) == cover["production (all)"].shape[1] == flagged.shape[1]
    for row in cover.values():
        assert np.all((0 <= row) & (row <= 1))
    # c_dof >= 1 and c_S >= 1: each widens the band, so coverage never falls
    assert np.all(cover["c_dof"] >= cover["P_std_linear"] - 1e-12)
    assert np.all(cover["c_dof c_S"] >= cover["c_dof"] - 1e-12)
    assert np.all(cover["production (all)"] >= cover["c_dof c_P"] - 1e-12)
    assert np.all((0 <= flagged) & (flagged <= 1))


def test_pooling_decomposition_hausman_rows_widen_their_base():
    """--decompose --hausman: the Hausman term of pooled least squares against pooled IV
    (b2H >= 0) is added to a band, so each such row covers at least what its base row
    covers; the halves' shared error and difference are reported (finite means)."""
    module = _load("pooling")
    bands, cover, flagged, medians = module.pooled_band_decomposition(groups=1, n_exp=4,
                                                                      hausman=True)
    for name, base in (("prod. + b2_H", "production (all)"),
                       ("c_dof c_P + P_bias + b2_H", "c_dof c_P + P_bias"),
                       ("prod., c_S 2nd order + b2_H", "prod., c_S 2nd order")):
        assert np.all(cover[name] >= cover[base] - 1e-12)
    shared = medians["shared Re(e_a e_b*) / (c_dof^2 v) (mean)"]
    spread = medians["w |e_a - e_b|^2 / (c_dof^2 v) (mean)"]
    assert np.all(np.isfinite(shared[:, 1:])) and np.all(spread[:, 1:] > 0)


def test_pooling_decomposition_variants():
    """The measurement variants of --decompose (benchmarks/pooling.py _variant): the
    circular fan vibration is its filter's periodic steady state (its DFT is the filter's
    FRF times the noise's DFT, its standard deviation the stationary one, 3.0 nm); the
    pooled instruments without their own transient are G1 R; the noise covariance as
    estimated is not mended; the pooled band's nonlinearity factor is the second-order one;
    all undone on exit."""
    from lcmr_xr.hdd import benchmark as hb, disturbances as hd
    from lcmr_xr.kernels import identification as kid
    from lcmr_xr.kernels.lti import frequency_response

    module = _load("pooling")
    from lcmr_xr.kernels.adaptive import second_order_factor

    fan, prediction = hb.fan_vibration, kid._prediction
    nearest, pooled_factor = kid.nearest_correlation, kid.pooled_nonlinearity_factor
    s = np.array([[1.0, 2.2], [2.2, 4.0]]) + 0j  # correlation 1.1
    assert abs(kid.nearest_correlation(s)[0, 1] - 2.0) < 1e-12  # production: mended
    n = 1 << 16
    with module._variant(circular_fan=True, own_transient=False, psd=False, second_order=True):
        np.testing.assert_array_equal(kid.nearest_correlation(s), s)
        assert kid.pooled_nonlinearity_factor is second_order_factor
        x = hb.fan_vibration(n, np.random.default_rng(3))
        e = hd.NOISE_SCALE * np.random.default_rng(3).uniform(-0.5, 0.5, size=n)
        H = frequency_response(hd.fan_filter(), np.fft.rfftfreq(n, d=hd.FAST_PERIOD))[:, 0, 0]
        np.testing.assert_allclose(np.fft.rfft(x), H * np.fft.rfft(e), atol=1e-9 * np.abs(H).max())
        std = hd.stationary_std(hd.fan_filter(), hd.NOISE_SCALE * hd.UNIFORM_STD)[0]
        assert abs(x.std() / std - 1) < 0.05
        rng = np.random.default_rng(0)
        G = rng.standard_normal((5, 2, 3)) + 0j
        R = rng.standard_normal((4, 5, 3)) + 0j
        T = rng.standard_normal((4, 5, 2)) + 0j
        Z = np.full((4, 5, 2), np.nan + 0j)
        zhat = kid._prediction(G, T, R, Z, circular=False, experiment_axis=0)
        np.testing.assert_allclose(zhat, np.einsum("mip,emp->emi", G, R))
        np.testing.assert_allclose(kid._prediction(G, T[0], R[0], Z[0], circular=False),
                                   np.einsum("mip,mp->mi", G, R[0]) + T[0])  # one record: as before
    assert hb.fan_vibration is fan and kid._prediction is prediction
    assert kid.nearest_correlation is nearest and kid.pooled_nonlinearity_factor is pooled_factor


def test_accuracy_window_tally_splits_the_band_table_by_chosen_window():
    """The per-window tool (benchmarks/accuracy.py --per-window): per band its windows' bins
    add up to the band's, and its unflagged covered bins plus the flagged ones give the band
    table's coverage exactly; the coverage counts the released bins against the truth only
    (a truth equal to the estimate: all covered; far from it: none)."""
    from lcmr_xr import hdd, identify

    module = _load("accuracy")
    exp = hdd.simulate(3600, case=2, noise=True, seed=0)
    frf = identify(exp, denominator="ls")
    truth = hdd.true_frf(frf.frequency[1:], case=2).reindex(frequency=frf.frequency)
    stats = module.band_stats(frf, truth)  # (band, input, [error, coverage, flagged])
    tally = module.window_tally(frf, truth)
    f = frf.frequency.values
    windows = set(frf.local_window.values.tolist())
    assert {w for _, w in tally} <= windows and len({w for _, w in tally}) >= 2
    for b, (lo, hi) in enumerate(module.BANDS):
        rows = [r for (bb, _), r in tally.items() if bb == b]
        n = ((f > lo) & (f < hi) & (f > 0) & (f < f.max())).sum()
        assert sum(r["bins"] for r in rows) == n
        assert all(r["flagged"] + r["unflagged"] == r["bins"] for r in rows)
        flagged = sum(r["flagged"] for r in rows)
        covered = sum(r["covered"] for r in rows)
        np.testing.assert_allclose((covered + flagged) / n, stats[b, :, 1], rtol=0, atol=1e-12)
        np.testing.assert_allclose(flagged / n, stats[b, 0, 2], rtol=0, atol=1e-12)
    exact = module.window_tally(frf, frf.P)
    assert all(np.all(r["covered"] == r["unflagged"]) for r in exact.values())
    far = module.window_tally(frf, frf.P + 1e6 * (1 + frf.P_std.where(np.isfinite(frf.P_std), 0)))
    assert all(np.all(r["covered"] == 0) for r in far.values())
    # and the tally accumulates over records
    twice = module.window_tally(frf, truth, module.window_tally(frf, truth))
    assert all(twice[k]["bins"] == 2 * tally[k]["bins"] and
               np.all(twice[k]["covered"] == 2 * tally[k]["covered"]) for k in tally)
    # a fixed window (--windows 30): one row per band, that window's, adding up to the band
    fixed = identify(exp, window=30, denominator="ls")
    stats = module.band_stats(fixed, truth)
    tally = module.window_tally(fixed, truth)
    assert sorted(tally) == [(b, 30) for b in range(len(module.BANDS))]
    for (b, _), r in tally.items():
        n = ((f > module.BANDS[b][0]) & (f < module.BANDS[b][1]) & (f > 0) & (f < f.max())).sum()
        assert r["bins"] == n
        np.testing.assert_allclose((r["covered"] + r["flagged"]) / n, stats[b, :, 1], atol=1e-12)
