"""The ``.lcmr`` accessor: forwards to the functions of :mod:`lcmr_xr`, holds no state.

``ds.lcmr.identify(window=30)`` is ``lcmr_xr.identify(ds, window=30)``; the functions are
the API and carry the documentation.  Each method forwards ``*args, **kwargs`` unchanged
and shows the function's signature (without its first argument) and docstring, so the
accessor cannot fall behind the function.
"""

from __future__ import annotations

import functools
import importlib
import inspect

import xarray as xr


class _Forward:
    """A method that calls ``module.name(obj, *args, **kwargs)``.

    The function is imported on first use, not when ``lcmr_xr`` is imported (the plot
    functions would pull in matplotlib).
    """

    def __init__(self, module: str, name: str):
        self.module, self.name = module, name

    @functools.cached_property
    def function(self):
        return getattr(importlib.import_module(self.module), self.name)

    def __get__(self, accessor, owner=None):
        func = self.function
        if accessor is None:
            return func
        obj = accessor._obj

        @functools.wraps(func)
        def method(*args, **kwargs):
            return func(obj, *args, **kwargs)

        sig = inspect.signature(func)
        method.__signature__ = sig.replace(parameters=list(sig.parameters.values())[1:])
        del method.__wrapped__  # the signature is the one set here, without the data argument
        return method


#: Accessor method -> (module, function); the first argument of each function is the data.
DATAARRAY_METHODS = {
    "lift": ("lcmr_xr.transforms", "lift"),
    "unlift": ("lcmr_xr.transforms", "unlift"),
    "dft": ("lcmr_xr.transforms", "dft"),
    "idft": ("lcmr_xr.transforms", "idft"),
    "bode": ("lcmr_xr.plot", "bode"),
}
DATASET_METHODS = {
    **DATAARRAY_METHODS,
    "identify": ("lcmr_xr.identification", "identify"),
    "validate": ("lcmr_xr.experiment", "validate_experiment"),
    "save": ("lcmr_xr.io", "save"),
}


class _Accessor:
    def __init__(self, obj):
        self._obj = obj


@xr.register_dataarray_accessor("lcmr")
class LcmrDataArrayAccessor(_Accessor):
    """``DataArray.lcmr``: lift, unlift, dft, idft, bode."""


@xr.register_dataset_accessor("lcmr")
class LcmrDatasetAccessor(_Accessor):
    """``Dataset.lcmr``: the DataArray methods plus identify, validate and save."""


for _cls, _methods in ((LcmrDataArrayAccessor, DATAARRAY_METHODS), (LcmrDatasetAccessor, DATASET_METHODS)):
    for _name, _target in _methods.items():
        setattr(_cls, _name, _Forward(*_target))
