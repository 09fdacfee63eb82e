"""Build and validate the experiment dataset of the ``lcmr-xr-1`` data contract.

One closed-loop multirate experiment: fast excitation ``r`` and plant input ``u`` on
(``time``, ``input``), slow plant output ``y`` on (``slow_time``, ``output``), attributes
``factor`` and ``conventions``.  See ``docs/conventions.md``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import xarray as xr

from lcmr_xr.conventions import (
    CHANNEL,
    CONVENTIONS,
    EXPERIMENT,
    FACTOR,
    INPUT,
    OUTPUT,
    PERIOD,
    SLOW_TIME,
    TIME,
    label_attrs,
    time_attrs,
)
from lcmr_xr.settings import as_bool, recorded_factor
from lcmr_xr.transforms._coords import even_spacing
from lcmr_xr.transforms._finite import channel_labels, describe_lazy_non_finite, describe_non_finite

__all__ = ["experiment", "validate_experiment", "experiment_factor"]

_LONG_NAMES = {
    "r": "fast-rate excitation",
    "u": "fast-rate plant input",
    "y": "slow-rate plant output",
}
# Time coordinates must start at 0 up to rounding, relative to one sample.
_START_RTOL = 1e-9


def _labels(given, default_prefix: str, count: int, what: str) -> np.ndarray:
    if given is None:
        return np.array([f"{default_prefix}{i}" for i in range(count)])
    if isinstance(given, str) or not isinstance(given, Sequence | np.ndarray):
        raise TypeError(f"{what} must be a sequence of labels, got {given!r}.")
    labels = np.array([str(g) for g in given])
    if labels.size != count:
        raise ValueError(
            f"{what} has {labels.size} labels but the data has {count} channels; "
            f"pass one label per channel."
        )
    return labels


def _scalar(value, name: str, meaning: str):
    """A Python number from a number or any size-1 array (``scipy.io.loadmat`` gives (1, 1))."""
    if isinstance(value, (bool, np.bool_)):
        raise TypeError(f"{name} must be a number ({meaning}), got the boolean {value!r}.")
    arr = np.asarray(value)
    if arr.dtype.kind not in "iuf" or arr.size != 1:
        shape = f"an array of shape {arr.shape}" if arr.ndim else f"{value!r}"
        raise TypeError(
            f"{name} must be a single real number ({meaning}), got {shape} of dtype {arr.dtype}; "
            f"pass a number, e.g. {name}=float(x) (for a MATLAB (1, 1) value: x.item())."
        )
    return arr.reshape(()).item()


def _check_orientation(arr: np.ndarray, time_dim: str, chan_dim: str, what: str) -> None:
    """Refuse numpy data that are almost surely transposed: more channels than samples."""
    samples, channels = arr.shape[-2], arr.shape[-1]
    if samples == 0 or channels == 0:  # no data at all: transposing would not help
        raise ValueError(
            f"{what} has shape {arr.shape}: {samples} sample(s) of {channels} channel(s), no "
            f"data; pass the recorded signal, ({time_dim}, {chan_dim}) with at least 2 samples."
        )
    if channels > samples:
        lead = "(experiment, " if arr.ndim == 3 else "("
        fix = f"np.swapaxes({what}, -1, -2)" if arr.ndim == 3 else f"{what}.T"
        raise ValueError(
            f"{what} has shape {arr.shape}, i.e. {channels} channels of {samples} sample(s): it "
            f"looks transposed. numpy input is {lead}{time_dim}, {chan_dim}); pass {fix} "
            f"(a MATLAB row vector is (1, N))."
        )


def _numpy_to_dataarray(a, time_dim, chan_dim, what: str) -> xr.DataArray:
    arr = np.asarray(a)
    if arr.ndim == 1:
        arr = arr[:, None]  # a single channel
    if arr.ndim in (2, 3):
        _check_orientation(arr, time_dim, chan_dim, what)
    if arr.ndim == 2:
        dims = (time_dim, chan_dim)
    elif arr.ndim == 3:
        dims = (EXPERIMENT, time_dim, chan_dim)
    else:
        raise ValueError(
            f"{what} has {arr.ndim} dims; numpy input must be ({time_dim}, {chan_dim}) or "
            f"(experiment, {time_dim}, {chan_dim}). For more leading dims pass DataArrays "
            "with named dims."
        )
    return xr.DataArray(arr, dims=dims)


def _as_signal(a, time_dim: str, chan_dim: str, what: str) -> xr.DataArray:
    if isinstance(a, xr.DataArray):
        da = a
        if chan_dim == INPUT and CHANNEL in da.dims and INPUT not in da.dims:
            da = da.rename({CHANNEL: INPUT})
        missing = [d for d in (time_dim, chan_dim) if d not in da.dims]
        if missing:
            raise ValueError(
                f"{what} must have dims ({time_dim!r}, {chan_dim!r}), got {da.dims}; rename "
                f"them, e.g. {what}.rename({{'old': {time_dim!r}}})."
            )
        # Keep only what the contract defines; foreign coords (crest_factor, ...) would clash.
        keep = {time_dim, chan_dim} | (set(da.dims) - {time_dim, chan_dim})
        return da.drop_vars([c for c in da.coords if c not in keep])
    return _numpy_to_dataarray(a, time_dim, chan_dim, what)


def _attach_labels(da, dim, given, prefix, what):
    if dim in da.coords:
        existing = np.asarray(da[dim].values).astype(str)
        if given is not None and list(existing) != [str(g) for g in given]:
            raise ValueError(
                f"{what} already has {dim} labels {existing.tolist()}, which differ from "
                f"{dim}s={list(given)}; pass matching labels or drop one of them."
            )
        return da.assign_coords({dim: (dim, existing, label_attrs(f"{dim} channel"))})
    labels = _labels(given, prefix, da.sizes[dim], f"{dim}s")
    return da.assign_coords({dim: (dim, labels, label_attrs(f"{dim} channel"))})


def experiment(
    r,
    u,
    y,
    *,
    factor: int,
    sampling_period: float | None = None,
    inputs=None,
    outputs=None,
    attrs: dict | None = None,
    input_units: str | None = None,
    output_units: str | None = None,
) -> xr.Dataset:
    """Build a validated experiment dataset (``lcmr-xr-1``) from arrays or DataArrays.

    Parameters
    ----------
    r, u : array_like or xarray.DataArray
        Fast excitation and measured plant input.  numpy: shape (N, nu) or
        (n_experiment, N, nu) (1-d means one channel).  DataArray: dims ``time`` and
        ``input`` (``channel`` is renamed to ``input``) plus any extra dims.
    y : array_like or xarray.DataArray
        Slow measured plant output: numpy (M, ny) or (n_experiment, M, ny); DataArray dims
        ``slow_time`` and ``output``.  ``M F`` must equal ``N``.
    factor : int
        Multirate factor F = Tl / Th.
    sampling_period : float, optional
        Fast sample time Th in s.  Required when ``r`` has no ``time`` coordinate; the
        coordinates are then ``time = n Th`` and ``slow_time = l F Th``.
    inputs, outputs : sequence of str, optional
        Channel labels; default ``"u0", "u1", ...`` and ``"y0", "y1", ...`` (or the labels
        the DataArrays carry, which must then agree).
    attrs : dict, optional
        Extra dataset attributes (e.g. the settings of a simulation).
    input_units, output_units : str, optional
        Units of ``r``/``u`` and of ``y``.  Default: the DataArray's ``units`` attribute,
        else ``"1"``.

    Returns
    -------
    xarray.Dataset
        ``r``, ``u`` (``time``, ``input``), ``y`` (``slow_time``, ``output``), all with
        ``units`` and ``long_name``; attributes ``factor`` and ``conventions="lcmr-xr-1"``.
        Dask-backed DataArrays stay lazy except for the finiteness check.

    Raises
    ------
    TypeError
        ``factor`` or ``sampling_period`` not a single number, labels not a sequence,
        ``input_units``/``output_units`` not a string.
    ValueError
        Empty units; shapes, labels, time coordinates or values that break the contract (see
        :func:`validate_experiment`).

    Examples
    --------
    >>> import numpy as np
    >>> ds = experiment(np.zeros((8, 1)), np.ones((8, 1)), np.ones((4, 2)), factor=2,
    ...                 sampling_period=0.5, outputs=["a", "b"])
    >>> ds.sizes["time"], ds.sizes["slow_time"], ds.output.values.tolist(), ds.attrs["factor"]
    (8, 4, ['a', 'b'], 2)
    """
    if attrs is not None and not isinstance(attrs, Mapping):  # dict([1]) fails inside Python
        raise TypeError(f"attrs must be a dict of extra dataset attributes, got {attrs!r} "
                        f"({type(attrs).__name__}); pass e.g. attrs={{'case': 2}}.")
    extra = dict(attrs or {})
    for key, remedy in ((FACTOR, "pass factor=F instead"),
                        ("conventions", f"experiment() always sets {CONVENTIONS!r}; drop it")):
        if key in extra:
            raise ValueError(
                f"attrs must not set {key!r}: it is part of the contract and set by experiment(); "
                f"{remedy}."
            )
    factor_value = _scalar(factor, "factor", "the multirate factor F = Tl/Th")
    if not np.isfinite(factor_value) or int(factor_value) != factor_value or factor_value < 1:
        whole = int(factor_value // 1) if np.isfinite(factor_value) and factor_value >= 1 else 2
        raise ValueError(f"factor must be a positive integer (the multirate factor F = Tl/Th; it "
                         f"is not rounded), got {factor!r}; pass e.g. factor={whole}.")
    factor = int(factor_value)
    if sampling_period is not None:
        sampling_period = _scalar(sampling_period, "sampling_period", "the fast sample time Th in s")

    r_da = _as_signal(r, TIME, INPUT, "r")
    u_da = _as_signal(u, TIME, INPUT, "u")
    y_da = _as_signal(y, SLOW_TIME, OUTPUT, "y")

    if input_units is None:
        input_units = str(r_da.attrs.get("units", u_da.attrs.get("units", "1")))
    if output_units is None:
        output_units = str(y_da.attrs.get("units", "1"))
    for what, units in (("input_units", input_units), ("output_units", output_units)):
        if not isinstance(units, str) or not units.strip():
            error = TypeError if not isinstance(units, str) else ValueError
            raise error(f"{what} must be a unit string (UDUNITS, e.g. 'm' or 'V'; '1' if "
                        f"dimensionless), got {units!r}.")

    # Labels are checked before the variables are combined: xarray would otherwise align
    # mismatched labels by an outer join and fill the gaps with NaN.
    r_da = _attach_labels(r_da, INPUT, inputs, "u", "r")
    u_da = _attach_labels(u_da, INPUT, inputs, "u", "u")
    y_da = _attach_labels(y_da, OUTPUT, outputs, "y", "y")
    if r_da.sizes[INPUT] != u_da.sizes[INPUT] or not np.array_equal(
        r_da[INPUT].values, u_da[INPUT].values
    ):
        raise ValueError(
            f"r and u must have the same input labels, got {r_da[INPUT].values.tolist()} and "
            f"{u_da[INPUT].values.tolist()}; pass inputs=[...] or relabel one of them."
        )

    n = r_da.sizes[TIME]
    if TIME in r_da.coords and TIME in u_da.coords and not np.array_equal(
        r_da[TIME].values, u_da[TIME].values
    ):
        raise ValueError(
            "r and u have different 'time' coordinates; they must be sampled at the same "
            "instants. Drop one coordinate (u.drop_vars('time')) or resample."
        )
    if TIME in r_da.coords:
        fast_t = (np.asarray(r_da[TIME].values), dict(r_da[TIME].attrs) or time_attrs())
    elif TIME in u_da.coords:
        fast_t = (np.asarray(u_da[TIME].values), dict(u_da[TIME].attrs) or time_attrs())
    elif sampling_period is not None:
        th = float(sampling_period)
        if not np.isfinite(th) or th <= 0:
            raise ValueError(f"sampling_period must be a positive time in s, got {sampling_period!r}.")
        fast_t = (np.arange(n) * th, time_attrs())
    else:
        raise ValueError(
            "the fast sample time is unknown: pass sampling_period=Th (in s), or give r a "
            "'time' coordinate."
        )
    if n < 2:
        raise ValueError(f"r has {n} fast sample(s); an experiment needs at least 2 slow samples.")
    _, th = even_spacing(fast_t[0], TIME)
    if sampling_period is not None and not np.isclose(th, float(sampling_period), rtol=1e-6, atol=0.0):
        raise ValueError(
            f"sampling_period={sampling_period} s disagrees with the spacing {th} s of the time "
            "coordinate; drop one of them."
        )
    m = y_da.sizes[SLOW_TIME]
    if SLOW_TIME in y_da.coords:
        slow_t = (np.asarray(y_da[SLOW_TIME].values), dict(y_da[SLOW_TIME].attrs))
    else:
        slow_t = (np.arange(m) * (factor * th), {})
    slow_attrs = {**time_attrs("slow time"), **slow_t[1]}
    fast_attrs = {**time_attrs(), **fast_t[1]}

    def finish(da, name, units, time_dim, t):
        da = da.assign_coords({time_dim: (time_dim, t[0], fast_attrs if time_dim == TIME else slow_attrs)})
        da.attrs = {**da.attrs, "units": units, "long_name": da.attrs.get("long_name", _LONG_NAMES[name])}
        da.name = name
        return da

    try:
        ds = xr.Dataset(
            {
                "r": finish(r_da, "r", input_units, TIME, fast_t),
                "u": finish(u_da, "u", input_units, TIME, fast_t),
                "y": finish(y_da, "y", output_units, SLOW_TIME, slow_t),
            },
            attrs={**extra, FACTOR: factor, "conventions": CONVENTIONS},
        )
    except ValueError as err:  # conflicting sizes of a shared dim, e.g. `experiment`
        raise ValueError(f"r, u and y do not fit together: {err}. Check their shapes.") from err
    for name, long_name in ((EXPERIMENT, EXPERIMENT),
                            (PERIOD, "period of the periodic excitation")):
        if name in ds.dims and name not in ds.coords:
            ds = ds.assign_coords({name: (name, np.arange(ds.sizes[name]), label_attrs(long_name))})
    return validate_experiment(ds)


def _is_lazy(a) -> bool:
    try:
        import dask
    except ImportError:  # dask is a dependency, but numpy-only use need not import it
        return False
    return dask.is_dask_collection(a)


def _fail(problem: str, fix: str):
    raise ValueError(f"invalid experiment dataset: {problem}. {fix}")


def _check_leading_dims(ds) -> None:
    """u and y carry the same leading dims, and r no dim they lack.

    An ``r`` with an ``experiment`` dim but ``u``, ``y`` without it would broadcast one
    measurement over every experiment (a silent wrong answer).  The converse, one ``r``
    shared by experiments whose ``u``, ``y`` differ (a repeated excitation), is valid.
    """
    core = {TIME, SLOW_TIME, INPUT, OUTPUT}
    lead = {name: [d for d in ds[name].dims if d not in core] for name in ("r", "u", "y")}
    if set(lead["u"]) != set(lead["y"]) or not set(lead["r"]) <= set(lead["u"]):
        listing = ", ".join(f"{name} {tuple(dims)}" for name, dims in lead.items())
        _fail(
            f"r, u and y have different leading dims ({listing}), so a measurement would be "
            "shared across experiments it does not belong to",
            "give u and y the same leading dims, and r no dim they lack (select one experiment "
            "with .isel(experiment=0), or stack the measurements of every experiment).",
        )


def _factor_hint(ds, factor: int) -> str:
    """Name the factor the data imply when it differs from the ``factor`` attribute."""
    n, m = ds.sizes[TIME], ds.sizes[SLOW_TIME]
    candidates = []
    if m and n % m == 0 and n // m != factor:
        candidates.append(f"N/M = {n}/{m} = {n // m}")
    try:
        ratio = even_spacing(ds[SLOW_TIME].values, SLOW_TIME)[1] / even_spacing(ds[TIME].values, TIME)[1]
    except (KeyError, ValueError):
        ratio = None
    if ratio is not None and abs(ratio - round(ratio)) < 1e-6 * ratio and round(ratio) != factor:
        candidates.append(f"slow_time spacing / time spacing = {round(ratio)}")
    if not candidates:
        return ""
    return (f" The attribute says factor={factor}, but the data suggest "
            f"{' and '.join(candidates)}: if the data are right, set ds.attrs['factor'] to that; "
            "otherwise fix y or the time coordinates.")


def _check_time(ds, dim: str, expected_spacing: float | None, hint: str = "") -> float:
    if dim not in ds.coords:
        _fail(f"coordinate {dim!r} is missing", f"assign it, e.g. ds.assign_coords({dim}=np.arange(n) * T).")
    values = np.asarray(ds[dim].values)
    if values.size < 2:
        _fail(f"{dim!r} has {values.size} sample(s)", "an experiment needs at least 2 samples on each time axis.")
    try:
        start, spacing = even_spacing(values, dim, ds[dim].attrs.get("units"))
    except ValueError as err:
        _fail(str(err).rstrip("."), "Fix the coordinate.")
    if abs(start) > _START_RTOL * spacing:
        _fail(
            f"{dim!r} starts at {start} s instead of 0",
            f"shift it: ds.assign_coords({dim}=ds.{dim} - ds.{dim}[0]).",
        )
    if expected_spacing is not None and not np.isclose(spacing, expected_spacing, rtol=1e-6, atol=0.0):
        _fail(
            f"{dim!r} is spaced by {spacing} s, but factor * (time spacing) = {expected_spacing} s",
            "the slow period must be F times the fast period: check the factor attribute and "
            f"both time coordinates.{hint}",
        )
    return spacing


#: ``r`` counts as repeating when its periods differ by at most this times its peak.
PERIODIC_RTOL = 1e-9


def _check_period_dims(ds):
    """``period`` (repeated periods of one excitation) must be on ``u`` and ``y`` together,
    its labels increasing: :func:`lcmr_xr.identify` drops the first ``transient_periods``
    by position, so periods out of recording order would keep the transient."""
    missing = [name for name in ("u", "y") if PERIOD not in ds[name].dims]
    if missing:
        _fail(
            f"the dataset has a {PERIOD!r} dim but {missing} lack it",
            f"the measured signals are recorded per period: give u and y the {PERIOD!r} dim "
            f"(time then counts within a period), or drop it from r.",
        )
    if PERIOD in ds.coords:
        labels = np.asarray(ds[PERIOD].values)
        if labels.dtype.kind not in "iu" or (labels.size > 1 and not (np.diff(labels) > 0).all()):
            shown = labels.tolist() if labels.size <= 8 else f"{labels[:7].tolist()} ..."
            _fail(
                f"the {PERIOD!r} coordinate {shown} is not increasing integers (the periods in "
                "the order they were recorded, 0..P-1)",
                f"sort them with ds.sortby({PERIOD!r}) (transient_periods drops the first ones "
                "by position), or relabel them 0..P-1 in recording order.",
            )


def _periodic_spread(r):
    """``(largest difference between periods, peak)`` of ``r``: floats, or dask scalars
    for lazy data (computed with the other checks, in one pass)."""
    x = r.transpose(PERIOD, ...).data
    if not x.size:
        return 0.0, 0.0
    return abs(x - x[:1]).max(), abs(x).max()


def _check_periodic_excitation(diff, peak):
    """Every period of ``r`` must be the same signal (averaging over periods relies on it)."""
    diff, peak = float(diff), float(peak)
    if diff > PERIODIC_RTOL * peak:
        _fail(
            f"r differs between periods (largest difference {diff:.3g}, {diff / peak:.2g} of its "
            f"peak): along {PERIOD!r} the excitation must repeat exactly",
            f"the {PERIOD!r} dim is for repeated periods of ONE periodic excitation; put records "
            "with different excitations on an 'experiment' dim instead.",
        )


def validate_experiment(ds: xr.Dataset, *, check_values: bool = True) -> xr.Dataset:
    """Check an experiment dataset against the ``lcmr-xr-1`` contract; return it if valid.

    Parameters
    ----------
    ds : xarray.Dataset
        Candidate experiment dataset; extra dims (e.g. ``experiment``), variables and
        attributes are allowed.  A ``period`` dim holds repeated periods of ONE periodic
        excitation (``time`` and ``slow_time`` then count within a period): ``u`` and ``y``
        must carry it, and ``r`` must repeat exactly (to 1e-9 of its peak) along it.
    check_values : bool, default True
        Also check the data for NaN and inf (and that ``r`` repeats over periods).  ``False`` reads metadata only, so lazy
        (dask-backed) data are not computed; lazy consumers such as
        :func:`lcmr_xr.identify` then refuse non-finite data when they are computed.

    Returns
    -------
    xarray.Dataset
        ``ds`` itself, unchanged.

    Raises
    ------
    ValueError
        Naming the problem and the fix, for: wrong ``conventions``; missing or invalid
        ``factor``; missing ``r``/``u``/``y``; wrong dims; missing ``time``, ``slow_time``,
        ``input``, ``output`` coordinates; ``N`` not a multiple of ``F`` or
        ``N != M F``; uneven spacing; time not starting at 0; a time coordinate whose
        ``units`` are another time unit than seconds (``ms``, ``us``, ``min``, ...); slow spacing not ``F`` times
        the fast one; complex, boolean or non-numeric data; NaN or inf; duplicate or empty
        channel labels; ``units`` that are not a non-empty string; a ``period`` dim missing
        on ``u`` or ``y``, a ``period`` coordinate that is not increasing integers, or an
        ``r`` that does not repeat over periods.
    TypeError
        If ``ds`` is not a Dataset, or ``check_values`` is not True or False.

    Notes
    -----
    Everything but the NaN/inf check reads metadata only.  The NaN/inf check has to look
    at the data: for dask-backed variables it computes the three ``isfinite(...).all()``
    reductions (and, with a ``period`` dim, the largest difference of ``r`` between
    periods) in a single ``dask.compute`` call (one pass over the data, nothing kept);
    only when one fails is that variable read once more, to name where its bad samples are
    (times, channels, experiments), as for data in memory.

    Examples
    --------
    >>> import numpy as np
    >>> ds = experiment(np.zeros((8, 1)), np.ones((8, 1)), np.ones((4, 1)), factor=2,
    ...                 sampling_period=0.5)
    >>> validate_experiment(ds) is ds
    True
    """
    if not isinstance(ds, xr.Dataset):
        raise TypeError(
            f"an experiment must be an xarray.Dataset, got {type(ds).__name__}; build one with "
            "lcmr_xr.experiment(r, u, y, factor=F, sampling_period=Th)."
        )
    check_values = as_bool(check_values, "check_values")  # "no" would read as True
    conv = ds.attrs.get("conventions")
    if conv is None:
        _fail("attribute 'conventions' is missing", f"set ds.attrs['conventions'] = {CONVENTIONS!r} after checking the contract.")
    if conv != CONVENTIONS:
        _fail(
            f"conventions is {conv!r}, expected {CONVENTIONS!r}",
            "this file follows another data contract; build an experiment from its arrays with "
            "lcmr_xr.experiment(r, u, y, factor=F, sampling_period=Th).",
        )
    if FACTOR not in ds.attrs:
        _fail("attribute 'factor' is missing", "set ds.attrs['factor'] = F (the multirate factor Tl/Th).")
    f_raw = ds.attrs[FACTOR]
    factor = recorded_factor(f_raw)  # the one reader of a stored factor (lift's lift_factor too)
    if factor is None:
        _fail(f"attribute 'factor' must be a positive integer, got {f_raw!r}", "set ds.attrs['factor'] = F.")

    required = {"r": (TIME, INPUT), "u": (TIME, INPUT), "y": (SLOW_TIME, OUTPUT)}
    for name, dims in required.items():
        if name not in ds.data_vars:
            if "P" in ds.data_vars:  # identify's result given where its input goes
                _fail(f"variable {name!r} is missing: this is an FRF dataset (it holds 'P', as "
                      "lcmr_xr.identify returns it), not an experiment",
                      "Pass the experiment (r, u, y) that was identified, e.g. "
                      "lcmr_xr.open_experiment(path); open an FRF file with lcmr_xr.open_frf.")
            _fail(f"variable {name!r} is missing", f"add {name!r} with dims {dims}.")
        var = ds[name]
        missing = [d for d in dims if d not in var.dims]
        if missing:
            _fail(f"{name!r} has dims {var.dims}, missing {missing}", f"{name!r} must have dims {dims} (plus optional leading dims).")
        wrong = [d for d in (TIME, SLOW_TIME, INPUT, OUTPUT) if d in var.dims and d not in dims]
        if wrong:
            _fail(f"{name!r} has dims {var.dims}, which include {wrong}", f"{name!r} must have dims {dims} (plus optional leading dims).")
        dt = var.dtype
        if np.issubdtype(dt, np.complexfloating):
            _fail(f"{name!r} is complex ({dt})", "time-domain signals must be real; pass the real signals, not spectra.")
        if dt.kind not in "fiu":
            _fail(f"{name!r} has non-numeric dtype {dt}", "convert it to float, e.g. ds[name].astype(float).")
        if "units" not in var.attrs or "long_name" not in var.attrs:
            _fail(f"{name!r} lacks the 'units' or 'long_name' attribute", "set both (units '1' if dimensionless).")
        units = var.attrs["units"]
        if not isinstance(units, str) or not units.strip():
            # the FRF's units are built from these ("m/V"): 5 or ['V'] would make "5/['V']"
            _fail(f"{name!r} has units {units!r}, not a unit string",
                  f"set ds[{name!r}].attrs['units'] to a UDUNITS string such as 'm' or 'V' "
                  "('1' if dimensionless).")

    for dim in (INPUT, OUTPUT):
        if dim not in ds.coords:
            _fail(f"label coordinate {dim!r} is missing", f"assign channel labels: ds.assign_coords({dim}=['...']).")
        labels = np.asarray(ds[dim].values)
        if labels.dtype.kind not in "UO" or any(str(v) == "" for v in labels):
            _fail(f"{dim!r} labels must be non-empty strings, got {labels.tolist()}", "relabel the channels, e.g. ['u0', 'u1'].")
        if len(set(labels.tolist())) != labels.size:
            _fail(f"{dim!r} labels {labels.tolist()} contain duplicates", "give every channel a unique label.")

    if PERIOD in ds.dims:  # the more specific message first
        _check_period_dims(ds)
    _check_leading_dims(ds)

    n, m = ds.sizes[TIME], ds.sizes[SLOW_TIME]
    hint = _factor_hint(ds, factor)
    if n % factor:
        _fail(f"N={n} fast samples is not a multiple of factor F={factor}", f"trim the experiment to {n - n % factor} fast samples.{hint}")
    if n != m * factor:
        _fail(f"N={n} fast samples but M={m} slow samples and F={factor} (M*F={m * factor})", f"y must cover the same time span as r and u: N = M * F.{hint}")
    th = _check_time(ds, TIME, None)
    _check_time(ds, SLOW_TIME, factor * th, hint)

    if not check_values:
        return ds
    checks = {name: np.isfinite(ds[name].data).all() for name in required if ds[name].dtype.kind == "f"}
    if PERIOD in ds["r"].dims:  # lazy r was not checked at all: it has to repeat as well
        checks["periodic"] = _periodic_spread(ds["r"])
    if any(_is_lazy(c) for c in checks.values()) or any(_is_lazy(c) for c in checks.get("periodic", ())):
        import dask

        # One graph for the reductions: the data are read once.
        values = dict(zip(checks, dask.compute(*checks.values())))
    else:
        values = checks
    if "periodic" in values:
        _check_periodic_excitation(*values.pop("periodic"))
    bad = [name for name, ok in values.items() if not bool(ok)]
    if bad:
        # the message of dft and identify's lazy guard (variable, count, channels, samples
        # and time range); lazy variables are read once more to find them
        said = [_bad_samples(ds[name]) for name in bad]
        how = ", ".join(f"ds[{name!r}].interpolate_na({TIME if TIME in ds[name].dims else SLOW_TIME!r})"
                        for name in bad)
        _fail("; ".join(said), f"Remove or interpolate the bad samples before identification "
              f"(e.g. {how}), or drop the experiments that hold them.")
    return ds


def experiment_factor(ds) -> int:
    """The multirate factor ``F`` of a validated experiment (or of the results made from
    one), as a Python int.

    :func:`validate_experiment` accepts the attribute as any whole positive number, also a
    one-element array (as an attribute may come back from a file or be set in memory);
    ``int()`` of such an array is an error in numpy 2, so every reader of the attribute
    goes through here, and this, :func:`validate_experiment` and :func:`lcmr_xr.lift` read
    it (as ``lift`` reads its ``lift_factor``) with :func:`lcmr_xr.settings.recorded_factor`.

    Parameters
    ----------
    ds : xarray.Dataset
        An experiment that passed :func:`validate_experiment`, or a result of one.

    Returns
    -------
    int
        The attribute ``factor``.

    Raises
    ------
    ValueError
        If the attribute is missing or not one whole number >= 1.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> experiment_factor(xr.Dataset(attrs={"factor": np.array([2])}))
    2
    """
    factor = recorded_factor(ds.attrs.get(FACTOR))
    if factor is None:
        raise ValueError(f"attribute 'factor' must be a positive integer, got "
                         f"{ds.attrs.get(FACTOR)!r}; set ds.attrs['factor'] = F (the multirate "
                         "factor Tl/Th) and check the dataset with lcmr_xr.validate_experiment.")
    return factor


def _bad_samples(var: xr.DataArray) -> str:
    """What :func:`lcmr_xr.dft` says of the non-finite values of an in-memory variable
    (:func:`lcmr_xr.transforms._finite.describe_non_finite`)."""
    dim = TIME if TIME in var.dims else SLOW_TIME
    if _is_lazy(var.data):
        return describe_lazy_non_finite(var, dim)
    bad = ~np.isfinite(var.transpose(..., dim).values)
    return describe_non_finite(var.name, bad, dim=dim, coord=np.asarray(var[dim].values),
                               where=channel_labels(var, dim, bad))
