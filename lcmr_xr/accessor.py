"""The ``.lcmr`` accessor: forwards to the functions of :mod:`lcmr_xr`, holds no state.

``ds.lcmr.identify(window=30)`` is ``lcmr_xr.identify(ds, window=30)``; the functions are
the API and carry the documentation.
"""

from __future__ import annotations

import xarray as xr


class _Forwarder:
    """Common methods of the DataArray and Dataset accessors."""

    def __init__(self, obj):
        self._obj = obj

    def lift(self, factor=None, *, dim="time"):
        """Lift the fast time dim; see :func:`lcmr_xr.lift`."""
        from lcmr_xr.transforms import lift

        return lift(self._obj, factor, dim=dim)

    def unlift(self, *, dim="slow_time"):
        """Undo :meth:`lift`; see :func:`lcmr_xr.unlift`."""
        from lcmr_xr.transforms import unlift

        return unlift(self._obj, dim=dim)

    def dft(self, dim=None, *, one_sided=False):
        """DFT along a time dim; see :func:`lcmr_xr.dft`."""
        from lcmr_xr.transforms import dft

        return dft(self._obj, dim, one_sided=one_sided)

    def idft(self, dim=None):
        """Inverse of :meth:`dft`; see :func:`lcmr_xr.idft`."""
        from lcmr_xr.transforms import idft

        return idft(self._obj, dim)

    def bode(self, *, ax=None, truth=None, band=0.95, nyquist=True, db=True, xlim=None):
        """Bode plot of an FRF; see :func:`lcmr_xr.plot.bode`."""
        from lcmr_xr.plot import bode

        return bode(self._obj, ax=ax, truth=truth, band=band, nyquist=nyquist, db=db, xlim=xlim)


@xr.register_dataarray_accessor("lcmr")
class LcmrDataArrayAccessor(_Forwarder):
    """``DataArray.lcmr``: lift, unlift, dft, idft, bode."""


@xr.register_dataset_accessor("lcmr")
class LcmrDatasetAccessor(_Forwarder):
    """``Dataset.lcmr``: the DataArray methods plus identify, validate and save."""

    def identify(self, *, method="lrm", window=30, degrees=None, closed_loop="indirect",
                 covariance=True, errors="raise", transient_periods=None, combine=None):
        """Identify the fast FRF of an experiment; see :func:`lcmr_xr.identify`."""
        from lcmr_xr.identification import identify

        return identify(self._obj, method=method, window=window, degrees=degrees,
                        closed_loop=closed_loop, covariance=covariance, errors=errors,
                        transient_periods=transient_periods, combine=combine)

    def validate(self):
        """Check the experiment conventions; see :func:`lcmr_xr.validate_experiment`."""
        from lcmr_xr.experiment import validate_experiment

        return validate_experiment(self._obj)

    def save(self, path):
        """Write atomically to NetCDF; see :func:`lcmr_xr.save`."""
        from lcmr_xr.io import save

        return save(self._obj, path)
