"""DFTs of labelled signals, their inverse, and the fast spectrum from lifted spectra.

Scaling is the plain sum of :func:`numpy.fft.fft` (attribute ``dft_scaling = "sum"``).
Everything the inverse needs (time start, spacing, name, attributes, length, dtype) is
stored as flat attributes on the new frequency coordinate, so spectra survive NetCDF.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lcmr_xr.conventions import (
    DFT_SCALING,
    DFT_SCALING_VALUE,
    FREQUENCY,
    LIFT_PHASE,
    SLOW_FREQUENCY,
    SLOW_TIME,
    TIME,
    frequency_attrs,
    frequency_dim_for,
)
from lcmr_xr.kernels import lifting as lifting_kernels
from lcmr_xr.settings import as_bool, as_integer
from lcmr_xr.transforms._coords import even_spacing, rebuild_time, time_inverse_attrs
from lcmr_xr.transforms._finite import checked_blocks, refuse_non_finite
from lcmr_xr.transforms.lifting import check_all_phases

__all__ = ["dft", "idft", "fast_spectrum_from_lifted"]

_ONE_SIDED = "one_sided"
_TIME_LONG_NAME = "time_domain_long_name"  # "" when the time signal had no long_name


def _require_single_chunk(da: xr.DataArray, dim: str) -> None:
    chunks = da.chunksizes.get(dim) if da.chunks is not None else None
    if chunks is not None and len(chunks) > 1:
        raise ValueError(
            f"{da.name or 'the input'!s} is split into {len(chunks)} dask chunks along {dim!r}, "
            f"but a DFT needs the whole {dim!r} axis in one chunk; rechunk first with "
            f".chunk({{{dim!r}: -1}})."
        )


def _pick_dim(x, candidates, what: str) -> str:
    for cand in candidates:
        if cand in x.dims:
            return cand
    raise ValueError(
        f"no {what} dimension found (looked for {list(candidates)}, dims are {list(x.dims)}); "
        "pass dim=<name>."
    )


def _require_xarray(x, func: str, coordinate: str) -> None:
    """Refuse anything but a DataArray or Dataset before its dims are looked at."""
    if not isinstance(x, (xr.DataArray, xr.Dataset)):
        raise TypeError(
            f"{func} needs an xarray DataArray or Dataset with a {coordinate} coordinate, got "
            f"{type(x).__name__}; wrap a numpy array with xr.DataArray(x, dims=..., "
            f"coords=...), or use numpy.fft for plain arrays."
        )


def _map_vars(x, dim: str, func):
    """Apply ``func`` to a DataArray, or to each data variable of a Dataset that has ``dim``."""
    if isinstance(x, xr.DataArray):
        return func(x)
    if not isinstance(x, xr.Dataset):
        raise TypeError(f"expected an xarray DataArray or Dataset, got {type(x).__name__}.")
    out = {}
    for name, var in x.data_vars.items():
        out[name] = func(var) if dim in var.dims else var
    # Coordinates on the transformed dim cannot survive; xr.Dataset drops them via the arrays.
    return xr.Dataset(out, attrs=dict(x.attrs))


def _spectrum_attrs(attrs: dict, name) -> dict:
    long_name = attrs.get("long_name")
    shown = long_name if long_name is not None else (name if name is not None else "signal")
    out = dict(attrs)
    out["long_name"] = f"DFT of {shown}"
    out[_TIME_LONG_NAME] = "" if long_name is None else long_name
    out[DFT_SCALING] = DFT_SCALING_VALUE
    return out


def _signal_attrs(attrs: dict) -> dict:
    out = dict(attrs)
    out.pop(DFT_SCALING, None)
    if _TIME_LONG_NAME in out:
        original = out.pop(_TIME_LONG_NAME)
        if original == "":
            out.pop("long_name", None)
        else:
            out["long_name"] = original
    return out


#: What NaN/inf would do to a DFT, and the remedy (the message of :mod:`._finite`).
_DFT_CONSEQUENCE = "a DFT would spread them over every frequency bin (all NaN)"


def _remedy(dim: str, what: str = "samples") -> str:
    return (f"Remove or interpolate the bad {what} first (e.g. x.interpolate_na({dim!r})), or "
            f"drop the channels or records that hold them.")


def _spectrum_remedy(dim: str) -> str:
    return ("Recompute the spectrum from finite data, or fill the bad bins where their value "
            "is known (e.g. X.fillna(0) where the spectrum vanishes), or drop the channels or "
            f"records that hold them (X.dropna(..., how='any') along a dim other than {dim!r}).")


def _check_finite(da: xr.DataArray, dim: str) -> None:
    """Refuse NaN/inf in in-memory data, naming the variable, channels and time range.

    Lazy data are checked block by block when computed (:func:`_finite_kernel`), as
    ``identify`` checks its lazy data.
    """
    refuse_non_finite(da, dim, consequence=_DFT_CONSEQUENCE, remedy=_remedy(dim))


def _finite_kernel(kernel, name, dim: str, t: np.ndarray):
    """``kernel`` on blocks of lazy data, refusing a block that holds NaN/inf."""
    return checked_blocks(kernel, name, dim, t, consequence=_DFT_CONSEQUENCE, remedy=_remedy(dim))


def _dft_dataarray(da: xr.DataArray, dim: str, one_sided: bool) -> xr.DataArray:
    if dim not in da.coords:
        raise ValueError(
            f"{dim!r} has no coordinate, so the frequency bins are unknown; assign times in "
            f"seconds first, e.g. x.assign_coords({dim}=np.arange(x.sizes[{dim!r}]) * T)."
        )
    n = da.sizes[dim]
    _, spacing = even_spacing(da[dim].values, dim, da[dim].attrs.get("units"))
    if one_sided and np.issubdtype(da.dtype, np.complexfloating):
        raise ValueError(
            f"one_sided=True needs a real signal, but {da.name or 'the input'} is complex; "
            "use the default two-sided DFT."
        )
    _require_single_chunk(da, dim)
    _check_finite(da, dim)
    fdim = frequency_dim_for(dim)
    n_out = n // 2 + 1 if one_sided else n
    kernel = np.fft.rfft if one_sided else np.fft.fft
    if da.chunks is not None and da.dtype.kind in "fc":
        kernel = _finite_kernel(kernel, da.name, dim, np.asarray(da[dim].values))
    out_dtype = np.result_type(da.dtype, np.complex64)
    spec = xr.apply_ufunc(
        kernel,
        da,
        input_core_dims=[[dim]],
        output_core_dims=[[fdim]],
        dask="parallelized",
        output_dtypes=[out_dtype],
        dask_gufunc_kwargs={"output_sizes": {fdim: n_out}},
        keep_attrs=True,  # also keeps the attributes of the other coordinates
        kwargs={"axis": -1},
    )
    coord_attrs = frequency_attrs("slow frequency" if fdim == SLOW_FREQUENCY else "frequency")
    coord_attrs.update(time_inverse_attrs(dim, da[dim].values, da[dim].attrs))
    coord_attrs[_ONE_SIDED] = int(one_sided)
    coord_attrs["signal_dtype"] = str(da.dtype)
    freqs = np.arange(n_out) / (n * spacing)
    # apply_ufunc moves the core dim last; put the new dim where the old one was.
    spec = spec.transpose(*[fdim if d == dim else d for d in da.dims])
    spec = spec.assign_coords({fdim: (fdim, freqs, coord_attrs)})
    spec.attrs = _spectrum_attrs(da.attrs, da.name)
    return spec


def dft(x, dim: str | None = None, *, one_sided: bool = False):
    """Discrete Fourier transform along a time dim, labelled in hertz.

    Parameters
    ----------
    x : xarray.DataArray or xarray.Dataset
        Signal(s) with an evenly spaced time coordinate in seconds.  In a Dataset, data
        variables without ``dim`` pass through unchanged.
    dim : str, optional
        Dimension to transform.  Default: ``time`` if present, else ``slow_time``.  The new
        dim is :func:`lcmr_xr.conventions.frequency_dim_for` of it (``frequency``,
        ``slow_frequency``).
    one_sided : bool, default False
        Return only bins ``k = 0..N//2`` (real input only, as :func:`numpy.fft.rfft`).

    Returns
    -------
    xarray.DataArray or xarray.Dataset
        ``X(k) = sum_n x(n) exp(-2j pi k n / N)`` (as :func:`numpy.fft.fft`) at frequencies
        ``k / (N T)`` Hz, ``k = 0..N-1`` (or ``0..N//2``), with ``T`` the coordinate spacing.
        Units are kept, ``long_name`` becomes ``"DFT of <long_name>"``, attribute
        ``dft_scaling = "sum"``.  The frequency coordinate's attributes record what
        :func:`idft` needs.  Other coordinates along ``dim`` are dropped.  Lazy on dask
        (``dim`` must be a single chunk).

    Raises
    ------
    ValueError
        Missing, unevenly spaced, non-increasing or single-sample coordinate, or one whose
        ``units`` name a time unit other than seconds (``ms``, ``us``, ``min``: its values
        would be read as seconds); ``dim`` chunked by dask; ``one_sided`` on complex data; NaN or inf in the data (they would
        make every bin NaN; the message names the variable, channels and time range; lazy
        data are checked when computed).
    TypeError
        ``x`` not a DataArray or Dataset; ``one_sided`` not True or False.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> x = xr.DataArray(np.cos(2 * np.pi * np.arange(8) / 8), dims="time",
    ...                  coords={"time": np.arange(8) * 0.5})
    >>> X = dft(x)
    >>> X.frequency.values.tolist()[:3], np.round(abs(X.values), 9).tolist()[:3]
    ([0.0, 0.25, 0.5], [0.0, 4.0, 0.0])
    >>> bool(np.allclose(idft(X), x))
    True
    """
    _require_xarray(x, "dft", "time (s)")
    one_sided = as_bool(one_sided, "one_sided")  # bool("no") is True: strings are refused
    if dim is None:
        dim = _pick_dim(x, (TIME, SLOW_TIME), "time")
    if dim not in x.dims:
        raise ValueError(f"cannot take the DFT along {dim!r}: not a dimension of {list(x.dims)}.")
    return _map_vars(x, dim, lambda da: _dft_dataarray(da, dim, one_sided))


def _idft_dataarray(da: xr.DataArray, fdim: str) -> xr.DataArray:
    attrs = da[fdim].attrs if fdim in da.coords else {}
    if "time_name" not in attrs:
        raise ValueError(
            f"the {fdim!r} coordinate lacks the attributes written by lcmr_xr.dft (time_name, "
            "n_time, ...), so the time axis cannot be rebuilt; compute the spectrum with dft."
        )
    tname, tvalues, tattrs = rebuild_time(attrs)
    n = int(attrs["n_time"])
    one_sided = bool(attrs.get(_ONE_SIDED, 0))
    expected = n // 2 + 1 if one_sided else n
    if da.sizes[fdim] != expected:
        raise ValueError(
            f"{fdim!r} has {da.sizes[fdim]} bins but the recorded signal length N={n} needs "
            f"{expected}; was the spectrum sliced? Use the full spectrum for idft."
        )
    _require_single_chunk(da, fdim)
    # NaN/inf spread over every time sample, silently: refused as dft refuses them
    consequence = "an inverse DFT would spread them over every time sample (all NaN)"
    coord = np.asarray(da[fdim].values) if fdim in da.coords else None
    refuse_non_finite(da, fdim, consequence=consequence, remedy=_spectrum_remedy(fdim),
                      unit="Hz", noun="bins")
    signal_dtype = np.dtype(attrs.get("signal_dtype", "float64"))
    real = not np.issubdtype(signal_dtype, np.complexfloating)
    if real:
        # A real signal comes back real, in its own float precision.
        out_dtype = signal_dtype if np.issubdtype(signal_dtype, np.floating) else np.dtype(float)
        if one_sided:
            def kernel(a):
                return np.fft.irfft(a, n=n, axis=-1).astype(out_dtype, copy=False)
        else:
            def kernel(a):
                return np.fft.ifft(a, axis=-1).real.astype(out_dtype, copy=False)
    else:
        out_dtype = np.result_type(da.dtype, np.complex64)

        def kernel(a):
            return np.fft.ifft(a, axis=-1)
    if da.chunks is not None and da.dtype.kind in "fc":
        kernel = checked_blocks(kernel, da.name, fdim, coord, consequence=consequence,
                                remedy=_spectrum_remedy(fdim), unit="Hz", noun="bins")
    sig = xr.apply_ufunc(
        kernel,
        da,
        input_core_dims=[[fdim]],
        output_core_dims=[[tname]],
        exclude_dims={fdim},
        dask="parallelized",
        # meta rather than output_dtypes: dask would cast a complex meta to real and warn.
        dask_gufunc_kwargs={"output_sizes": {tname: n}, "meta": np.empty((0,) * da.ndim, out_dtype)},
        keep_attrs=True,  # also keeps the attributes of the other coordinates
    )
    sig = sig.transpose(*[tname if d == fdim else d for d in da.dims])
    sig = sig.assign_coords({tname: (tname, tvalues, tattrs)})
    sig.attrs = _signal_attrs(da.attrs)
    return sig


def idft(x, dim: str | None = None):
    """Inverse of :func:`dft`: back to the time dim, coordinate and attributes restored.

    Parameters
    ----------
    x : xarray.DataArray or xarray.Dataset
        Output of :func:`dft` (the frequency coordinate must keep its attributes).
    dim : str, optional
        Frequency dimension.  Default: ``frequency`` if present, else ``slow_frequency``.

    Returns
    -------
    xarray.DataArray or xarray.Dataset
        The signal, real if the transformed signal was real; the time coordinate is rebuilt
        bit for bit, so ``idft(dft(x))`` equals ``x`` up to FFT rounding (~1e-16 relative).

    Raises
    ------
    TypeError
        ``x`` not a DataArray or Dataset.
    ValueError
        No frequency dim, or a frequency coordinate without the attributes :func:`dft`
        sets, or a sliced spectrum; NaN or inf in the spectrum (they would make every time
        sample NaN; the message names the variable, channels and frequency range as
        :func:`dft`'s; lazy data are checked when computed, block by block).

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> x = xr.DataArray([1.0, 2.0, 0.0, -1.0], dims="time", coords={"time": [0, 0.1, 0.2, 0.3]})
    >>> bool(np.allclose(idft(dft(x, one_sided=True)), x))
    True
    """
    _require_xarray(x, "idft", "frequency (Hz, from dft)")
    if dim is None:
        dim = _pick_dim(x, (FREQUENCY, SLOW_FREQUENCY), "frequency")
    if dim not in x.dims:
        raise ValueError(f"cannot invert along {dim!r}: not a dimension of {list(x.dims)}.")
    return _map_vars(x, dim, lambda da: _idft_dataarray(da, dim))


def fast_spectrum_from_lifted(X, dim: str = SLOW_FREQUENCY, factor: int | None = None):
    """Fast-rate DFT of a signal from the slow-rate DFTs of its lifted phases.

    Labelled form of :func:`lcmr_xr.kernels.lifting.fast_spectrum_from_lifted`:
    ``X(k) = sum_j exp(-2j pi k j / N) X_j(k mod M)``, so that
    ``dft(x) == fast_spectrum_from_lifted(dft(lift(x), dim="slow_time"))``.

    Parameters
    ----------
    X : xarray.DataArray
        Two-sided slow DFT with dims ``dim`` (M bins) and ``lift_phase`` (F), as returned by
        ``dft(lift(x), dim="slow_time")``; other dims broadcast.
    dim : str, default "slow_frequency"
        The slow frequency dimension; the result is on ``frequency`` (for ``slow_frequency``)
        or on ``dim`` with a leading ``slow_`` removed.
    factor : int, optional
        Lifting factor F; default the length of ``lift_phase`` (must match if given).
        Read by the library's integer rule (:func:`lcmr_xr.settings.as_integer`): ``2.0``
        and a 0-d array are 2, ``2.5`` is refused (never rounded).

    Returns
    -------
    xarray.DataArray
        ``N = M F`` fast bins at ``k / (N Th)`` Hz, ``Th = Tl / F``, same units and
        attributes as ``X``; the coordinate carries what :func:`idft` needs.

    Raises
    ------
    TypeError
        ``X`` not a DataArray; ``factor`` not a number (``"2"``, a bool).
    ValueError
        Missing dims, a fractional ``factor`` or one other than the number of phases, phases that are not
        the lifting's ``0..F-1`` in order (reordered, or fewer than its ``lift_factor``,
        as :func:`lcmr_xr.unlift` refuses them), a one-sided slow
        spectrum, a core dim split into dask chunks; NaN or inf in ``X`` (each would make
        ``F`` fast bins NaN; the message names the variable, channels and frequency range as
        :func:`dft`'s; lazy data are checked when computed, block by block).

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> from lcmr_xr.transforms.lifting import lift
    >>> x = xr.DataArray(np.arange(12.0), dims="time", coords={"time": np.arange(12) * 0.1})
    >>> X = fast_spectrum_from_lifted(dft(lift(x, 3), dim="slow_time"))
    >>> bool(np.allclose(X.values, np.fft.fft(np.arange(12.0))))
    True
    """
    if not isinstance(X, xr.DataArray):
        raise TypeError(
            f"expected an xarray DataArray, got {type(X).__name__}; apply it per variable."
        )
    if dim not in X.dims or LIFT_PHASE not in X.dims:
        raise ValueError(
            f"need dims {dim!r} and {LIFT_PHASE!r}, got {list(X.dims)}; pass "
            "dft(lift(x), dim='slow_time')."
        )
    f_ = X.sizes[LIFT_PHASE]
    if factor is not None:  # the settings' integer rule: 2.0 yes, 2.5 no (ValueError), "2", True no (TypeError)
        factor = as_integer(factor, "factor", minimum=1, example=f_)
    check_all_phases(X, "form the fast spectrum", "transform every phase and select bins "
                     "afterwards")
    if factor is not None and factor != f_:
        raise ValueError(
            f"factor={factor} does not match the {f_} lifting phases of the input; omit factor."
        )
    attrs = X[dim].attrs if dim in X.coords else {}
    if attrs.get(_ONE_SIDED, 0):
        raise ValueError("the slow spectrum is one-sided; compute it with dft(..., one_sided=False).")
    m = X.sizes[dim]
    n = m * f_
    fast_dim = dim[len("slow_"):] if dim.startswith("slow_") else f"fast_{dim}"
    _require_single_chunk(X, dim)
    _require_single_chunk(X, LIFT_PHASE)
    # a NaN/inf slow bin would make its F fast bins NaN, silently: refused as dft refuses
    consequence = (f"each would make the {f_} fast bins it serves NaN (fast bin k reads slow "
                   f"bin k mod {m} of every phase)")
    coord = np.asarray(X[dim].values) if dim in X.coords else None
    refuse_non_finite(X, dim, consequence=consequence, remedy=_spectrum_remedy(dim),
                      unit="Hz", noun="bins")
    kernel = lifting_kernels.fast_spectrum_from_lifted
    if X.chunks is not None and X.dtype.kind in "fc":
        kernel = checked_blocks(kernel, X.name, dim, coord, consequence=consequence,
                                remedy=_spectrum_remedy(dim), unit="Hz", noun="bins", axes=2)
    out = xr.apply_ufunc(
        kernel,
        X,
        input_core_dims=[[dim, LIFT_PHASE]],
        output_core_dims=[[fast_dim]],
        dask="parallelized",
        output_dtypes=[np.result_type(X.dtype, np.complex64)],
        dask_gufunc_kwargs={"output_sizes": {fast_dim: n}},
        keep_attrs=True,
    )
    out = out.transpose(*[fast_dim if d == dim else d for d in X.dims if d != LIFT_PHASE])
    coord_attrs = frequency_attrs(fast_dim.replace("_", " "))
    if "time_spacing" in attrs:
        slow_period = float(attrs["time_spacing"])
        fast_period = slow_period / f_
        start = float(attrs["time_start"])
        tname = str(attrs["time_name"])
        tname = tname[len("slow_"):] if tname.startswith("slow_") else tname
        coord_attrs.update(
            time_name=tname, n_time=n, time_dtype=attrs.get("time_dtype", "float64"),
            time_start=start, time_spacing=fast_period, time_recipe="start+n*spacing",
            signal_dtype=attrs.get("signal_dtype", "float64"),
        )
        coord_attrs.update({k: v for k, v in attrs.items() if k.startswith("time_attr_")})
        coord_attrs[_ONE_SIDED] = 0
        freqs = np.arange(n) / (n * fast_period)
    elif dim in X.coords and m > 1:
        # Slow and fast bins share the spacing 1/(M Tl) = 1/(N Th).
        step = float(X[dim].values[1] - X[dim].values[0])
        freqs = np.arange(n) * step
    else:
        return out
    return out.assign_coords({fast_dim: (fast_dim, freqs, coord_attrs)})
