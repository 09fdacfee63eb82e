"""Estimator settings: one table, one validator for every entry point; shared pipeline pieces."""

from __future__ import annotations

import inspect

import dask
import numpy as np
import pytest
import xarray as xr

import lcmr_xr
from lcmr_xr import cli, hdd
from lcmr_xr.accessor import DATAARRAY_METHODS, DATASET_METHODS, _Forward
from lcmr_xr.identification import identify, identify_single_rate
from lcmr_xr.identification.identify import result_template, stacked_local_model
from lcmr_xr.kernels.identification import identify_arrays, identify_single_rate_arrays
from lcmr_xr.scaleout import save_archive, sweep
from lcmr_xr.settings import (
    CLOSED_LOOP,
    METHODS,
    degrees_arguments,
    estimator_settings,
    parse_degrees,
)


@pytest.fixture(scope="module")
def exp():
    return hdd.simulate(n_samples=400, noise=True, seed=2)  # F = 2, nu = 2: 4 lifted channels


def _forbid(*args, **kwargs):
    raise AssertionError("something was computed while checking the settings")


# (keyword arguments, exception type, words of the message)
BAD = [
    (dict(window=30.5), ValueError, ["window must be an integer", "not rounded", "window=30"]),
    (dict(window="30"), TypeError, ["window must be an integer", "str"]),
    (dict(window=True), TypeError, ["window must be an integer", "bool"]),
    (dict(window=0), ValueError, ["window must be >= 1"]),
    (dict(window=float("nan")), ValueError, ["window must be an integer"]),
    (dict(covariance="no"), TypeError, ["covariance must be True or False", "'no'"]),
    (dict(covariance=1), TypeError, ["covariance must be True or False"]),
    (dict(errors="warn"), ValueError, ["errors must be 'raise' or 'ignore'", "'warn'"]),
    (dict(method="arx"), ValueError, ["method must be 'lrm' or 'lpm'", "'arx'"]),
    (dict(method=None), ValueError, ["method must be 'lrm' or 'lpm'", "NoneType"]),
    (dict(closed_loop="indirekt"), ValueError, ["closed_loop must be 'indirect' or 'direct'"]),
    (dict(frequency_chunks=40.5), ValueError, ["frequency_chunks must be an integer"]),
    (dict(frequency_chunks="40"), TypeError, ["frequency_chunks must be an integer"]),
    (dict(frequency_chunks=5, window=12), ValueError, ["frequency_chunks >= 12"]),
    (dict(degrees=(3, 3.5, 3)), ValueError, ["not three non-negative integers", "'3-3-3'"]),
    (dict(degrees=(3, 3)), ValueError, ["not three non-negative integers"]),
    (dict(degrees=(-1, 3, 3)), ValueError, ["not three non-negative integers"]),
    (dict(degrees="3-x-3"), ValueError, ["not three non-negative integers"]),
    (dict(degrees=3), ValueError, ["not three non-negative integers"]),
    (dict(method="lpm", degrees=(3, 3, 3)), ValueError,
     ["local polynomial model", "degrees=(3, 3, 0)", "method='lrm'"]),
    (dict(method="lpm", degrees="2-2-1"), ValueError, ["'2-2-0'"]),
]


def _raised(func, *args, **kwargs):
    with pytest.raises(Exception) as info:
        func(*args, **kwargs)
    return info


@pytest.mark.parametrize("kwargs,kind,words", BAD, ids=[str(k) for k, _, _ in BAD])
def test_bad_setting_same_clear_message_eager_and_lazy(exp, kwargs, kind, words):
    eager = _raised(identify, exp, **kwargs)
    with dask.config.set(scheduler=_forbid):  # checked before anything is computed
        lazy = _raised(identify, exp.chunk(), **kwargs)
    for info in (eager, lazy):
        assert info.type is kind, info.value
        for word in words:
            assert word in str(info.value), (word, str(info.value))
    assert str(eager.value) == str(lazy.value)
    # the settings are checked before the data: not even a non-dataset gets that far
    assert _raised(identify, "not a dataset", **kwargs).type is kind


@pytest.mark.parametrize("kwargs,kind,words",
                         [b for b in BAD if set(b[0]) <= {"window", "covariance", "method", "degrees"}],
                         ids=lambda v: str(v) if isinstance(v, dict) else "")
