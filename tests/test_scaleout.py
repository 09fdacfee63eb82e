"""Scale-out: archives, lazy dask sweeps (on a 2-process LocalCluster), settings selection, CLI."""

from __future__ import annotations

import argparse
import os
import signal
import time

import dask
import numpy as np
import pytest
import xarray as xr
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from lcmr_xr.experiment import experiment
from lcmr_xr.identification import identify
from lcmr_xr.io import open_dataset, save
from lcmr_xr.kernels.excitation import random_phase_multisine
from lcmr_xr.scaleout import open_archive, save_archive, select_settings, sweep
from lcmr_xr.scaleout.archive import _file_stem
from lcmr_xr.scaleout.cli import add_sweep_parser
from lcmr_xr.scaleout.select import _nanmedian, cross_prediction_scores
from _closed_loop_fd import matrix_frf, periodic_experiment, tf_frf

TH = 1e-3
FACTOR = 2
# A resonant plant (poles at radius 0.985): low-degree local models cannot follow it.
RAD, ANG = 0.985, 0.35
PLANT = ([0.0, 0.02, 0.015], [1.0, -2 * RAD * np.cos(ANG), RAD**2])
CONTROLLER = ([0.25, -0.15], [1.0, -0.3])
FILTER = ([0.6, 0.0], [1.0, -0.4])
SETTING_COORDS = ["numerator_degree", "transient_degree", "denominator_degree", "parameters_per_row"]


