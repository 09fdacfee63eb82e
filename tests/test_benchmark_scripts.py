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
    pieces; its bound form (today's c_S) gives identify's own coverage, bin for bin."""
    from lcmr_xr import hdd, identify

    module = _load("accuracy")
    cover = module.band_forms(cases=[2], seeds=1, n_samples=3600)
    exp = hdd.simulate(3600, case=2, noise=True, seed=0)
    frf = identify(exp, denominator="ls")
    truth = hdd.true_frf(frf.frequency[1:], case=2).reindex(frequency=frf.frequency)
    np.testing.assert_allclose(cover["bound c_S (today)"][0, 0],
                               module.band_stats(frf, truth)[..., 1], atol=1e-12)
    # the forms differ where they should: without c_S fewer bins hold the truth
    assert np.all(cover["no c_S"][0, 0, 1:] <= cover["bound c_S (today)"][0, 0, 1:])
    assert cover["no c_S"][0, 0, 1:].sum() < cover["bound c_S (today)"][0, 0, 1:].sum()


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
    z, var, bias2, mse = lrm["white"][0, 2]  # excitation seed 0, 5-25.2 kHz
    assert bias2 > 0.1 and var < 1.0 and mse > var + 0.1
    assert np.all(np.abs(lpm["white"][0, :, 2]) < 0.01)  # medians of bias^2 / G_var
    assert bias["white"].shape == (1, 1800, 5, 4)