def test_single_rate_and_sweep_apply_the_same_rules(exp, kwargs, kind, words):
    single = _raised(identify_single_rate, exp, **kwargs)
    assert single.type is kind and all(w in str(single.value) for w in words)
    swept = _raised(sweep, exp, **{k: [v] if k in ("method", "window") and not isinstance(v, str)
                                   else v for k, v in kwargs.items()})
    assert swept.type is kind
    # one rule, one message: the sweep lists the setting with identify's words
    assert all(w in str(swept.value) for w in words if "window=30" not in w), str(swept.value)


def test_integral_values_of_other_types_are_the_same_settings(exp):
    want = identify(exp, window=12, degrees=(2, 2, 2))
    for kwargs in (dict(window=12.0), dict(window=np.int64(12)), dict(degrees="2-2-2"),
                   dict(degrees="2,2,2"), dict(degrees=np.array([2, 2, 2])),
                   dict(degrees=(2.0, 2, np.int8(2))), dict(covariance=np.True_)):
        got = identify(exp, **{"window": 12, "degrees": (2, 2, 2), **kwargs})
        xr.testing.assert_identical(got, want)
        assert type(got.attrs["window"]) is int


def test_settings_table_defaults_and_lpm_pair():
    assert estimator_settings().degrees == METHODS["lrm"].default_degrees == (3, 3, 3)
    assert estimator_settings(method="lpm").degrees == METHODS["lpm"].default_degrees == (3, 3, 0)
    assert estimator_settings(method="lpm", degrees=(2, 1)).degrees == (2, 1, 0)
    assert parse_degrees("3 2 1") == parse_degrees("3-2-1") == parse_degrees([3, 2, 1]) == (3, 2, 1)
    with pytest.raises(ValueError, match="not three"):
        parse_degrees((2, 1), "lrm")  # a pair only for the LPM
    assert degrees_arguments(["2", "2", "2"]) == ["2-2-2"]
    assert degrees_arguments(["3-3-3", "2,2,0"]) == ["3-3-3", "2,2,0"]


def test_closed_loop_table_matches_what_the_kernels_implement():
    from lcmr_xr.kernels.identification import CLOSED_LOOP_METHODS

    assert tuple(CLOSED_LOOP) == CLOSED_LOOP_METHODS


def test_kernels_import_nothing_outside_the_kernel_layer():
    """docs/architecture.md: the kernels import nothing outside ``lcmr_xr.kernels``."""
    import ast
    from pathlib import Path

    root = Path(lcmr_xr.__file__).parent / "kernels"
    outside = []
    for path in root.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) and not node.level
                     else [])
            outside += [f"{path.name}: {n}" for n in names
                        if n.split(".")[0] == "lcmr_xr" and not n.startswith("lcmr_xr.kernels")]
    assert outside == []


def test_sweep_refuses_lpm_with_a_denominator_and_says_how(exp):
    with pytest.raises(ValueError, match=r"(?s)1 of 2 sweep settings are invalid.*method=lpm, "
                                         r"degrees=3-3-3.*'3-3-0'.*LRM with Rd = 0 is the LPM"):
        sweep(exp, window=[12], method=["lrm", "lpm"], degrees=["3-3-3"])
    res = sweep(exp, window=[12], method=["lpm"])  # the method's default degrees
    assert res.degrees.values.tolist() == ["3-3-0"]
    assert res.denominator_degree.values.tolist() == [[0]]