def _experiment(seed, n=480, noise=1e-3):
    """Periodic steady-state closed-loop experiment (exact lifted construction) + white noise."""
    m = n // FACTOR
    P, C, Fi = matrix_frf([[PLANT]], n), matrix_frf([[CONTROLLER]], m), matrix_frf([[FILTER]], n)
    rng = np.random.default_rng(seed)
    r = random_phase_multisine(n, 1, np.arange(1, n // 2 + 1), 1.0, rng)
    u, y = periodic_experiment(P, C, Fi, FACTOR, r)
    u = u + noise * np.std(u) * rng.standard_normal(u.shape)
    y = y + noise * np.std(y) * rng.standard_normal(y.shape)
    return experiment(r, u, y, factor=FACTOR, sampling_period=TH, output_units="m")


def _stack(labels, n=480):
    exps = xr.concat([_experiment(i, n) for i in range(len(labels))], "experiment")
    return exps.assign_coords(experiment=("experiment", list(labels),
                                          {"units": "1", "long_name": "experiment"}))


@pytest.fixture(scope="module")
def cluster_client():
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                      silence_logs=40) as cluster, Client(cluster, set_as_default=False) as client:
        client.run(lambda: __import__("lcmr_xr.identification"))  # warm the workers' imports
        yield cluster, client


def _forbid(*args, **kwargs):
    raise AssertionError("something was computed while the graph was being built")


def _in_memory(exps, method, degrees, window):
    return identify(exps, method=method, degrees=degrees, window=window, errors="ignore")


# ------------------------------------------------------------------------------- archive
def test_archive_round_trip_names_order_and_laziness(tmp_path):
    labels = ["b10", "a 2/x", "c"]  # unsorted, one needs sanitising
    exps = _stack(labels)
    files = save_archive(exps, tmp_path)
    assert [p.name for p in files] == ["b10.nc", "a_2_x.nc", "c.nc"]
    arc = open_archive(tmp_path)
    assert arc.r.chunks is not None and arc.r.chunks[0] == (3,)  # up to 16 files per chunk
    assert open_archive(tmp_path, chunks={"experiment": 1}).r.chunks[0] == (1, 1, 1)
    xr.testing.assert_identical(arc.compute(), exps)


def test_archive_of_a_sequence_and_appending_keeps_order(tmp_path):
    first = [_experiment(0).assign_coords(experiment="x1"), _experiment(1).assign_coords(experiment="x0")]
    save_archive(first, tmp_path)
    save_archive([_experiment(2).assign_coords(experiment="a")], tmp_path)
    arc = open_archive(tmp_path)
    assert arc.experiment.values.tolist() == ["x1", "x0", "a"]
    np.testing.assert_array_equal(arc.r.isel(experiment=2).values, _experiment(2).r.values)


def test_archive_refuses_different_lengths_with_the_lengths(tmp_path):
    mixed = [_experiment(0, n=480).assign_coords(experiment="short"),
             _experiment(1, n=960).assign_coords(experiment="long")]
    with pytest.raises(ValueError, match=r"N=480: 1 \(short\); N=960: 1 \(long\).*own archive"):
        save_archive(mixed, tmp_path / "a.nc")
    # files written by separate calls into one directory: refused on the second write...
    save_archive([mixed[0]], tmp_path / "b", layout="files")
    with pytest.raises(ValueError, match=r"another shape.*short\.nc \(N=480"):
        save_archive([mixed[1]], tmp_path / "b", layout="files")
    # ...and on open when they got there some other way
    save(mixed[1].assign_attrs(), tmp_path / "b" / "long.nc")
    with pytest.raises(ValueError, match=r"different lengths \(N=480: 1 \(short\.nc\); N=960: 1 \(long\.nc\)"):
        open_archive(tmp_path / "b")


def test_archive_overwrite_rules(tmp_path):
    save_archive([_experiment(0).assign_coords(experiment="e")], tmp_path)
    # same shape (a re-measurement) replaces the file
    save_archive([_experiment(5).assign_coords(experiment="e")], tmp_path)
    np.testing.assert_array_equal(open_archive(tmp_path).r.isel(experiment=0).values,
                                  _experiment(5).r.values)
    longer = _experiment(1, n=960).assign_coords(experiment="e")
    with pytest.raises(ValueError, match="overwrite=True"):
        save_archive([longer], tmp_path)
    np.testing.assert_array_equal(open_archive(tmp_path).r.isel(experiment=0).values,
                                  _experiment(5).r.values)  # untouched
    save_archive([longer], tmp_path, overwrite=True)
    assert open_archive(tmp_path).sizes["time"] == 960


def test_archive_errors(tmp_path):
    with pytest.raises(FileNotFoundError, match="does not exist"):
        open_archive(tmp_path / "missing")
    with pytest.raises(FileNotFoundError, match="holds no .nc, .nc4 or .netcdf files"):
        open_archive(tmp_path)
    save(xr.Dataset({"a": ("x", [1.0])}, attrs={"conventions": "other"}), tmp_path / "foreign.nc")
    with pytest.raises(ValueError, match="not an lcmr-xr-1 experiment file"):
        open_archive(tmp_path)
    with pytest.raises(ValueError, match="same file names"):
        save_archive(_stack(["a b", "a_b"]), tmp_path / "dupes", layout="files")


@given(st.text(max_size=30))
def test_file_stem_is_safe_and_idempotent(label):
    stem = _file_stem(label)
    assert stem and all(c.isascii() and (c.isalnum() or c in "._-") for c in stem)
    assert not stem.startswith(".")
    assert _file_stem(stem) == stem


# ------------------------------------------------------------------------------- sweep
def test_sweep_is_lazy_and_equals_in_memory_on_the_cluster(cluster_client):
    _, client = cluster_client
    exps = _stack(["e0", "e1", "e2"])
    with dask.config.set(scheduler=_forbid):
        # the LPM has no denominator: a sweep over both methods takes degrees with Rd = 0
        res = sweep(exps, window=[10, 20], degrees=["2-2-0", "3-3-0"], method=["lrm", "lpm"])
    assert res.P.chunks is not None and res.S.chunks is not None
    assert dict(res.P.sizes) == {"method": 2, "degrees": 2, "window": 2, "experiment": 3,
                                 "frequency": 241, "output": 1, "input": 1}
    assert res.denominator_degree.sel({"method": "lpm"}).values.tolist() == [0, 0]
    for name in list(res.coords):
        assert {"units", "long_name"} <= set(res[name].attrs), name
    computed = client.compute(res).result()
    for m in ("lrm", "lpm"):
        for label, deg in (("2-2-0", (2, 2, 0)), ("3-3-0", (3, 3, 0))):
            for w in (10, 20):
                got = computed.sel({"method": m, "degrees": label, "window": w}, drop=True)
                want = _in_memory(exps, m, deg if m == "lrm" else deg[:2] + (0,), w)
                got = got.drop_vars(SETTING_COORDS, errors="ignore")
                assert got.experiment_error.values.tolist() == ["", "", ""]  # none failed
                got = got.drop_vars("experiment_error")
                got.attrs = want.attrs
                xr.testing.assert_allclose(got, want, rtol=1e-12, atol=0)


@pytest.mark.parametrize("settings", [
    dict(method="lrm", window=12, degrees=(2, 2, 2), closed_loop="indirect", covariance=True),
    dict(method="lpm", window=12, degrees=(2, 2, 0), closed_loop="direct", covariance=False),
    dict(method="lrm", window=12, degrees=(2, 2, 2), closed_loop="indirect", covariance=True,
         denominator="iv"),
])
def test_a_task_labels_its_block_once_and_equals_identify_per_experiment(settings):
    """The stacked task path (kernel per experiment, labels once) gives exactly the result of
    identify per experiment concatenated, failed experiments (NaN, an unexcited lifted
    channel) included with identify's own messages."""
    from lcmr_xr.scaleout.sweep import _identify_block, _identify_or_flag

    exps = _stack(["a", "b", "c", "d"]).compute().assign_coords(
        seed=("experiment", [1, 2, 3, 4], {"units": "1", "long_name": "seed"}))
    r = exps.r.values.copy()
    r[1, 5, 0] = np.nan
    r[3] = 0.0  # no excitation: the indirect estimate's rank check refuses it
    exps["r"] = exps.r.copy(data=r)
    settings = {"denominator": None, **settings}
    got = _identify_block(exps, source="runs.nc", **settings)
    want = xr.concat([_identify_or_flag(exps.isel(experiment=slice(i, i + 1)), "runs.nc", settings)
                      for i in range(4)], "experiment", data_vars="all", coords="minimal",
                     compat="override", join="exact", combine_attrs="override")
    for name in ("experiment", "seed"):  # the experiments' attrs kept (concat drops them)
        assert got[name].attrs == exps[name].attrs
        got[name].attrs = {}
    xr.testing.assert_identical(got, want)
    errors = got.experiment_error.values
    assert errors[0] == errors[2] == "" and "'b' of runs.nc" in errors[1]
    assert "NaN or inf" in errors[1] and bool(np.isnan(got.P[1]).all())
    assert ("rank 0" in errors[3]) == (settings["closed_loop"] == "indirect")


def test_sweep_invalid_settings_fail_before_any_compute():
    exps = _stack(["e0", "e1"]).chunk({"experiment": 1})
    with dask.config.set(scheduler=_forbid):
        with pytest.raises(ValueError, match=r"(?s)2 of 4 sweep settings are invalid.*"
                                             r"degrees=1-1-1, window=3.*Use window >= 4.*"
                                             r"degrees=3-3-3, window=3.*Use window >= 8") as err:
            sweep(exps, window=[3, 20], degrees=["1-1-1", "3-3-3"])
        assert "window=20:" not in str(err.value)
        with pytest.raises(ValueError, match="wider than the spectrum"):
            sweep(exps, window=[200])
        with pytest.raises(ValueError, match="not three non-negative integers"):
            sweep(exps, degrees=["3-3"])
        with pytest.raises(ValueError, match="lists 10 twice"):
            sweep(exps, window=[10, 10])


def test_worker_killed_mid_sweep_loses_nothing(cluster_client):
    cluster, client = cluster_client
    exps = _stack([f"e{i}" for i in range(8)], n=960)
    res = sweep(exps, window=[15, 25, 40], degrees=["3-3-3"])
    want = res.compute(scheduler="synchronous")
    pids = client.run(os.getpid)
    future = client.compute(res)

    def in_memory(dask_scheduler):
        return sum(ts.state == "memory" for ts in dask_scheduler.tasks.values())

    deadline = time.monotonic() + 30
    while client.run_on_scheduler(in_memory) == 0 and time.monotonic() < deadline:
        time.sleep(0.02)
    busy = [addr for addr, keys in client.processing().items() if keys]
    assert busy and not future.done(), "the sweep finished before a worker could be killed"
    os.kill(pids[busy[0]], signal.SIGKILL)
    got = future.result(timeout=120)
    xr.testing.assert_identical(got, want)
    client.wait_for_workers(2, timeout=60)
    assert set(client.run(os.getpid).values()) != set(pids.values())  # the nanny restarted it


def test_sweep_result_round_trips_through_netcdf(tmp_path):
    res = sweep(_stack(["e0", "e1"]), window=[15], degrees=["3-3-0"],
                method=["lrm", "lpm"]).compute(scheduler="synchronous")
    save(res, tmp_path / "sweep.nc")
    xr.testing.assert_identical(open_dataset(tmp_path / "sweep.nc"), res)


def test_sweep_of_one_experiment_without_experiment_dim():
    exp = _experiment(3)
    res = sweep(exp, window=[12, 20]).compute(scheduler="synchronous")
    assert res.P.dims == ("method", "degrees", "window", "frequency", "output", "input")
    want = identify(exp, window=12, errors="ignore")
    np.testing.assert_allclose(res.P.isel(method=0, degrees=0, window=0).values, want.P.values, rtol=1e-12)


def test_sweep_pools_groups_of_experiments_from_an_archive(tmp_path):
    exps = _stack([f"e{i}" for i in range(5)])
    save_archive(exps, tmp_path)
    arc = open_archive(tmp_path)
    res = sweep(arc, window=[15], degrees=["2-2-2"], pool=[1, 2])
    assert dict(res.P.sizes) == {"method": 1, "degrees": 1, "window": 1, "pool": 2,
                                 "pool_group": 5, "frequency": 241, "output": 1, "input": 1}
    res = res.compute(scheduler="synchronous")
    got = res.P.isel(method=0, degrees=0, window=0)
    # pool 2: groups (e0, e1), (e2, e3); e4 left over, group slots 2..4 NaN
    for g in range(2):
        want = identify(exps.isel(experiment=[2 * g, 2 * g + 1]), window=15, degrees=(2, 2, 2),
                        combine="experiment", errors="ignore")
        np.testing.assert_allclose(got.sel(pool=2).isel(pool_group=g).values, want.P.values,
                                   rtol=1e-9)
    assert np.isnan(got.sel(pool=2).isel(pool_group=slice(2, None)).values).all()
    one = identify(exps.isel(experiment=4), window=15, degrees=(2, 2, 2), errors="ignore")
    np.testing.assert_allclose(got.sel(pool=1).isel(pool_group=4).values, one.P.values, rtol=1e-9)
    # identify pools the lazily opened archive itself (one local model over its experiments)
    lazy = identify(arc, window=15, degrees=(2, 2, 2), combine="experiment", errors="ignore")
    assert lazy.P.chunks is not None
    np.testing.assert_allclose(lazy.P.values, identify(exps, window=15, degrees=(2, 2, 2),
                                                       combine="experiment", errors="ignore").P.values,
                               rtol=1e-9)
    # and a consolidated archive (one file) the same way
    from lcmr_xr.scaleout import consolidate_archive

    one_file = consolidate_archive(tmp_path, tmp_path.parent / f"{tmp_path.name}-all.nc")
    lazy_c = identify(open_archive(one_file), window=15, degrees=(2, 2, 2), combine="experiment",
                      errors="ignore")
    np.testing.assert_allclose(lazy_c.P.values, lazy.P.values, rtol=1e-12)
    with pytest.raises(ValueError, match="more than the 5 experiments"):
        sweep(arc, window=[15], pool=[8])


# ------------------------------------------------------------------------------- selection
def _true_error(res):
    truth = tf_frf(*PLANT, 480)[: 241]
    err = np.abs(res.P.isel(output=0, input=0) - truth) / np.abs(truth)
    return err.median(["frequency", "experiment"])


@pytest.fixture(scope="module")
def resonant_sweep():
    exps = _stack([f"run{i}" for i in range(4)])
    # the LPM is the LRM with Rd = 0: degrees "1-1-0" and "3-3-0" are the LPMs of these orders
    res = sweep(exps, window=[8, 15, 30], degrees=["1-1-0", "1-1-1", "3-3-0", "3-3-3"], method=["lrm"])
    return exps, res.compute(scheduler="synchronous")


@pytest.mark.parametrize("criterion", ["cross", "fpe"])
def test_selection_picks_the_settings_that_fit_a_resonance(resonant_sweep, criterion):
    exps, res = resonant_sweep
    choice = select_settings(res, exps, criterion=criterion)
    assert choice.attrs["criterion"] == criterion
    assert choice.score.dims == ("experiment", "method", "degrees", "window")
    assert choice.best_method.values.tolist() == ["lrm"] * 4
    assert choice.best_degrees.values.tolist() == ["3-3-3"] * 4
    # degrees too low for the resonance lose clearly, for every experiment and window
    low = choice.score.sel({"method": "lrm", "degrees": "1-1-0"})  # the LPM of degree 1
    assert bool((low > 3 * choice.best_score).all())
    # and against the known truth the chosen settings are in the better half of the sweep
    # (the scores of the good settings are close to the noise floor, so near-ties between
    # them are decided by noise; the bad ones are far off)
    true_err = _true_error(res)
    ranked = np.sort(true_err.values.ravel())
    for e in range(4):
        picked = true_err.sel({"method": str(choice.best_method[e].values),
                               "degrees": str(choice.best_degrees[e].values),
                               "window": int(choice.best_window[e])})
        assert float(picked) <= ranked[ranked.size // 2 - 1]
        assert float(picked) < 3 * ranked[0]
    np.testing.assert_allclose(
        choice.best_score, choice.score.min(["method", "degrees", "window"]), rtol=0)


def test_selection_with_one_experiment_uses_fpe_and_cross_is_refused(resonant_sweep):
    exps, res = resonant_sweep
    one_exp, one_res = exps.isel(experiment=[1]), res.isel(experiment=[1])
    choice = select_settings(one_res, one_exp)
    assert choice.attrs["criterion"] == "fpe"
    assert choice.best_degrees.values.tolist() == ["3-3-3"]
    with pytest.raises(ValueError, match="needs at least two"):
        select_settings(one_res, one_exp, criterion="cross")
    with pytest.raises(ValueError, match="experiments has 4 experiments but sweep_result 1"):
        select_settings(one_res, exps)


def test_failed_bins_count_as_infinite_error(resonant_sweep):
    exps, res = resonant_sweep
    broken = res.copy(deep=True)
    broken["S"].loc[{"method": "lrm", "degrees": "3-3-3"}] = np.nan  # a setting that failed
    choice = select_settings(broken, exps)
    assert np.isinf(choice.score.sel({"method": "lrm", "degrees": "3-3-3"})).all()
    assert "3-3-3" not in [d for d, m in zip(choice.best_degrees.values, choice.best_method.values)
                           if m == "lrm"]


def test_cross_prediction_score_is_exact_for_a_known_model():
    rng = np.random.default_rng(0)
    G = rng.standard_normal((3, 5, 2, 1)) + 1j * rng.standard_normal((3, 5, 2, 1))
    R = rng.standard_normal((3, 5, 1)) + 1j
    Z = np.einsum("mzr,fmr->fmz", G[0], R)  # experiment 0's model is exact
    scores = cross_prediction_scores(G, R, Z)
    assert scores[0] == pytest.approx(0.0, abs=1e-15)
    rel = np.abs(np.einsum("mzr,fmr->fmz", G[1], R) - Z) / np.abs(Z)
    assert scores[1] == pytest.approx(np.median(rel[[0, 2]]), rel=1e-14)


@settings(max_examples=60, deadline=None)
@given(hnp.arrays(float, hnp.array_shapes(min_dims=1, max_dims=3, max_side=7),
                  elements=st.one_of(st.floats(-1e6, 1e6), st.just(np.nan), st.just(np.inf))))
def test_nanmedian_matches_numpy(x):
    import warnings

    got = _nanmedian(x)
    with warnings.catch_warnings():  # numpy warns on all-NaN rows; ours returns NaN quietly
        warnings.simplefilter("ignore")
        want = np.nanmedian(x, axis=-1)
    np.testing.assert_array_equal(got, want)


# ------------------------------------------------------------------------------- CLI
def _cli(argv):
    parser = argparse.ArgumentParser(prog="lcmr-xr")
    add_sweep_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.func(args)


@pytest.mark.parametrize("scheduler", ["threads", "cluster"])
def test_cli_sweep_writes_the_same_result(tmp_path, capsys, cluster_client, scheduler):
    cluster, _ = cluster_client
    exps = _stack(["e0", "e1"])
    save_archive(exps, tmp_path / "arc.nc")
    address = cluster.scheduler_address if scheduler == "cluster" else scheduler
    status = _cli(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "res.nc"), "--window", "12", "20",
                   "--degrees", "3-3-0", "2-2-0", "--method", "lrm", "lpm", "--scheduler", address,
                   "--select", str(tmp_path / "choice.nc")])
    assert status == 0
    got = open_dataset(tmp_path / "res.nc")
    want = sweep(exps, window=[12, 20], degrees=["3-3-0", "2-2-0"], method=["lrm", "lpm"])
    xr.testing.assert_allclose(got, want.compute(scheduler="synchronous"), rtol=1e-12)
    choice = open_dataset(tmp_path / "choice.nc")
    assert choice.best_window.dims == ("experiment",)
    captured = capsys.readouterr()
    assert "100% Completed" in captured.out + captured.err  # a progress bar was shown
    # what is swept and where, said once (after the connection to a cluster) before the progress
    first = captured.err.splitlines()[0]
    assert first.startswith("sweeping {'method': 2, 'degrees': 2, 'window': 2, 'experiment': 2}"), first
    assert first.endswith(f"on scheduler {address}") and captured.err.count("sweeping") == 1


