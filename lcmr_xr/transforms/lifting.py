"""Lifting of labelled signals: fast dim ``time`` (N) <-> ``slow_time`` (M) x ``lift_phase`` (F).

Lifting is a reshape, so it is done on each variable's data directly (lazy on dask) rather
than through ``apply_ufunc``; the work here is keeping coordinates and attributes such that
:func:`unlift` restores the input exactly:

* the fast coordinate (``time``) is kept as a 2-d coordinate on (``slow_time``,
  ``lift_phase``), holding the original values bit for bit;
* the ``lift_phase`` coordinate's attributes record the fast dim name and whether the slow
  coordinate was created by :func:`lift` (a Dataset may already have one, used by ``y``).
"""

from __future__ import annotations

from typing import Hashable

import numpy as np
import xarray as xr

from lcmr_xr.conventions import FACTOR, LIFT_PHASE, TIME
from lcmr_xr.settings import as_integer, recorded_factor
from lcmr_xr.transforms._coords import slow_dim_for

__all__ = ["lift", "unlift"]

_TMP_NAME = "__lcmr_xr_lift__"
_LIFTED_DIM = "lifted_dim"
_CREATED_SLOW = "lift_created_slow_coord"
#: The factor F on the ``lift_phase`` coordinate: a selection of phases keeps the
#: coordinate's attributes, so a partial one (``isel(lift_phase=[0, 1])`` of F = 4, whose
#: labels are ``0..1`` in order) is told from a whole lifting.
LIFT_FACTOR = "lift_factor"


def _as_dataset(x):
    if isinstance(x, xr.DataArray):
        return x.to_dataset(name=_TMP_NAME, promote_attrs=False), x.name
    if isinstance(x, xr.Dataset):
        return x, None
    raise TypeError(
        f"expected an xarray DataArray or Dataset, got {type(x).__name__}; wrap numpy arrays "
        "with xr.DataArray(x, dims=...) or use lcmr_xr.kernels.lifting for plain arrays."
    )


def _back(ds: xr.Dataset, was_dataarray: bool, name: Hashable | None):
    if not was_dataarray:
        return ds
    out = ds[_TMP_NAME]
    out.name = name
    return out


def _resolve_factor(x, factor, dim: str = TIME) -> int:
    """The lifting factor: ``factor`` if given, else ``x.attrs["factor"]``; both given and
    lifting along ``time``, they must agree (a signal lifted by another F than it records
    would carry a wrong ``factor`` on).  The recorded factor is the ratio of ``time`` to
    ``slow_time``: a lifting along another dim (``dim="slow_time"``) is not held to it."""
    attrs = getattr(x, "attrs", {})
    stored = attrs.get(FACTOR)
    recorded = None if stored is None else recorded_factor(stored)
    if factor is not None:  # the settings' integer rule: 2.0 yes, 2.5 no (ValueError), "2" no (TypeError)
        factor = as_integer(factor, "factor", minimum=1, example=2)
        if recorded is not None and recorded != factor and dim == TIME:
            raise ValueError(
                f"cannot lift by factor={factor}: the signal records the factor F = {recorded} "
                f"(x.attrs[{FACTOR!r}]). Pass factor={recorded} (or omit factor to use it); to "
                f"lift by {factor} on purpose, set x.attrs[{FACTOR!r}] = {factor} first (e.g. "
                f"x.assign_attrs({FACTOR}={factor}))."
            )
        return factor
    if stored is None:
        raise ValueError(
            "lift needs the lifting factor F: pass factor=F, or set the attribute "
            f"x.attrs[{FACTOR!r}] = F."
        )
    if recorded is None:
        raise ValueError(
            f"cannot lift: the attribute x.attrs[{FACTOR!r}] is {stored!r}, not a lifting factor "
            f"(one whole number >= 1); set it to F (e.g. x.assign_attrs({FACTOR}=2)) or pass "
            "factor=F."
        )
    return recorded


