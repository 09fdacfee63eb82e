"""What ``identify`` does to its data before the kernels see them, so no dependency fails.

- Lazy data chunked along the core dims (``time``, ``slow_time``, channels) are rechunked
  to one chunk there: one experiment is small, and the kernels need whole records.
- Lazy data are checked for NaN/inf per block, at compute time, and the message names the
  variable and the time range (the eager path checks in ``validate_experiment``); a lazy
  ``r`` with a ``period`` dim is checked to repeat over the periods when the results are
  computed.
- Data whose magnitude is far outside the range where squares stay finite (about 1e-150
  to 1e150; e.g. data in units scaled by 1e300) are scaled by exact powers of two before
  the fit and the results scaled back, so the estimate does not depend on the units.
"""

from __future__ import annotations

import numpy as np

from lcmr_xr import conventions as cv
from lcmr_xr.transforms._finite import describe_non_finite, message

#: Variables whose largest magnitude lies outside [1 / SAFE_MAGNITUDE, SAFE_MAGNITUDE] are
#: scaled.  Products of two spectra (covariances, noise variances) must stay finite and
#: normal; 1e50 leaves margin for products of three and for sums over a window.
SAFE_MAGNITUDE = 1e50


def rechunk_core(ds):
    """One chunk along the core dims of the lazy variables ``r``, ``u``, ``y``."""
    core = {cv.TIME: -1, cv.INPUT: -1, cv.SLOW_TIME: -1, cv.OUTPUT: -1}
    out = {}
    for name in ("r", "u", "y"):
        var = ds[name]
        if var.chunks is None:
            continue
        wanted = {d: -1 for d in core if d in var.dims}
        if any(len(var.chunks[var.get_axis_num(d)]) > 1 for d in wanted):
            out[name] = var.chunk(wanted)
    return ds.assign(out) if out else ds


def periodic_spread(ds):
    """What :func:`gated` needs to refuse lazy data whose ``r`` does not repeat over the
    periods, as :func:`lcmr_xr.validate_experiment` refuses it in memory (same message):
    None without a ``period`` dim on ``r``; ``r`` in memory (lazy ``u``, ``y``) is checked
    now (None); lazy ``r``: its spread between periods, ``(diff, peak)`` dask scalars,
    reduced with the data when they are computed."""
    from lcmr_xr.experiment.dataset import _check_periodic_excitation, _periodic_spread

    r = ds["r"]
    if cv.PERIOD not in r.dims:
        return None
    spread = _periodic_spread(r)
    if r.chunks is None:
        _check_periodic_excitation(*spread)
        return None
    return spread


def gated(out, spread):
    """``out`` (a result Dataset) whose lazy variables refuse to compute unless ``spread``
    (:func:`periodic_spread`; None: nothing to check) passes.  The results, not ``r``, wait
    for the check: ``r``'s blocks are not held until all of ``r`` is read."""
    if spread is None:
        return out
    import dask.array as da

    checks = [x for v in spread for x in (v, ())]
    lazy = {}
    for name, var in out.data_vars.items():
        if var.chunks is not None:
            index = tuple(range(var.ndim))
            lazy[name] = var.copy(data=da.blockwise(_checked_block, index, var.data, index,
                                                    *checks, dtype=var.dtype))
    return out.assign(lazy)


def _checked_block(block, diff, peak):
    """``block`` of a result once ``r``'s spread between periods is checked."""
    from lcmr_xr.experiment.dataset import _check_periodic_excitation

    _check_periodic_excitation(diff, peak)
    return block


