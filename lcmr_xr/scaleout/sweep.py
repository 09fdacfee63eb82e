"""``sweep``: identify a stack of experiments for every combination of settings, lazily.

Each (method, degrees, window) combination is one :func:`xarray.map_blocks` over the
experiment chunks; the function run per block is :func:`lcmr_xr.identify` itself on the
in-memory block.  Why blocks and not ``identify`` on the dask dataset directly: ``identify``
validates its input, and on dask data that validation computes a pass over the data, once
per setting.  Per block, the validation runs inside the task on data already in memory, so
building the sweep reads nothing and computing it reads every experiment once per setting.
A task holds several experiments (:data:`EXPERIMENTS_PER_TASK`, so a sweep of 10 000
experiments is not 10 000 tiny tasks per setting) and identifies them one at a time (its
memory is that of one ``identify``); an experiment that cannot be identified becomes a
flagged result with the reason in ``experiment_error``, not a failed sweep.

Every setting is checked by :func:`lcmr_xr.settings.estimator_settings` (the rules of
``identify``) and against the experiment's size before anything is computed, and the
output structure is derived from the layout of :func:`lcmr_xr.identify`'s result
(:func:`lcmr_xr.identification.identify.result_template`): no data are read to build it.
"""

from __future__ import annotations

import itertools
import numbers
import os
from collections.abc import Iterable