def test_cli_errors_exit_2_and_write_nothing(tmp_path, capsys):
    save_archive(_stack(["e0"]), tmp_path / "arc.nc")
    assert _cli(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "r.nc"), "--window", "3"]) == 2
    assert "Use window >=" in capsys.readouterr().err
    assert _cli(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "r.nc"),
                 "--scheduler", "gpu"]) == 2
    assert "neither threads" in capsys.readouterr().err
    assert not (tmp_path / "r.nc").exists()


def test_cli_sweep_variables_writes_only_those(tmp_path, capsys):
    exps = _stack(["e0", "e1"])
    save_archive(exps, tmp_path / "arc.nc")
    status = _cli(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "res.nc"), "--window", "12",
                   "--degrees", "2-2-2", "--variables", "P", "P_std", "--scheduler", "synchronous"])
    assert status == 0
    got = open_dataset(tmp_path / "res.nc")
    assert sorted(got.data_vars) == ["P", "P_std", "experiment_error"]
    want = sweep(exps, window=[12], degrees=["2-2-2"]).compute(scheduler="synchronous")
    xr.testing.assert_allclose(got.P, want.P, rtol=1e-12)
    xr.testing.assert_allclose(got.P_std, want.P_std, rtol=1e-12)
    assert "wrote" in capsys.readouterr().out


