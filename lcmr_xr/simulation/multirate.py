"""Labelled simulation of a multirate closed loop, returning an experiment dataset.

The numerics live in :mod:`lcmr_xr.kernels.lti`; this module maps the named dims of the
data contract onto its axes with :func:`xarray.apply_ufunc` and builds the dataset with
:func:`lcmr_xr.experiment.experiment`.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from lcmr_xr.conventions import INPUT, OUTPUT, PERIOD, SLOW_TIME, TIME
from lcmr_xr.experiment import experiment
from lcmr_xr.kernels.lti import StateSpace, multirate_closed_loop, simulate_multirate
from lcmr_xr.settings import as_bool, as_integer

__all__ = ["simulate_closed_loop"]

_CORE_DIMS = {"r": [TIME, INPUT], "d_u": [TIME, INPUT], "d_y": [TIME, OUTPUT],
              "reference": [SLOW_TIME, OUTPUT]}


def _check_signal(da, name: str):
    if not isinstance(da, xr.DataArray):
        raise TypeError(
            f"{name} must be an xarray.DataArray with dims {tuple(_CORE_DIMS[name])}, got "
            f"{type(da).__name__}; wrap it, e.g. xr.DataArray(x, dims={tuple(_CORE_DIMS[name])})."
        )
    missing = [d for d in _CORE_DIMS[name] if d not in da.dims]
    if missing:
        raise ValueError(
            f"{name} must have dims {tuple(_CORE_DIMS[name])}, missing {missing} (has {da.dims}); "
            f"rename its dims, e.g. {name}.rename({{'old': {missing[0]!r}}})."
        )


def _check_periods(periods, given: dict) -> int | None:
    """``periods`` as an int (or None), and the ``period`` dims of the signals checked.

    The excitation is ONE period, repeated; the disturbances are not periodic, so they
    need their own ``period`` dim: period ``p`` holds their samples ``p N .. (p+1) N - 1``.
    """
    if periods is None:
        for name, da in given.items():
            if PERIOD in da.dims:
                raise ValueError(
                    f"{name} has a {PERIOD!r} dim but periods is not given; pass "
                    f"periods={da.sizes[PERIOD]} to simulate that many periods of r."
                )
        return None
    periods = as_integer(periods, "periods", minimum=1, example=2)  # 2.0 yes, 2.5 no
    if PERIOD in given["r"].dims:
        raise ValueError(
            f"r has a {PERIOD!r} dim, but with periods={periods} r is ONE period of the "
            f"excitation (it repeats); pass r.isel({PERIOD}=0) or a periodic signal."
        )
    for name, da in given.items():
        if name == "r":
            continue
        if da.sizes.get(PERIOD) != periods:
            raise ValueError(
                f"{name} must have a {PERIOD!r} dim of size {periods} (it is not periodic: "
                f"period p holds its samples p N .. (p+1) N - 1 of one continuous record), got "
                f"dims {dict(da.sizes)}. Reshape a record x of {periods} N samples, e.g. "
                f"xr.DataArray(x.reshape({periods}, N, -1), dims=({PERIOD!r}, "
                f"{_CORE_DIMS[name][0]!r}, {_CORE_DIMS[name][1]!r}))."
            )
    return periods


def _output_labels(outputs, given: dict, ny: int) -> list[str]:
    for da in given.values():
        if OUTPUT in da.coords:
            labels = [str(v) for v in da[OUTPUT].values]
            if outputs is not None and list(outputs) != labels:
                raise ValueError(
                    f"outputs={list(outputs)} differ from the output labels {labels} of the "
                    "disturbance/reference signals; pass matching labels."
                )
            return labels
    if outputs is None:
        return [f"y{i}" for i in range(ny)]
    if isinstance(outputs, str) or len(outputs) != ny:
        raise ValueError(f"outputs must be a sequence of {ny} labels (one per plant output), "
                         f"got {outputs!r}.")
    return [str(o) for o in outputs]


def simulate_closed_loop(
    plant: StateSpace,
    controller: StateSpace,
    filter: StateSpace | None,
    factor: int,
    r: xr.DataArray,
    *,
    d_u: xr.DataArray | None = None,
    d_y: xr.DataArray | None = None,
    reference: xr.DataArray | None = None,
    outputs: Sequence[str] | None = None,
    output_units: str | None = None,
    fast_output: bool = False,
    attrs: dict | None = None,
    periods: int | None = None,
) -> xr.Dataset:
    """Simulate a multirate closed-loop experiment from rest and return its dataset.

    The loop is that of :func:`lcmr_xr.kernels.lti.multirate_closed_loop`: slow
    controller on ``e = reference - y_l``, zero-order hold, fast filter, ``u_h = r + Fi v_h``
    recorded, plant input ``u_h + d_u``, output ``P(u_h + d_u) + d_y``, measured
    ``y_l(l) = y(lF)``.

    Parameters
    ----------
    plant : StateSpace
        Fast plant, ``nu`` inputs, ``ny`` outputs, period ``Th``.
    controller : StateSpace
        Slow controller, ``ny`` inputs, ``nu`` outputs, period ``F Th``.
    filter : StateSpace or None
        Fast filter (``nu`` x ``nu``, period ``Th``); ``None`` for none.
    factor : int
        Multirate factor ``F``.
    r : xarray.DataArray
        Excitation, dims (``time``, ``input``) plus any leading dims; ``N`` a multiple of
        ``F``.  A ``time`` coordinate, when present, must be spaced by ``Th``.
    d_u : xarray.DataArray, optional
        Input disturbance (``time``, ``input``), added after ``u`` is measured; default 0.
    d_y : xarray.DataArray, optional
        Output disturbance (``time``, ``output``); default 0.
    reference : xarray.DataArray, optional
        Slow reference (``slow_time``, ``output``), e.g. run-out; default 0.
    outputs : sequence of str, optional
        Output labels; default those of ``d_y``/``reference``, else ``"y0", ...``.
    output_units : str, optional
        Units of ``y``; default the ``units`` attribute of ``d_y`` or ``reference``, else
        ``"1"``.  ``r`` and ``u`` keep the units of ``r`` (default ``"1"``).
    fast_output : bool, optional
        Also return the fast output ``y_fast`` (``time``, ``output``), which a real
        experiment does not measure (e.g. for stroke checks); default False.
    attrs : dict, optional
        Extra dataset attributes (the simulation settings).
    periods : int, optional
        Simulate ``periods`` repetitions of the excitation ``r`` (one period of ``N``
        samples) in ONE run from rest: the loop and the disturbances run on across the
        periods.  ``r``, ``u``, ``y`` then get a ``period`` dim (coordinate ``0..P-1``)
        and ``time``/``slow_time`` count within a period.  ``d_u``, ``d_y`` and
        ``reference`` must then carry a ``period`` dim of size ``periods`` (period ``p``
        holds their samples ``p N .. (p+1) N - 1``).  Default: no ``period`` dim.

    Returns
    -------
    xarray.Dataset
        Experiment dataset of the ``lcmr-xr-1`` contract (``r``, ``u``, ``y``), plus
        ``y_fast`` when asked.

    Raises
    ------
    ValueError
        Unstable loop, a ``factor`` that is not a positive whole number (never truncated),
        wrong dims or sizes, or a time coordinate not spaced by ``Th``.
    TypeError
        A system that is not a StateSpace, a signal that is not a DataArray, a ``factor``
        or ``periods`` that is not a number, or ``fast_output`` not True or False.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> from lcmr_xr.kernels.lti import static_gain, tf_q_inverse
    >>> P = tf_q_inverse([0.0, 0.5], [1.0, -0.9], dt=0.5)
    >>> r = xr.DataArray(np.ones((8, 1)), dims=("time", "input"))
    >>> ds = simulate_closed_loop(P, static_gain(0.2, dt=1.0), None, 2, r)
    >>> ds.sizes["time"], ds.sizes["slow_time"]
    (8, 4)
    """
    fast_output = as_bool(fast_output, "fast_output")  # "no" would read as True
    factor = as_integer(factor, "factor", minimum=1, example=2)  # 2.5 refused, "2" a TypeError
    loop = multirate_closed_loop(plant, controller, filter, factor)
    F, ny, th = loop.factor, plant.n_outputs, plant.dt
    given = {"r": r, "d_u": d_u, "d_y": d_y, "reference": reference}
    given = {k: v for k, v in given.items() if v is not None}
    for name, da in given.items():
        _check_signal(da, name)
    if r.sizes[INPUT] != plant.n_inputs:
        raise ValueError(f"r has {r.sizes[INPUT]} inputs but the plant has {plant.n_inputs}; "
                         "pass one excitation channel per plant input.")
    if TIME in r.coords and r.sizes[TIME] > 1:
        spacing = np.diff(np.asarray(r[TIME].values, dtype=float))
        if not np.allclose(spacing, th, rtol=1e-6, atol=0):
            raise ValueError(
                f"the time coordinate of r is spaced by {spacing[0]} s but the plant is sampled "
                f"at Th = {th} s; resample r or discretise the plant at the spacing of r."
            )
    periods = _check_periods(periods, given)
    labels = _output_labels(outputs, given, ny)
    if output_units is None:
        output_units = next((str(da.attrs["units"]) for k, da in given.items()
                             if k in ("d_y", "reference") and "units" in da.attrs), "1")
    names = list(given)
    # with periods, every signal but r carries (period, time): one continuous record
    lead_core = [] if periods is None else [PERIOD]
    core_in = [_CORE_DIMS[k] if k == "r" else lead_core + _CORE_DIMS[k] for k in names]

    def kernel(*arrays):
        kw = dict(zip(names, arrays))
        if periods is not None:  # one record of P N samples: the loop runs on across periods
            kw = {k: _flatten_periods(v, periods, tile=(k == "r")) for k, v in kw.items()}
        res = simulate_multirate(loop, kw["r"], kw.get("d_u"), kw.get("d_y"), kw.get("reference"))
        if periods is None:
            return res.u, res.y
        return _split_periods(res.u, periods), _split_periods(res.y, periods)

    u, y_fast = xr.apply_ufunc(
        kernel, *given.values(),
        input_core_dims=core_in,
        output_core_dims=[lead_core + [TIME, INPUT], lead_core + [TIME, OUTPUT]],
        dask="parallelized",
        output_dtypes=[float, float],
        dask_gufunc_kwargs={"output_sizes": {OUTPUT: ny, **({PERIOD: periods} if periods else {})}},
        keep_attrs=False,
    )
    if periods is not None:  # the excitation is the same in every period
        r = r.broadcast_like(u.isel({INPUT: 0}, drop=True)).transpose(*u.dims)
    y_fast = y_fast.assign_coords({OUTPUT: labels})
    # y_l(l) = y(lF): the slow samples are every F-th fast sample.
    y = y_fast.isel({TIME: slice(None, None, F)}).rename({TIME: SLOW_TIME})
    y = y.drop_vars(SLOW_TIME, errors="ignore")  # experiment() builds slow_time = l F Th
    in_units = str(r.attrs.get("units", "1"))
    ds = experiment(r, u.assign_attrs(units=in_units, long_name="fast-rate plant input"),
                    y.assign_attrs(units=output_units, long_name="slow-rate plant output"),
                    factor=F, sampling_period=None if TIME in r.coords else th,
                    outputs=labels, attrs=attrs, input_units=in_units,
                    output_units=output_units)
    if fast_output:
        ds["y_fast"] = y_fast.assign_coords({TIME: ds[TIME], OUTPUT: ds[OUTPUT]}).assign_attrs(
            units=output_units, long_name="fast-rate plant output (not measured)")
    return ds


def _flatten_periods(x: np.ndarray, periods: int, tile: bool) -> np.ndarray:
    """(..., P, L, c) -> (..., P L, c); ``tile``: (..., L, c) repeated P times."""
    x = np.asarray(x)
    if tile:
        reps = (1,) * (x.ndim - 2) + (periods, 1)
        return np.tile(x, reps)
    return x.reshape(x.shape[:-3] + (x.shape[-3] * x.shape[-2], x.shape[-1]))


def _split_periods(x: np.ndarray, periods: int) -> np.ndarray:
    """(..., P L, c) -> (..., P, L, c): period ``p`` holds samples ``p L .. (p+1) L - 1``."""
    return x.reshape(x.shape[:-2] + (periods, x.shape[-2] // periods, x.shape[-1]))
