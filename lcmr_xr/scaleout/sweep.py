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
_CORE_DIMS = (cv.TIME, cv.SLOW_TIME, cv.INPUT, cv.OUTPUT)
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


#: Experiments per task when the sweep chunks numpy data itself: a task of several
#: experiments is worth scheduling (dask's overhead is ~1 ms per task, and a sweep of
#: 10 000 experiments x 3 settings would otherwise be 30 000 map tasks, each with one
#: extraction task per output variable).  Memory does not grow with it: a task identifies
#: its experiments one at a time.
EXPERIMENTS_PER_TASK = 8
#: Output variable of a sweep: why an experiment failed ("" when it did not).
ERROR_VAR = "experiment_error"
ERROR_ATTRS = {"units": "1", "long_name": "why the experiment could not be identified ('' if it was)"}


def _chunked(ds: xr.Dataset, per_task: int | None = None) -> xr.Dataset:
    """Dask-backed copy with whole records per chunk and several experiments per chunk.

    ``identify`` needs the time and channel dims in one chunk.  Along ``experiment``,
    numpy data get ``per_task`` (default :data:`EXPERIMENTS_PER_TASK`) experiments per
    chunk; dask data keep their chunks unless ``per_task`` is given.  Other leading dims
    are kept whole (or as chunked).
    """
    chunks = {d: -1 for d in _CORE_DIMS if d in ds.dims}
    for d in _leading_dims(ds):
        if d == cv.EXPERIMENT and (per_task is not None or ds["r"].chunks is None):
            chunks[d] = per_task or EXPERIMENTS_PER_TASK
        elif ds["r"].chunks is None:
            chunks[d] = -1
        else:  # spelled out, so that numpy coords along d (metadata) get the same chunks
            chunks[d] = ds["r"].chunks[ds["r"].get_axis_num(d)]
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


def _identify_block(block: xr.Dataset, source: str | None = None, **settings) -> xr.Dataset:
    """``identify`` one block, one experiment at a time; a bad experiment becomes a flagged result.

    One at a time: the temporaries of ``identify`` (moment table, covariance) then exist
    for one experiment, not for the whole block, so a task's peak memory does not grow
    with the experiments per task.  An experiment whose data ``identify`` refuses (NaN,
    an excitation that does not excite every lifted channel) gets NaN estimates, every
    flag set, and ``experiment_error`` naming its archive (file) and the reason.
    """
    lead = _leading_dims(block)
    if not lead:
        return _identify_or_flag(block, source, settings)
    dim = lead[0]
    parts = [_identify_or_flag(block.isel({dim: slice(i, i + 1)}), source, settings)
             for i in range(block.sizes[dim])]
    if len(parts) == 1:
        return parts[0]
    return xr.concat(parts, dim, data_vars="all", coords="minimal", compat="override",
                     join="exact", combine_attrs="override")


def _identify_or_flag(one: xr.Dataset, source, settings) -> xr.Dataset:
    from lcmr_xr.identification import identify

    lead = _leading_dims(one)
    shape = tuple(one.sizes[d] for d in lead)
    try:
        res = identify(one, errors="ignore", **settings)
        message = ""
    except ValueError as err:
        message = f"{_where(one, source)}: {err}"
        res = _failed_result(one, settings)
    return res.assign({ERROR_VAR: (tuple(lead), np.full(shape, message, dtype=object), ERROR_ATTRS)})


def _where(one: xr.Dataset, source) -> str:
    """'experiment 'e7' of archive.nc' (the file itself for a directory archive)."""
    label = (one[cv.EXPERIMENT].values.ravel()[0].item() if cv.EXPERIMENT in one.coords
             and one[cv.EXPERIMENT].size == 1 else None)
    if label is None:
        return "experiment"
    if source:
        from pathlib import Path

        from lcmr_xr.scaleout.archive import SUFFIX, _file_stem

        file = Path(source) / (_file_stem(label) + SUFFIX)
        if Path(source).is_dir() and file.is_file():
            return f"experiment {label!r} (file {file})"
        return f"experiment {label!r} of {source}"
    return f"experiment {label!r}"


def _failed_result(one: xr.Dataset, settings) -> xr.Dataset:
    """The result structure of ``identify`` for ``one``, every estimate NaN, every flag set."""
    from lcmr_xr.identification import identify

    rng = np.random.default_rng(0)
    probe = one.copy(data={name: (rng.standard_normal(one[name].shape) if name in ("r", "u", "y")
                                  else one[name].values) for name in one.data_vars})
    res = identify(probe, errors="ignore", **settings)
    filled = {}
    for name, var in res.data_vars.items():
        if var.dtype.kind == "b":
            filled[name] = var.copy(data=np.ones(var.shape, bool))
        elif var.dtype.kind in "fc":
            filled[name] = var.copy(data=np.full(var.shape, np.nan, var.dtype))
    return res.assign(filled)


def _with_error(template: xr.Dataset, ds: xr.Dataset, lead: list[str]) -> xr.Dataset:
    """The template plus the lazy ``experiment_error`` (str) variable along the leading dims."""
    chunks = tuple(ds["r"].chunks[ds["r"].get_axis_num(d)] for d in lead)
    data = dsa.full(tuple(ds.sizes[d] for d in lead), "", dtype=object, chunks=chunks)
    return template.assign({ERROR_VAR: (tuple(lead), data, ERROR_ATTRS)})


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
          closed_loop: str = "indirect", covariance: bool = True,
          experiments_per_task: int | None = None) -> xr.Dataset:
    """Identify experiments for every combination of settings; one lazy FRF dataset.

    Parameters
    ----------
    experiments : xarray.Dataset
        Experiment dataset (``lcmr-xr-1``), typically with a leading ``experiment`` dim,
        e.g. from :func:`lcmr_xr.scaleout.open_archive`.  numpy-backed data are chunked
        :data:`EXPERIMENTS_PER_TASK` experiments per chunk; dask-backed data keep their
        leading chunks (time and channel dims are merged into one chunk).
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
    experiments_per_task : int, optional
        Experiments per chunk along ``experiment`` (one task per chunk and setting);
        default: the chunks of dask data, :data:`EXPERIMENTS_PER_TASK` for numpy data.
        A task identifies its experiments one at a time, so its peak memory is that of
        one experiment plus the block's data and results.

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
        ``ill_posed`` (``identify(..., errors="ignore")``): a failed bin is data.  An
        experiment whose data cannot be identified (NaN or inf, an excitation that does
        not excite every lifted channel) is NaN with every flag set, and
        ``experiment_error`` (str; ``""`` for the others) says which experiment (its
        archive file) and why: the rest of the sweep is unaffected.

    Raises
    ------
    ValueError
        Before anything is computed, listing every invalid combination: a window too small
        for the number of local parameters, a window wider than the spectrum, unknown
        methods or malformed degrees.  Data errors are not raised: see ``experiment_error``.

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
    # metadata only: bad values become flagged experiments in the tasks, not a failed sweep
    validate_experiment(ds, check_values=False)
    if experiments_per_task is not None and (int(experiments_per_task) != experiments_per_task
                                             or experiments_per_task < 1):
        raise ValueError(f"experiments_per_task must be a positive integer, got {experiments_per_task!r}.")
    source = experiments.encoding.get("source")
    ds = _chunked(ds, experiments_per_task)
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
                res = xr.map_blocks(_identify_block, ds, kwargs={**settings, "source": source},
                                    template=_with_error(_template(frf, ds, lead), ds, lead))
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
