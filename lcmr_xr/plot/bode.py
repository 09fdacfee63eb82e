"""Bode plot of an identified fast-rate FRF, with its confidence band and the slow Nyquist line."""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.conventions import FACTOR, FREQUENCY, INPUT, OUTPUT
from lcmr_xr.settings import as_bool
from lcmr_xr.plot._shared import (
    check_color,
    confidence_radius,
    draw_band,
    draw_unbounded,
    frequency_selection,
    magnitude,
    magnitude_label,
    phase_label,
    prepare_axes,
    quantity_label,
    require_complex,
    require_dims,
    ticks_for_short_log_span,
)

_P_DIMS = (FREQUENCY, OUTPUT, INPUT)
# Wrapped phase axis: ticks every 90 degrees over (-180, 180]; the axis runs to +-225 deg
# so an estimate drawn next to a truth at +-180 deg stays in view.
_PHASE_TICKS = (-180, -90, 0, 90, 180)
_PHASE_LIMIT = 225.0


@dataclass
class BodePlot:
    """Figure, axes and artists of a :func:`bode` plot.

    Attributes
    ----------
    figure : matplotlib.figure.Figure
        The figure holding the axes.
    axes : numpy.ndarray of matplotlib.axes.Axes
        Shape ``(2 * n_outputs, n_inputs)`` when the phase is drawn (rows alternate
        magnitude, phase for each output), ``(n_outputs, n_inputs)`` otherwise.
    lines : dict
        ``lines[(output, input)]`` is a dict with keys ``"estimate"`` (magnitude and
        phase :class:`~matplotlib.lines.Line2D`), ``"truth"`` (same, dashed),
        ``"band"`` (upper and lower edge ``Line2D``, the filled
        :class:`~matplotlib.collections.PolyCollection`, then one hatched span per run of
        bins where ``P_std`` is inf: not determined by the data, unbounded band) and ``"nyquist"`` (one
        vertical ``Line2D`` per axes of the pair); absent artists give empty lists.
    """

    figure: object
    axes: np.ndarray
    lines: dict


