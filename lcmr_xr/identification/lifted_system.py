"""Exact lifted-system tools on labelled FRFs (both directions of the lifting identity).

* :func:`lifted_frf`: the lifted FRF ``Pbar`` (``F ny x F nu`` per slow bin) of a fast LTI
  system whose FRF is known on the fast DFT grid.
* :func:`frf_from_first_block_row`: the fast FRF from the first block row of ``Pbar``
  (what identification estimates).

The numpy kernels and the proofs are in :mod:`lcmr_xr.kernels.lifting`.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.kernels import lifting as kl
from lcmr_xr.settings import as_integer


def _require(da, dims: tuple, func: str, what: str) -> None:
    """``da`` is a DataArray with ``dims`` (plus leading dims): labels are checked here,
    before numpy or xarray would fail on them with their own words."""
    if not isinstance(da, xr.DataArray):
        raise TypeError(f"{func} needs {what} as an xarray DataArray with dims (..., "
                        f"{', '.join(dims)}), got {type(da).__name__}; label a numpy array with "
                        f"xr.DataArray(x, dims=(..., {', '.join(repr(d) for d in dims)})).")
    missing = [d for d in dims if d not in da.dims]
    if missing:
        raise ValueError(f"{func} needs {what} with dims (..., {', '.join(dims)}), but it has "
                         f"{da.dims}, without {missing}; rename its dims, e.g. "
                         f"x.rename({{'old': {missing[0]!r}}}).")

def _full_circle(frf: xr.DataArray, n_samples: int | None) -> tuple[xr.DataArray, int]:
    """The FRF on all ``N`` fast bins, completing a one-sided FRF by conjugate symmetry."""
    nf = frf.sizes[cv.FREQUENCY]
    if n_samples is None:
        n_samples = int(frf.attrs.get(cv.N_SAMPLES, nf))
    if nf == n_samples:
        return frf, n_samples
    if nf == n_samples // 2 + 1:
        # a real system: P(N - k) = conj(P(k)) completes the circle
        frf = frf.transpose(..., cv.FREQUENCY, cv.OUTPUT, cv.INPUT)
        vals = frf.values
        mirror = np.conj(vals[..., 1 : n_samples - nf + 1, :, :][..., ::-1, :, :])
        df = float(frf[cv.FREQUENCY][1] - frf[cv.FREQUENCY][0])
        coords = {d: frf[d] for d in frf.dims if d != cv.FREQUENCY and d in frf.coords}
        coords[cv.FREQUENCY] = (cv.FREQUENCY, np.arange(n_samples) * df, frf[cv.FREQUENCY].attrs)
        full = xr.DataArray(np.concatenate([vals, mirror], axis=-3), dims=frf.dims,
                            coords=coords, attrs=frf.attrs)
        return full, n_samples
    raise ValueError(
        f"the FRF has {nf} frequency bins; lifting needs all N = {n_samples} fast DFT bins "
        f"k/(N Th), k = 0..N-1, or the one-sided {n_samples // 2 + 1} bins of a real system. "
        f"Pass n_samples=N that matches the frequency grid."
    )


def lifted_frf(frf: xr.DataArray, factor: int, *, n_samples: int | None = None) -> xr.DataArray:
    """Lifted FRF of a fast LTI system from its FRF on the fast DFT grid.

    Parameters
    ----------
    frf : xarray.DataArray
        Complex FRF with dims (..., ``frequency``, ``output``, ``input``) on the fast bins
        ``k / (N Th)`` Hz: all ``N`` of them, or ``k = 0..N/2`` of a real system.
    factor : int
        Lifting factor ``F``; ``N`` must be a multiple of it.
    n_samples : int, optional
        ``N``; needed only for a one-sided FRF without an ``n_samples`` attribute.

    Returns
    -------
    xarray.DataArray
        Dims (..., ``slow_frequency``, ``lift_phase``, ``output``, ``lift_phase2``, ``input``):
        block ``[i, j]`` maps input phase ``j`` to output phase ``i``, equal to
        ``1/F sum_f P(k_f) exp(2j pi k_f (i - j) / N)``, ``k_f = m + f M``.

    Raises
    ------
    TypeError
        ``frf`` not a DataArray; ``factor`` or ``n_samples`` not a whole number.
    ValueError
        A missing dim, a fractional ``factor`` (never truncated), or ``N`` not a multiple
        of ``F`` or not matching the frequency grid.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> P = xr.DataArray(np.ones((8, 1, 1), complex), dims=("frequency", "output", "input"),
    ...                  coords={"frequency": np.arange(8) / 8.0})
    >>> lifted_frf(P, 2).sizes["slow_frequency"]
    4
    """
    _require(frf, (cv.FREQUENCY, cv.OUTPUT, cv.INPUT), "lifted_frf", "the FRF")
    f_ = as_integer(factor, "factor", minimum=1, example=2)  # 2.5 is refused, not truncated
    if n_samples is not None:
        n_samples = as_integer(n_samples, "n_samples", minimum=1, example=3600)
    full, n = _full_circle(frf, n_samples)
    m = n // f_ if n % f_ == 0 else None
    if m is None:
        raise ValueError(f"N = {n} is not a multiple of factor {f_}; lifting needs N = M F.")
    ny, nu = full.sizes[cv.OUTPUT], full.sizes[cv.INPUT]
    values = kl.lifted_frf(full.transpose(..., cv.FREQUENCY, cv.OUTPUT, cv.INPUT).values, f_)
    values = values.reshape(values.shape[:-2] + (f_, ny, f_, nu))
    lead = [d for d in full.dims if d not in (cv.FREQUENCY, cv.OUTPUT, cv.INPUT)]
    df = float(full[cv.FREQUENCY][1] - full[cv.FREQUENCY][0])
    coords = {d: full[d] for d in lead if d in full.coords}
    coords.update({
        cv.SLOW_FREQUENCY: (cv.SLOW_FREQUENCY, np.arange(m) * df, cv.frequency_attrs("slow-rate DFT frequency")),
        cv.LIFT_PHASE: (cv.LIFT_PHASE, np.arange(f_), cv.label_attrs("output lift phase")),
        cv.LIFT_PHASE2: (cv.LIFT_PHASE2, np.arange(f_), cv.label_attrs("input lift phase")),
        cv.OUTPUT: full[cv.OUTPUT] if cv.OUTPUT in full.coords else np.arange(ny),
        cv.INPUT: full[cv.INPUT] if cv.INPUT in full.coords else np.arange(nu),
    })
    return xr.DataArray(
        values, dims=lead + [cv.SLOW_FREQUENCY, cv.LIFT_PHASE, cv.OUTPUT, cv.LIFT_PHASE2, cv.INPUT],
        coords=coords,
        attrs={"long_name": f"lifted {frf.attrs.get('long_name', 'FRF')}",
               "units": frf.attrs.get("units", "1"), cv.FACTOR: f_, cv.N_SAMPLES: n},
    )


def frf_from_first_block_row(first_row: xr.DataArray, factor: int | None = None) -> xr.DataArray:
    """Fast FRF (bins ``k = 0..N/2``) from the first block row of a lifted FRF.

    Parameters
    ----------
    first_row : xarray.DataArray
        Dims (..., ``slow_frequency``, ``output``, ``lift_phase2``, ``input``) or the
        ``input2`` naming of :func:`lcmr_xr.identify`'s ``PS``-like outputs; block ``j`` maps
        input phase ``j`` to the output at phase 0.
    factor : int, optional
        ``F``; default: the size of ``lift_phase2``.

    Returns
    -------
    xarray.DataArray
        ``P(k) = sum_j exp(2j pi k j / N) P1_j(k mod M)`` on ``frequency`` = ``k / (N Th)``,
        ``k = 0..N/2``, dims (..., ``frequency``, ``output``, ``input``).

    Raises
    ------
    TypeError
        ``first_row`` not a DataArray; ``factor`` not a whole number.
    ValueError
        A missing dim, a fractional ``factor`` (never truncated), or ``factor`` other than
        the size of ``lift_phase2``.

    Examples
    --------
    >>> import numpy as np, xarray as xr
    >>> P = xr.DataArray(np.arange(1.0, 6.0).astype(complex)[:, None, None],
    ...                  dims=("frequency", "output", "input"),
    ...                  coords={"frequency": np.arange(5) / 8.0})  # k = 0..N/2, N = 8
    >>> row = lifted_frf(P, 2, n_samples=8).isel(lift_phase=0)
    >>> bool(np.allclose(frf_from_first_block_row(row).values, P.values))
    True
    """
    in_dim = cv.INPUT2 if isinstance(first_row, xr.DataArray) and cv.INPUT2 in first_row.dims \
        and cv.INPUT not in first_row.dims else cv.INPUT
    _require(first_row, (cv.SLOW_FREQUENCY, cv.OUTPUT, cv.LIFT_PHASE2, in_dim),
             "frf_from_first_block_row", "the first block row")
    n_phases = first_row.sizes[cv.LIFT_PHASE2]
    f_ = as_integer(factor, "factor", minimum=1, example=n_phases) if factor is not None else n_phases
    if n_phases != f_:
        raise ValueError(f"lift_phase2 has {n_phases} entries but factor is {f_}.")
    arr = first_row.transpose(..., cv.SLOW_FREQUENCY, cv.OUTPUT, cv.LIFT_PHASE2, in_dim)
    m, ny, _, nu = arr.shape[-4:]
    n = m * f_
    values = kl.frf_from_first_block_row(arr.values.reshape(arr.shape[:-2] + (f_ * nu,)), f_)
    values = values[..., : n // 2 + 1, :, :]
    df = float(first_row[cv.SLOW_FREQUENCY][1] - first_row[cv.SLOW_FREQUENCY][0])
    lead = [d for d in arr.dims if d not in (cv.SLOW_FREQUENCY, cv.OUTPUT, cv.LIFT_PHASE2, in_dim)]
    coords = {d: arr[d] for d in lead if d in arr.coords}
    coords[cv.FREQUENCY] = (cv.FREQUENCY, np.arange(n // 2 + 1) * df, cv.frequency_attrs())
    if cv.OUTPUT in arr.coords:
        coords[cv.OUTPUT] = arr[cv.OUTPUT]
    if in_dim in arr.coords:
        coords[cv.INPUT] = (cv.INPUT, arr[in_dim].values, arr[in_dim].attrs)
    return xr.DataArray(values, dims=lead + [cv.FREQUENCY, cv.OUTPUT, cv.INPUT], coords=coords,
                        attrs={"long_name": "fast FRF from the first block row",
                               "units": first_row.attrs.get("units", "1")})
