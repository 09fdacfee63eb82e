"""Plots of the slow-rate (lifted) estimates: S or PS entry by entry, and the residual noise.

These show what the identification saw before the fast FRF was reconstructed: one
panel per entry of the lifted matrix against slow frequency, and the noise variance
left in each row of the lifted signal ``Z = [y; u]``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.conventions import INPUT, LIFT_PHASE, OUTPUT, SLOW_FREQUENCY
from lcmr_xr.settings import as_bool
from lcmr_xr.plot._shared import (
    check_color,
    check_xlim,
    confidence_radius,
    draw_band,
    entry_title,
    frequency_selection,
    lifted_channel_label,
    magnitude,
    magnitude_label,
    prepare_axes,
    quantity_label,
    require_complex,
    require_dims,
    ticks_for_short_log_span,
    wrapped_label,
)

# Row dims of each lifted estimate; the columns are always (lift_phase2, input2),
# flattened phase-major like the lifted channels of lcmr_xr.kernels.lifting.
_ROW_DIMS = {cv.LIFTED_S: (LIFT_PHASE, INPUT), cv.LIFTED_PS: (OUTPUT,)}
_COLUMN_DIMS = (cv.LIFT_PHASE2, cv.INPUT2)


@dataclass
class LiftedPlot:
    """Figure, axes and artists of a :func:`lifted` plot.

    Attributes
    ----------
    figure : matplotlib.figure.Figure
        The figure holding the axes.
    axes : numpy.ndarray of matplotlib.axes.Axes
        Shape ``(rows, columns)`` of the lifted matrix: ``(F n_inputs, F n_inputs)`` for
        ``S``, ``(n_outputs, F n_inputs)`` for ``PS``.
    lines : dict
        ``lines[(row, column)]`` (labels such as ``("phase 0 vcm", "phase 1 pzt")``) is a
        dict with keys ``"estimate"`` (the magnitude ``Line2D``) and ``"band"`` (upper
        and lower edge ``Line2D`` then the filled ``PolyCollection``; empty without
        a ``*_std`` variable or with ``band=None``).
    """

    figure: object
    axes: np.ndarray
    lines: dict


@dataclass
class NoisePlot:
    """Figure, axes and artists of a :func:`noise` plot.

    Attributes
    ----------
    figure : matplotlib.figure.Figure
        The figure holding the axes.
    axes : numpy.ndarray of matplotlib.axes.Axes
        Shape ``(2, 1)``: output rows of ``Z`` on top, lifted input rows below.
    lines : dict
        ``lines[(variable, row)]`` is a one-element list with the ``Line2D`` of that row,
        e.g. ``("noise_variance_y", "position")`` or
        ``("noise_variance_u", "phase 1 vcm")``.
    """

    figure: object
    axes: np.ndarray
    lines: dict


def lifted(frf, *, ax=None, which="S", db=True, band=0.95, color=None, xlim=None):
    """Magnitude of each entry of the lifted estimate ``S`` or ``PS`` against slow frequency.

    One panel per entry, titled like ``S[phase 0 vcm <- phase 1 pzt]`` (the entry that
    maps input ``pzt`` at lift phase 1 to input ``vcm`` at lift phase 0), on a
    logarithmic slow-frequency axis; the DC bin is skipped and zero or non-finite
    entries are left as gaps.

    Parameters
    ----------
    frf : xarray.Dataset
        FRF dataset with ``S`` (dims ``slow_frequency, lift_phase, input, lift_phase2,
        input2``) or ``PS`` (dims ``slow_frequency, output, lift_phase2, input2``), and
        optionally ``S_std``/``PS_std``.  Select one case of any leading dim first
        (for example ``frf.isel(experiment=0)``).
    ax : numpy.ndarray of matplotlib.axes.Axes, optional
        Existing axes shaped like the lifted matrix (see :class:`LiftedPlot`); default
        None creates a new figure.
    which : {"S", "PS"}, optional
        The lifted estimate to plot (default ``"S"``).
    db : bool, optional
        Magnitude in decibels, ``20 log10 |x|`` (default True), else ``|x|`` on a log axis.
    band : float or None, optional
        Confidence level of the band from ``S_std``/``PS_std`` (0 < band < 1, default
        0.95; radius ``sqrt(-ln(1 - band))`` standard deviations, as in
        :func:`lcmr_xr.plot.bode`).  None draws no band.
    color : color, optional
        Matplotlib color of the lines (default None: next color of the cycle).
    xlim : tuple of float, optional
        ``(f_lo, f_hi)`` slow-frequency range in Hz to draw and zoom to; default None.

    Returns
    -------
    LiftedPlot
        The figure, the axes grid and the artists per entry.

    Raises
    ------
    ValueError
        If ``which`` is not ``"S"``/``"PS"``, the variable is missing, has other dims or
        is real (the lifted estimates are complex), or ``ax``, ``band``, ``xlim`` or
        ``color`` are wrong.
    TypeError
        If ``frf`` is not a Dataset, ``db`` is not True or False, or ``color`` is not a
        color of any form.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> import lcmr_xr.plot
    >>> fs = np.arange(8) / (8 * 2e-3)  # M = 8 slow bins, Tl = 2 ms
    >>> S = xr.DataArray(
    ...     np.full((8, 2, 1, 2, 1), 0.5 + 0.5j),
    ...     dims=("slow_frequency", "lift_phase", "input", "lift_phase2", "input2"),
    ...     coords={"slow_frequency": fs, "lift_phase": [0, 1], "input": ["u"],
    ...             "lift_phase2": [0, 1], "input2": ["u"]},
    ...     attrs={"long_name": "lifted sensitivity", "units": "1"})
    >>> result = lcmr_xr.plot.lifted(xr.Dataset({"S": S}))
    >>> result.axes.shape
    (2, 2)
    >>> result.axes[0, 1].get_title()
    'S[phase 0 u <- phase 1 u]'
    >>> import matplotlib.pyplot as plt
    >>> plt.close(result.figure)
    """
    if not isinstance(which, str) or which not in _ROW_DIMS:
        raise ValueError(f"which must be one of {sorted(_ROW_DIMS)}, got {which!r}.")
    db = as_bool(db, "db")  # bool("no") is True: a string would draw the opposite
    _require_dataset(frf, which)
    if which not in frf.data_vars:
        other = next((w for w in sorted(_ROW_DIMS) if w != which and w in frf.data_vars), None)
        direct = frf.attrs.get(cv.CLOSED_LOOP) == "direct"
        raise ValueError(
            f"The dataset has no variable {which!r} (it has {sorted(frf.data_vars)})"
            + ("; a closed_loop='direct' estimate has no lifted sensitivity" if direct else "")
            + (f": plot which={other!r}." if other else
               "; plot a dataset from lcmr_xr.identify.")
        )
    dims = (SLOW_FREQUENCY,) + _ROW_DIMS[which] + _COLUMN_DIMS
    estimate = require_dims(frf[which], dims, which)
    std_name = which + cv.STD_SUFFIX
    std = require_dims(frf[std_name], dims, std_name) if std_name in frf.data_vars else None
    band_factor = confidence_radius(band)  # validated even when there is no *_std to draw
    if std is None:
        band_factor = None
    require_complex(estimate, which)
    color = check_color(color)

    frequency = np.asarray(estimate[SLOW_FREQUENCY].values, dtype=float)
    keep = frequency_selection(frequency, xlim)
    x = frequency[keep]
    row_labels = _channel_labels(estimate, _ROW_DIMS[which])
    column_labels = _channel_labels(estimate, _COLUMN_DIMS)
    shape = (len(row_labels), len(column_labels))
    figure, axes = prepare_axes(ax, shape, sharex=True)

    # (slow_frequency, rows, columns): the row and column dims flatten phase-major.
    values = estimate.values[keep].reshape((x.size,) + shape)
    sigma = None if band_factor is None else std.values[keep].reshape((x.size,) + shape)
    lines = {}
    for r, row in enumerate(row_labels):
        for c, column in enumerate(column_labels):
            a = axes[r, c]
            entry = {"estimate": a.plot(x, magnitude(values[:, r, c], db), color=color)}
            color = entry["estimate"][0].get_color()
            entry["band"] = (
                []
                if sigma is None
                else draw_band(a, x, values[:, r, c], sigma[:, r, c], band_factor, db, color, None)
            )
            a.set_title(entry_title(which, row, column), fontsize="small")
            lines[(row, column)] = entry

    _style_slow_axes(
        axes, quantity_label(estimate[SLOW_FREQUENCY].attrs, SLOW_FREQUENCY),
        [magnitude_label(estimate.attrs, which, db=db)] * shape[0], log_y=not db, xlim=xlim,
    )
    return LiftedPlot(figure=figure, axes=axes, lines=lines)


def noise(frf, *, ax=None, xlim=None):
    """Residual noise variance of each row of the lifted signal ``Z`` against slow frequency.

    Top panel: one line per output (``noise_variance_y``); bottom panel: one line per
    lifted input row, ``phase j`` of each input (``noise_variance_u``).  Both axes are
    logarithmic; the DC bin is skipped and zero or non-finite variances are gaps.  Each
    panel's y label is its variable's ``long_name [units]`` (wrapped), as on every plot.

    Parameters
    ----------
    frf : xarray.Dataset
        FRF dataset with ``noise_variance_y`` (dims ``slow_frequency, output``) and
        ``noise_variance_u`` (dims ``slow_frequency, lift_phase, input``).  Select one
        case of any leading dim first (for example ``frf.isel(experiment=0)``).
    ax : numpy.ndarray of matplotlib.axes.Axes, optional
        Two existing axes (shape ``(2, 1)`` or ``(2,)``); default None creates a figure.
    xlim : tuple of float, optional
        ``(f_lo, f_hi)`` slow-frequency range in Hz to draw and zoom to; default None.

    Returns
    -------
    NoisePlot
        The figure, the axes and the line of each row.

    Raises
    ------
    ValueError
        If a variable is missing or has other dims, or ``ax`` or ``xlim`` are wrong.
    TypeError
        If ``frf`` is not a Dataset.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> import lcmr_xr.plot
    >>> fs = np.arange(8) / (8 * 2e-3)
    >>> coords = {"slow_frequency": fs, "lift_phase": [0, 1], "input": ["u"], "output": ["y"]}
    >>> frf = xr.Dataset(
    ...     {"noise_variance_y": (("slow_frequency", "output"), np.full((8, 1), 1e-6)),
    ...      "noise_variance_u": (("slow_frequency", "lift_phase", "input"),
    ...                           np.full((8, 2, 1), 1e-4))},
    ...     coords=coords)
    >>> result = lcmr_xr.plot.noise(frf)
    >>> sorted(result.lines)  # doctest: +NORMALIZE_WHITESPACE
    [('noise_variance_u', 'phase 0 u'), ('noise_variance_u', 'phase 1 u'),
     ('noise_variance_y', 'y')]
    >>> import matplotlib.pyplot as plt
    >>> plt.close(result.figure)
    """
    panels = ((cv.NOISE_VARIANCE_Y, (OUTPUT,)), (cv.NOISE_VARIANCE_U, (LIFT_PHASE, INPUT)))
    for name, _ in panels:
        _require_dataset(frf, name)
        if name not in frf.data_vars:
            raise ValueError(
                f"The dataset has no variable {name!r} (it has {sorted(frf.data_vars)}); "
                "plot the FRF dataset returned by lcmr_xr.identify."
            )
    variables = [
        require_dims(frf[name], (SLOW_FREQUENCY,) + rows, name) for name, rows in panels
    ]
    if xlim is not None:
        check_xlim(xlim)
    selections = [
        frequency_selection(np.asarray(v[SLOW_FREQUENCY].values, dtype=float), xlim)
        for v in variables
    ]
    figure, axes = prepare_axes(ax, (2, 1), sharex=True)

    lines = {}
    for a, (name, rows), variable, keep in zip(axes[:, 0], panels, variables, selections):
        x = np.asarray(variable[SLOW_FREQUENCY].values, dtype=float)[keep]
        labels = _channel_labels(variable, rows)
        values = variable.values[keep].reshape(x.size, len(labels))
        for k, row in enumerate(labels):
            # A variance is not a magnitude of an amplitude: plotted as is, log axis.
            lines[(name, row)] = a.plot(x, magnitude(values[:, k], db=False), label=row)
        a.legend(fontsize="small")
    # the y labels are the variables' "long_name [units]", as on every plot; the long
    # names are long ("residual noise variance of the output spectrum"): wrapped
    _style_slow_axes(
        axes,
        quantity_label(variables[0][SLOW_FREQUENCY].attrs, SLOW_FREQUENCY),
        [wrapped_label(quantity_label(v.attrs, name)) for v, (name, _) in zip(variables, panels)],
        log_y=True,
        xlim=xlim,
    )
    return NoisePlot(figure=figure, axes=axes, lines=lines)


def _require_dataset(frf, name: str) -> None:
    if not isinstance(frf, xr.Dataset):
        raise TypeError(
            f"This plot reads {name!r} from the FRF dataset; pass the xarray Dataset returned "
            f"by lcmr_xr.identify, got {type(frf).__name__}."
        )


def _channel_labels(da: xr.DataArray, dims: tuple) -> list[str]:
    """Labels of the flattened ``dims`` (phase-major): ``"phase 1 vcm"`` or ``"position"``."""
    coords = [da[d].values for d in dims]
    if len(dims) == 1:
        return [str(v) for v in coords[0]]
    return [lifted_channel_label(j, str(ch)) for j in coords[0] for ch in coords[1]]


def _style_slow_axes(axes, x_label: str, y_labels: list, *, log_y: bool, xlim) -> None:
    rows, cols = axes.shape
    for r in range(rows):
        for c in range(cols):
            a = axes[r, c]
            a.set_xscale("log")
            if log_y:
                a.set_yscale("log")
            if c == 0:
                a.set_ylabel(y_labels[r], fontsize="small")
            if r == rows - 1:
                a.set_xlabel(x_label)
            a.grid(True, which="both", alpha=0.3)
            if xlim is not None:
                a.set_xlim(*xlim)
            ticks_for_short_log_span(a)
