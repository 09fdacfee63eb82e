"""Helpers shared by the plot modules: axis labels and ticks, input checks, axes grids, bands.

Private to :mod:`lcmr_xr.plot`; the names of the data contract come from
:mod:`lcmr_xr.conventions`, never from here.
"""

from __future__ import annotations

import math
from numbers import Real

import numpy as np
import xarray as xr

# The band is drawn down to this fraction of the smallest magnitude of the estimate, 20 dB
# under its lowest point: a lower edge that reaches zero (or comes close) is clipped there,
# so the band fills to the bottom of the panel instead of spiking far below it (a log axis
# cannot show zero).
_BAND_FLOOR_RATIO = 0.1


# ----------------------------------------------------------------------------- labels


def long_name_and_units(attrs: dict, fallback_name: str) -> tuple[str, str | None]:
    """``(long_name, units)`` from ``attrs``; ``fallback_name`` replaces a missing long_name."""
    long_name = str(attrs.get("long_name") or fallback_name)
    units = attrs.get("units")
    return long_name, (None if units in (None, "") else str(units))


def quantity_label(attrs: dict, fallback_name: str, *, units: str | None = None) -> str:
    """``"long_name [units]"``; ``units`` overrides the attribute (e.g. ``rad/s``)."""
    long_name, attr_units = long_name_and_units(attrs, fallback_name)
    shown = units if units is not None else attr_units
    return f"{long_name} [{shown}]" if shown else long_name


def magnitude_label(attrs: dict, fallback_name: str, *, db: bool) -> str:
    """Label of a frequency-response magnitude: output units per input unit.

    A response's ``units`` are output units over input units (``"m/N"``); a plain unit
    (``"m"``) or a ``"/1"`` denominator means a dimensionless input, shown as ``m/unit``
    (metres per unit of input).  Decibels are relative to one of these; a dimensionless
    response (``"1"``) is plain dB.
    """
    long_name, units = long_name_and_units(attrs, fallback_name)
    ratio = None
    if units not in (None, "1"):
        numerator, slash, denominator = units.rpartition("/")
        if not slash:  # "m": per unit of a dimensionless input
            ratio = f"{units}/unit"
        elif denominator.strip() in ("1", ""):  # "m/1"
            ratio = f"{numerator}/unit"
        else:
            ratio = units
    if db:
        # 20 log10 |x| is only meaningful relative to a reference: one output unit per
        # input unit (implicit for a dimensionless response).
        return f"{long_name} [dB re 1 {ratio}]" if ratio else f"{long_name} [dB]"
    return f"{long_name} [{ratio or units}]" if (ratio or units) else long_name


def wrapped_label(label: str, width: int = 34) -> str:
    """``label`` broken into lines of about ``width`` characters (a long ``long_name``
    beside a panel), never inside a word or the ``[units]``."""
    import textwrap

    return textwrap.fill(label, width, break_long_words=False, break_on_hyphens=False)


def phase_label(attrs: dict, fallback_name: str) -> str:
    """Label of a phase axis, always in degrees."""
    long_name, _ = long_name_and_units(attrs, fallback_name)
    return f"{long_name} phase [deg]"


def lifted_channel_label(phase: int, channel: str) -> str:
    """``"phase 0 vcm"``: one row or column of a lifted matrix."""
    return f"phase {int(phase)} {channel}"


def entry_title(name: str, row: str, column: str) -> str:
    """``"S[phase 0 vcm <- phase 1 pzt]"``: the entry mapping ``column`` to ``row``."""
    return f"{name}[{row} <- {column}]"


# ----------------------------------------------------------------------------- inputs and axes


def require_dims(da: xr.DataArray, dims: tuple, name: str) -> xr.DataArray:
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


def require_complex(da: xr.DataArray, name: str) -> None:
    """Refuse a response that is not complex: its magnitude and phase are what is drawn."""
    kind = da.dtype.kind
    if kind == "c":
        return
    if kind in "iuf":
        raise ValueError(
            f"{name} is real ({da.dtype}), but a frequency response is complex: the plot draws "
            f"its magnitude and phase, and a real array has lost the phase (a magnitude, its dB, "
            f"or a standard deviation such as P_std?). Pass the complex FRF (P as "
            f"lcmr_xr.identify returns it); a response that is real by construction (a static "
            f"gain) plots as {name}.astype(complex)."
        )
    raise TypeError(f"{name} must hold complex numbers (a frequency response), got dtype {da.dtype}.")


def check_color(color):
    """``color`` if matplotlib takes it as a color (or None); else a message naming the forms."""
    if color is None:
        return None
    from matplotlib.colors import is_color_like

    if not isinstance(color, (bool, np.bool_)) and is_color_like(color):
        return color
    forms = ("a color name ('tab:red', 'C1'), a hex string ('#1f77b4'), a grey level as a "
             "string ('0.5') or an RGB(A) tuple of numbers in [0, 1] ((0.1, 0.2, 0.5))")
    if isinstance(color, (str, tuple, list, np.ndarray)):
        raise ValueError(f"color {color!r} is not a matplotlib color; pass {forms}, or None for "
                         "the next color of the axes' cycle.")
    raise TypeError(f"color must be a matplotlib color, got {color!r} ({type(color).__name__}); "
                    f"pass {forms}, or None.")


