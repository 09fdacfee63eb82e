"""The main job (``lcmr-xr demo``), the command line, and the HDD benchmark identified."""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr

import lcmr_xr
from lcmr_xr import cli, hdd
from lcmr_xr.demo import (
    BANDS_HZ,
    band_errors,
    band_median,
    band_table,
    find_bundled_experiment,
    relative_error_table,
    resonance_peaks,
    run_demo,
)


@pytest.fixture(scope="module")
def noiseless_hdd_frf():
    exp = hdd.simulate(n_samples=3600, noise=False, seed=1)
    frf = lcmr_xr.identify(exp, window=30, degrees=(3, 3, 3))
    truth = hdd.true_frf(frf.frequency[1:]).reindex(frequency=frf.frequency)
    return frf, truth


def test_noiseless_benchmark_identified_within_one_percent(noiseless_hdd_frf):
    """Paper settings on the noiseless benchmark: median relative error below 1 % per actuator."""
    frf, truth = noiseless_hdd_frf
    rel = (abs(frf.P - truth) / abs(truth)).isel(frequency=slice(1, -1))
    median = rel.median("frequency").isel(output=0)
    assert float(median.sel(input="vcm")) < 0.01
    assert float(median.sel(input="pzt")) < 0.01
    # beyond the slow Nyquist frequency too: the point of the method
    above = rel.where(rel.frequency > frf.attrs["slow_nyquist"]).median("frequency").isel(output=0)
    assert float(above.max()) < 0.02


def test_error_table_and_resonance_peaks_against_truth(noiseless_hdd_frf):
    frf, truth = noiseless_hdd_frf
    table = relative_error_table(frf, truth)
    assert set(table.data_vars) == {"below", "above"}
    assert table.below.dims == ("output", "input")
    exact = relative_error_table(frf.assign(P=truth), truth)  # the truth scores zero
    assert float(exact.below.max()) == 0.0 and float(exact.above.max()) == 0.0
    peaks = resonance_peaks(frf, truth)
    assert len(peaks) >= 3
    # band errors: a 10 % gain error scores 0.1 in every band; the bands split at 500 Hz
    # and the slow Nyquist frequency, DC and the fast Nyquist bin left out
    off = band_errors(frf.assign(P=1.1 * truth), truth)
    assert off.dims == ("band", "input") and off.sizes["band"] == 3
    np.testing.assert_allclose(off.values, 0.1, rtol=1e-12)
    f = frf.frequency
    counts = band_median(xr.ones_like(frf.P.real).where(f > 0), frf.attrs["slow_nyquist"])
    assert float(counts.min()) == 1.0  # every band holds bins
    df = float(frf.frequency[1])
    for true_hz, est_hz in peaks:
        assert 38000 <= true_hz <= 50400
        assert abs(est_hz - true_hz) <= df  # within one bin (28 Hz) without noise


def test_band_table_against_exact_errors(noiseless_hdd_frf):
    """A 10 % gain error scores 0.1 in every band; the coverage counts the bins whose band
    holds the truth plus the flagged ones.  The table carried a stray scalar coordinate
    frequency = 0 (a column of zeros in the README's to_dataframe())."""
    frf, truth = noiseless_hdd_frf
    flagged = frf.P_undetermined.copy(data=np.zeros(frf.sizes["frequency"], bool))
    flagged[5:40] = True  # 0-500 Hz: 17 bins; 500-5000 Hz: 18 of 160
    off = frf.assign(P=1.1 * truth, P_undetermined=flagged)
    table = band_table(off.assign(P_std=abs(truth)), truth)
    assert set(table.coords) == {"band", "output", "input"}
    assert list(table.to_dataframe().columns) == ["median_error", "coverage", "flagged"]
    np.testing.assert_allclose(table.median_error.values, 0.1, rtol=1e-12)
    assert float(table.coverage.min()) == 1.0
    f = frf.frequency.values
    for band, (lo, hi) in zip(table.band.values, BANDS_HZ):
        inside = (f > lo) & (f < hi) & (f > 0) & (f < f.max())
        want = flagged.values[inside].mean()
        np.testing.assert_allclose(table.flagged.sel(band=band).values, want, rtol=1e-12)
        tight = band_table(off.assign(P_std=0.01 * abs(truth)), truth).coverage.sel(band=band)
        np.testing.assert_allclose(tight.values, want, rtol=1e-12)  # only the flagged bins


