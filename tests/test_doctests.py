"""Every Examples section in the package runs and prints what it shows."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import matplotlib
import pytest

import lcmr_xr

matplotlib.use("Agg")

MODULES = sorted(
    info.name for info in pkgutil.walk_packages(lcmr_xr.__path__, prefix="lcmr_xr.")
)


@pytest.mark.parametrize("name", MODULES)
def test_examples_run(name, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # examples that write files write here
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE,
                             verbose=False, report=True)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"


def test_modules_were_found():
    assert "lcmr_xr.identification.identify" in MODULES and len(MODULES) > 20
