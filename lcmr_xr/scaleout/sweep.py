"""``sweep``: identify a stack of experiments for every combination of settings, lazily.

Each (method, degrees, window) combination is one :func:`xarray.map_blocks` over the
experiment chunks; the function run per block is :func:`lcmr_xr.identify` itself on the
in-memory block.  Why blocks and not ``identify`` on the dask dataset directly: ``identify``
validates its input, and on dask data that validation computes a pass over the data, once
per setting.  Per block, the validation runs inside the task on data already in memory, so
building the sweep reads nothing and computing it reads every experiment once per setting.

The output structure (and every settings error: a window too small for the degrees, a
window wider than the spectrum) is found before anything is computed by running
``identify`` on a small synthetic probe with the same shape as one experiment.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable

import dask.array as dsa
import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv

__all__ = ["sweep", "parse_degrees", "degrees_label", "SETTING_DIMS"]

#: Dims a sweep adds, outermost first.
SETTING_DIMS = ("method", "degrees", "window")
# ``period`` (repeated periods, averaged by identify) belongs to one experiment's record
_CORE_DIMS = (cv.TIME, cv.SLOW_TIME, cv.INPUT, cv.OUTPUT, cv.PERIOD)
_PER_SETTING_ATTRS = ("method", "window", "window_bins", "degrees", "parameters_per_row", "title")


def parse_degrees(value) -> tuple[int, int, int]:
    """``(Rn, Rm, Rd)`` from a label ``"Rn-Rm-Rd"`` or a sequence of three integers.

    Parameters
    ----------
    value : str or sequence of int
        ``"3-3-3"``, ``"3,3,3"`` or ``(3, 3, 3)``.

    Returns
    -------
    tuple of int

    Examples
    --------
    >>> parse_degrees("3-2-1"), parse_degrees((2, 2, 0))
    ((3, 2, 1), (2, 2, 0))
    """
    parts = value.replace(",", "-").split("-") if isinstance(value, str) else value
    try:
        out = tuple(int(p) for p in parts)
    except (TypeError, ValueError):
        out = ()
    if len(out) != 3 or min(out) < 0:
        raise ValueError(
            f"degrees {value!r} is not three non-negative integers Rn-Rm-Rd (numerator, "
            "transient, denominator); write e.g. '3-3-3' or (3, 3, 3)."
        )
    return out


def degrees_label(degrees) -> str:
    """The ``"Rn-Rm-Rd"`` label of a degrees triple (the ``degrees`` coordinate of a sweep).

    Parameters
    ----------
    degrees : tuple of int or str
        ``(Rn, Rm, Rd)`` or a label such as ``"3-3-3"`` (anything :func:`parse_degrees`
        accepts).

    Returns
    -------
    str
        ``"Rn-Rm-Rd"``.

    Examples
    --------
    >>> degrees_label((3, 3, 0))
    '3-3-0'
    """
    return "-".join(str(d) for d in parse_degrees(degrees))


def _as_list(value, what: str) -> list:
    if isinstance(value, (str, int, np.integer)):
        return [value]
    if not isinstance(value, Iterable):
        raise TypeError(f"{what} must be a value or a sequence of values, got {type(value).__name__}.")
    items = list(value)
    if not items:
        raise ValueError(f"{what} is empty; give at least one setting.")
    return items


def _degrees_list(degrees) -> list[tuple[int, int, int]]:
    if degrees is None:
        return [(3, 3, 3)]
    if isinstance(degrees, str):
        return [parse_degrees(degrees)]
    items = _as_list(degrees, "degrees")
    if len(items) == 3 and all(isinstance(d, (int, np.integer)) for d in items):
        return [parse_degrees(items)]  # one triple, not three settings
    return [parse_degrees(d) for d in items]


def _unique(items, what):
    seen = []
    for it in items:
        if it in seen:
            raise ValueError(f"{what} lists {it!r} twice; give each setting once.")
        seen.append(it)
    return seen


def _effective_degrees(method: str, degrees):
    """The LPM is the LRM with denominator degree 0: its ``Rd`` is ignored (set to 0)."""
    return (degrees[0], degrees[1], 0) if method == "lpm" else tuple(degrees)


def _leading_dims(ds: xr.Dataset) -> list[str]:
    return [d for d in ds["r"].dims if d not in _CORE_DIMS]


def _chunked(ds: xr.Dataset) -> xr.Dataset:
    """Dask-backed copy with one chunk per experiment and whole records per chunk.

    ``identify`` needs the time and channel dims in one chunk; along the leading dims a
    chunk per experiment is the natural unit of parallel work (and of memory).
    """
    chunks = {d: -1 for d in _CORE_DIMS if d in ds.dims}
    for d in _leading_dims(ds):
        if ds["r"].chunks is None:
            chunks[d] = 1 if d == cv.EXPERIMENT else -1
    return ds.chunk(chunks)


def _probe(ds: xr.Dataset, lead: list[str]) -> xr.Dataset:
    """One synthetic experiment with the shape, coords and attrs of ``ds`` (random data).

    Random signals excite every lifted channel, so ``identify`` on the probe fails only for
    reasons of the settings, and gives the exact output structure without touching the data.
    """
    one = ds.isel({d: 0 for d in lead}, drop=True)
    one = one.drop_vars([c for c in one.coords if c not in one.dims and not set(one[c].dims) <= set(_CORE_DIMS)])
    rng = np.random.default_rng(0)
    data = {name: (one[name].dims, rng.standard_normal(one[name].shape), one[name].attrs)
            for name in ("r", "u", "y")}
    if cv.PERIOD in one["r"].dims:  # r repeats over periods (the contract)
        r = one["r"]
        period0 = r.isel({cv.PERIOD: 0})
        repeated = period0.copy(data=rng.standard_normal(period0.shape)).broadcast_like(r)
        data["r"] = (r.dims, repeated.transpose(*r.dims).values, r.attrs)
    return xr.Dataset(data, coords=one.coords, attrs=ds.attrs)


def _template(frf: xr.Dataset, ds: xr.Dataset, lead: list[str]) -> xr.Dataset:
    """Lazy zeros shaped like the result of ``identify`` on all of ``ds`` (for map_blocks)."""
    lead_chunks = tuple(ds["r"].chunks[ds["r"].get_axis_num(d)] for d in lead)
    lead_shape = tuple(ds.sizes[d] for d in lead)
    variables = {}
    for name, var in frf.data_vars.items():
        data = dsa.zeros(lead_shape + var.shape, dtype=var.dtype,
                         chunks=lead_chunks + tuple((s,) for s in var.shape))
        variables[name] = (tuple(lead) + var.dims, data, var.attrs)
    out = xr.Dataset(variables, coords=frf.coords, attrs=frf.attrs)
    # identify copies the experiment's coords that fit the output dims; so does the template
    for name in ds.coords:
        if name not in out.coords and set(ds[name].dims) <= set(out.dims):
            out = out.assign_coords({name: ds[name]})
    return out


def _identify_block(block: xr.Dataset, **settings) -> xr.Dataset:
    from lcmr_xr.identification import identify

    return identify(block, errors="ignore", **settings)


def _check_settings(windows, degrees_list, methods, closed_loop):
    if closed_loop not in ("indirect", "direct"):
        raise ValueError(f"closed_loop must be 'indirect' or 'direct', got {closed_loop!r}.")
    for m in methods:
        if m not in ("lrm", "lpm"):
            raise ValueError(f"method {m!r} is unknown; use 'lrm' and/or 'lpm'.")
    for w in windows:
        if isinstance(w, (bool, np.bool_)) or int(w) != w:
            raise ValueError(f"window {w!r} is not an integer half-width; use e.g. window=[10, 20, 30].")


def sweep(experiments: xr.Dataset, *, window=(30,), degrees=None, method=("lrm",),
          closed_loop: str = "indirect", covariance: bool = True) -> xr.Dataset:
    """Identify experiments for every combination of settings; one lazy FRF dataset.

    Parameters
    ----------
    experiments : xarray.Dataset
        Experiment dataset (``lcmr-xr-1``), typically with a leading ``experiment`` dim,
        e.g. from :func:`lcmr_xr.scaleout.open_archive`.  numpy-backed data are chunked one
        experiment per chunk; dask-backed data keep their leading chunks (time and channel
        dims are merged into one chunk).
    window : int or sequence of int, default (30,)
        Local window half-widths ``n`` (``2 n + 1`` slow bins each).
    degrees : str, (int, int, int) or sequence of them, optional
        Local model degrees ``(Rn, Rm, Rd)``, as triples or labels ``"Rn-Rm-Rd"``; default
        ``"3-3-3"``.  For ``method="lpm"`` the denominator degree is 0 whatever ``Rd`` says
        (the LPM is the LRM without denominator), so ``degrees="3-3-3"`` with LPM fits
        ``(3, 3, 0)``; the coordinate ``denominator_degree`` (method, degrees) records it.
    method : str or sequence of str, default ("lrm",)
        ``"lrm"`` and/or ``"lpm"``.
    closed_loop : {"indirect", "direct"}, default "indirect"
        Passed to :func:`lcmr_xr.identify` (not swept).
    covariance : bool, default True
        Passed to :func:`lcmr_xr.identify`: compute ``P_std`` and the lifted std's.

    Returns
    -------
    xarray.Dataset
        Dask-backed: the variables of :func:`lcmr_xr.identify` with leading dims
        ``method``, ``degrees``, ``window`` (always present, also for a single value), then
        the leading dims of ``experiments``.  Coordinates: ``method`` (str), ``degrees``
        (str ``"Rn-Rm-Rd"``), ``window`` (int) with integer ``numerator_degree``,
        ``transient_degree`` on ``degrees`` and ``denominator_degree``,
        ``parameters_per_row`` on (``method``, ``degrees``).  Computing it runs every
        (setting, experiment chunk) as one task on the current dask scheduler.
        Bins that cannot be estimated are NaN with the flags ``P_flag``, ``s_singular``,
        ``ill_posed`` (``identify(..., errors="ignore")``): a failed bin is data.

    Raises
    ------
    ValueError
        Before anything is computed, listing every invalid combination: a window too small
        for the number of local parameters, a window wider than the spectrum, unknown
        methods or malformed degrees.  Data errors (NaN in the data, an excitation that
        does not excite every lifted channel) are raised by the tasks when computed.

    Examples
    --------
    >>> from lcmr_xr import hdd
    >>> import xarray as xr
    >>> exps = xr.concat([hdd.simulate(n_samples=1200, seed=s) for s in (0, 1)], "experiment")
    >>> res = sweep(exps, window=[20, 30], degrees=["2-2-2", "3-3-3"])
    >>> dict(res.P.sizes)
    {'method': 1, 'degrees': 2, 'window': 2, 'experiment': 2, 'frequency': 601, 'output': 1, 'input': 2}
    >>> res.P.chunks is not None
    True
    """
    from lcmr_xr.experiment import validate_experiment
    from lcmr_xr.identification import identify
    from lcmr_xr.kernels.local_models import parameters_per_row

    if not isinstance(experiments, xr.Dataset):
        raise TypeError(f"sweep expects an experiment Dataset, got {type(experiments).__name__}; "
                        "open an archive with lcmr_xr.scaleout.open_archive.")
    windows = _unique([int(w) if not isinstance(w, (bool, np.bool_)) and int(w) == w else w
                       for w in _as_list(window, "window")], "window")
    degrees_list = _unique(_degrees_list(degrees), "degrees")
    methods = _unique([str(m) for m in _as_list(method, "method")], "method")
    _check_settings(windows, degrees_list, methods, closed_loop)

    ds = experiments
    lead = _leading_dims(ds)
    if ds["r"].chunks is None:
        validate_experiment(ds)  # in memory: cheap, and errors surface here, not in a task
    ds = _chunked(ds)
    probe = _probe(ds, lead)

    # Build every setting's probe result first: all invalid settings are reported at once.
    probes, problems = {}, []
    for m, deg, w in itertools.product(methods, degrees_list, windows):
        eff = _effective_degrees(m, deg)
        try:
            probes[m, deg, w] = identify(probe, method=m, window=w, degrees=eff,
                                         closed_loop=closed_loop, covariance=covariance,
                                         errors="ignore")
        except ValueError as err:
            problems.append(f"method={m}, degrees={degrees_label(deg)}, window={w}: {err}")
    if problems:
        raise ValueError(
            f"{len(problems)} of {len(probes) + len(problems)} sweep settings are invalid for "
            f"these experiments (nothing was computed); remove them from the sweep:\n  - "
            + "\n  - ".join(problems)
        )

    nested = []
    for m in methods:
        per_degree = []
        for deg in degrees_list:
            per_window = []
            for w in windows:
                frf = probes[m, deg, w]
                settings = dict(method=m, window=w, degrees=_effective_degrees(m, deg),
                                closed_loop=closed_loop, covariance=covariance)
                res = xr.map_blocks(_identify_block, ds, kwargs=settings,
                                    template=_template(frf, ds, lead))
                res = res.expand_dims({"method": [m], "degrees": [degrees_label(deg)], "window": [w]})
                per_window.append(res)
            per_degree.append(per_window)
        nested.append(per_degree)
    out = xr.combine_nested(nested, concat_dim=list(SETTING_DIMS), combine_attrs="drop_conflicts",
                            join="exact", compat="override", coords="minimal", data_vars="all")
    for key in _PER_SETTING_ATTRS:
        out.attrs.pop(key, None)
    nr_factor = int(ds.attrs[cv.FACTOR]) * ds.sizes[cv.INPUT]
    ppr = np.array([[parameters_per_row(nr_factor, _effective_degrees(m, d)) for d in degrees_list]
                    for m in methods])
    rd = np.array([[_effective_degrees(m, d)[2] for d in degrees_list] for m in methods])
    out = out.assign_coords({
        "method": ("method", methods, {"units": "1", "long_name": "local model (lrm: rational, lpm: polynomial)"}),
        "degrees": ("degrees", [degrees_label(d) for d in degrees_list],
                    {"units": "1", "long_name": "local model degrees Rn-Rm-Rd as requested"}),
        "window": ("window", np.array(windows, dtype=int),
                   {"units": "1", "long_name": "local window half-width n (2n+1 slow bins)"}),
        "numerator_degree": ("degrees", np.array([d[0] for d in degrees_list], dtype=int),
                             {"units": "1", "long_name": "numerator degree Rn"}),
        "transient_degree": ("degrees", np.array([d[1] for d in degrees_list], dtype=int),
                             {"units": "1", "long_name": "transient degree Rm"}),
        "denominator_degree": (("method", "degrees"), rd,
                               {"units": "1", "long_name": "denominator degree Rd used (0 for lpm)"}),
        "parameters_per_row": (("method", "degrees"), ppr,
                               {"units": "1", "long_name": "local parameters per row of Z"}),
    })
    out.attrs.update({
        "swept_settings": list(SETTING_DIMS),
        "title": f"sweep of lifted {closed_loop} closed-loop FRF estimates over {', '.join(SETTING_DIMS)}",
    })
    return out