def test_demo_writes_frf_and_pictures(tmp_path):
    bundled = find_bundled_experiment()
    assert bundled is not None and bundled.name == "hdd_case2_N3600.nc"
    lines = []
    result = run_demo(bundled, tmp_path, echo=lines.append)
    assert [p.name for p in result["files"]] == ["hdd_frf.nc", "hdd_bode.png", "hdd_pzt_zoom.png"]
    for p in result["files"]:
        assert p.stat().st_size > 0
    for png in result["files"][1:]:
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    saved = lcmr_xr.open_frf(result["files"][0])
    xr.testing.assert_allclose(saved.P, result["frf"].P)
    text = "\n".join(lines)
    assert "median relative error" in text and "pzt" in text and "vcm" in text
    assert "main PZT resonance peaks" in text
    # the table printed is the one computed
    assert f"{float(result['errors'].below.sel(input='pzt').item()):.2e}" in text
    # the per-band table: the 95 % bands (unbounded where flagged) hold the truth
    assert "per band" in text and "flagged" in text
    assert float(result["bands"].coverage.min()) >= 0.9
    assert float(result["bands"].flagged.sel(band="500-5000 Hz").max()) <= 0.1


def test_cli_simulate_chooses_the_disturbances(tmp_path, capsys):
    assert cli.DISTURBANCES == hdd.DISTURBANCES
    path = tmp_path / "exp.nc"
    assert cli.main(["simulate", "-o", str(path), "--samples", "400", "--seed", "4",
                     "--disturbances", "fan", "runout"]) == 0
    assert "disturbances: fan runout" in capsys.readouterr().out
    got = lcmr_xr.open_experiment(path)
    want = hdd.simulate(n_samples=400, seed=4, disturbances=["fan", "runout"])
    np.testing.assert_array_equal(got.y.values, want.y.values)
    assert got.attrs["disturbances"] == "fan runout"
    assert cli.main(["simulate", "-o", str(tmp_path / "b.nc"), "--samples", "400", "--noiseless",
                     "--disturbances", "fan"]) == 2
    assert "--noiseless switches every disturbance off" in capsys.readouterr().err
    assert not (tmp_path / "b.nc").exists()
    with pytest.raises(SystemExit):
        cli.main(["simulate", "-o", str(tmp_path / "c.nc"), "--disturbances", "wind"])
    assert "invalid choice: 'wind'" in capsys.readouterr().err


def test_cli_integers_follow_the_integer_rule(tmp_path, capsys):
    """Whole numbers on the command line as in Python (lcmr_xr.settings.as_integer): 400.0
    is 400 (as --window 30.0 and hdd.simulate(400.0, case=2.0, seed=4.0) are), 400.5 is
    refused naming the option, never rounded; --case and --pool alike."""
    path = tmp_path / "exp.nc"
    assert cli.main(["simulate", "-o", str(path), "--samples", "400.0", "--seed", "4.0",
                     "--case", "2.0", "--noiseless"]) == 0
    got = lcmr_xr.open_experiment(path)
    np.testing.assert_array_equal(got.y.values, hdd.simulate(400, case=2, seed=4, noise=False).y.values)
    for option, value in (("--samples", "400.5"), ("--seed", "1.5"), ("--case", "2.5"),
                          ("--samples", "four")):
        with pytest.raises(SystemExit):
            cli.main(["simulate", "-o", str(tmp_path / "x.nc"), option, value])
        err = capsys.readouterr().err
        assert option in err and value in err and "whole number" in err, err
        assert not (tmp_path / "x.nc").exists()
    with pytest.raises(SystemExit):
        cli.main(["simulate", "-o", str(tmp_path / "x.nc"), "--case", "10.0"])
    assert "invalid choice: 10" in capsys.readouterr().err
    args = cli._parser().parse_args(["sweep", "arc", "-o", "r.nc", "--pool", "2.0", "3"])
    assert args.pool == [2, 3] and all(type(k) is int for k in args.pool)
    with pytest.raises(SystemExit):
        cli._parser().parse_args(["sweep", "arc", "-o", "r.nc", "--pool", "2.5"])
    assert "--pool" in capsys.readouterr().err


