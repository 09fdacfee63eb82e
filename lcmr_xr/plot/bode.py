"""Bode plot of an identified fast-rate FRF, with its confidence band and the slow Nyquist line.

The private helpers here (magnitudes without ``log(0)``, band edges, axes-grid checks)
are shared with :mod:`lcmr_xr.plot.lifted`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from numbers import Real

import numpy as np
import xarray as xr

from lcmr_xr.conventions import FACTOR, FREQUENCY, INPUT, OUTPUT
from lcmr_xr.plot._labels import (
    P_NAME,
    SAMPLING_PERIOD,
    SLOW_NYQUIST,
    STD_SUFFIX,
    magnitude_label,
    phase_label,
    quantity_label,
)

_P_DIMS = (FREQUENCY, OUTPUT, INPUT)
# Below this fraction of the smallest plotted magnitude a band edge that reaches zero is
# drawn (a log axis cannot show zero): 20 dB under the lowest point of the panel.
_BAND_FLOOR_RATIO = 0.1


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
    unwrap=True,
    label=None,
    color=None,
    xlim=None,
):
    """Bode plot of the fast-rate FRF ``P`` for every output/input pair.

    Magnitude (top) and phase (below it) of each pair are drawn against a logarithmic
    frequency axis, with the confidence band from ``P_std`` around the magnitude,
    an optional exact FRF as a dashed line and the slow Nyquist frequency as a
    vertical dashed line.  The DC bin is skipped (a log axis cannot show 0 Hz), and
    bins where the estimate is zero or not finite (for example not excited) are left
    as gaps instead of producing ``log(0)``.

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
        A Dataset is read through its variable ``P``.  Drawn dashed.  Default None.
    band : float or None, optional
        Confidence level (0 < band < 1) of the band on the magnitude, from the
        circular complex Gaussian error model: ``|P_hat - P| <= sqrt(-ln(1 - band)) * P_std``
        (1.731 ``P_std`` for the default 0.95).  Where the lower edge reaches zero it
        is drawn 20 dB below the smallest magnitude of the panel; where ``P_std`` is inf
        (``P_undetermined``) a hatched span marks the unbounded band.  None (or False)
        draws no band; no band is drawn either when ``frf`` has no ``P_std``.
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
        Unwrap the phase along frequency, across gaps (default True).
    label : str, optional
        Legend label of the estimate (default None: not in the legend).
    color : color, optional
        Matplotlib color of the estimate and its band (default None: next color of the
        axes' cycle).
    xlim : tuple of float, optional
        ``(f_lo, f_hi)`` in Hz (whatever ``hz``): only bins in this range are drawn and
        the axes are zoomed to it.  Default None: all bins above DC.

    Returns
    -------
    BodePlot
        The figure, the axes grid and the drawn artists per pair.

    Raises
    ------
    ValueError
        If ``P`` has the wrong dims (leading dims included), the ``ax`` grid has the
        wrong shape, ``band``, ``nyquist`` or ``xlim`` are out of range, or ``truth``
        lacks a channel of the estimate.
    TypeError
        If ``frf``, ``truth`` or ``ax`` have the wrong type.

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
    estimate, std, attrs = _frf_parts(frf)
    band_factor = _band_factor(band)  # validated even when there is no P_std to draw
    if std is None:
        band_factor = None
    nyquist_hz = _slow_nyquist(attrs, nyquist)
    frequency = np.asarray(estimate[FREQUENCY].values, dtype=float)
    keep = _frequency_selection(frequency, xlim)
    f_plot = frequency[keep]
    to_axis = 1.0 if hz else 2.0 * np.pi
    x = f_plot * to_axis

    outputs = [str(v) for v in estimate[OUTPUT].values]
    inputs = [str(v) for v in estimate[INPUT].values]
    rows_per_output = 2 if phase else 1
    shape = (rows_per_output * len(outputs), len(inputs))
    truth_values = None if truth is None else _truth_at(truth, estimate, f_plot)
    figure, axes = _prepare_axes(ax, shape, sharex=True)

    values = estimate.values[keep]
    sigma = None if band_factor is None else std.values[keep]
    lines = {}
    for o, out_label in enumerate(outputs):
        for i, in_label in enumerate(inputs):
            mag_ax = axes[rows_per_output * o, i]
            phase_ax = axes[rows_per_output * o + 1, i] if phase else None
            pair = {"estimate": [], "truth": [], "band": [], "nyquist": []}
            first = o == 0 and i == 0
            mag = _magnitude(values[:, o, i], db)
            pair["estimate"] += mag_ax.plot(x, mag, color=color, label=label)
            # One color for every artist of this estimate: the first line takes the next
            # color of the first axes' cycle, so an overlay on reused axes gets a new one.
            color = pair["estimate"][0].get_color()
            if sigma is not None:
                pair["band"] += _draw_band(
                    mag_ax, x, values[:, o, i], sigma[:, o, i], band_factor, db, color,
                    f"{band:.0%} confidence" if first else None,
                )
                pair["band"] += _draw_unbounded(mag_ax, x, sigma[:, o, i], color,
                                                "not determined (unbounded band)" if first else None)
            if truth_values is not None:
                pair["truth"] += mag_ax.plot(
                    x, _magnitude(truth_values[:, o, i], db), color="k", linestyle="--",
                    linewidth=1.0, label="truth" if first else None,
                )
            if phase:
                est_phase = _phase_deg(values[:, o, i], unwrap)
                pair["estimate"] += phase_ax.plot(x, est_phase, color=color)
                if truth_values is not None:
                    true_phase = _align_phase(_phase_deg(truth_values[:, o, i], unwrap), est_phase)
                    pair["truth"] += phase_ax.plot(
                        x, true_phase, color="k", linestyle="--", linewidth=1.0
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
    if label is not None or truth is not None or sigma is not None or nyquist_hz is not None:
        _deduplicated_legend(axes[0, 0])
    return BodePlot(figure=figure, axes=axes, lines=lines)


# ----------------------------------------------------------------------------- inputs


def _frf_parts(frf):
    """``(P, P_std or None, attrs)`` with P transposed to (frequency, output, input)."""
    if isinstance(frf, xr.Dataset):
        if P_NAME not in frf.data_vars:
            raise ValueError(
                f"The dataset has no variable {P_NAME!r} (it has {sorted(frf.data_vars)}); "
                "pass the FRF dataset returned by lcmr_xr.identify, or the complex DataArray P."
            )
        estimate = frf[P_NAME]
        std = frf.get(P_NAME + STD_SUFFIX)
        attrs = {**estimate.attrs, **frf.attrs}
    elif isinstance(frf, xr.DataArray):
        estimate, std, attrs = frf, None, dict(frf.attrs)
    else:
        raise TypeError(
            f"bode needs an xarray Dataset (FRF dataset) or DataArray (P), got "
            f"{type(frf).__name__}; build one with lcmr_xr.identify or xarray.DataArray."
        )
    estimate = _require_dims(estimate, _P_DIMS, estimate.name or P_NAME)
    if std is not None:
        std = _require_dims(std, _P_DIMS, P_NAME + STD_SUFFIX)
    return estimate, std, attrs


def _require_dims(da: xr.DataArray, dims: tuple, name: str) -> xr.DataArray:
    """Transpose ``da`` to ``dims`` (frequency first); refuse extra, missing or non-Hz dims."""
    extra = [d for d in da.dims if d not in dims]
    if extra:
        sizes = ", ".join(f"{d}={da.sizes[d]}" for d in extra)
        first = extra[0]
        raise ValueError(
            f"{name} has dims {da.dims}, with extra dim(s) ({sizes}) besides {dims}: plots "
            f"show one case at a time. Select one first, e.g. frf.isel({first}=0) or "
            f"frf.sel({first}=...)."
        )
    missing = [d for d in dims if d not in da.dims]
    if missing:
        raise ValueError(
            f"{name} has dims {da.dims} but needs {dims}; missing {tuple(missing)}. For a "
            f"single channel add them, e.g. da.expand_dims({missing[0]}=['{missing[0]}'])."
        )
    for d in dims:
        if d not in da.coords:
            raise ValueError(
                f"{name} has no coordinate for dim {d!r}; assign one, e.g. "
                f"da.assign_coords({d}=...) (frequencies in Hz, channel labels as strings)."
            )
    # Frequency axes are drawn and labelled in Hz (or converted from Hz to rad/s): a
    # coordinate in other units would be silently mislabelled.
    frequency_dim = dims[0]
    units = da[frequency_dim].attrs.get("units", "Hz")
    if units != "Hz":
        raise ValueError(
            f"{name}: coordinate {frequency_dim!r} has units {units!r}, but plots need Hz; "
            f"convert it, e.g. da.assign_coords({frequency_dim}=da.{frequency_dim} / (2 * np.pi)) "
            "for rad/s, and set its attrs units='Hz'."
        )
    return da.transpose(*dims)


def _band_factor(band) -> float | None:
    """Radius of the (band) confidence disk in units of P_std: sqrt(-ln(1 - band))."""
    if band is None or band is False:
        return None
    if isinstance(band, bool) or not isinstance(band, Real) or not 0.0 < float(band) < 1.0:
        raise ValueError(
            f"band must be a confidence level strictly between 0 and 1 (e.g. 0.95), or None "
            f"for no band; got {band!r}."
        )
    return math.sqrt(-math.log1p(-float(band)))


def _slow_nyquist(attrs: dict, nyquist) -> float | None:
    """Slow Nyquist frequency in Hz from the argument or the dataset attrs, or None."""
    if nyquist is False or nyquist is None:
        return None
    if nyquist is True:
        if SLOW_NYQUIST in attrs:
            return float(attrs[SLOW_NYQUIST])
        if FACTOR in attrs and SAMPLING_PERIOD in attrs:
            return 1.0 / (2.0 * float(attrs[FACTOR]) * float(attrs[SAMPLING_PERIOD]))
        return None
    if isinstance(nyquist, Real) and math.isfinite(nyquist) and nyquist > 0:
        return float(nyquist)
    raise ValueError(
        f"nyquist must be True (from the attrs), False (no line) or a positive frequency in "
        f"Hz; got {nyquist!r}."
    )


def _frequency_selection(frequency: np.ndarray, xlim) -> np.ndarray:
    """Boolean mask of the bins to draw: above DC and, if given, inside ``xlim`` (Hz)."""
    keep = frequency > 0
    if xlim is not None:
        lo, hi = _check_xlim(xlim)
        keep &= (frequency >= lo) & (frequency <= hi)
    if not keep.any():
        raise ValueError(
            f"No frequency bin above 0 Hz{'' if xlim is None else f' inside xlim={xlim}'} "
            f"(bins span {frequency.min():g}..{frequency.max():g} Hz); widen xlim or check "
            "the frequency coordinate."
        )
    return keep


def _check_xlim(xlim) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in xlim)
    except (TypeError, ValueError):
        raise ValueError(f"xlim must be a pair (f_lo, f_hi) in Hz, got {xlim!r}.") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ValueError(
            f"xlim must satisfy 0 < f_lo < f_hi (Hz, log axis), got {xlim!r}; e.g. xlim=(1, 500)."
        )
    return lo, hi


def _truth_at(truth, estimate: xr.DataArray, f_plot: np.ndarray) -> np.ndarray:
    """Exact FRF at ``f_plot`` as an array (n_f, n_outputs, n_inputs)."""
    if isinstance(truth, xr.Dataset):
        if P_NAME not in truth.data_vars:
            raise ValueError(
                f"truth is a Dataset without variable {P_NAME!r}; pass the exact FRF DataArray."
            )
        truth = truth[P_NAME]
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


def _prepare_axes(ax, shape: tuple[int, int], *, sharex: bool):
    """``(figure, axes)`` with axes an object ndarray of ``shape``; new figure when ax is None."""
    if ax is None:
        import matplotlib.pyplot as plt  # lazy: importing lcmr_xr.plot must not pick a backend

        rows, cols = shape
        figure, axes = plt.subplots(
            rows, cols, squeeze=False, sharex=sharex,
            figsize=(3.2 + 2.8 * cols, 1.2 + 2.0 * rows), layout="constrained",
        )
        return figure, axes
    from matplotlib.axes import Axes

    axes = np.asarray(ax, dtype=object)
    if axes.ndim == 0:
        axes = axes.reshape(1)
    # plt.subplots squeezes single rows/columns: accept any array whose non-unit
    # dimensions match the grid.
    squeezed = tuple(n for n in axes.shape if n != 1)
    if squeezed != tuple(n for n in shape if n != 1):
        raise ValueError(
            f"ax has shape {axes.shape} but this plot needs a grid of shape {shape} "
            f"(rows, columns); create one with plt.subplots({shape[0]}, {shape[1]}, "
            "squeeze=False) or pass ax=None."
        )
    axes = axes.reshape(shape)
    for a in axes.flat:
        if not isinstance(a, Axes):
            raise TypeError(
                f"ax must hold matplotlib Axes, found {type(a).__name__}; pass the array "
                "returned by plt.subplots or a previous plot's result.axes."
            )
    return axes[0, 0].figure, axes


# ----------------------------------------------------------------------------- numerics


def _magnitude(values: np.ndarray, db: bool) -> np.ndarray:
    """``20 log10 |x|`` (db) or ``|x|``; NaN where x is zero or not finite, without warnings."""
    mag = np.abs(values)
    ok = np.isfinite(mag) & (mag > 0)
    out = np.full(mag.shape, np.nan)
    out[ok] = 20.0 * np.log10(mag[ok]) if db else mag[ok]
    return out


def _phase_deg(values: np.ndarray, unwrap: bool) -> np.ndarray:
    """Phase in degrees along axis 0; NaN where x is zero or not finite.

    Unwrapping runs over the finite points only, so a gap (a non-excited bin) does
    not turn every later point into NaN.
    """
    ok = np.isfinite(values) & (values != 0)
    out = np.full(values.shape, np.nan)
    angle = np.angle(values[ok])
    out[ok] = np.degrees(np.unwrap(angle) if unwrap else angle)
    return out


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


def _band_edges(values: np.ndarray, sigma: np.ndarray, factor: float):
    """Magnitude edges ``|x| +- factor sigma`` (linear); a lower edge <= 0 goes to a floor.

    The floor is ``_BAND_FLOOR_RATIO`` times the smallest positive magnitude or lower
    edge of the curve, so the band visibly reaches "zero" without stretching the axis.
    """
    mag = np.abs(values)
    radius = factor * np.asarray(sigma, dtype=float)
    valid = np.isfinite(mag) & (mag > 0) & np.isfinite(radius)
    upper = np.where(valid, mag + np.where(valid, radius, 0.0), np.nan)
    lower = np.where(valid, mag - np.where(valid, radius, 0.0), np.nan)
    positive = valid & (lower > 0)
    floor = _BAND_FLOOR_RATIO * np.min(
        np.concatenate([mag[valid], lower[positive]]), initial=np.inf
    )
    lower = np.where(valid & ~positive, floor, lower)
    return upper, lower


def _draw_band(axis, x, values, sigma, factor, db, color, label):
    """Upper and lower edge lines plus the fill between them; returns the artists."""
    upper, lower = _band_edges(values, sigma, factor)
    upper, lower = _magnitude(upper, db), _magnitude(lower, db)
    edges = axis.plot(x, upper, x, lower, color=color, linewidth=0.5, alpha=0.5)
    fill = axis.fill_between(x, lower, upper, color=color, alpha=0.2, linewidth=0, label=label)
    return edges + [fill]


def _draw_unbounded(axis, x, sigma, color, label):
    """Hatched spans where ``P_std`` is inf: the data do not bound the error there."""
    inf = np.isposinf(np.asarray(sigma, dtype=float))
    if not inf.any():
        return []
    edges = np.flatnonzero(np.diff(np.concatenate([[0], inf.astype(int), [0]])))
    spans = []
    for start, stop in zip(edges[::2], edges[1::2]):  # runs [start, stop)
        lo, hi = x[max(start - 1, 0)], x[min(stop, x.size - 1)]
        spans.append(axis.axvspan(lo, hi, facecolor=color, alpha=0.12, hatch="//",
                                  edgecolor=color, linewidth=0, label=label))
        label = None
    return spans


# ----------------------------------------------------------------------------- styling


def _style_bode_axes(axes, estimate, db, hz, phase, rows_per_output, xlim, to_axis):
    freq_label = quantity_label(
        estimate[FREQUENCY].attrs, FREQUENCY, units=None if hz else "rad/s"
    )
    name = str(estimate.name or P_NAME)
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


def _deduplicated_legend(axis) -> None:
    """Legend of ``axis`` with one entry per label (overlays repeat band/Nyquist labels)."""
    handles, labels = axis.get_legend_handles_labels()
    unique = dict(zip(labels, handles))
    if unique:
        axis.legend(unique.values(), unique.keys(), fontsize="small")