def test_cli_sweep_variables_refused_before_anything_runs(tmp_path, capsys):
    save_archive(_stack(["e0", "e1"]), tmp_path / "arc.nc")
    base = ["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "r.nc"), "--window", "12",
            "--degrees", "2-2-2", "--scheduler", "synchronous"]
    assert _cli(base + ["--variables", "P", "Pstd"]) == 2
    err = capsys.readouterr().err
    assert "['Pstd'] are not in this sweep's result" in err and "P_std" in err
    assert _cli(base + ["--variables", "P", "--select", str(tmp_path / "c.nc")]) == 2
    err = capsys.readouterr().err
    assert "--select scores the local model" in err and "noise_variance_y" in err
    assert not (tmp_path / "r.nc").exists() and not (tmp_path / "c.nc").exists()
    assert not any(p.name.startswith(".r.nc") for p in tmp_path.iterdir())  # no parts either


def test_cli_sweep_pooled_variables(tmp_path):
    save_archive(_stack(["e0", "e1"]), tmp_path / "arc.nc")
    status = _cli(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "res.nc"), "--window", "15",
                   "--degrees", "2-2-2", "--pool", "2", "--variables", "P", "P_flag",
                   "--scheduler", "synchronous"])
    assert status == 0
    assert sorted(open_dataset(tmp_path / "res.nc").data_vars) == ["P", "P_flag"]


def test_cli_sweep_pools_experiments(tmp_path):
    exps = _stack(["e0", "e1", "e2"])
    save_archive(exps, tmp_path / "arc.nc")
    status = _cli(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "res.nc"), "--window", "15",
                   "--degrees", "2-2-2", "--pool", "1", "2", "--scheduler", "synchronous"])
    assert status == 0
    got = open_dataset(tmp_path / "res.nc")
    want = sweep(exps, window=[15], degrees=["2-2-2"], pool=[1, 2]).compute(scheduler="synchronous")
    assert got.P.sizes["pool"] == 2 and got.P.sizes["pool_group"] == 3
    np.testing.assert_allclose(got.P.values, want.P.values, rtol=1e-12)