def bode(
    frf,
    *,
    ax=None,
    truth=None,
    band=0.95,
    nyquist=True,
    db=True,
    hz=True,
    phase=True,
    unwrap=False,
    label=None,
    color=None,
    xlim=None,
    title=None,
):
    """Bode plot of the fast-rate FRF ``P`` for every output/input pair.

    Magnitude (top) and phase (below it) of each pair are drawn against a logarithmic
    frequency axis, with the confidence band from ``P_std`` around the magnitude,
    an optional exact FRF as a dashed line and the slow Nyquist frequency as a
    vertical dashed line.  The DC bin is skipped (a log axis cannot show 0 Hz), and
    bins where the estimate is zero or not finite (for example not excited) are left
    as gaps instead of producing ``log(0)``.  The magnitude is labelled in output units
    per input unit (``m/unit`` for a ``P`` in metres per unit command), the phase is
    wrapped to (-180, 180] by default, and the legend lists only what is in view.

    Parameters
    ----------
    frf : xarray.Dataset or xarray.DataArray
        FRF dataset (variables ``P`` and optionally ``P_std``, attrs ``slow_nyquist``
        or ``factor`` and ``sampling_period``), or the complex DataArray ``P`` alone.
        ``P`` must have exactly the dims ``(frequency, output, input)`` with
        ``frequency`` in Hz; select one case of any leading dim (for example
        ``frf.isel(experiment=0)``) before plotting.
    ax : numpy.ndarray of matplotlib.axes.Axes, optional
        Existing axes to draw into (to overlay several estimates), shaped like the grid
        described in :class:`BodePlot`; default None creates a new figure.
    truth : xarray.DataArray or xarray.Dataset, optional
        Exact FRF with dims ``frequency`` (Hz) and, optionally, ``output``/``input``
        containing the estimate's labels; linearly interpolated (real and imaginary
        parts) at the estimate's frequencies, NaN outside its frequency range.
        A Dataset is read through its variable ``P``.  Its ``frequency`` must be in Hz
        (a ``units`` attribute other than ``Hz`` is refused).  Drawn dashed.  Default None.
    band : float or None, optional
        Confidence level (0 < band < 1) of the band on the magnitude, from the
        circular complex Gaussian error model: ``|P_hat - P| <= sqrt(-ln(1 - band)) * P_std``
        (1.731 ``P_std`` for the default 0.95).  The band is clipped 20 dB below the
        smallest magnitude of the estimate in the panel: where the lower edge reaches
        zero (or falls below that floor) the band fills down to it and the edge line
        stops.  Where ``P_std`` is inf (``P_undetermined``: the data do not bound the
        error) a hatched span marks the unbounded band.  None (or False) draws no band; no band is drawn either when ``frf`` has
        no ``P_std``.
    nyquist : bool or float, optional
        True (default) draws the slow Nyquist frequency from the attrs (``slow_nyquist``,
        else ``1 / (2 factor sampling_period)``) and draws nothing when neither is
        known (a bare DataArray without attrs); a positive number gives it in Hz;
        False draws none.
    db : bool, optional
        Magnitude in decibels, ``20 log10 |P|`` (default True); False plots ``|P|`` on a
        log axis.
    hz : bool, optional
        Frequency axis in Hz (default True) or in rad/s (False).
    phase : bool, optional
        Draw the phase rows, in degrees (default True).
    unwrap : bool, optional
        Default False: the phase is wrapped to (-180, 180] deg, with ticks every 90 deg
        and the line broken where it wraps; with a truth, an estimate bin is moved by a
        turn where that puts it next to the truth within +-225 deg (so an estimate at
        -179 deg is drawn at 181 deg beside a truth at 179 deg).  True unwraps it along frequency, across
        gaps, and moves the truth by whole turns onto the estimate's branch.
    label : str, optional
        Legend label of the estimate (default None: not in the legend).
    color : color, optional
        Matplotlib color of the estimate and its band (default None: next color of the
        axes' cycle); checked before anything is drawn.
    xlim : tuple of float, optional
        ``(f_lo, f_hi)`` in Hz (whatever ``hz``): only bins in this range are drawn and
        the axes are zoomed to it (a span under a decade gets linear ticks with
        engineering labels, e.g. ``40k``).  Default None: all bins above DC.
    title : str, optional
        Figure title (``Figure.suptitle``); default None leaves the title alone.

    Returns
    -------
    BodePlot
        The figure, the axes grid and the drawn artists per pair.

    Raises
    ------
    ValueError
        If ``P`` has the wrong dims (leading dims included) or is real (an FRF is
        complex: ``abs(P)`` has lost the phase), the ``ax`` grid has the wrong shape,
        ``band``, ``nyquist`` or ``xlim`` are out of range, ``truth`` is real or lacks a
        channel of the estimate, or ``color`` is not a matplotlib color.
    TypeError
        If ``frf``, ``truth``, ``ax`` or ``color`` have the wrong type, or ``db``, ``hz``,
        ``phase`` or ``unwrap`` is not True or False.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> import lcmr_xr.plot
    >>> f = np.linspace(0.0, 500.0, 101)
    >>> s = 2j * np.pi * f
    >>> P = xr.DataArray(
    ...     (1e4 / (s**2 + 20 * s + 4e4))[:, None, None],
    ...     dims=("frequency", "output", "input"),
    ...     coords={"frequency": ("frequency", f, {"units": "Hz", "long_name": "frequency"}),
    ...             "output": ["y"], "input": ["u"]},
    ...     name="P", attrs={"long_name": "plant FRF", "units": "m/N"})
    >>> result = lcmr_xr.plot.bode(P, nyquist=100.0)
    >>> result.axes.shape
    (2, 1)
    >>> result.axes[0, 0].get_title()
    'y <- u'
    >>> import matplotlib.pyplot as plt
    >>> plt.close(result.figure)
    """
    # flags only as True/False: bool("no") is True, so a string would draw the opposite
    db, hz, phase, unwrap = (as_bool(v, n) for v, n in ((db, "db"), (hz, "hz"), (phase, "phase"),
                                                        (unwrap, "unwrap")))
    estimate, std, attrs = _frf_parts(frf)
    color = check_color(color)  # before a figure is made: matplotlib's error would come mid-draw
    band_factor = confidence_radius(band)  # validated even when there is no P_std to draw
    if std is None:
        band_factor = None
    nyquist_hz = _slow_nyquist(attrs, nyquist)
    frequency = np.asarray(estimate[FREQUENCY].values, dtype=float)
    keep = frequency_selection(frequency, xlim)
    f_plot = frequency[keep]
    to_axis = 1.0 if hz else 2.0 * np.pi
    x = f_plot * to_axis

    outputs = [str(v) for v in estimate[OUTPUT].values]
    inputs = [str(v) for v in estimate[INPUT].values]
    rows_per_output = 2 if phase else 1
    shape = (rows_per_output * len(outputs), len(inputs))
    truth_values = None if truth is None else _truth_at(truth, estimate, f_plot)
    figure, axes = prepare_axes(ax, shape, sharex=True)

    values = estimate.values[keep]
    sigma = None if band_factor is None else std.values[keep]
    lines = {}
    for o, out_label in enumerate(outputs):
        for i, in_label in enumerate(inputs):
            mag_ax = axes[rows_per_output * o, i]
            phase_ax = axes[rows_per_output * o + 1, i] if phase else None
            pair = {"estimate": [], "truth": [], "band": [], "nyquist": []}
            first = o == 0 and i == 0
            mag = magnitude(values[:, o, i], db)
            pair["estimate"] += mag_ax.plot(x, mag, color=color, label=label)
            # One color for every artist of this estimate: the first line takes the next
            # color of the first axes' cycle, so an overlay on reused axes gets a new one.
            color = pair["estimate"][0].get_color()
            if sigma is not None:
                pair["band"] += draw_band(
                    mag_ax, x, values[:, o, i], sigma[:, o, i], band_factor, db, color,
                    f"{band:.0%} confidence" if first else None,
                )
                pair["band"] += draw_unbounded(mag_ax, x, sigma[:, o, i], color,
                                               "not determined (unbounded band)" if first else None)
            if truth_values is not None:
                pair["truth"] += mag_ax.plot(
                    x, magnitude(truth_values[:, o, i], db), color="k", linestyle="--",
                    linewidth=1.0, label="truth" if first else None,
                )
            if phase:
                est_phase = _phase_deg(values[:, o, i], unwrap)
                true_phase = None
                if truth_values is not None:
                    true_phase = _phase_deg(truth_values[:, o, i], unwrap)
                    if unwrap:
                        true_phase = _align_phase(true_phase, est_phase)
                    else:
                        # +179 and -179 deg agree: where a turn puts the estimate next to the
                        # truth and still inside the axis (|phase| <= 225), draw it there
                        shifted = est_phase - 360.0 * np.round((est_phase - true_phase) / 360.0)
                        closer = np.isfinite(shifted) & (np.abs(shifted) <= _PHASE_LIMIT)
                        est_phase = np.where(closer, shifted, est_phase)
                pair["estimate"] += phase_ax.plot(*_phase_line(x, est_phase, unwrap), color=color)
                if true_phase is not None:
                    pair["truth"] += phase_ax.plot(
                        *_phase_line(x, true_phase, unwrap), color="k", linestyle="--",
                        linewidth=1.0,
                    )
            if nyquist_hz is not None:
                for k, target in enumerate(a for a in (mag_ax, phase_ax) if a is not None):
                    pair["nyquist"].append(
                        target.axvline(
                            nyquist_hz * to_axis, color="0.4", linestyle="--", linewidth=1.0,
                            label="slow Nyquist" if first and k == 0 else None,
                        )
                    )
            mag_ax.set_title(f"{out_label} <- {in_label}")
            lines[(out_label, in_label)] = pair

    _style_bode_axes(axes, estimate, db, hz, phase, rows_per_output, xlim, to_axis)
    if phase and not unwrap:
        for a in axes[1::rows_per_output].flat:
            a.set_yticks(_PHASE_TICKS)
            a.set_ylim(-_PHASE_LIMIT, _PHASE_LIMIT)
    if label is not None or truth is not None or sigma is not None or nyquist_hz is not None:
        _deduplicated_legend(axes[0, 0])
    if title is not None:
        figure.suptitle(str(title))
    return BodePlot(figure=figure, axes=axes, lines=lines)