def test_cli_identify_and_plot(tmp_path, capsys):
    exp_path = tmp_path / "exp.nc"
    assert cli.main(["simulate", "-o", str(exp_path), "--samples", "1200", "--noiseless",
                     "--seed", "3"]) == 0
    out = tmp_path / "frf.nc"
    png = tmp_path / "bode.png"
    assert cli.main(["identify", str(exp_path), "-o", str(out), "--window", "20",
                     "--degrees", "2", "2", "2", "--plot", str(png)]) == 0
    frf = lcmr_xr.open_frf(out)
    assert list(frf.attrs["degrees"]) == [2, 2, 2] and frf.attrs["window"] == 20
    direct = lcmr_xr.identify(lcmr_xr.open_experiment(exp_path), window=20, degrees=(2, 2, 2))
    np.testing.assert_allclose(frf.P.values, direct.P.values)
    assert png.read_bytes()[:4] == b"\x89PNG"
    assert "wrote" in capsys.readouterr().out


def test_cli_errors_are_one_line_and_write_nothing(tmp_path, capsys):
    out = tmp_path / "frf.nc"
    assert cli.main(["identify", str(tmp_path / "missing.nc"), "-o", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("lcmr-xr identify: error:") and "missing.nc" in err
    bad = tmp_path / "corrupt.nc"
    bad.write_bytes(b"CDF\x01 this is not a netcdf file")
    assert cli.main(["identify", str(bad), "-o", str(out)]) == 2
    assert "corrupt.nc" in capsys.readouterr().err
    exp_path = tmp_path / "exp.nc"
    cli.main(["simulate", "-o", str(exp_path), "--samples", "400", "--noiseless"])
    capsys.readouterr()
    assert cli.main(["identify", str(exp_path), "-o", str(out), "--window", "200"]) == 2
    assert "wider than the spectrum" in capsys.readouterr().err
    assert not out.exists()


def test_cli_rejects_unknown_options():
    with pytest.raises(SystemExit) as info:
        cli.main(["identify", "x.nc", "-o", "y.nc", "--windw", "3"])
    assert info.value.code == 2


def test_accessor_forwards_without_state():
    exp = hdd.simulate(n_samples=400, noise=False, seed=2)
    a = exp.lcmr.identify(window=12, degrees=(2, 2, 2))
    b = lcmr_xr.identify(exp, window=12, degrees=(2, 2, 2))
    xr.testing.assert_identical(a, b)
    xr.testing.assert_identical(exp.r.lcmr.lift(2), lcmr_xr.lift(exp.r, 2))
    xr.testing.assert_identical(exp.r.lcmr.lift(2).lcmr.unlift(), exp.r)
    assert exp.lcmr.validate() is exp
    assert not vars(exp.lcmr).keys() - {"_obj"}


def test_simulate_errors_name_the_options(tmp_path, capsys):
    """A refused --samples or --seed is named as the command line spells it, with a remedy in
    its syntax (hdd.simulate's own names, n_samples and seed=0, meant nothing there)."""
    for option, value, said in (("--samples", "3", "--samples must be a multiple of the factor 2"),
                                ("--samples", "401", "give e.g. 3600"),
                                ("--seed", "-1", "--seed must be >= 0, got -1; pass e.g. --seed=0")):
        assert cli.main(["simulate", "-o", str(tmp_path / "x.nc"), option, value]) == 2
        err = capsys.readouterr().err
        assert said in err and "n_samples" not in err and "seed=0" not in err.replace("--seed=0", ""), err
        assert not (tmp_path / "x.nc").exists()
