"""Coordinate helpers shared by the transforms: spacing checks and exact time rebuilds.

A DFT throws away the time coordinate; the inverse has to rebuild it *bit for bit* so
that ``idft(dft(x))`` has the very same coordinate.  Time axes are almost always built
by one of a few recipes (``t0 + n*T``, ``t0 + n/fs``, ``linspace``); we find the recipe
that reproduces the values exactly and record it in flat (NetCDF-friendly) attributes,
falling back to storing the values themselves.
"""

from __future__ import annotations

import numpy as np

# Relative tolerance on the spacing of an "evenly spaced" coordinate.  Times built as
# n * T carry rounding of a few ulps of t, i.e. up to ~N eps relative to T.
SPACING_RTOL = 1e-6

# Prefix of the attributes (on a frequency coordinate) that hold the time coordinate's
# own attributes, so they stay flat for NetCDF.
TIME_ATTR_PREFIX = "time_attr_"


def slow_dim_for(dim: str) -> str:
    """Name of the slow dimension that lifting ``dim`` creates (``time`` -> ``slow_time``)."""
    return f"slow_{dim}"


#: Time units other than the second, in seconds: a coordinate that declares one would be
#: read as seconds (every frequency off by the factor), so it is refused.
OTHER_TIME_UNITS = {
    **dict.fromkeys(("ms", "msec", "millisecond", "milliseconds"), 1e-3),
    **dict.fromkeys(("us", "\u00b5s", "\u03bcs", "usec", "microsecond", "microseconds"), 1e-6),
    **dict.fromkeys(("ns", "nsec", "nanosecond", "nanoseconds"), 1e-9),
    **dict.fromkeys(("min", "minute", "minutes"), 60.0),
    **dict.fromkeys(("h", "hr", "hour", "hours"), 3600.0),
}


def check_seconds(units, dim: str) -> None:
    """Refuse a coordinate whose ``units`` attribute names a time unit other than ``s``."""
    if not isinstance(units, str) or units.strip().lower() not in OTHER_TIME_UNITS:
        return
    scale = OTHER_TIME_UNITS[units.strip().lower()]
    raise ValueError(
        f"coordinate {dim!r} is in {units!r}, but the time coordinates of this library are in "
        f"seconds (docs/conventions.md): its values would be read as seconds, every frequency "
        f"off by a factor {1 / scale:g}. Convert it, e.g. x = x.assign_coords("
        f"{dim}=(x[{dim!r}] * {scale:g}).assign_attrs(units='s'))."
    )


def even_spacing(values, dim: str, units=None) -> tuple[float, float]:
    """``(start, spacing)`` of an evenly spaced, increasing coordinate; refuse anything else.

    Parameters
    ----------
    values : array_like of float
        Coordinate values (s).
    dim : str
        Its name, for messages.
    units : str, optional
        The coordinate's ``units`` attribute: a time unit other than seconds (``ms``,
        ``us``, ``min``, ...) is refused (:func:`check_seconds`).

    Returns
    -------
    tuple of float
        First value and the mean spacing ``(t[-1] - t[0]) / (N - 1)``.
    """
    check_seconds(units, dim)
    t = np.asarray(values)
    if t.dtype.kind in "mM":  # numpy counts timedelta64 as a number: read in its ticks (ns)
        c = f"x[{dim!r}]"
        seconds = (f"{c}.dt.total_seconds()" if t.dtype.kind == "m"
                   else f"({c} - {c}[0]).dt.total_seconds()")
        raise ValueError(
            f"coordinate {dim!r} is {t.dtype}; the time coordinates of this library are real "
            f"numbers in seconds (docs/conventions.md). Convert it, e.g. "
            f"x = x.assign_coords({dim}={seconds})."
        )
    if not np.issubdtype(t.dtype, np.number) or np.iscomplexobj(t):
        raise ValueError(
            f"coordinate {dim!r} must be real numbers (seconds), got dtype {t.dtype}; "
            f"assign numeric times, e.g. x.assign_coords({dim}=np.arange(n) * T)."
        )
    t = t.astype(float)
    if t.size < 2:
        raise ValueError(
            f"coordinate {dim!r} has {t.size} sample(s), so its spacing is undefined; "
            "a DFT needs at least 2 evenly spaced samples."
        )
    spacing = (t[-1] - t[0]) / (t.size - 1)
    if not np.isfinite(spacing) or spacing <= 0:
        raise ValueError(
            f"coordinate {dim!r} must be strictly increasing with a nonzero, finite spacing "
            f"(got mean spacing {spacing}); sort it (x.sortby({dim!r})) or rebuild it as "
            f"np.arange(n) * T."
        )
    steps = np.diff(t)
    worst = np.max(np.abs(steps - spacing)) / spacing
    if worst > SPACING_RTOL:
        raise ValueError(
            f"coordinate {dim!r} is not evenly spaced (steps vary by a relative {worst:.3g}, "
            f"tolerance {SPACING_RTOL:g}); the DFT assumes uniform sampling. Resample the "
            f"signal onto a uniform grid, or rebuild the coordinate as np.arange(n) * T if "
            "the samples are in fact uniform."
        )
    return float(t[0]), float(spacing)


def time_inverse_attrs(name: str, values, attrs: dict) -> dict:
    """Flat attributes from which :func:`rebuild_time` restores this time coordinate exactly."""
    t = np.asarray(values)
    start, spacing = even_spacing(t, name)
    out = {"time_name": name, "n_time": int(t.size), "time_dtype": str(t.dtype),
           "time_start": start, "time_spacing": spacing}
    rate = float(f"{1.0 / spacing:.12g}")
    candidates = [
        ("start+n*spacing", {"time_spacing": float(t[1] - t[0])}),
        ("start+n*spacing", {}),
        ("start+n/rate", {"time_rate": rate}),
        ("linspace", {"time_stop": float(t[-1])}),
    ]
    for recipe, extra in candidates:
        trial = {**out, **extra, "time_recipe": recipe}
        if np.array_equal(_recipe_values(trial), t.astype(float)):
            out = trial
            break
    else:
        out = {**out, "time_recipe": "values", "time_values": t.astype(float)}
    for key, value in attrs.items():
        out[TIME_ATTR_PREFIX + key] = value
    return out


def _recipe_values(a: dict) -> np.ndarray:
    n = np.arange(int(a["n_time"]))
    recipe = a["time_recipe"]
    if recipe == "start+n*spacing":
        return a["time_start"] + n * a["time_spacing"]
    if recipe == "start+n/rate":
        return a["time_start"] + n / a["time_rate"]
    if recipe == "linspace":
        return np.linspace(a["time_start"], a["time_stop"], int(a["n_time"]))
    if recipe == "values":
        return np.asarray(a["time_values"], dtype=float)
    raise ValueError(f"unknown time recipe {recipe!r} in the frequency coordinate's attributes.")


def rebuild_time(freq_attrs: dict) -> tuple[str, np.ndarray, dict]:
    """``(name, values, attrs)`` of the time coordinate recorded by :func:`time_inverse_attrs`."""
    values = _recipe_values(freq_attrs).astype(freq_attrs.get("time_dtype", "float64"))
    attrs = {
        key[len(TIME_ATTR_PREFIX):]: value
        for key, value in freq_attrs.items()
        if key.startswith(TIME_ATTR_PREFIX)
    }
    return freq_attrs["time_name"], values, attrs
