"""Exchange an FRF with python-control: ``to_frd`` and ``from_frd``.

python-control is where loop shaping, notch design and margin checks happen; its
:class:`control.FrequencyResponseData` holds a response as ``(outputs, inputs,
frequency)`` at angular frequencies ``omega`` in rad/s, with the sampling period ``dt``
of a discrete-time system.  An FRF dataset holds ``P`` as ``(frequency, output, input)``
in Hz.  python-control is an optional dependency (``pip install "lcmr_xr[control]"``),
imported only when these functions run.
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np
import xarray as xr

from lcmr_xr.conventions import FREQUENCY, INPUT, OUTPUT, P, SAMPLING_PERIOD, frequency_attrs, label_attrs

__all__ = ["from_frd", "to_frd"]

_DIMS = (FREQUENCY, OUTPUT, INPUT)


def _control():
    """The python-control module, or an ImportError that says how to install it."""
    try:
        import control
    except ImportError as err:
        raise ImportError(
            "lcmr_xr.to_frd / from_frd need python-control; install it with "
            "pip install \"lcmr_xr[control]\" (or pip install control)."
        ) from err
    return control


def _response(frf, variable: str) -> tuple[xr.DataArray, dict]:
    """``(DataArray (frequency, output, input), attrs to read the sampling period from)``."""
    if isinstance(frf, xr.Dataset):
        if variable not in frf.data_vars:
            raise ValueError(
                f"the dataset has no variable {variable!r} (it has {sorted(frf.data_vars)}); "
                "pass variable= the name of a complex (frequency, output, input) response."
            )
        da, attrs = frf[variable], {**frf[variable].attrs, **frf.attrs}
    elif isinstance(frf, xr.DataArray):
        da, attrs = frf, dict(frf.attrs)
    else:
        raise TypeError(
            f"to_frd needs an FRF dataset or a DataArray like its P, got {type(frf).__name__}."
        )
    extra = [d for d in da.dims if d not in _DIMS]
    if extra:
        raise ValueError(
            f"{variable} has dims {da.dims}: a FrequencyResponseData holds one system, so "
            f"select one case of {extra} first, e.g. frf.isel({extra[0]}=0)."
        )
    missing = [d for d in _DIMS if d not in da.dims or d not in da.coords]
    if missing:
        raise ValueError(
            f"{variable} has dims {da.dims} but needs {_DIMS} with coordinates; missing "
            f"{missing}. For one channel add it, e.g. da.expand_dims(input=['u'])."
        )
    units = da[FREQUENCY].attrs.get("units", "Hz")
    if units != "Hz":
        raise ValueError(
            f"the frequency coordinate of {variable} has units {units!r}; to_frd converts "
            "from Hz to rad/s. Convert it to Hz first."
        )
    return da.transpose(*_DIMS), attrs


def _sampling_period(attrs: dict, sampling_period) -> float:
    stored = attrs.get(SAMPLING_PERIOD)
    if sampling_period is None:
        if stored is None:
            raise ValueError(
                "the FRF has no 'sampling_period' attribute; pass sampling_period= the fast "
                "sampling period Th in s (the FRD is discrete time with dt = Th)."
            )
        sampling_period = stored
    if isinstance(sampling_period, bool) or not isinstance(sampling_period, Real) or not (
        math.isfinite(sampling_period) and sampling_period > 0
    ):
        raise ValueError(f"sampling_period must be a positive number of seconds, got {sampling_period!r}.")
    if stored is not None and float(stored) != float(sampling_period):
        raise ValueError(
            f"sampling_period={sampling_period!r} contradicts the FRF's attribute "
            f"sampling_period={stored!r}; leave it out to use the attribute."
        )
    return float(sampling_period)


def to_frd(frf, variable: str = P, *, sampling_period=None):
    """Convert an FRF to a python-control ``FrequencyResponseData`` (discrete time, ``dt = Th``).

    Parameters
    ----------
    frf : xarray.Dataset or xarray.DataArray
        FRF dataset (from :func:`lcmr_xr.identify` or :func:`lcmr_xr.open_frf`) or a complex
        DataArray with dims ``(frequency, output, input)``, frequency in Hz.  Select one
        case of any leading dim (``frf.isel(experiment=0)``) first.
    variable : str, optional
        Variable of a dataset to convert (default ``"P"``, the fast-rate FRF).
    sampling_period : float, optional
        Fast sampling period ``Th`` in s, the FRD's ``dt``.  Default None: the
        ``sampling_period`` attribute (every FRF dataset has it); a value that contradicts
        the attribute is refused.

    Returns
    -------
    control.FrequencyResponseData
        Response ``(outputs, inputs, frequency)`` at ``omega = 2 pi frequency`` in rad/s,
        in the order of the frequency coordinate; ``dt = Th``; input and output labels
        from the ``input``/``output`` coordinates; name ``variable``.  Bins that could not
        be estimated stay NaN (drop them with ``frf.dropna("frequency")`` first when a
        python-control function needs finite data).

    Raises
    ------
    ImportError
        If python-control is not installed (``pip install "lcmr_xr[control]"``).
    ValueError
        If the variable is missing, has other dims, a frequency outside ``[0, 1/(2 Th)]`` or
        frequencies that do not increase strictly, or the sampling period is missing or
        contradicts the attribute.
    TypeError
        If ``frf`` is neither a Dataset nor a DataArray.

    See Also
    --------
    from_frd : The inverse.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> f = np.array([0.0, 100.0, 200.0])
    >>> P = xr.DataArray(np.array([1.0, 0.5j, -0.25])[:, None, None],
    ...                  dims=("frequency", "output", "input"),
    ...                  coords={"frequency": f, "output": ["y"], "input": ["u"]},
    ...                  attrs={"units": "m", "sampling_period": 1e-3})
    >>> frd = to_frd(P)
    >>> frd.dt, frd.input_labels, frd.output_labels, frd.frdata.shape
    (0.001, ['u'], ['y'], (1, 1, 3))
    >>> bool(np.allclose(frd.omega, 2 * np.pi * f))
    True
    """
    control = _control()
    da, attrs = _response(frf, variable)
    dt = _sampling_period(attrs, sampling_period)
    hz = np.asarray(da[FREQUENCY].values, dtype=float)
    nyquist = 1.0 / (2.0 * dt)
    if not (np.isfinite(hz).all() and (hz >= 0).all() and (hz <= nyquist * (1 + 1e-12)).all()):
        raise ValueError(
            f"the frequencies of {variable} ({hz.min():g}..{hz.max():g} Hz) must lie in "
            f"[0, {nyquist:g}] Hz, the Nyquist band of dt = {dt:g} s; check sampling_period."
        )
    steps = np.diff(hz)
    if (steps <= 0).any():
        # python-control takes omega as given, but its margins, interpolation and plots
        # assume increasing frequencies: stability_margins fails with 'Invalid inputs'
        k = int(np.argmax(steps <= 0))
        raise ValueError(
            f"the frequency coordinate of {variable} must increase strictly, but bin {k + 1} "
            f"({hz[k + 1]:g} Hz) follows {hz[k]:g} Hz; python-control's functions assume "
            "sorted, distinct frequencies. Sort with frf.sortby('frequency') and drop repeated "
            "bins with frf.drop_duplicates('frequency') first."
        )
    values = np.moveaxis(np.asarray(da.values), 0, -1)  # (output, input, frequency)
    return control.FrequencyResponseData(
        values, 2.0 * np.pi * hz, dt=dt, name=str(variable),
        inputs=[str(v) for v in da[INPUT].values],
        outputs=[str(v) for v in da[OUTPUT].values],
    )


def from_frd(frd, *, units=None, long_name=None) -> xr.DataArray:
    """Convert a python-control ``FrequencyResponseData`` to a labelled DataArray like ``P``.

    Parameters
    ----------
    frd : control.FrequencyResponseData
        Any FRD (for example from :func:`to_frd`, or ``control.frd(sys, omega)``).
    units : str, optional
        Units of the response (output units per input unit, e.g. ``"m"`` for metres
        per unit command); python-control carries none.  Default None: no ``units``
        attribute.
    long_name : str, optional
        Long name of the response; default None gives ``"frequency response"``.

    Returns
    -------
    xarray.DataArray
        Complex, dims ``(frequency, output, input)``, named after the FRD; ``frequency``
        in Hz (``omega / 2 pi``; within one rounding of the Hz values :func:`to_frd` was
        given), ``output``/``input`` labels from the FRD's signal names; attribute
        ``sampling_period`` = ``dt`` for a discrete-time FRD (so :func:`to_frd` needs no
        argument to go back).

    Raises
    ------
    ImportError
        If python-control is not installed.
    TypeError
        If ``frd`` is not a ``FrequencyResponseData``, or ``units``/``long_name`` is not a
        non-empty string.

    See Also
    --------
    to_frd : The inverse.

    Examples
    --------
    >>> import control, numpy as np
    >>> frd = control.frd(np.array([1.0, 0.5j]), 2 * np.pi * np.array([10.0, 20.0]), dt=1e-3)
    >>> P = from_frd(frd, units="m")
    >>> P.dims, P.frequency.values.tolist(), P.attrs["sampling_period"]
    (('frequency', 'output', 'input'), [10.0, 20.0], 0.001)
    """
    control = _control()
    if not isinstance(frd, control.FrequencyResponseData):
        raise TypeError(
            f"from_frd needs a control.FrequencyResponseData, got {type(frd).__name__}; for "
            "a transfer function or state space use control.frd(sys, omega) first."
        )
    for what, text in (("units", units), ("long_name", long_name)):
        if text is not None and (not isinstance(text, str) or not text.strip()):
            raise TypeError(f"{what} must be a non-empty string (e.g. units='m', long_name='plant "
                            f"FRF'), got {text!r}; the plots label axes 'long_name [units]'.")
    attrs = {"long_name": long_name if long_name is not None else "frequency response"}
    if units is not None:
        attrs["units"] = units
    # dt: None or 0 is continuous time, True a discrete time of unspecified period
    if not isinstance(frd.dt, bool) and frd.dt:
        attrs[SAMPLING_PERIOD] = float(frd.dt)
    return xr.DataArray(
        np.moveaxis(np.asarray(frd.frdata, dtype=complex), -1, 0),
        dims=_DIMS,
        coords={
            FREQUENCY: (FREQUENCY, np.asarray(frd.omega, dtype=float) / (2.0 * np.pi), frequency_attrs()),
            OUTPUT: (OUTPUT, [str(v) for v in frd.output_labels], label_attrs("output channel")),
            INPUT: (INPUT, [str(v) for v in frd.input_labels], label_attrs("input channel")),
        },
        name=str(frd.name),
        attrs=attrs,
    )