def lift(x, factor: int | None = None, *, dim: str = TIME):
    """Lift a fast signal: dim ``time`` (N) -> ``slow_time`` (M = N/F) and ``lift_phase`` (F).

    Parameters
    ----------
    x : xarray.DataArray or xarray.Dataset
        Signal(s) with dimension ``dim``; any other dims (in any order) are kept.  In a
        Dataset, variables without ``dim`` (e.g. ``y`` on ``slow_time``) pass through.
    factor : int, optional
        Lifting factor F.  Default: ``x.attrs["factor"]``; if both are given and ``dim``
        is ``"time"`` (the dim whose ratio to ``slow_time`` the attribute records) they
        must be equal.
    dim : str, default "time"
        The fast dimension.  The slow dimension is named ``"slow_" + dim``.

    Returns
    -------
    xarray.DataArray or xarray.Dataset
        Element ``[l, j]`` (``slow_time=l``, ``lift_phase=j``) is ``x(l F + j)``.
        ``slow_time`` has the values ``time[::F]`` and the attributes of ``time``
        (if the Dataset already has ``slow_time``, it is kept and must match ``time[::F]``);
        ``lift_phase`` is the integer coordinate ``0..F-1`` (units "1");
        the fast coordinate survives as a 2-d coordinate on (``slow_time``, ``lift_phase``).
        Dask-backed data stays lazy (a reshape).

    Raises
    ------
    ValueError
        If N is not a multiple of F, no factor is known, ``factor`` is fractional or
        below 1 (never rounded), differs from the factor ``x.attrs["factor"]`` records
        (lifting along ``time``), or ``dim`` is missing.
    TypeError
        If ``factor`` is not a number (``"2"``, a bool).

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> x = xr.DataArray(np.arange(6.0), dims="time", coords={"time": np.arange(6) * 0.1})
    >>> lift(x, 2).values.tolist()
    [[0.0, 1.0], [2.0, 3.0], [4.0, 5.0]]
    >>> xr.testing.assert_identical(unlift(lift(x, 2)), x)
    """
    ds, name = _as_dataset(x)
    factor = _resolve_factor(x, factor, dim)
    slow = slow_dim_for(dim)
    if dim not in ds.dims:
        raise ValueError(
            f"cannot lift along {dim!r}: it is not a dimension (dims are {list(ds.dims)}); "
            "pass dim=<name of the fast time dimension>."
        )
    if LIFT_PHASE in ds.dims:
        raise ValueError(
            f"the input already has a {LIFT_PHASE!r} dimension (it is already lifted); "
            "unlift it first."
        )
    n = ds.sizes[dim]
    if n % factor:
        keep = n - n % factor
        raise ValueError(
            f"cannot lift {n} samples (N={n}) along {dim!r} by factor F={factor}: N must be a "
            f"multiple of F. Trim the signal to {keep} samples, e.g. x.isel({dim}=slice(0, {keep}))."
        )
    m = n // factor

    has_slow = slow in ds.dims or slow in ds.variables
    if has_slow and ds.sizes.get(slow, m) != m:
        raise ValueError(
            f"the input already has {slow!r} of length {ds.sizes[slow]}, but lifting {n} samples "
            f"by F={factor} gives {m} slow samples; make N = F * len({slow}) or pass a different factor."
        )

    variables = {}
    for var_name, var in ds.variables.items():
        if dim in var.dims:
            axis = var.dims.index(dim)
            dims = var.dims[:axis] + (slow, LIFT_PHASE) + var.dims[axis + 1:]
            shape = var.shape[:axis] + (m, factor) + var.shape[axis + 1:]
            # A C-order reshape of the time axis gives out[l, j] = x[l F + j].
            data = var.data.reshape(shape) if var_name != dim else np.asarray(var.values).reshape(shape)
            variables[var_name] = xr.Variable(dims, data, attrs=var.attrs, encoding=var.encoding)
        else:
            variables[var_name] = var

    coord_names = set(ds.coords)
    if dim in ds.coords and not has_slow:
        fast = ds[dim]
        variables[slow] = xr.Variable(slow, fast.values[::factor], attrs=dict(fast.attrs))
        coord_names.add(slow)
    elif dim in ds.coords and slow in ds.coords:
        existing = np.asarray(ds[slow].values, dtype=float)
        expected = np.asarray(ds[dim].values[::factor], dtype=float)
        scale = max(np.max(np.abs(expected)), np.finfo(float).tiny)
        if not np.allclose(existing, expected, rtol=0, atol=1e-9 * scale):
            raise ValueError(
                f"the existing {slow!r} coordinate does not match {dim}[::{factor}] "
                f"(first values {existing[:3].tolist()} vs {expected[:3].tolist()}); the slow "
                f"samples must be taken at every F-th fast sample. Check factor={factor} and "
                "the time coordinates."
            )
    variables[LIFT_PHASE] = xr.Variable(
        LIFT_PHASE,
        np.arange(factor),
        attrs={
            "units": "1",
            "long_name": "lifting phase (fast sample within a slow period)",
            _LIFTED_DIM: dim,
            _CREATED_SLOW: int(not has_slow),
            LIFT_FACTOR: int(factor),
        },
    )
    coord_names.add(LIFT_PHASE)
    data_vars = {k: v for k, v in variables.items() if k not in coord_names}
    coords = {k: v for k, v in variables.items() if k in coord_names}
    out = xr.Dataset(data_vars, coords=coords, attrs=ds.attrs)
    return _back(out, isinstance(x, xr.DataArray), name)