def check_finite(r, u, y, *, th: float, factor: int) -> None:
    """Refuse NaN/inf in a block, naming the variable and its time range (the message of
    :func:`lcmr_xr.transforms._finite.describe_non_finite`, as :func:`lcmr_xr.dft`'s)."""
    for name, x, step, dim in (("r", r, th, cv.TIME), ("u", u, th, cv.TIME),
                               ("y", y, th * factor, cv.SLOW_TIME)):
        x = np.asarray(x)
        bad = ~np.isfinite(x)
        if not bad.any():
            continue
        where = " (in at least one experiment)" if x.ndim > 2 else ""
        raise ValueError(message(
            describe_non_finite(name, np.moveaxis(bad, -2, -1), dim=dim,
                                coord=np.arange(x.shape[-2]) * step, where=where),
            "its spectra would be NaN at every bin",
            f"Remove or interpolate the bad samples before identification (e.g. "
            f"x.interpolate_na({dim!r})), or drop the experiments that hold them (lazy data "
            f"are checked when computed)."))


def _power_of_two_scale(x) -> float:
    """1.0, or the power of two that brings the largest magnitude of ``x`` near 1."""
    peak = float(np.max(np.abs(x))) if np.size(x) else 0.0
    if peak == 0.0 or not np.isfinite(peak) or 1 / SAFE_MAGNITUDE <= peak <= SAFE_MAGNITUDE:
        return 1.0
    return float(2.0 ** -np.round(np.log2(peak)))


def scales(r, u, y) -> tuple[float, float, float]:
    """Exact power-of-two scales of ``r``, ``u``, ``y`` (1.0 for data of ordinary magnitude)."""
    return _power_of_two_scale(r), _power_of_two_scale(u), _power_of_two_scale(y)


def scaled_call(kernel, r, u, y, *, closed_loop: str = "indirect", noise_covariance=None) -> dict:
    """``kernel(r, u, y, noise_covariance=...)`` (a dict of results) on scaled data, scaled back.

    Scaling by powers of two is exact, and every result is homogeneous in the data:
    ``G`` rows ``[U; Y]`` (``Y`` for ``closed_loop="direct"``) over columns ``R``,
    ``P = Y / U``; variances as squares; condition numbers, flags, relative errors
    (``s_weak_rel_std``) and the window choice of ``window="auto"`` (relative criteria)
    do not change.  A
    known noise covariance of the rows of ``Z`` (``(..., M, nz, nz)``, from repeated
    periods) is scaled with its rows and columns.
    """
    sr, su, sy = scales(r, u, y)
    if sr == su == sy == 1.0:
        return kernel(r, u, y, noise_covariance=noise_covariance)
    nz = np.shape(y)[-1] + (np.shape(u)[-1] * (np.shape(u)[-2] // np.shape(y)[-2])
                            if closed_loop == "indirect" else 0)
    z_scale = np.full(nz, sy)
    if closed_loop == "indirect":
        z_scale[: nz - np.shape(y)[-1]] = su
    if noise_covariance is not None:
        with np.errstate(over="ignore"):
            noise_covariance = noise_covariance * z_scale[:, None] * z_scale[None, :]
    out = dict(kernel(np.asarray(r) * sr, np.asarray(u) * su, np.asarray(y) * sy,
                      noise_covariance=noise_covariance))
    p = su / sy  # divide the scaled P by sy / su
    # squares as two products: the square of a scale alone may overflow where the result
    # does not; a variance beyond the double range becomes inf (it is that large)
    with np.errstate(over="ignore"):
        out["P"] = out["P"] * p
        if "P_var" in out:
            out["P_var"] = out["P_var"] * p * p
        if "P_var_linear" in out:
            out["P_var_linear"] = out["P_var_linear"] * p * p
        if "P_bias" in out:  # window="auto": the model error, in P's units
            out["P_bias"] = out["P_bias"] * p
        if "G" in out:
            src = sr if closed_loop == "indirect" else su
            nz = out["G"].shape[-2]
            rows = np.full(nz, 1.0 / sy)
            if closed_loop == "indirect":
                rows[: nz - np.shape(y)[-1]] = 1.0 / su
            factor = rows[:, None] * src
            out["G"] = out["G"] * factor
            out["G_var"] = out["G_var"] * factor * factor
            out["T"] = out["T"] * rows
            out["noise_variance"] = out["noise_variance"] * rows * rows
    return out