# ----------------------------------------------------------------------------- inputs


def _frf_parts(frf):
    """``(P, P_std or None, attrs)`` with P transposed to (frequency, output, input)."""
    if isinstance(frf, xr.Dataset):
        if cv.P not in frf.data_vars:
            raise ValueError(
                f"The dataset has no variable {cv.P!r} (it has {sorted(frf.data_vars)}); "
                "pass the FRF dataset returned by lcmr_xr.identify, or the complex DataArray P."
            )
        estimate = frf[cv.P]
        std = frf.get(cv.P + cv.STD_SUFFIX)
        attrs = {**estimate.attrs, **frf.attrs}
    elif isinstance(frf, xr.DataArray):
        estimate, std, attrs = frf, None, dict(frf.attrs)
    else:
        raise TypeError(
            f"bode needs an xarray Dataset (FRF dataset) or DataArray (P), got "
            f"{type(frf).__name__}; build one with lcmr_xr.identify or xarray.DataArray."
        )
    estimate = require_dims(estimate, _P_DIMS, estimate.name or cv.P)
    require_complex(estimate, str(estimate.name or cv.P))
    if std is not None:
        std = require_dims(std, _P_DIMS, cv.P + cv.STD_SUFFIX)
    return estimate, std, attrs


def _slow_nyquist(attrs: dict, nyquist) -> float | None:
    """Slow Nyquist frequency in Hz from the argument or the dataset attrs, or None."""
    if nyquist is False or nyquist is None:
        return None
    if nyquist is True:
        if cv.SLOW_NYQUIST in attrs:
            return float(attrs[cv.SLOW_NYQUIST])
        if FACTOR in attrs and cv.SAMPLING_PERIOD in attrs:
            return 1.0 / (2.0 * float(attrs[FACTOR]) * float(attrs[cv.SAMPLING_PERIOD]))
        return None
    if isinstance(nyquist, Real) and math.isfinite(nyquist) and nyquist > 0:
        return float(nyquist)
    raise ValueError(
        f"nyquist must be True (from the attrs), False (no line) or a positive frequency in "
        f"Hz; got {nyquist!r}."
    )