def check_all_phases(x, what: str, remedy: str) -> None:
    """Refuse a ``lift_phase`` dim of ``x`` (Dataset or DataArray) that is not the lifting's
    phases ``0..F-1`` in order: fewer phases than the lifting made (the ``lift_factor`` its
    coordinate records; coordinates without it, made by hand or by an earlier version,
    pass), or labels reordered (``sortby``, ``isel``).  ``what`` reads position ``j`` as
    phase ``j`` of a lifting by the dim's length, so either would give wrong values."""
    n_phases = x.sizes[LIFT_PHASE]
    if LIFT_PHASE not in x.coords:
        return
    # position j is read as phase j: the labels must be 0..F-1 in order, or a reordered
    # (sortby, isel) or partial selection would come out scrambled
    phases = np.asarray(x[LIFT_PHASE].values)
    if phases.shape != (n_phases,) or not np.array_equal(phases, np.arange(n_phases)):
        shown = phases.tolist() if phases.size <= 8 else f"{phases[:8].tolist()[:-1]} ..."
        raise ValueError(
            f"cannot {what}: the {LIFT_PHASE!r} coordinate is {shown}, but every phase "
            f"0..{n_phases - 1} is needed in order (element [l, j] is the fast sample l F + j). "
            f"Sort it with x.sortby({LIFT_PHASE!r}), or {remedy}."
        )
    recorded = _recorded_factor(x[LIFT_PHASE].attrs.get(LIFT_FACTOR), what, n_phases)
    if recorded is not None and recorded != n_phases:
        raise ValueError(
            f"cannot {what}: the {LIFT_PHASE!r} dim holds {n_phases} of the {recorded} "
            f"phases of the lifting (F = {recorded}, recorded in its coordinate's "
            f"{LIFT_FACTOR!r}); the result would be a lifting by {n_phases}, with wrong times "
            f"and frequencies. Keep every phase: {remedy}."
        )


def _recorded_factor(value, what: str, n_phases: int) -> int | None:
    """The ``lift_factor`` attribute as an int: one whole number >= 1 (a NetCDF file may
    give it back as a one-element array); anything else is refused, not guessed."""
    if value is None:
        return None
    number = recorded_factor(value)
    if number is None:
        raise ValueError(
            f"cannot {what}: the {LIFT_PHASE!r} coordinate's attribute {LIFT_FACTOR!r} is "
            f"{value!r}, not a lifting factor (one whole number >= 1, as lcmr_xr.lift records "
            f"it). Set it to the factor of the lifting, e.g. x = x.assign_coords({LIFT_PHASE}="
            f"x.{LIFT_PHASE}.assign_attrs({LIFT_FACTOR}={n_phases})) if the dim holds every "
            f"phase, or drop the attribute."
        )
    return number


