"""lcmr_xr: lifted closed-loop multirate FRF identification on labelled data.

Identify the fast-rate frequency response function of a system running in closed
loop with a slow-rate output, beyond the slow Nyquist frequency, from one experiment
(van Haren, Mae, Blanken and Oomen, Mechatronics 108:103311).

Functions are the API (``lcmr_xr.identify(ds)``); the ``.lcmr`` accessor on DataArrays
and Datasets forwards to them (``ds.lcmr.identify()``).

The names below are imported on first use: ``import lcmr_xr`` imports neither xarray
nor numba, so that the kernels on plain arrays (``lcmr_xr.kernels``) start without
xarray and pandas (about 0.8 s).  The ``.lcmr`` accessor is registered as soon as xarray
is imported (at once if it already is): every DataArray or Dataset has it.
"""

from __future__ import annotations

import importlib
import importlib.abc
import sys
import types

__version__ = "0.1.0"

#: Public name -> the module that defines it (imported on first use).
_NAMES = {
    "CONVENTIONS": "lcmr_xr.conventions",
    "dft": "lcmr_xr.transforms",
    "experiment": "lcmr_xr.experiment",
    "fast_spectrum_from_lifted": "lcmr_xr.transforms",
    "frf_from_first_block_row": "lcmr_xr.identification.lifted_system",
    "from_frd": "lcmr_xr.io",
    "identify": "lcmr_xr.identification",
    "identify_single_rate": "lcmr_xr.identification",
    "idft": "lcmr_xr.transforms",
    "lift": "lcmr_xr.transforms",
    "lifted_frf": "lcmr_xr.identification.lifted_system",
    "multisine": "lcmr_xr.excitation",
    "open_dataset": "lcmr_xr.io",
    "open_experiment": "lcmr_xr.io",
    "open_frf": "lcmr_xr.io",
    "orthogonal_multisines": "lcmr_xr.excitation",
    "save": "lcmr_xr.io",
    "simulate_closed_loop": "lcmr_xr.simulation",
    "to_frd": "lcmr_xr.io",
    "unlift": "lcmr_xr.transforms",
    "validate_experiment": "lcmr_xr.experiment",
}
#: Subpackages and modules, attributes of the package once imported (on first use here).
_SUBMODULES = frozenset({
    "accessor", "cli", "conventions", "demo", "excitation", "experiment", "hdd",
    "identification", "io", "kernels", "plot", "scaleout", "settings", "simulation",
    "transforms",
})

__all__ = ["__version__", *sorted(_NAMES)]


def __getattr__(name):
    module = _NAMES.get(name)
    if module is not None:
        value = getattr(importlib.import_module(module), name)
        globals()[name] = value
        return value
    if name in _SUBMODULES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__():
    return sorted(set(globals()) | set(_NAMES) | _SUBMODULES)


class _Package(types.ModuleType):
    """The package's module type.  ``lcmr_xr.experiment`` is the function: importing the
    subpackage of the same name binds the subpackage to the package's attribute (the
    import system does, after the subpackage ran), which this property ignores."""

    @property
    def experiment(self):
        return getattr(importlib.import_module("lcmr_xr.experiment"), "experiment")

    @experiment.setter
    def experiment(self, value):
        if not isinstance(value, types.ModuleType):
            raise AttributeError(
                "lcmr_xr.experiment is the function lcmr_xr.experiment.experiment and cannot "
                "be replaced; patch lcmr_xr.experiment.experiment (the subpackage's "
                "attribute) instead")

    def __reduce__(self):
        # by reference, as pickle and cloudpickle (dask) treat plain modules
        return importlib.import_module, (self.__name__,)


sys.modules[__name__].__class__ = _Package


class _RegisterAccessor(importlib.abc.Loader):
    """xarray's loader, which registers the ``.lcmr`` accessor once xarray has run."""

    def __init__(self, loader):
        self._loader = loader

    def create_module(self, spec):
        return self._loader.create_module(spec)

    def exec_module(self, module):
        self._loader.exec_module(module)
        if _ON_XARRAY_IMPORT in sys.meta_path:
            sys.meta_path.remove(_ON_XARRAY_IMPORT)
        importlib.import_module("lcmr_xr.accessor")

    def __getattr__(self, name):  # resource readers and the like: xarray's own loader
        return getattr(self._loader, name)


class _OnXarrayImport(importlib.abc.MetaPathFinder):
    """Finds xarray with the other finders and wraps its loader in
    :class:`_RegisterAccessor`: the accessor is registered when xarray is imported."""

    def find_spec(self, name, path=None, target=None):
        if name != "xarray":
            return None
        for finder in list(sys.meta_path):
            find = getattr(finder, "find_spec", None)
            if finder is self or find is None:
                continue
            spec = find(name, path, target)
            if spec is not None:
                if spec.loader is not None and hasattr(spec.loader, "exec_module"):
                    spec.loader = _RegisterAccessor(spec.loader)
                return spec
        return None


_ON_XARRAY_IMPORT = _OnXarrayImport()
if "xarray" in sys.modules:
    importlib.import_module("lcmr_xr.accessor")
else:
    sys.meta_path.insert(0, _ON_XARRAY_IMPORT)
