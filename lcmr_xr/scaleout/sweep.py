"""``sweep``: identify a stack of experiments for every combination of settings, lazily.

Each (method, degrees, window) combination is one :func:`xarray.map_blocks` over the
experiment chunks; the function run per block is :func:`lcmr_xr.identify` itself on the
in-memory block.  Why blocks and not ``identify`` on the dask dataset directly: ``identify``
validates its input, and on dask data that validation computes a pass over the data, once
per setting.  Per block, the validation runs inside the task on data already in memory, so
building the sweep reads nothing and computing it reads every experiment once per setting.

Every setting is checked by :func:`lcmr_xr.settings.estimator_settings` (the rules of
``identify``) and against the experiment's size before anything is computed, and the
output structure is derived from the layout of :func:`lcmr_xr.identify`'s result
(:func:`lcmr_xr.identification.identify.result_template`): no data are read to build it.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.settings import (
    AUTO_WINDOW,
    CLOSED_LOOP,
    METHODS,
    as_bool,
    as_choice,
    as_integer,
    check_window_fits,
    degrees_label,
    estimator_settings,
    parse_degrees,
)

__all__ = ["sweep", "sweep_settings", "parse_degrees", "degrees_label", "SETTING_DIMS"]

#: Dims a sweep adds, outermost first.
SETTING_DIMS = ("method", "degrees", "window")
# ``period`` (repeated periods, averaged by identify) belongs to one experiment's record
_CORE_DIMS = (cv.TIME, cv.SLOW_TIME, cv.INPUT, cv.OUTPUT, cv.PERIOD)
_PER_SETTING_ATTRS = ("method", "window", "window_bins", "degrees", "parameters_per_row", "title")


def _as_list(value, what: str) -> list:
    if isinstance(value, (str, int, np.integer)):
        return [value]
    if not isinstance(value, Iterable):
        raise TypeError(f"{what} must be a value or a sequence of values, got {type(value).__name__}.")
    items = list(value)
    if not items:
        raise ValueError(f"{what} is empty; give at least one setting.")
    return items


def _degrees_list(degrees, methods) -> list[tuple[int, int, int]]:
    if degrees is None:  # the methods' defaults (settings.METHODS), each once
        return list(dict.fromkeys(METHODS[m].default_degrees for m in methods))
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


def _pools(pool, ds: xr.Dataset):
    """Checked pool sizes (None: no pooling)."""
    if pool is None:
        return None
    if cv.EXPERIMENT not in ds["r"].dims:
        raise ValueError("pool groups the 'experiment' dim, which these experiments do not have; "
                         "stack them with xr.concat([...], dim='experiment') or leave pool out.")
    n_exp = ds.sizes[cv.EXPERIMENT]
    pools = _unique([as_integer(k, "pool", minimum=1, example=4) for k in _as_list(pool, "pool")],
                    "pool")
    too_big = [k for k in pools if k > n_exp]
    if too_big:
        raise ValueError(f"pool={too_big} is more than the {n_exp} experiments; use pool <= "
                         f"{n_exp} or add experiments.")
    return sorted(pools)


def _pooled(ds: xr.Dataset, pools, settings) -> xr.Dataset:
    """``identify(..., combine="experiment")`` per group of ``k`` experiments, for every
    ``k``, lazily (dims ``pool``, ``pool_group``; see :func:`sweep`)."""
    from lcmr_xr.identification import identify

    per_k = []
    for k in pools:
        groups = ds.sizes[cv.EXPERIMENT] // k
        part = ds.isel({cv.EXPERIMENT: slice(0, groups * k)})
        part = part.drop_vars([c for c in part.coords if cv.EXPERIMENT in part[c].dims])
        part = part.coarsen({cv.EXPERIMENT: k}).construct(
            {cv.EXPERIMENT: ("pool_group", cv.EXPERIMENT)})
        part = part.chunk({"pool_group": 1, cv.EXPERIMENT: -1})
        res = identify(part, combine="experiment", errors="ignore", **settings)
        drop = [v for v in res.data_vars if cv.EXPERIMENT in res[v].dims]  # transients: per k
        res = res.drop_vars(drop).assign_coords(pool_group=np.arange(groups))
        for key in (cv.POOLED_EXPERIMENTS, cv.RECORDS_AVERAGED, cv.NOISE_DOF):
            res.attrs.pop(key, None)
        per_k.append(res.expand_dims(pool=[k]))
    out = xr.concat(per_k, "pool", join="outer", combine_attrs="drop_conflicts")
    out["pool"].attrs.update(units="1", long_name="experiments pooled per estimate")
    out["pool_group"].attrs.update(units="1", long_name="group of pooled experiments")
    return out


def _identify_block(block: xr.Dataset, **settings) -> xr.Dataset:
    from lcmr_xr.identification import identify

    return identify(block, errors="ignore", **settings)


def sweep_settings(*, window=(30,), degrees=None, method=("lrm",), closed_loop="indirect",
                   covariance=True, experiments: xr.Dataset | None = None) -> dict:
    """Check every (method, degrees, window) of a sweep by the rules of ``identify``.

    All invalid combinations are reported at once, before anything is computed.  Without
    ``experiments`` only what does not depend on the data is checked (the command line
    does that before it opens the archive); with it, also that each window fits the
    number of local parameters and the length of the spectrum.

    Parameters
    ----------
    window, degrees, method, closed_loop, covariance
        As in :func:`sweep`.
    experiments : xarray.Dataset, optional
        The experiments (only sizes and the ``factor`` attribute are read).

    Returns
    -------
    dict
        ``{(method, degrees, window): EstimatorSettings}`` in sweep order, ``degrees`` as
        the requested triple.

    Raises
    ------
    TypeError, ValueError
        A malformed list or value, or (``ValueError``) the list of invalid combinations.

    Examples
    --------
    >>> list(sweep_settings(window=[20, 30], degrees=["3-3-0"], method=["lrm", "lpm"]))[:2]
    [('lrm', (3, 3, 0), 20), ('lrm', (3, 3, 0), 30)]
    """
    listed = _as_list(window, "window")
    if any(isinstance(w, str) and w == AUTO_WINDOW for w in listed):
        raise ValueError("a sweep compares fixed windows: window='auto' (chosen per bin) is not "
                         "supported here; pass integer half-widths (e.g. window=[10, 20, 30]), "
                         "or call lcmr_xr.identify(..., window='auto') per experiment.")
    windows = _unique([as_integer(w, "window", minimum=1, example=30) for w in listed], "window")
    methods = _unique([as_choice(m, "method", METHODS) for m in _as_list(method, "method")], "method")
    degrees_list = _unique(_degrees_list(degrees, methods), "degrees")
    closed_loop = as_choice(closed_loop, "closed_loop", CLOSED_LOOP)
    covariance = as_bool(covariance, "covariance")
    fits = None
    if experiments is not None:
        factor = int(np.asarray(experiments.attrs[cv.FACTOR]).item())
        fits = (factor * experiments.sizes[cv.INPUT], experiments.sizes[cv.SLOW_TIME])
    checked, problems = {}, []
    for m, deg, w in itertools.product(methods, degrees_list, windows):
        try:
            s = estimator_settings(method=m, window=w, degrees=deg, closed_loop=closed_loop,
                                   covariance=covariance, errors="ignore")
            if fits is not None:
                check_window_fits(s.window, s.degrees, *fits)
            checked[m, deg, w] = s
        except ValueError as err:
            problems.append(f"method={m}, degrees={degrees_label(deg)}, window={w}: {err}")
    if problems:
        hint = ""
        if len(methods) > 1 and any(not METHODS[m].has_denominator and d[2] != 0
                                    for m in methods for d in degrees_list):
            hint = ("\nEvery degrees entry is combined with every method, and the LPM has Rd = 0: "
                    "give degrees with Rd = 0 (e.g. '3-3-0'), or sweep method='lrm' alone with "
                    "both '3-3-3' and '3-3-0' (the LRM with Rd = 0 is the LPM).")
        where = "for these experiments " if experiments is not None else ""
        raise ValueError(
            f"{len(problems)} of {len(checked) + len(problems)} sweep settings are invalid "
            f"{where}(nothing was computed); remove them from the sweep:\n  - "
            + "\n  - ".join(problems) + hint
        )
    return checked


def sweep(experiments: xr.Dataset, *, window=(30,), degrees=None, method=("lrm",),
          closed_loop: str = "indirect", covariance: bool = True, pool=None) -> xr.Dataset:
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
        Local model degrees ``(Rn, Rm, Rd)``, as triples or labels ``"Rn-Rm-Rd"`` (the
        rules of :func:`lcmr_xr.settings.parse_degrees`); default: each method's default
        degrees (``"3-3-3"`` for LRM, ``"3-3-0"`` for LPM).  Every degrees entry is combined
        with every method, and the LPM has no denominator: with ``method="lpm"`` every
        entry needs ``Rd = 0`` (e.g. ``["2-2-0", "3-3-0"]``), or it is refused.  To compare
        LRM and LPM on other degrees, sweep ``method="lrm"`` with both ``"3-3-3"`` and
        ``"3-3-0"``: the LRM with ``Rd = 0`` is the LPM.
    method : str or sequence of str, default ("lrm",)
        ``"lrm"`` and/or ``"lpm"``.
    closed_loop : {"indirect", "direct"}, default "indirect"
        Passed to :func:`lcmr_xr.identify` (not swept).
    covariance : bool, default True
        Passed to :func:`lcmr_xr.identify`: compute ``P_std`` and the lifted std's.
    pool : int or sequence of int, optional
        Pool ``k`` experiments at a time (``identify(..., combine="experiment")``: one local
        model over ``k`` experiments with different excitations, or their average with the
        same one), for each ``k`` given: consecutive groups ``[g k, (g + 1) k)`` of the
        ``experiment`` dim (a trailing remainder of fewer than ``k`` is left out).  The result
        then has the dims ``pool`` (``k``) and ``pool_group`` (``g``) in place of
        ``experiment`` (groups a ``k`` does not fill are NaN), so the error and the band can
        be followed as the data grow.  Default: every experiment on its own.

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
        for the number of local parameters, a window wider than the spectrum, ``Rd != 0``
        with the LPM; or unknown methods, malformed degrees or non-integer windows (see
        :func:`sweep_settings`).  Data errors (NaN in the data, an excitation that does not
        excite every lifted channel) are raised by the tasks when computed.

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
    from lcmr_xr.identification.identify import result_template
    from lcmr_xr.kernels.local_models import parameters_per_row

    if not isinstance(experiments, xr.Dataset):
        raise TypeError(f"sweep expects an experiment Dataset, got {type(experiments).__name__}; "
                        "open an archive with lcmr_xr.scaleout.open_archive.")
    ds = experiments
    if ds["r"].chunks is None:
        validate_experiment(ds)  # in memory: cheap, and errors surface here, not in a task
    checked = sweep_settings(window=window, degrees=degrees, method=method,
                             closed_loop=closed_loop, covariance=covariance, experiments=ds)
    methods = list(dict.fromkeys(m for m, _, _ in checked))
    degrees_list = list(dict.fromkeys(d for _, d, _ in checked))
    windows = list(dict.fromkeys(w for _, _, w in checked))
    pools = _pools(pool, ds)
    ds = _chunked(ds)

    nested = []
    for m in methods:
        per_degree = []
        for deg in degrees_list:
            per_window = []
            for w in windows:
                s = checked[m, deg, w]
                settings = dict(method=m, window=s.window, degrees=s.degrees,
                                closed_loop=s.closed_loop, covariance=s.covariance)
                if pools is None:
                    res = xr.map_blocks(_identify_block, ds, kwargs=settings,
                                        template=result_template(ds, s))
                else:
                    res = _pooled(ds, pools, settings)
                res = res.expand_dims({"method": [m], "degrees": [degrees_label(deg)], "window": [w]})
                per_window.append(res)
            per_degree.append(per_window)
        nested.append(per_degree)
    out = xr.combine_nested(nested, concat_dim=list(SETTING_DIMS), combine_attrs="drop_conflicts",
                            join="exact", compat="override", coords="minimal", data_vars="all")
    for key in _PER_SETTING_ATTRS:
        out.attrs.pop(key, None)
    nr_factor = int(ds.attrs[cv.FACTOR]) * ds.sizes[cv.INPUT]
    used = [[checked[m, d, windows[0]].degrees for d in degrees_list] for m in methods]
    ppr = np.array([[parameters_per_row(nr_factor, d) for d in row] for row in used])
    rd = np.array([[d[2] for d in row] for row in used])
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
