"""Command line manners (issue 16.5): defaults in every help, log-friendly progress, criteria explained."""

from __future__ import annotations

import argparse
import io

import dask.array as da
import pytest
import xarray as xr

from lcmr_xr import cli, hdd
from lcmr_xr._cli_support import LineProgressBar, heartbeat, progress
from lcmr_xr.io import save
from lcmr_xr.scaleout import save_archive

COMMANDS = ("identify", "demo", "simulate", "sweep")


def _subparsers():
    parser = cli._parser()
    action = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    return action.choices


@pytest.mark.parametrize("command", COMMANDS)
def test_every_option_help_states_its_default(command):
    sub = _subparsers()[command]
    formatter = sub._get_formatter()
    for action in sub._actions:
        if not action.option_strings or isinstance(action, argparse._HelpAction):
            continue
        if action.required:
            continue  # required options have no default to state
        text = formatter._get_help_string(action)
        assert "default" in text, f"{command} {action.option_strings[0]}: {text!r}"


@pytest.mark.parametrize("command, expected", [
    ("simulate", ["(default: 3600)", "(default: 2)", "(default: 0)", "(default: with noise)"]),
    ("demo", ["(default: demo-output)", "(default: auto)", "(default 3-3-3", "(default: the bundled"]),
    ("identify", ["(default: lrm)", "(default: auto)", "(default 3-3-3; LPM: 3-3-0", "(default: indirect)",
                  "(default: no plot)", "(default: refuse them)"]),
    ("sweep", ["(default: threads)", "(default: the method's, 3-3-3 for LRM", "(default: 10.0)",
               "(default: no selection)",
               # pooled groups default to IV (the sweep's denominator_fit says so); the help said ls
               "default: ls for a model with a denominator (iv for the --pool groups"]),
])
def test_help_text_shows_defaults(command, expected, capsys):
    with pytest.raises(SystemExit) as info:
        cli.main([command, "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    for item in expected:
        assert item in text, item


def test_sweep_help_explains_the_criteria(capsys):
    with pytest.raises(SystemExit):
        cli.main(["sweep", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "'cross': held-out experiments" in text
    assert "'fpe': final prediction error" in text


def test_progress_is_plain_lines_when_not_a_terminal():
    out = io.StringIO()
    x = da.ones((40, 40), chunks=(4, 40)).sum(axis=1)
    with progress(out):
        x.compute(scheduler="synchronous")
    text = out.getvalue()
    assert "\r" not in text
    lines = text.splitlines()
    assert lines[-1].startswith("100% Completed |")
    percents = [int(line.split("%")[0]) for line in lines]
    assert percents == sorted(percents) and len(percents) <= 12  # one line per 10 %, not per task


def test_progress_animates_on_a_terminal():
    class Terminal(io.StringIO):
        def isatty(self):
            return True

    out = Terminal()
    bar = progress(out)
    assert not isinstance(bar, LineProgressBar)
    with bar:
        da.ones(10, chunks=2).sum().compute(scheduler="synchronous")
    assert "\r" in out.getvalue() and "100% Completed" in out.getvalue()


def test_heartbeat_writes_lines_then_done():
    import time

    out = io.StringIO()
    with heartbeat("fitting", out, every=0.05):
        time.sleep(0.3)
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue()
    assert len(lines) >= 3 and all(line.startswith("fitting: ") for line in lines)
    assert lines[-1].startswith("fitting: done in ")
    out = io.StringIO()
    with pytest.raises(RuntimeError), heartbeat("fitting", out, every=10):
        raise RuntimeError("boom")
    assert out.getvalue().startswith("fitting: failed in ")


def test_cli_identify_reports_progress_on_stderr(tmp_path, capsys):
    exp = tmp_path / "exp.nc"
    save(hdd.simulate(n_samples=400, noise=False, seed=1), exp)
    assert cli.main(["identify", str(exp), "-o", str(tmp_path / "frf.nc"), "--window", "12",
                     "--degrees", "2-2-2"]) == 0
    err = capsys.readouterr().err
    assert "identifying exp.nc (200 slow bins, lrm, window 12): done in" in err
    assert "\r" not in err


def test_cli_sweep_select_explains_the_criterion(tmp_path, capsys):
    exps = xr.concat([hdd.simulate(n_samples=400, noise=False, seed=s) for s in (1, 2)], "experiment")
    save_archive(exps, tmp_path / "arc.nc")
    assert cli.main(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "r.nc"), "--window", "12",
                     "--degrees", "2-2-2", "--select", str(tmp_path / "c.nc")]) == 0
    captured = capsys.readouterr()
    assert "criterion cross (held-out experiments" in captured.out
    assert "100% Completed" in captured.err and "\r" not in captured.err
    # a second run refuses the existing outputs unless told to overwrite them
    assert cli.main(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "r.nc"), "--window", "12",
                     "--degrees", "2-2-2"]) == 2
    assert "already exists" in capsys.readouterr().err
    before = (tmp_path / "r.nc").stat().st_mtime_ns
    assert cli.main(["sweep", str(tmp_path / "arc.nc"), "-o", str(tmp_path / "r.nc"), "--window", "12",
                     "--degrees", "2-2-2", "--overwrite"]) == 0
    assert (tmp_path / "r.nc").stat().st_mtime_ns != before
    with xr.open_dataset(tmp_path / "r.nc") as result:
        assert result.sizes["experiment"] == 2