# ------------------------------------------------------------------ shared pipeline
def test_single_rate_is_the_lifted_pipeline_with_factor_one():
    rng = np.random.default_rng(7)
    f_, m = 3, 90
    r, u = rng.standard_normal((2, 2, m * f_, 1))
    y = rng.standard_normal((2, m, 1))
    got = identify_single_rate_arrays(r, u, y, factor=f_, half_width=9, degrees=(2, 2, 2))
    want = identify_arrays(r[..., ::f_, :], u[..., ::f_, :], y, factor=1, half_width=9,
                           degrees=(2, 2, 2))
    for key in ("P", "P_var", "P_bad"):
        np.testing.assert_array_equal(got[key], want[key])
    assert got["P"].shape == (2, m // 2 + 1, 1, 1)


def test_stacked_local_model_is_the_kernel_result_and_the_inverse_of_the_split(exp):
    for closed_loop in ("indirect", "direct"):
        full = identify(exp, window=12, degrees=(2, 2, 2), closed_loop=closed_loop, stacked=True)
        G, noise = stacked_local_model(full)
        plain = identify(exp, window=12, degrees=(2, 2, 2), closed_loop=closed_loop)
        G2, noise2 = stacked_local_model(plain)  # rebuilt from S, PS
        np.testing.assert_array_equal(G.values, G2.values)
        np.testing.assert_array_equal(noise.values, noise2.values)
        xr.testing.assert_identical(plain, full.drop_vars(["G", "G_std", "noise_variance",
                                                           "response", "excitation"]))
        # the kernel's G, as it fits it
        r, u = (exp[v].transpose("time", "input").values for v in ("r", "u"))
        kern = identify_arrays(r, u, exp.y.values, factor=2, half_width=12, degrees=(2, 2, 2),
                               closed_loop=closed_loop)
        np.testing.assert_array_equal(G.values, kern["G"])
        rows = ["y:position"] if closed_loop == "direct" else ["u:0:vcm", "u:0:pzt", "u:1:vcm",
                                                                 "u:1:pzt", "y:position"]
        assert full.response.values.tolist() == rows
        assert full.excitation.values.tolist()[0] == ("r:0:vcm" if closed_loop == "indirect" else "u:0:vcm")


@pytest.mark.parametrize("closed_loop", ["indirect", "direct"])
def test_result_template_is_the_result_without_computing(exp, closed_loop):
    stack = xr.concat([exp, exp], "experiment").assign_coords(experiment=["a", "b"])
    s = estimator_settings(window=12, degrees=(2, 2, 2), closed_loop=closed_loop)
    with dask.config.set(scheduler=_forbid):
        template = result_template(stack.chunk({"experiment": 1}), s)
    got = identify(stack, window=12, degrees=(2, 2, 2), closed_loop=closed_loop)
    assert list(template.data_vars) == list(got.data_vars)
    for name in got.data_vars:
        assert template[name].dims == got[name].dims and template[name].dtype == got[name].dtype
        assert template[name].shape == got[name].shape and template[name].attrs == got[name].attrs
        assert template[name].chunks[0] == (1, 1)
    xr.testing.assert_identical(template.coords.to_dataset(), got.coords.to_dataset())
    assert template.attrs.keys() == got.attrs.keys()
    for key, value in got.attrs.items():
        np.testing.assert_array_equal(template.attrs[key], value)


# ------------------------------------------------------------------ accessor
@pytest.mark.parametrize("name", sorted(DATASET_METHODS))
def test_accessor_signature_and_doc_are_the_function_s(exp, name):
    func = _Forward(*DATASET_METHODS[name]).function
    params = list(inspect.signature(func).parameters.values())[1:]
    holders = [exp] + ([exp.r] if name in DATAARRAY_METHODS else [])
    for obj in holders:
        method = getattr(obj.lcmr, name)
        assert inspect.signature(method) == inspect.signature(func).replace(parameters=params)
        assert method.__doc__ == func.__doc__


def test_accessor_forwards_every_keyword(exp):
    lazy = exp.lcmr.identify(window=12, degrees=(2, 2, 2), frequency_chunks=20)
    xr.testing.assert_allclose(lazy.compute(), identify(exp, window=12, degrees=(2, 2, 2)))
    import matplotlib.pyplot as plt

    frf = identify(exp, window=12, degrees=(2, 2, 2))
    handles = frf.P.lcmr.bode(label="estimate", hz=True, unwrap=False, color="C3")
    assert handles is not None
    plt.close("all")


# ------------------------------------------------------------------ command lines
def test_cli_degrees_syntax_and_lpm_rule(tmp_path, capsys):
    exp_path = tmp_path / "exp.nc"
    lcmr_xr.save(hdd.simulate(n_samples=400, noise=False, seed=3), exp_path)
    outs = []
    for i, tokens in enumerate((["2-2-2"], ["2", "2", "2"], ["2,2,2"])):
        out = tmp_path / f"frf{i}.nc"
        assert cli.main(["identify", str(exp_path), "-o", str(out), "--window", "12",
                         "--degrees", *tokens]) == 0
        outs.append(lcmr_xr.open_frf(out))
    for other in outs[1:]:
        xr.testing.assert_identical(other, outs[0])
    capsys.readouterr()
    bad = tmp_path / "bad.nc"
    assert cli.main(["identify", str(exp_path), "-o", str(bad), "--method", "lpm",
                     "--degrees", "3-3-3"]) == 2
    assert "degrees=(3, 3, 0)" in capsys.readouterr().err
    assert cli.main(["identify", str(exp_path), "-o", str(bad), "--degrees", "3-3-3", "2-2-2"]) == 2
    assert "one setting" in capsys.readouterr().err
    # the settings are checked before the input is read: a missing file is not mentioned
    assert cli.main(["identify", str(tmp_path / "missing.nc"), "-o", str(bad), "--method", "lpm",
                     "--degrees", "3-3-3"]) == 2
    assert "3, 3, 0" in capsys.readouterr().err
    assert cli.main(["sweep", str(tmp_path / "no-archive"), "-o", str(bad), "--method", "lrm", "lpm",
                     "--degrees", "3-3-3"]) == 2
    err = capsys.readouterr().err
    assert "method=lpm, degrees=3-3-3" in err and "no-archive" not in err
    assert not bad.exists()


def test_cli_sweep_takes_bare_integers_as_one_setting(tmp_path):
    save_archive(xr.concat([hdd.simulate(n_samples=400, seed=s) for s in (0, 1)], "experiment"),
                 tmp_path / "arc.nc")
    out = tmp_path / "res.nc"
    assert cli.main(["sweep", str(tmp_path / "arc.nc"), "-o", str(out), "--window", "12",
                     "--degrees", "2", "2", "2", "--scheduler", "synchronous"]) == 0
    assert lcmr_xr.open_dataset(out).degrees.values.tolist() == ["2-2-2"]


@pytest.mark.parametrize("frequency_chunks", [None, 40])
def test_eager_identify_computes_each_lifted_spectrum_once(exp, monkeypatch, frequency_chunks):
    import lcmr_xr.kernels.identification as kid

    calls = []
    real = kid.lifted_spectra

    def counting(x, factor):
        calls.append(np.shape(x))
        return real(x, factor)

    monkeypatch.setattr(kid, "lifted_spectra", counting)
    frf = identify(exp, window=12, degrees=(2, 2, 2), frequency_chunks=frequency_chunks)
    frf.compute()
    assert len(calls) == 2  # lifted r and lifted u, once each (the rank check reuses r's)


def test_one_reader_of_a_stored_factor():
    """validate_experiment, experiment_factor and lift's lift_factor each read a stored
    factor their own way (validate took np.array([True]) as 1 and failed inside int() on
    inf with an OverflowError); they share settings.recorded_factor now, and agree."""
    from lcmr_xr.experiment.dataset import experiment_factor
    from lcmr_xr.settings import recorded_factor
    from lcmr_xr.transforms.lifting import _recorded_factor

    small = hdd.simulate(n_samples=400, noise=False, seed=1)
    good = [2, 2.0, np.int32(2), np.array([2]), np.array([[2.0]]), np.uint8(2), [2]]
    bad = ["2", "two", 2.5, 0, -2, np.nan, np.inf, True, np.array([True]), np.array([2, 2]),
           np.array([]), None, [2, 2], 2 + 0j, [1, [2]]]  # ragged: numpy's ValueError escaped
    for value in good:
        assert recorded_factor(value) == 2 and type(recorded_factor(value)) is int
        assert experiment_factor(small.assign_attrs(factor=value)) == 2
        lcmr_xr.validate_experiment(small.assign_attrs(factor=value))
        assert _recorded_factor(value, "unlift", 2) == 2
    for value in bad:
        assert recorded_factor(value) is None, value
        with pytest.raises(ValueError, match="'factor' must be a positive integer"):
            experiment_factor(small.assign_attrs(factor=value))
        with pytest.raises(ValueError, match="'factor' must be a positive integer"):
            lcmr_xr.validate_experiment(small.assign_attrs(factor=value))
        if value is not None:  # (lift_phase without the attribute: a lifting made by hand)
            with pytest.raises(ValueError, match="not a lifting factor"):
                _recorded_factor(value, "unlift", 2)