import dask.array as dsa
import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.experiment.dataset import experiment_factor
from lcmr_xr.settings import (
    AUTO_WINDOW,
    CLOSED_LOOP,
    METHODS,
    DEFAULT_DENOMINATOR,
    POOLED_DEFAULT_DENOMINATOR,
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
_PER_SETTING_ATTRS = ("method", "window", "window_bins", "degrees", "parameters_per_row", "title",
                      cv.DENOMINATOR, cv.IV_FIRST_WINDOW)


def _as_list(value, what: str) -> list:
    # any scalar is one setting, for the setting's own check to judge (window=30.0 is 30,
    # window=12.5 is refused as fractional), not a "sequence" error
    if isinstance(value, (str, numbers.Number, np.generic)):
        return [value]
    if isinstance(value, (np.ndarray, xr.DataArray)) and value.ndim == 0:
        return [value]  # one number (a sweep choice's .values): as_integer reads it
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


#: Experiments per task when the sweep chunks numpy data itself: a task of several
#: experiments is worth scheduling (dask's overhead is ~1 ms per task, and a sweep of
#: 10 000 experiments x 3 settings would otherwise be 30 000 map tasks, each with one
#: extraction task per output variable).  Memory does not grow with it: a task identifies
#: its experiments one at a time.
EXPERIMENTS_PER_TASK = 8
#: Output variable of a sweep: why an experiment failed ("" when it did not).
ERROR_VAR = cv.EXPERIMENT_ERROR
ERROR_ATTRS = {"units": "1", "long_name": "why the experiment could not be identified ('' if it was)"}


def _chunked(ds: xr.Dataset, per_task: int | None = None) -> xr.Dataset:
    """Dask-backed copy with whole records per chunk and several experiments per chunk.

    ``identify`` needs the time and channel dims in one chunk.  Along ``experiment``,
    numpy data get ``per_task`` (default :data:`EXPERIMENTS_PER_TASK`) experiments per
    chunk; dask data keep their chunks unless ``per_task`` is given.  Other leading dims
    are kept whole (or as chunked).
    """
    chunks = {d: -1 for d in _CORE_DIMS if d in ds.dims}
    if per_task is not None:  # 2.0 from a caller that checked it: an int for dask
        per_task = as_integer(per_task, "experiments_per_task", minimum=1, example=EXPERIMENTS_PER_TASK)
    for d in _leading_dims(ds):
        if d == cv.EXPERIMENT and (per_task is not None or ds["r"].chunks is None):
            chunks[d] = per_task or EXPERIMENTS_PER_TASK
        elif ds["r"].chunks is None:
            chunks[d] = -1
        else:  # spelled out, so that numpy coords along d (metadata) get the same chunks
            chunks[d] = ds["r"].chunks[ds["r"].get_axis_num(d)]
    return _damaged_files_flagged(ds.chunk(chunks))


def _damaged_files_flagged(ds: xr.Dataset) -> xr.Dataset:
    """``ds`` whose reads of a directory archive's files give NaN for a damaged file (one
    whose values HDF5 cannot read), so that its experiment is flagged with the reason
    (:func:`_identify_or_flag`) instead of the task failing and the sweep with it."""
    from lcmr_xr.scaleout.directory import reading_damaged_as_nan

    out = {name: var.copy(data=reading_damaged_as_nan(var.data)) for name, var in ds.data_vars.items()
           if var.chunks is not None}
    return ds.assign(out) if out else ds


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


def _identify_block(block: xr.Dataset, source: str | None = None, drop=(), carried=None,
                    setting=None, **settings) -> xr.Dataset:
    """``identify`` one block, one experiment at a time; a bad experiment becomes a flagged result.

    One at a time: the temporaries of ``identify`` (moment table, covariance) then exist
    for one experiment, not for the whole block, so a task's peak memory does not grow
    with the experiments per task.  An experiment whose data ``identify`` refuses (NaN,
    an excitation that does not excite every lifted channel) gets NaN estimates, every
    flag set, and ``experiment_error`` naming its archive (file) and the reason.
    ``drop``: coordinates left out of the block's result (see :func:`_new_indexes`);
    ``carried``: coordinates of the record put back on the block (see :func:`_carried`);
    ``setting``: ``{dim: value}`` of the sweep's setting dims, added to the result as
    leading dims of size one (see :func:`_setting_template`).
    """
    if carried:
        block = block.assign_coords(carried)
    labels = [name for name in block.data_vars if name.startswith(_LABELS)]
    if labels:  # the leading dims' labels, as dask data (see _labels_as_data)
        block = block.assign_coords({block[name].dims[0]: block[name].values for name in labels})
        block = block.drop_vars(labels)
    lead = _leading_dims(block)
    if not lead:
        res = _identify_or_flag(block, source, settings)
    else:
        res = _identify_stacked(block, source, settings) if len(lead) == 1 else None
        if res is None:
            dim = lead[0]
            parts = [_identify_or_flag(block.isel({dim: slice(i, i + 1)}), source, settings)
                     for i in range(block.sizes[dim])]
            res = parts[0] if len(parts) == 1 else xr.concat(
                parts, dim, data_vars="all", coords="minimal", compat="override", join="exact",
                combine_attrs="override")
    if setting:
        res = res.expand_dims({d: [v] for d, v in setting.items()})
    return res.drop_vars(list(drop))


def _identify_stacked(block: xr.Dataset, source, settings) -> xr.Dataset | None:
    """``identify`` of each experiment of ``block`` (one leading dim) through the unlabelled
    kernel, the results stacked and labelled once; None where this path does not apply.

    Why: labelling a result (19 variables, their coordinates and attributes) and
    concatenating the labelled results cost about as much per experiment as a third of
    the kernel itself; here the block is checked and labelled once.  The result is
    identical to ``identify`` per experiment concatenated along the leading dim (tested).
    The arrays are those of :func:`_stacked_outputs`.
    """
    from lcmr_xr.identification.identify import _label, _settings_attrs

    got = _stacked_outputs(block, source, settings)
    if got is None:
        return None
    res = xr.Dataset({name: (dims, values) for name, (dims, values) in got.arrays.items()
                      if name != ERROR_VAR})
    res = _label(res, got.ds, factor=got.factor, th=got.th)
    res.attrs.update(_settings_attrs(got.ds, got.settings, factor=got.factor, th=got.th))
    dims, errors = got.arrays[ERROR_VAR]
    return res.assign({ERROR_VAR: (dims, errors, ERROR_ATTRS)})


class _Stacked:
    """What :func:`_stacked_outputs` returns: ``arrays`` ``{name: (dims, values)}`` (the
    variables of ``identify`` in its order, then ``experiment_error``), and what labelling
    them needs: the validated block ``ds``, the checked ``settings``, ``factor``, ``th``."""

    __slots__ = ("arrays", "ds", "settings", "factor", "th")

    def __init__(self, arrays, ds, settings, factor, th):
        self.arrays, self.ds, self.settings, self.factor, self.th = arrays, ds, settings, factor, th


def _stacked_outputs(block: xr.Dataset, source, settings, keep=None) -> _Stacked | None:
    """The unlabelled outputs of ``identify`` for each experiment of ``block`` (one leading
    dim), stacked along it; None where this path does not apply.

    The kernel is :func:`lcmr_xr.identification.identify.record_kernel`, the one
    ``identify``'s eager path calls, so the values are those of ``identify``.  An
    experiment the kernel refuses (NaN or inf, an excitation that does not excite every
    lifted channel) goes through :func:`_identify_or_flag`, so its flagged result and
    message are those of ``identify``.  Records with repeated periods (averaged by
    ``identify``) and block-level problems (a window that does not fit) take the
    per-experiment path (None).  ``sweep_to_disk`` writes these arrays to its part files
    as they are (its result gets its labels from the lazy sweep), :func:`_identify_stacked`
    labels them.  ``keep``: the names of the variables to return (default: all); the
    others are dropped as each experiment finishes, so a task that writes ``P``, ``P_std``,
    ``P_flag`` does not hold the 1.27 MB of every variable per experiment.
    """
    from lcmr_xr.experiment import validate_experiment
    from lcmr_xr.identification.identify import output_specs, record_kernel
    from lcmr_xr.transforms._coords import even_spacing

    if cv.PERIOD in block.dims:
        return None
    dim = _leading_dims(block)[0]
    try:
        s = estimator_settings(**settings, errors="ignore")
        ds = validate_experiment(block, check_values=False)
        factor = experiment_factor(ds)
        nu, ny = ds.sizes[cv.INPUT], ds.sizes[cv.OUTPUT]
        check_window_fits(s.window, s.degrees, factor * nu, ds.sizes[cv.SLOW_TIME])
        th = even_spacing(ds[cv.TIME].values, cv.TIME)[1]
    except ValueError:  # every experiment fails alike: identify says why, per experiment
        return None
    specs = output_specs(s.closed_loop)
    kernel = record_kernel(s, factor=factor, n=ds.sizes[cv.TIME], nu=nu, th=th, check_rank=True,
                           split=dict(specs=specs, factor=factor, nu=nu, ny=ny,
                                      closed_loop=s.closed_loop))
    wanted = [j for j, (name, _, _) in enumerate(specs) if keep is None or name in keep]
    r, u = (ds[v].transpose(dim, cv.TIME, cv.INPUT).values for v in ("r", "u"))
    y = ds["y"].transpose(dim, cv.SLOW_TIME, cv.OUTPUT).values
    n_exp = ds.sizes[dim]
    outs, errors = [], np.full(n_exp, "", dtype=object)
    for i in range(n_exp):
        one = slice(i, i + 1)  # a leading axis of one, as identify's apply_ufunc passes it
        try:
            out = kernel(r[one], u[one], y[one])
        except ValueError:  # identify's own check and message, and the flagged result
            flagged = _identify_or_flag(ds.isel({dim: one}), source, settings)
            errors[i] = flagged[ERROR_VAR].values[0]
            out = tuple(flagged[name].transpose(dim, *dims).values for name, dims, _ in specs)
        outs.append(tuple(out[j] for j in wanted))
    arrays = {specs[j][0]: ((dim, *specs[j][1]), np.concatenate([o[k] for o in outs]))
              for k, j in enumerate(wanted)}
    arrays[ERROR_VAR] = ((dim,), errors)
    return _Stacked(arrays, ds, s, factor, th)


def _block_arrays(block: xr.Dataset, source: str | None = None, keep=None,
                 **settings) -> dict:
    """The data variables of :func:`_identify_block` (``keep`` only, when given) as
    ``{name: (dims, values)}``, unlabelled where the block allows it.

    What a task of ``sweep_to_disk`` writes to its part: the result there takes its
    coordinates and attributes from the lazy sweep, so a labelled block would be thrown
    away (labelling cost 0.4-0.7 ms CPU per experiment, and writing the labelled block
    with xarray 5.3-6.0 ms against 2.6 ms for the values; measured).  Blocks the
    unlabelled path does not take (repeated periods, a window that does not fit) go
    through :func:`_identify_block`; the values are the same either way.
    """
    got = (_stacked_outputs(block, source, settings, keep) if len(_leading_dims(block)) == 1
           else None)
    if got is not None:
        arrays = got.arrays
    else:
        res = _identify_block(block, source, **settings)
        arrays = {name: (res[name].dims, res[name].values) for name in res.data_vars}
    return {name: arrays[name] for name in arrays if keep is None or name in keep}


def _new_indexes(template: xr.Dataset, ds: xr.Dataset) -> list:
    """Index coordinates of the result that the experiments do not have (``frequency``, ...).

    Why they are left out of the blocks and put back on the whole result: ``map_blocks``
    tokenizes (pickles) every new index once per block, which for a sweep of 10 000
    experiments (625 blocks x 5 indexes x 3 settings) was 4 of its 5 s of graph building.
    The values are the template's; ``identify`` in the blocks computes the same ones.
    """
    return [name for name in template.xindexes if name not in ds.xindexes]


def _setting_template(template: xr.Dataset, setting: dict) -> xr.Dataset:
    """``template`` with the setting dims (size one, one chunk) in front of every variable.

    Built from new lazy arrays rather than with ``expand_dims``, which slices every dask
    variable of the template (19 variables x 3 settings: a second of graph building for
    10 000 experiments); the tasks add the dims to their results themselves.
    """
    lead = tuple(setting)
    variables = {}
    for name, var in template.data_vars.items():
        data = dsa.empty((1,) * len(lead) + var.shape, dtype=var.dtype,
                         chunks=((1,),) * len(lead) + var.chunks)
        variables[name] = (lead + var.dims, data, var.attrs)
    out = xr.Dataset(variables, coords=template.coords, attrs=template.attrs)
    return out.assign_coords({d: [v] for d, v in setting.items()})


def _input_coords(res: xr.Dataset, experiments: xr.Dataset) -> dict:
    """The experiments' own non-index coordinates (metadata along ``experiment``) for the
    same names on a ``map_blocks`` result.

    Why: ``map_blocks`` returns every coordinate of its template as an output of its
    tasks, so a result variable replaced by another computation (``sweep_to_disk``
    assembles the result from its part files) still pulled the metadata, and with it
    the whole sweep, through the identify tasks again (measured: the assembly of 32
    experiments ran all 32 identify calls a second time).
    """
    return {name: experiments[name].variable for name in res.coords
            if name in experiments.coords and name not in res.xindexes
            and experiments[name].dims == res[name].dims}


def _carried(ds: xr.Dataset) -> dict:
    """Coordinates that do not vary along the leading dims (``time``, ``slow_time``,
    ``input``, ``output``, scalars): handed to every task whole instead of being cut out
    of ``ds`` per block.

    Why: ``map_blocks`` subsets every coordinate of its input per block and tokenizes
    the pieces (an index is converted to a numpy array and hashed: 29 kB for ``time`` of
    an N = 3600 experiment); for a sweep of 10 000 experiments (625 blocks x 3 settings)
    that was most of the graph-building time.  Passed as a keyword argument, each is
    tokenized once per setting and referenced by every task.
    """
    lead = set(_leading_dims(ds))
    return {name: ds[name].variable for name in ds.coords if not lead & set(ds[name].dims)}


#: Prefix of the data variables that carry the leading dims' labels into the blocks.
_LABELS = "_labels_of_"


def _labels_as_data(ds: xr.Dataset, lead: list[str]) -> xr.Dataset:
    """The leading dims' index coordinates as dask data variables chunked like the data.

    Why: ``map_blocks`` converts a string index (the ``experiment`` labels) to a whole
    numpy array for every block it cuts (10 000 labels x 625 blocks x 3 settings: seconds
    of graph building); a dask variable is cut by slicing the graph.  The blocks turn
    them back into coordinates (:func:`_identify_block`), and the labels are put back on
    the whole result.
    """
    out = ds
    for d in lead:
        if d in ds.xindexes:
            chunks = ds["r"].chunks[ds["r"].get_axis_num(d)]
            data = dsa.from_array(ds[d].values, chunks=(chunks,))
            out = out.drop_vars(d).assign({_LABELS + d: ((d,), data)})
    return out


def _identify_or_flag(one: xr.Dataset, source, settings) -> xr.Dataset:
    from lcmr_xr.identification import identify

    lead = _leading_dims(one)
    shape = tuple(one.sizes[d] for d in lead)
    try:
        res = identify(one, errors="ignore", **settings)
        message = ""
    except ValueError as err:
        message = f"{_where(one, source)}: {_damage(one, source) or err}"
        res = _failed_result(one, settings)
    return res.assign({ERROR_VAR: (tuple(lead), np.full(shape, message, dtype=object), ERROR_ATTRS)})


def _sources(ds: xr.Dataset) -> tuple[str, ...]:
    """The archive directories whose files the lazy data of ``ds`` read
    (:func:`lcmr_xr.scaleout.directory.directories_read`): where an experiment's file is
    looked for, also after operations that drop ``encoding["source"]`` (``astype``)."""
    from lcmr_xr.scaleout.directory import directories_read

    found = {}
    for var in ds.data_vars.values():
        if var.chunks is not None:
            found.update(dict.fromkeys(directories_read(var.data)))
    return tuple(found)


def _label_and_file(one: xr.Dataset, source):
    """The label of experiment ``one`` (None: no single label) and its file in the archive
    directory ``source`` (or the first of several directories holding a file of its name;
    None: no such file)."""
    label = (one[cv.EXPERIMENT].values.ravel()[0].item() if cv.EXPERIMENT in one.coords
             and one[cv.EXPERIMENT].size == 1 else None)
    if label is None or not source:
        return label, None
    from pathlib import Path

    from lcmr_xr.scaleout.archive import SUFFIX, _file_stem, _nc_names

    stem = _file_stem(label)
    for place in ((source,) if isinstance(source, str) else source):
        file = Path(place) / (stem + SUFFIX)  # the name the library's writers give it
        if Path(place).is_dir() and file.is_file():
            return label, file
    for place in ((source,) if isinstance(source, str) else source):  # another NetCDF
        if Path(place).is_dir():  # ending (x.NC, x.nc4): listed only on this error path
            name = next((n for n in _nc_names(Path(place)) if os.path.splitext(n)[0] == stem), None)
            if name is not None:
                return label, Path(place) / name
    return label, None


def _where(one: xr.Dataset, source) -> str:
    """'experiment 'e7' of archive.nc' (the file itself for a directory archive)."""
    label, file = _label_and_file(one, source)
    if label is None:
        return "experiment"
    if file is not None:
        return f"experiment {label!r} (file {file})"
    if not source:
        return f"experiment {label!r}"
    return f"experiment {label!r} of {source if isinstance(source, str) else ', '.join(source)}"


def _damage(one: xr.Dataset, source) -> str | None:
    """Why the file of experiment ``one`` of a directory archive cannot be read (None: it
    can, or there is none): its NaN then came from the damaged file (:func:`_chunked`)."""
    from lcmr_xr.scaleout.directory import damage

    file = _label_and_file(one, source)[1]
    return None if file is None else damage(file)


def _failed_result(one: xr.Dataset, settings) -> xr.Dataset:
    """The result structure of ``identify`` for ``one``, every estimate NaN, every flag set.

    Derived from :func:`~lcmr_xr.identification.identify.result_template` (the layout of
    ``identify``'s result), so no estimate is computed for an experiment that failed.
    """
    from lcmr_xr.identification.identify import result_template

    res = result_template(one, estimator_settings(**settings, errors="ignore")).compute()
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


def sweep_settings(*, window=(30,), degrees=None, method=("lrm",), closed_loop="indirect",
                   covariance=True, experiments: xr.Dataset | None = None,
                   denominator=None) -> dict:
    """Check every (method, degrees, window) of a sweep by the rules of ``identify``.

    All invalid combinations are reported at once, before anything is computed.  Without
    ``experiments`` only what does not depend on the data is checked (the command line
    does that before it opens the archive); with it, also that each window fits the
    number of local parameters and the length of the spectrum.

    Parameters
    ----------
    window, degrees, method, closed_loop, covariance, denominator
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
        factor = experiment_factor(experiments)
        fits = (factor * experiments.sizes[cv.INPUT], experiments.sizes[cv.SLOW_TIME])
    checked, problems = {}, []
    for m, deg, w in itertools.product(methods, degrees_list, windows):
        try:
            s = estimator_settings(method=m, window=w, degrees=deg, closed_loop=closed_loop,
                                   covariance=covariance, errors="ignore", denominator=denominator)
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
          closed_loop: str = "indirect", covariance: bool = True,
          experiments_per_task: int | None = None, pool=None, denominator=None) -> xr.Dataset:
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
    experiments_per_task : int, optional
        Experiments per chunk along ``experiment`` (one task per chunk and setting);
        default: the chunks of dask data, :data:`EXPERIMENTS_PER_TASK` for numpy data.
        A task identifies its experiments one at a time, so its peak memory is that of
        one experiment plus the block's data and results.
    pool : int or sequence of int, optional
        Pool ``k`` experiments at a time (``identify(..., combine="experiment")``: one local
        model over ``k`` experiments with different excitations, or their average with the
        same one), for each ``k`` given: consecutive groups ``[g k, (g + 1) k)`` of the
        ``experiment`` dim (a trailing remainder of fewer than ``k`` is left out).  The result
        then has the dims ``pool`` (``k``) and ``pool_group`` (``g``) in place of
        ``experiment`` (groups a ``k`` does not fill are NaN), so the error and the band can
        be followed as the data grow.  Default: every experiment on its own.
    denominator : {None, "ls", "iv"}, optional
        Passed to :func:`lcmr_xr.identify` for every setting with a denominator (``"iv"``
        with a method or degrees without one, ``Rd = 0``, is an invalid combination);
        recorded as the coordinate ``denominator_fit`` (``"ls"``, ``"iv"`` or ``"none"``;
        with ``pool`` and the default, ``"iv"``: identify's default for pooled experiments).

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
        not excite every lifted channel, a file of an archive directory whose values
        cannot be read: damaged) is NaN with every flag set, and
        ``experiment_error`` (str; ``""`` for the others) says which experiment (its
        archive file) and why: the rest of the sweep is unaffected.  A file that no
        longer opens (removed or moved out after the archive was opened, no permission)
        is not data: its read fails the computation, naming the file.  Compute the
        result on its own (``.compute()``, or :func:`lcmr_xr.scaleout.sweep_to_disk`):
        in ONE ``dask.compute`` together with another use of the same lazy archive
        (e.g. ``dask.compute(sweep(ds, ...), ds.r.sum())``) both share the archive's
        read tasks (the same keys), so a damaged file may then fail the whole
        computation with ``DamagedFile`` instead of being flagged, or be read as NaN by
        the other use.

    Raises
    ------
    ValueError
        Before anything is computed, listing every invalid combination: a window too small
        for the number of local parameters, a window wider than the spectrum, ``Rd != 0``
        with the LPM; or unknown methods, malformed degrees, non-integer windows (see
        :func:`sweep_settings`) or an ``experiments_per_task`` below 1 or fractional (a
        non-number is a ``TypeError``).  Data errors are not
        raised: see ``experiment_error``.

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
    lead = _leading_dims(ds)
    # metadata only: bad values become flagged experiments in the tasks, not a failed sweep
    validate_experiment(ds, check_values=False)
    if experiments_per_task is not None:  # the settings' integer rule: 2.0 yes, 2.5 no, "2" no
        experiments_per_task = as_integer(experiments_per_task, "experiments_per_task", minimum=1,
                                          example=EXPERIMENTS_PER_TASK)
    checked = sweep_settings(window=window, degrees=degrees, method=method,
                             closed_loop=closed_loop, covariance=covariance, experiments=ds,
                             denominator=denominator)
    methods = list(dict.fromkeys(m for m, _, _ in checked))
    degrees_list = list(dict.fromkeys(d for _, d, _ in checked))
    windows = list(dict.fromkeys(w for _, _, w in checked))
    pools = _pools(pool, ds)
    ds = _chunked(ds, experiments_per_task)
    source = _sources(ds) or experiments.encoding.get("source")
    carried = _carried(ds)
    blocks_in = _labels_as_data(ds.drop_vars(list(carried)), lead)

    nested = []
    for m in methods:
        per_degree = []
        for deg in degrees_list:
            per_window = []
            for w in windows:
                s = checked[m, deg, w]
                settings = dict(method=m, window=s.window, degrees=s.degrees,
                                closed_loop=s.closed_loop, covariance=s.covariance,
                                denominator=denominator)
                setting = {"method": m, "degrees": degrees_label(deg), "window": w}
                if pools is None:
                    template = _setting_template(_with_error(result_template(ds, s), ds, lead),
                                                 setting)
                    drop = _new_indexes(template, blocks_in)
                    res = xr.map_blocks(_identify_block, blocks_in,
                                        kwargs={**settings, "source": source, "drop": drop,
                                                "carried": carried, "setting": setting},
                                        template=template.drop_vars(drop))
                    res = res.assign_coords({name: template[name].variable for name in drop})
                    res = res.assign_coords(_input_coords(res, experiments))
                else:
                    res = _pooled(ds, pools, settings).expand_dims(
                        {d: [v] for d, v in setting.items()})
                per_window.append(res)
            per_degree.append(per_window)
        nested.append(per_degree)
    out = xr.combine_nested(nested, concat_dim=list(SETTING_DIMS), combine_attrs="drop_conflicts",
                            join="exact", compat="override", coords="minimal", data_vars="all")
    for key in _PER_SETTING_ATTRS:
        out.attrs.pop(key, None)
    nr_factor = experiment_factor(ds) * ds.sizes[cv.INPUT]
    used = [[checked[m, d, windows[0]].degrees for d in degrees_list] for m in methods]
    ppr = np.array([[parameters_per_row(nr_factor, d) for d in row] for row in used])
    rd = np.array([[d[2] for d in row] for row in used])
    fits = np.array([[checked[m, d, windows[0]].denominator for d in degrees_list] for m in methods])
    if pools is not None and denominator is None:  # identify's default for pooled experiments
        fits = np.where(fits == DEFAULT_DENOMINATOR, POOLED_DEFAULT_DENOMINATOR, fits)
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
        "denominator_fit": (("method", "degrees"), fits,
                            {"units": "1", "long_name": "how the denominator is estimated "
                                                        "(ls, iv; none without one)"}),
        "parameters_per_row": (("method", "degrees"), ppr,
                               {"units": "1", "long_name": "local parameters per row of Z"}),
    })
    out.attrs.update({
        "swept_settings": list(SETTING_DIMS),
        "title": f"sweep of lifted {closed_loop} closed-loop FRF estimates over {', '.join(SETTING_DIMS)}",
    })
    return out