def unlift(x, *, dim: str = "slow_time"):
    """Exact inverse of :func:`lift`: (``slow_time``, ``lift_phase``) -> ``time``.

    Parameters
    ----------
    x : xarray.DataArray or xarray.Dataset
        A lifted signal; ``slow_time`` and ``lift_phase`` may be in any order and position.
        Variables with ``slow_time`` but no ``lift_phase`` pass through unchanged.
    dim : str, default "slow_time"
        The slow dimension.

    Returns
    -------
    xarray.DataArray or xarray.Dataset
        ``unlift(lift(x))`` is identical to ``x`` (values, coordinates, attributes).  The
        fast dim takes the place of ``dim`` in each variable.  Dask stays lazy.

    Raises
    ------
    ValueError
        If ``dim`` or ``lift_phase`` is missing, the fast dim already exists, a variable has
        ``lift_phase`` without ``dim``, or the ``lift_phase`` coordinate is not ``0..F-1`` in
        order or holds fewer phases than the lifting made (its ``lift_factor``): reordered
        or selected phases would come out scrambled.
    TypeError
        If ``x`` is not a DataArray or Dataset.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> x = xr.DataArray([[0.0, 1.0], [2.0, 3.0]], dims=("slow_time", "lift_phase"))
    >>> unlift(x).dims, unlift(x).values.tolist()
    (('time',), [0.0, 1.0, 2.0, 3.0])
    """
    ds, name = _as_dataset(x)
    if dim not in ds.dims or LIFT_PHASE not in ds.dims:
        raise ValueError(
            f"unlift needs dims {dim!r} and {LIFT_PHASE!r}, got {list(ds.dims)}; pass the "
            "output of lift (or dim=<slow dimension>)."
        )
    phase_attrs = ds[LIFT_PHASE].attrs if LIFT_PHASE in ds.coords else {}
    default_fast = dim[len("slow_"):] if dim.startswith("slow_") else TIME
    fast = phase_attrs.get(_LIFTED_DIM, default_fast)
    if fast in ds.dims:
        raise ValueError(
            f"cannot unlift into {fast!r}: the input already has that dimension; rename it first."
        )
    factor = ds.sizes[LIFT_PHASE]
    m = ds.sizes[dim]
    check_all_phases(ds, "unlift", f"unlift the whole lifted signal and select {fast} samples "
                     "afterwards")

    variables = {}
    for var_name, var in ds.variables.items():
        if var_name in (LIFT_PHASE, dim):
            continue
        if LIFT_PHASE in var.dims and dim in var.dims:
            # Bring lift_phase right after the slow dim, then merge them (C order).
            order = [d for d in var.dims if d != LIFT_PHASE]
            axis = order.index(dim)
            order.insert(axis + 1, LIFT_PHASE)
            var_t = var.transpose(*order)
            dims = tuple(order[:axis]) + (fast,) + tuple(order[axis + 2:])
            shape = var_t.shape[:axis] + (m * factor,) + var_t.shape[axis + 2:]
            variables[var_name] = xr.Variable(
                dims, var_t.data.reshape(shape), attrs=var.attrs, encoding=var.encoding
            )
        elif LIFT_PHASE in var.dims:
            raise ValueError(
                f"variable {var_name!r} has {LIFT_PHASE!r} but not {dim!r}, so it cannot be "
                f"put back on {fast!r}; drop it (x.drop_vars({var_name!r})) before unlifting."
            )
        else:
            variables[var_name] = var

    still_slow = any(dim in v.dims for v in variables.values())
    created = phase_attrs.get(_CREATED_SLOW, 0 if still_slow else 1)
    coord_names = set(ds.coords) - {LIFT_PHASE}
    if dim in ds.variables and (still_slow or not created):
        variables[dim] = ds.variables[dim]
    else:
        coord_names.discard(dim)
    data_vars = {k: v for k, v in variables.items() if k not in coord_names}
    coords = {k: v for k, v in variables.items() if k in coord_names}
    out = xr.Dataset(data_vars, coords=coords, attrs=ds.attrs)
    return _back(out, isinstance(x, xr.DataArray), name)
