"""The one message for NaN/inf refused in labelled data.

:func:`lcmr_xr.dft`, :func:`lcmr_xr.idft`, :func:`lcmr_xr.fast_spectrum_from_lifted`,
``identify``'s lazy guard (:mod:`lcmr_xr.identification._guards`) and
:func:`lcmr_xr.validate_experiment` say the same of non-finite values: which variable, how
many values, which channels (where labels are known), how many samples or bins of the
transformed dim and their coordinate range and indices, what the values would do, and
what to do instead.  In-memory data are checked at once (:func:`refuse_non_finite`);
lazy data block by block when computed (:func:`checked_blocks`).
"""

from __future__ import annotations

import numpy as np

#: Where the NaN/inf of a lazy block was found (no labels: a block does not carry them).
IN_A_BLOCK = " (in one dask block; lazy data are checked when computed)"


def describe_non_finite(name, bad: np.ndarray, *, dim: str, coord=None, unit: str = "s",
                        noun: str = "samples", where: str = "", count: int | None = None) -> str:
    """``"<name> contains <count> NaN or inf value(s)<where> at <rows> of its <n> <dim>
    <noun>, from <dim> = <a> <unit> to <b> <unit> (indices i..j)"``.

    ``bad`` is the mask of non-finite values with ``dim`` last (leading axes: channels,
    records); ``coord`` the coordinate along ``dim`` (the range is left out without one);
    ``where`` e.g. the channels (:func:`channel_labels`).  At least one value must be bad.
    ``count``: the number of bad values when ``bad`` is already reduced over the leading
    axes (:func:`describe_lazy_non_finite`); default ``bad.sum()``.
    """
    bad = np.asarray(bad, dtype=bool)
    rows = np.flatnonzero(bad.reshape(-1, bad.shape[-1]).any(axis=0))
    span = "" if coord is None else (
        f", from {dim} = {float(coord[rows[0]]):.6g} {unit} to {float(coord[rows[-1]]):.6g} {unit}")
    count = int(bad.sum()) if count is None else int(count)
    return (f"{name or 'the input'} contains {count} NaN or inf value(s){where} at "
            f"{rows.size} of its {bad.shape[-1]} {dim} {noun}{span} (indices "
            f"{rows[0]}..{rows[-1]})")


def channel_labels(da, dim: str, bad: np.ndarray) -> str:
    """``" (input='pzt', output in ['a', 'b'])"``: the labels (or indices) of the other dims
    of ``da`` at which ``bad`` (``da``'s mask transposed to ``dim`` last) holds a value."""
    others = [d for d in da.dims if d != dim]
    hits = [bad.any(axis=tuple(j for j in range(bad.ndim) if j != i)) for i in range(len(others))]
    return _labels_at(da, others, hits)


def _labels_at(da, others, hits) -> str:
    where = []
    for d, hit in zip(others, hits):
        hit = np.flatnonzero(hit)
        labels = da[d].values[hit].tolist() if d in da.coords else hit.tolist()
        where.append(f"{d}={labels[0]!r}" if len(labels) == 1 else f"{d} in {labels}")
    return f" ({', '.join(where)})" if where else ""


def describe_lazy_non_finite(da, dim: str, *, unit: str = "s", noun: str = "samples") -> str:
    """:func:`describe_non_finite` with :func:`channel_labels` of a lazy (dask) DataArray
    known to hold NaN/inf: the count, the bad samples along ``dim`` and the bad labels of
    each other dim, reduced in one ``dask.compute`` (a pass over the data; no mask of the
    whole array is kept)."""
    import dask

    bad = ~np.isfinite(da.data)
    others = [d for d in da.dims if d != dim]
    axes = {d: da.get_axis_num(d) for d in da.dims}

    def any_but(keep):
        return bad.any(axis=tuple(a for d, a in axes.items() if d != keep))

    count, rows, *hits = dask.compute(bad.sum(), any_but(dim), *(any_but(d) for d in others))
    coord = np.asarray(da[dim].values) if dim in da.coords else None
    return describe_non_finite(da.name, rows, dim=dim, coord=coord, unit=unit, noun=noun,
                               where=_labels_at(da, others, hits), count=count)


def refuse_non_finite(da, dim: str, *, consequence: str, remedy: str, unit: str = "s",
                      noun: str = "samples") -> None:
    """Raise ValueError if the in-memory float or complex DataArray ``da`` holds NaN/inf:
    :func:`describe_non_finite` with its channels, then ``consequence`` and ``remedy``.
    Lazy data pass (wrap their kernel in :func:`checked_blocks`)."""
    if da.dtype.kind not in "fc" or da.chunks is not None:
        return
    bad = ~np.isfinite(da.transpose(..., dim).values)
    if not bad.any():
        return
    coord = np.asarray(da[dim].values) if dim in da.coords else None
    raise ValueError(message(describe_non_finite(
        da.name, bad, dim=dim, coord=coord, unit=unit, noun=noun,
        where=channel_labels(da, dim, bad)), consequence, remedy))


def checked_blocks(kernel, name, dim: str, coord, *, consequence: str, remedy: str,
                   unit: str = "s", noun: str = "samples", axes: int = 1):
    """``kernel`` on blocks of lazy data (``dim`` among the last ``axes`` axes, its own
    axis ``-axes``), refusing a block that holds NaN/inf with the message of
    :func:`refuse_non_finite` (no channel labels; "in one dask block")."""
    def checked(a, *args, **kwargs):
        bad = ~np.isfinite(a)
        if bad.any():
            mask = np.moveaxis(bad, -axes, -1)
            raise ValueError(message(describe_non_finite(
                name, mask, dim=dim, coord=coord, unit=unit, noun=noun, where=IN_A_BLOCK),
                consequence, remedy))
        return kernel(a, *args, **kwargs)
    return checked


def message(description: str, consequence: str, remedy: str) -> str:
    """``"<description>; <consequence>.  <remedy>"`` (the consequence may be empty)."""
    return f"{description}; {consequence}.  {remedy}" if consequence else f"{description}.  {remedy}"