def _truth_at(truth, estimate: xr.DataArray, f_plot: np.ndarray) -> np.ndarray:
    """Exact FRF at ``f_plot`` as an array (n_f, n_outputs, n_inputs)."""
    if isinstance(truth, xr.Dataset):
        if cv.P not in truth.data_vars:
            raise ValueError(
                f"truth is a Dataset without variable {cv.P!r}; pass the exact FRF DataArray."
            )
        truth = truth[cv.P]
    if not isinstance(truth, xr.DataArray):
        raise TypeError(
            f"truth must be an xarray DataArray like P (dims frequency, output, input), got "
            f"{type(truth).__name__}."
        )
    extra = [d for d in truth.dims if d not in _P_DIMS]
    if FREQUENCY not in truth.dims or FREQUENCY not in truth.coords or extra:
        raise ValueError(
            f"truth has dims {truth.dims}; it needs a {FREQUENCY!r} dim with a coordinate in Hz "
            f"and may only have the dims {_P_DIMS} (select leading dims first)."
        )
    units = truth[FREQUENCY].attrs.get("units", "Hz")
    if units != "Hz":  # read as Hz, a truth in rad/s was drawn at 2 pi times its frequencies
        raise ValueError(
            f"truth: coordinate {FREQUENCY!r} has units {units!r}, but plots need Hz (as P's); "
            f"convert it, e.g. truth.assign_coords({FREQUENCY}=truth.{FREQUENCY} / (2 * np.pi)) "
            "for rad/s, and set its attrs units='Hz'."
        )
    for dim in (OUTPUT, INPUT):
        if dim in truth.dims:
            wanted = estimate[dim].values.tolist()  # plain str, for a readable message
            have = set(truth[dim].values.tolist())
            lacking = [v for v in wanted if v not in have]
            if lacking:
                raise ValueError(
                    f"truth lacks {dim} label(s) {lacking} of the estimate; give an exact FRF "
                    f"for every {dim} in {wanted}."
                )
            truth = truth.sel({dim: wanted})
    truth = truth.broadcast_like(estimate.isel({FREQUENCY: 0}, drop=True))
    truth = truth.transpose(FREQUENCY, OUTPUT, INPUT)
    require_complex(truth, "truth")
    f_truth = np.asarray(truth[FREQUENCY].values, dtype=float)
    order = np.argsort(f_truth)
    f_truth = f_truth[order]
    data = np.asarray(truth.values)[order]
    out = np.empty((f_plot.size,) + data.shape[1:], dtype=complex)
    for idx in np.ndindex(*data.shape[1:]):
        column = data[(slice(None),) + idx]
        # Linear in real and imaginary parts; an exact-grid truth is reproduced exactly.
        out[(slice(None),) + idx] = np.interp(
            f_plot, f_truth, column.real, left=np.nan, right=np.nan
        ) + 1j * np.interp(f_plot, f_truth, np.imag(column), left=np.nan, right=np.nan)
    return out


# ----------------------------------------------------------------------------- numerics