def confidence_radius(band) -> float | None:
    """Radius of the (band) confidence disk in units of P_std: sqrt(-ln(1 - band))."""
    if band is None or band is False:
        return None
    if isinstance(band, bool) or not isinstance(band, Real) or not 0.0 < float(band) < 1.0:
        raise ValueError(
            f"band must be a confidence level strictly between 0 and 1 (e.g. 0.95), or None "
            f"for no band; got {band!r}."
        )
    return math.sqrt(-math.log1p(-float(band)))


def frequency_selection(frequency: np.ndarray, xlim) -> np.ndarray:
    """Boolean mask of the bins to draw: above DC and, if given, inside ``xlim`` (Hz)."""
    keep = frequency > 0
    if xlim is not None:
        lo, hi = check_xlim(xlim)
        keep &= (frequency >= lo) & (frequency <= hi)
    if not keep.any():
        raise ValueError(
            f"No frequency bin above 0 Hz{'' if xlim is None else f' inside xlim={xlim}'} "
            f"(bins span {frequency.min():g}..{frequency.max():g} Hz); widen xlim or check "
            "the frequency coordinate."
        )
    return keep


def check_xlim(xlim) -> tuple[float, float]:
    try:
        lo, hi = (float(v) for v in xlim)
    except (TypeError, ValueError):
        raise ValueError(f"xlim must be a pair (f_lo, f_hi) in Hz, got {xlim!r}.") from None
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo < hi):
        raise ValueError(
            f"xlim must satisfy 0 < f_lo < f_hi (Hz, log axis), got {xlim!r}; e.g. xlim=(1, 500)."
        )
    return lo, hi


def prepare_axes(ax, shape: tuple[int, int], *, sharex: bool):
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
    # the type first: ax="a" is no grid of the wrong shape
    for a in axes.flat:
        if not isinstance(a, Axes):
            raise TypeError(
                f"ax must hold matplotlib Axes, found {type(a).__name__}; pass the array "
                "returned by plt.subplots or a previous plot's result.axes."
            )
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
    return axes[0, 0].figure, axes


# ----------------------------------------------------------------------------- magnitudes and bands


def magnitude(values: np.ndarray, db: bool) -> np.ndarray:
    """``20 log10 |x|`` (db) or ``|x|``; NaN where x is zero or not finite, without warnings."""
    mag = np.abs(values)
    ok = np.isfinite(mag) & (mag > 0)
    out = np.full(mag.shape, np.nan)
    out[ok] = 20.0 * np.log10(mag[ok]) if db else mag[ok]
    return out


def _band_edges(values: np.ndarray, sigma: np.ndarray, factor: float):
    """Magnitude edges ``|x| +- factor sigma`` (linear); a lower edge under the floor is clipped.

    The floor is ``_BAND_FLOOR_RATIO`` times the smallest positive magnitude of the
    curve, so the band visibly reaches "zero" without stretching the axis down to a
    lower edge that merely comes close to zero.  Returns ``(upper, lower, floor)``.
    """
    mag = np.abs(values)
    radius = factor * np.asarray(sigma, dtype=float)
    valid = np.isfinite(mag) & (mag > 0) & np.isfinite(radius)
    upper = np.where(valid, mag + np.where(valid, radius, 0.0), np.nan)
    lower = np.where(valid, mag - np.where(valid, radius, 0.0), np.nan)
    floor = _BAND_FLOOR_RATIO * np.min(mag[valid], initial=np.inf)
    lower = np.where(valid, np.maximum(lower, floor), np.nan)
    return upper, lower, floor


def draw_band(axis, x, values, sigma, factor, db, color, label):
    """Upper and lower edge lines plus the fill between them; returns the artists.

    The lower edge line stops where the edge is clipped at the floor; the fill goes on
    down to the floor there (the band contains magnitudes down to zero).
    """
    upper, lower, floor = _band_edges(values, sigma, factor)
    clipped = lower <= floor
    upper, lower = magnitude(upper, db), magnitude(lower, db)
    edges = axis.plot(x, upper, x, np.where(clipped, np.nan, lower), color=color,
                      linewidth=0.5, alpha=0.5)
    fill = axis.fill_between(x, lower, upper, color=color, alpha=0.2, linewidth=0, label=label)
    return edges + [fill]


def draw_unbounded(axis, x, sigma, color, label):
    """Hatched spans where ``P_std`` is inf: the data do not bound the error there.

    Each run of such bins is spanned from the bin before it to the bin after it, so a
    single bin is visible; returns the spans (the first carries ``label``).
    """
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


def ticks_for_short_log_span(axis) -> None:
    """Linear ticks with engineering labels (``40k``) on a log x axis spanning under a decade.

    On such a span a log axis has at most one labelled decade tick; the data there are
    close to linear in frequency, so evenly spaced round values read best.
    """
    from matplotlib.ticker import EngFormatter, MaxNLocator, NullFormatter

    lo, hi = axis.get_xlim()
    if lo > 0 and hi / lo < 10.0:
        # at most 5 intervals: the labels of a narrow panel (lifted grids) must not collide
        axis.xaxis.set_major_locator(MaxNLocator(nbins=5, steps=[1, 2, 2.5, 5, 10], min_n_ticks=3))
        axis.xaxis.set_major_formatter(EngFormatter(sep=""))
        axis.xaxis.set_minor_formatter(NullFormatter())
