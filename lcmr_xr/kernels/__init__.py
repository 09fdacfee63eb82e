"""Pure-numpy kernels: no labels, no xarray import; they work on trailing axes.

The labelled layer of :mod:`lcmr_xr` maps named dimensions onto these axes with
``xarray.apply_ufunc``.  Keep this package free of xarray so the math can be read,
tested and reused on plain arrays.
"""
