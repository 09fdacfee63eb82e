"""What a new process imports: ``import lcmr_xr`` and the kernels stay light (issue 12,
warm start), and the lazily imported names and the ``.lcmr`` accessor still work."""

import pickle
import pkgutil
import subprocess
import sys

import pytest

import lcmr_xr
import lcmr_xr.kernels


def _run(code):
    """Run ``code`` in a fresh interpreter; its stdout."""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout


HEAVY = ("xarray", "pandas", "numba", "scipy", "matplotlib", "dask", "netCDF4", "h5py")


def test_import_lcmr_xr_imports_no_heavy_dependency():
    """``import lcmr_xr`` imports none of xarray, pandas, numba, scipy, matplotlib, dask,
    netCDF4, h5py: each comes with the first function that needs it."""
    out = _run(f"import sys, lcmr_xr; print([m for m in {HEAVY!r} if m in sys.modules])")
    assert out.strip() == "[]"


def test_labelled_api_imports_only_xarray_and_pandas():
    """The functions a first ``identify`` script reaches (``identify``, ``experiment``,
    ``lcmr_xr.hdd``, ``lcmr_xr.io``, ``lcmr_xr.plot``) import xarray and pandas but
    none of dask, distributed, numba, scipy, matplotlib, netCDF4, h5netcdf, h5py: numba
    comes with the first compiled call, the others with the functions that use them."""
    heavy = ("dask", "distributed", "numba", "scipy", "matplotlib", "netCDF4", "h5netcdf",
             "h5py")
    out = _run("import sys, lcmr_xr\n"
               "lcmr_xr.identify, lcmr_xr.experiment, lcmr_xr.save, lcmr_xr.open_experiment\n"
               "import lcmr_xr.hdd, lcmr_xr.io, lcmr_xr.plot\n"
               f"print([m for m in {heavy!r} if m in sys.modules],"
               " 'xarray' in sys.modules, 'pandas' in sys.modules)")
    assert out.strip() == "[] True True"


def test_kernels_import_no_xarray():
    """Every module of lcmr_xr.kernels (the compiled one included) imports without xarray
    and pandas: the kernels on plain arrays start without them."""
    names = [m.name for m in pkgutil.walk_packages(lcmr_xr.kernels.__path__, "lcmr_xr.kernels.")]
    assert "lcmr_xr.kernels.local_model_bins" in names and len(names) > 10
    out = _run("import importlib, sys\n"
               f"for name in {names!r}:\n"
               "    importlib.import_module(name)\n"
               "print('xarray' in sys.modules, 'pandas' in sys.modules, 'numba' in sys.modules)")
    assert out.split() == ["False", "False", "True"]


@pytest.mark.parametrize("first", ["lcmr_xr", "xarray"])
def test_accessor_registered_whichever_is_imported_first(first):
    """The ``.lcmr`` accessor exists on every Dataset and DataArray after ``import lcmr_xr``,
    whether xarray was imported before it or after it (then when xarray is imported)."""
    second = "xarray" if first == "lcmr_xr" else "lcmr_xr"
    out = _run(f"import {first}\nimport {second}\nimport xarray as xr\n"
               "print(type(xr.Dataset().lcmr).__name__, type(xr.DataArray(0.0).lcmr).__name__,"
               " callable(xr.Dataset().lcmr.identify))")
    assert out.split() == ["LcmrDatasetAccessor", "LcmrDataArrayAccessor", "True"]


def test_lazy_names_and_experiment_stays_the_function():
    """Every name of ``__all__`` resolves to its module's object; ``lcmr_xr.experiment`` is
    the function even after the subpackage of the same name was imported (which binds the
    subpackage to that attribute); submodules are attributes on first use."""
    out = _run("import lcmr_xr.identification.identify\n"  # imports lcmr_xr.experiment
               "import lcmr_xr, inspect\n"
               "print(inspect.isfunction(lcmr_xr.experiment), lcmr_xr.settings.__name__)")
    assert out.split() == ["True", "lcmr_xr.settings"]
    from lcmr_xr.experiment import experiment
    from lcmr_xr.identification import identify
    from lcmr_xr.io import save
    assert lcmr_xr.experiment is experiment and lcmr_xr.identify is identify
    assert lcmr_xr.save is save
    for name in lcmr_xr.__all__:
        assert getattr(lcmr_xr, name) is not None
        assert name in dir(lcmr_xr)
    namespace = {}
    exec("from lcmr_xr import *", namespace)
    assert set(lcmr_xr.__all__) <= set(namespace)
    with pytest.raises(AttributeError, match="no attribute 'nonexistent'"):
        lcmr_xr.nonexistent  # noqa: B018
    with pytest.raises(AttributeError, match="patch lcmr_xr.experiment.experiment"):
        lcmr_xr.experiment = len


def test_package_pickles_by_reference():
    """The package object pickles by reference (dask's cloudpickle meets it among the
    globals of the functions it ships to workers), as a plain module does."""
    import cloudpickle

    assert pickle.loads(pickle.dumps(lcmr_xr)) is lcmr_xr
    assert cloudpickle.loads(cloudpickle.dumps(lcmr_xr)) is lcmr_xr

    def uses_the_package():
        return lcmr_xr.__name__

    assert cloudpickle.loads(cloudpickle.dumps(uses_the_package))() == "lcmr_xr"