def _phase_deg(values: np.ndarray, unwrap: bool) -> np.ndarray:
    """Phase in degrees along axis 0; NaN where x is zero or not finite.

    Unwrapping runs over the finite points only, so a gap (a non-excited bin) does
    not turn every later point into NaN.
    """
    ok = np.isfinite(values) & (values != 0)
    out = np.full(values.shape, np.nan)
    angle = np.angle(values[ok])
    if unwrap:
        out[ok] = np.degrees(np.unwrap(angle))
    else:
        degrees = np.degrees(angle)
        out[ok] = np.where(degrees <= -180.0, degrees + 360.0, degrees)  # (-180, 180]
    return out


def _phase_line(x: np.ndarray, phase: np.ndarray, unwrap: bool):
    """``(x, phase)`` to draw; a wrapped phase gets a NaN point between bins where it wraps.

    Without the break, a jump from +179 to -179 deg would be drawn as a vertical line
    across the whole axis.  Only the breaks are added: the bins keep their values.
    """
    if unwrap:
        return x, phase
    finite = np.flatnonzero(np.isfinite(phase))
    jumps = finite[1:][np.abs(np.diff(phase[finite])) > 180.0]
    if jumps.size == 0:
        return x, phase
    # a break just before each bin that follows a wrap (between it and its finite predecessor)
    return np.insert(x, jumps, np.nan), np.insert(phase, jumps, np.nan)


def _align_phase(phase: np.ndarray, reference: np.ndarray) -> np.ndarray:
    """Shift ``phase`` by the whole number of turns that best puts it on ``reference``.

    Two independently unwrapped curves of the same FRF can differ by whole turns.  The
    median offset (not the first bin's) is used because a noisy estimate is often
    poorest at the lowest frequencies.
    """
    both = np.isfinite(phase) & np.isfinite(reference)
    if not both.any():
        return phase
    offset = np.median(reference[both] - phase[both])
    return phase + 360.0 * np.round(offset / 360.0)


# ----------------------------------------------------------------------------- styling


def _style_bode_axes(axes, estimate, db, hz, phase, rows_per_output, xlim, to_axis):
    freq_label = quantity_label(
        estimate[FREQUENCY].attrs, FREQUENCY, units=None if hz else "rad/s"
    )
    name = str(estimate.name or cv.P)
    rows, cols = axes.shape
    for r in range(rows):
        for c in range(cols):
            a = axes[r, c]
            a.set_xscale("log")
            is_phase = phase and r % rows_per_output == 1
            if not db and not is_phase:
                a.set_yscale("log")
            if c == 0 and not a.get_ylabel():  # an overlay keeps the first estimate's label
                a.set_ylabel(
                    phase_label(estimate.attrs, name)
                    if is_phase
                    else magnitude_label(estimate.attrs, name, db=db)
                )
            if r == rows - 1:
                a.set_xlabel(freq_label)
            a.grid(True, which="both", alpha=0.3)
            if xlim is not None:
                a.set_xlim(xlim[0] * to_axis, xlim[1] * to_axis)
            ticks_for_short_log_span(a)


def _deduplicated_legend(axis) -> None:
    """Legend of ``axis``: one entry per label, only for artists with data in view.

    Overlays repeat the band and Nyquist labels; a zoom can leave the Nyquist line or the
    truth outside the axes, and a legend entry for what is not drawn misleads.
    """
    handles, labels = axis.get_legend_handles_labels()
    lo, hi = sorted(axis.get_xlim())
    unique = {}
    for handle, text in zip(handles, labels):
        if text not in unique and _in_view(handle, lo, hi):
            unique[text] = handle
    legend = axis.get_legend()
    if unique:
        axis.legend(unique.values(), unique.keys(), fontsize="small")
    elif legend is not None:
        legend.remove()


def _in_view(artist, lo: float, hi: float) -> bool:
    """True when ``artist`` has a finite point with x in ``[lo, hi]`` (data coordinates)."""
    if hasattr(artist, "get_xydata"):  # Line2D; axvline's y is in axes coordinates
        xy = np.asarray(artist.get_xydata(), dtype=float)
    elif hasattr(artist, "get_width"):  # the hatched span of an unbounded band (Rectangle)
        x0, x1 = sorted((artist.get_x(), artist.get_x() + artist.get_width()))
        return bool(x0 <= hi and x1 >= lo)
    else:  # the band's PolyCollection
        paths = artist.get_paths()
        xy = np.concatenate([p.vertices for p in paths]) if paths else np.empty((0, 2))
    ok = np.isfinite(xy).all(axis=1) & (xy[:, 0] >= lo) & (xy[:, 0] <= hi)
    return bool(ok.any())