def test_archive_consolidate_help_states_its_defaults(capsys):
    with pytest.raises(SystemExit) as info:
        cli.main(["archive", "consolidate", "--help"])
    assert info.value.code == 0
    text = " ".join(capsys.readouterr().out.split())
    assert "--overwrite" in text and "(default: refuse them)" in text
    assert "not inside the directory" in text


def test_python_m_lcmr_xr_runs_the_command_line(tmp_path):
    """``python -m lcmr_xr`` is the ``lcmr-xr`` console script (for a venv not on PATH)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    import lcmr_xr

    env = {**os.environ, "PYTHONPATH": str(Path(lcmr_xr.__file__).parent.parent)}
    ok = subprocess.run([sys.executable, "-m", "lcmr_xr", "simulate", "--help"], capture_output=True,
                        text=True, env=env, cwd=tmp_path)
    assert ok.returncode == 0 and ok.stdout.startswith("usage: lcmr-xr simulate"), ok.stderr
    bad = subprocess.run([sys.executable, "-m", "lcmr_xr", "simulate", "-o", "x.nc", "--seed", "-1"],
                         capture_output=True, text=True, env=env, cwd=tmp_path)
    assert bad.returncode == 2 and "lcmr-xr simulate: error: --seed must be >= 0" in bad.stderr
    assert list(tmp_path.iterdir()) == []


def test_identify_reads_and_writes_matlab_files(tmp_path, capsys):
    """identify's help named NetCDF only, though it reads a .mat experiment; its -o refused
    .mat ("must end in .nc"), though lcmr_xr.save writes the frd-ready file.  Now both are
    said and done: the .mat FRF holds the same P as the .nc one."""
    import numpy as np
    import scipy.io

    import lcmr_xr

    with pytest.raises(SystemExit):
        cli.main(["identify", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "MATLAB .mat with the variables r, u, y, F and Ts" in text and ".mat for MATLAB's frd" in text
    exp = hdd.simulate(n_samples=400, noise=False, seed=1)
    lcmr_xr.save(exp, tmp_path / "e.mat")
    args = ["--window", "12", "--degrees", "2-2-2"]
    assert cli.main(["identify", str(tmp_path / "e.mat"), "-o", str(tmp_path / "f.mat"), *args]) == 0
    assert cli.main(["identify", str(tmp_path / "e.mat"), "-o", str(tmp_path / "f.nc"), *args]) == 0
    frf = lcmr_xr.open_frf(tmp_path / "f.nc")
    xr.testing.assert_identical(frf.drop_attrs(deep=False), lcmr_xr.identify(exp, window=12, degrees=(2, 2, 2))
                                .drop_attrs(deep=False))
    m = scipy.io.loadmat(tmp_path / "f.mat")
    np.testing.assert_array_equal(m["P"], frf.P.transpose("output", "input", "frequency").values)
    stacked = xr.concat([exp, exp], "experiment")
    save(stacked, tmp_path / "two.nc")
    capsys.readouterr()
    assert cli.main(["identify", str(tmp_path / "two.nc"), "-o", str(tmp_path / "g.mat"), *args]) == 2
    err = capsys.readouterr().err
    assert "a .mat file holds one FRF" in err and "identifying" not in err, err
    assert not (tmp_path / "g.mat").exists()


def test_identify_writes_a_periodic_experiment_to_mat(tmp_path, capsys):
    """A record of repeated periods (a 'period' dim) is identified into ONE FRF (its periods
    pooled), but -o .mat refused it as 'experiments along ['period']' with the remedy of
    keeping one period (isel(period=0): the others thrown away).  Only the dims that stay in
    the result (experiments) make a stack that a .mat cannot hold."""
    import numpy as np
    import scipy.io

    import lcmr_xr

    exp = hdd.simulate(n_samples=400, noise=True, seed=1, periods=3)
    save(exp, tmp_path / "p.nc")
    args = ["--window", "12", "--degrees", "2-2-2"]
    assert cli.main(["identify", str(tmp_path / "p.nc"), "-o", str(tmp_path / "p.mat"), *args]) == 0, \
        capsys.readouterr().err
    m = scipy.io.loadmat(tmp_path / "p.mat")
    want = lcmr_xr.identify(exp, window=12, degrees=(2, 2, 2))
    np.testing.assert_array_equal(m["P"], want.P.transpose("output", "input", "frequency").values)
