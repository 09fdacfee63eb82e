"""Pooled estimates in ``identify``: repeated periods, several experiments, window 0.

What :func:`lcmr_xr.identify` does with a ``period`` dim or ``combine="experiment"``
(the numerics are in :mod:`lcmr_xr.kernels.pooling`; references there):

* **Periods** (a ``period`` dim, e.g. ``hdd.simulate(periods=P)``): the first
  ``transient_periods`` periods (default 1: the loop starts from rest) are dropped, the
  remaining ``P_s`` steady-state periods are averaged (the noise variance of the average
  falls as ``1/P_s``), and the noise covariance of the averaged spectra is estimated
  nonparametrically from the period-to-period spread (sample covariance / ``P_s``,
  ``P_s - 1`` degrees of freedom; Pintelon and Schoukens 2012, sections 2.4 and 7.2, the
  robust LPM).  The local model then runs on the averaged record and its band uses the
  nonparametric covariance (averaged over the local window) instead of the residual one.
  The local model still carries its transient term (degrees ``Rm`` as given): what is
  left of the transient after dropping periods is absorbed by it.  On these steady-state
  averaged records ``degrees=(Rn, -1, Rd)`` leaves the transient term out (one parameter
  less per row, no transient/FRF trade-off); ``identify`` refuses ``Rm = -1`` for any
  record that did not go through :func:`plan` with a ``period`` dim and at least one
  dropped period.
* **Experiments** (``combine="experiment"``): experiments with the SAME excitation are
  pooled by averaging, like periods (the deterministic response is the same in each).
  With different excitations and ``window=0`` (``E >= F nu`` periodic experiments),
  ``G(k) = Z(k) R(k)^+`` at every slow bin, no local model.  Different excitations with
  a local window are fitted as ONE local model (``local_model(..., experiment_axis=)``:
  ``G`` and ``D`` shared, a transient per experiment, noise dof ``E (2n + 1) - p``), each
  experiment's periods averaged first; lazy data are always fitted this way (they are
  not read to compare the excitations).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.experiment.dataset import experiment_factor
from lcmr_xr.kernels.identification import experiment_spectra
from lcmr_xr.kernels.pooling import mean_and_covariance
from lcmr_xr.settings import as_integer

COMBINE = (None, "experiment")
#: Default number of leading periods dropped: the loop starts from rest in period 0.
DEFAULT_TRANSIENT_PERIODS = 1
_Z, _Z2 = "_z", "_z2"


class Plan(NamedTuple):
    """What :func:`lcmr_xr.identify` fits after pooling (see :func:`plan`).

    Parameters
    ----------
    dataset : xarray.Dataset
        The averaged record (window > 0), or the steady-state periods of every
        experiment (window 0).
    window0 : bool
        ``G`` bin by bin over the experiments, no local model.
    noise_covariance : xarray.DataArray or None
        (..., ``slow_frequency``, ``_z``, ``_z2``): covariance of the noise on the averaged
        spectra ``Z`` from the spread over the records; None when not estimated.
    attrs : dict
        Settings and counts recorded on the result.
    experiments : bool
        ``dataset`` keeps an ``experiment`` dim whose experiments (different
        excitations) are fitted as one local model (shared ``G``, a transient each).
    """

    dataset: xr.Dataset
    window0: bool
    noise_covariance: xr.DataArray | None
    attrs: dict
    experiments: bool = False


def requested(ds: xr.Dataset, transient_periods, combine) -> bool:
    """Whether ``identify`` must pool: a ``period`` dim, or a pooling argument given.

    Parameters
    ----------
    ds : xarray.Dataset
        The experiment.
    transient_periods : int or None
        As given to :func:`lcmr_xr.identify`.
    combine : str or None
        As given to :func:`lcmr_xr.identify`.

    Returns
    -------
    bool
    """
    return cv.PERIOD in ds.dims or transient_periods is not None or combine is not None


def is_window0(window) -> bool:
    """Whether ``window`` asks for no local model (``0``; ``False`` is not a window).

    Parameters
    ----------
    window : object
        The ``window`` argument of :func:`lcmr_xr.identify`.

    Returns
    -------
    bool

    Examples
    --------
    >>> is_window0(0), is_window0(30), is_window0(False)
    (True, False, False)
    """
    return not isinstance(window, (bool, np.bool_, str)) and np.ndim(window) == 0 and window == 0


def check_settings(*, window, transient_periods, combine, degrees) -> None:
    """Refuse pooling settings that are wrong whatever the data (before they are read).

    Parameters
    ----------
    window, transient_periods, combine, degrees
        As given to :func:`lcmr_xr.identify`.

    Raises
    ------
    ValueError
        An unknown ``combine``, a ``transient_periods`` below 0 or not whole (the integer
        rule, :func:`lcmr_xr.settings.as_integer`), ``window=0`` without
        ``combine="experiment"``, or ``degrees`` with ``window=0``.
    TypeError
        A ``transient_periods`` that is not a number.
    """
    if combine not in COMBINE:
        raise ValueError(f"combine must be None or 'experiment', got {combine!r}.")
    if transient_periods is not None:
        as_integer(transient_periods, "transient_periods", minimum=0, example=1)
    if not is_window0(window):
        return
    if combine != "experiment":
        raise ValueError(
            "window must be >= 1 (the half-width n of the local window) for one record; "
            "window=0 (G bin by bin, no local model) needs pooled experiments: pass "
            "combine='experiment' with E >= F nu periodic experiments with different "
            "excitations."
        )
    if degrees is not None:
        raise ValueError(
            f"window=0 fits no local model (G = Z R^+ bin by bin), so degrees={degrees!r} would "
            "be ignored; leave degrees out."
        )


def _same_excitation(r: xr.DataArray, dim: str) -> bool:
    """Is ``r`` the same signal along ``dim`` (to 1e-9 of its peak)?  Computed if lazy."""
    first = r.isel({dim: 0})
    diff, peak = abs(r - first).max(), abs(first).max()
    if diff.chunks is not None:
        import dask

        diff, peak = dask.compute(diff, peak)
    return float(diff) <= 1e-9 * float(peak)


def plan(ds: xr.Dataset, *, window, transient_periods, combine, closed_loop: str,
         covariance: bool, frequency_chunks) -> Plan:
    """Check the pooling settings against the data and build what is fitted.

    Parameters
    ----------
    ds : xarray.Dataset
        Validated experiment dataset.
    window : int
        Half-width of the local window; ``0``: ``G`` bin by bin over experiments.
    transient_periods : int or None
        Leading periods dropped (default 1 with a ``period`` dim).
    combine : {None, "experiment"}
        Pool the ``experiment`` dim into one estimate.
    closed_loop : {"indirect", "direct"}
        As :func:`lcmr_xr.identify`.
    covariance : bool
        Whether a band is wanted (window 0 then needs a noise estimate).
    frequency_chunks : int or None
        Refused with ``window=0`` (no local windows to chunk).

    Returns
    -------
    Plan

    Raises
    ------
    ValueError
        Every combination that cannot be pooled, naming the remedy.
    """
    check_settings(window=window, transient_periods=transient_periods, combine=combine,
                   degrees=None)
    has_period = cv.PERIOD in ds.dims
    if combine == "experiment" and any(cv.EXPERIMENT not in ds[v].dims for v in ("r", "u", "y")):
        raise ValueError(
            "combine='experiment' pools the 'experiment' dim, but r, u and y do not all have "
            f"it (dims: r {ds['r'].dims}, u {ds['u'].dims}, y {ds['y'].dims}); stack the "
            "experiments with xr.concat([...], dim='experiment')."
        )
    if transient_periods is not None and not has_period:
        raise ValueError(
            f"transient_periods={transient_periods!r} needs records with a {cv.PERIOD!r} dim "
            "(repeated periods of one excitation, e.g. hdd.simulate(..., periods=P)); this "
            "experiment has none: drop the argument."
        )
    window0 = is_window0(window)
    if frequency_chunks is not None and window0:
        raise ValueError(
            "frequency_chunks chunks the local windows; window=0 has none (every bin is "
            "solved on its own): leave frequency_chunks out, or chunk the leading dims."
        )
    n_periods = ds.sizes.get(cv.PERIOD, 1)
    drop = 0
    if has_period:
        drop = as_integer(DEFAULT_TRANSIENT_PERIODS if transient_periods is None
                          else transient_periods, "transient_periods", minimum=0, example=1)
        if drop >= n_periods:
            raise ValueError(
                f"transient_periods={drop} drops all {n_periods} period(s); keep at least one "
                f"steady-state period (transient_periods <= {n_periods - 1}) or record more periods."
            )
    steady = ds.isel({cv.PERIOD: slice(drop, None)}) if has_period else ds
    p_steady = n_periods - drop
    if has_period and cv.PERIOD not in steady["r"].dims:  # r repeats: give it the dim too
        steady = steady.assign(r=steady["r"].broadcast_like(steady["u"][{cv.INPUT: 0}], exclude=()))
        steady["r"] = steady["r"].transpose(*steady["u"].dims)
    n_exp = ds.sizes.get(cv.EXPERIMENT, 1) if combine == "experiment" else 1
    attrs = {cv.COMBINE: str(combine), cv.PERIODS: int(n_periods),
             cv.TRANSIENT_PERIODS: int(drop), cv.STEADY_PERIODS: int(p_steady)}

    if window0:
        _check_window0(ds, steady, has_period=has_period, n_exp=n_exp,
                       p_steady=p_steady, covariance=covariance)
        noise = "periods" if p_steady > 1 else "residual over experiments"
        if steady["u"].chunks is not None:  # G at a bin needs every experiment and period
            steady = steady.chunk({cv.EXPERIMENT: -1, cv.PERIOD: -1})
        attrs.update({cv.RECORDS_AVERAGED: int(p_steady), cv.NOISE_ESTIMATE: noise,
                      cv.NOISE_DOF: int(p_steady - 1 if p_steady > 1 else
                                        n_exp - experiment_factor(ds) * ds.sizes[cv.INPUT])})
        return Plan(steady, True, None, attrs)

    pool = ([cv.PERIOD] if has_period else []) + ([cv.EXPERIMENT] if combine == "experiment" else [])
    if combine == "experiment" and ds.sizes[cv.EXPERIMENT] > 1 \
            and (steady["r"].chunks is not None
                 or not _same_excitation(steady["r"], cv.EXPERIMENT)):
        # different excitations (or lazy data, not read to compare them): ONE local model
        # over the experiments, G and D shared, a transient each (pooled kernel)
        noise_cov = None
        if has_period and p_steady > 1:  # per experiment over its periods, then the mean
            noise_cov = _spread_covariance(steady, [cv.PERIOD], closed_loop).mean(cv.EXPERIMENT)
        fitted = _average(steady, [cv.PERIOD]) if has_period else steady
        if fitted["u"].chunks is not None:  # one local model needs every experiment
            fitted = fitted.chunk({cv.EXPERIMENT: -1})
        attrs.update({cv.RECORDS_AVERAGED: int(p_steady), cv.POOLED_EXPERIMENTS: int(n_exp),
                      cv.NOISE_ESTIMATE: "periods" if noise_cov is not None else "residual",
                      cv.NOISE_DOF: int(n_exp * (p_steady - 1)) if noise_cov is not None
                      else -1})
        return Plan(fitted, False, noise_cov, attrs, True)
    k = p_steady * n_exp
    noise_cov = None
    if has_period and k > 1:
        noise_cov = _spread_covariance(steady, pool, closed_loop)
    averaged = _average(steady, pool)
    attrs.update({cv.RECORDS_AVERAGED: int(k),
                  cv.NOISE_ESTIMATE: "periods" if noise_cov is not None else "residual",
                  cv.NOISE_DOF: int(k - 1) if noise_cov is not None else -1})
    return Plan(averaged, False, noise_cov, attrs)


def _check_window0(ds, steady, *, has_period, n_exp, p_steady, covariance):
    factor, nu = experiment_factor(ds), ds.sizes[cv.INPUT]
    nr = factor * nu
    if not has_period:
        raise ValueError(
            "window=0 needs steady-state periodic data: records with a 'period' dim (e.g. "
            "hdd.simulate(..., periods=P)) whose transient periods are dropped "
            "(transient_periods). Transient-laden records need the local model's transient "
            "term (window >= 1)."
        )
    if n_exp < nr:
        raise ValueError(
            f"window=0 needs at least F nu = {nr} experiments with different excitations "
            f"(the lifted excitation has {nr} channels); got E = {n_exp}. Record more "
            "experiments, or use a local window (window >= 1)."
        )
    if steady["r"].chunks is None and _same_excitation(steady["r"], cv.EXPERIMENT):
        raise ValueError(
            "window=0: every experiment has the same excitation, so the experiments cannot "
            "tell the lifted channels apart (rank 1 at every bin). Use a different multisine "
            "per experiment (e.g. other random phases, or "
            "lcmr_xr.kernels.excitation.orthogonal_random_phase_multisines), or pool them by "
            "averaging with a local window (window >= 1)."
        )
    if covariance and p_steady < 2 and n_exp == nr:
        raise ValueError(
            f"window=0 with E = F nu = {nr} experiments of one steady-state period each leaves "
            "nothing to estimate the noise from: record at least 2 steady-state periods per "
            "experiment, more experiments, or pass covariance=False."
        )


def _average(steady: xr.Dataset, pool: list[str]) -> xr.Dataset:
    """One record: ``u``, ``y`` averaged over ``pool``; ``r`` taken from the first record.

    ``r`` is the same in every pooled record (checked), and taking it instead of its mean
    keeps it bit-identical (a mean of equal floats can differ in the last bit).
    """
    r = steady["r"].isel({d: 0 for d in pool if d in steady["r"].dims}, drop=True)
    u = steady["u"].mean(pool, keep_attrs=True)
    y = steady["y"].mean(pool, keep_attrs=True)
    out = xr.Dataset({"r": r, "u": u, "y": y}, attrs=steady.attrs)
    return out.drop_vars([c for c in out.coords if set(steady[c].dims) & set(pool)],
                         errors="ignore")


def _spread_covariance(steady: xr.Dataset, pool: list[str], closed_loop: str) -> xr.DataArray:
    """Noise covariance of the averaged spectra ``Z`` from the spread over the records."""
    factor = experiment_factor(steady)
    m = steady.sizes[cv.SLOW_TIME]
    nz = steady.sizes[cv.OUTPUT] + (factor * steady.sizes[cv.INPUT] if closed_loop == "indirect" else 0)

    def kernel(r, u, y):
        _, Z = experiment_spectra(r, u, y, factor=factor, closed_loop=closed_loop)
        return mean_and_covariance(Z, len(pool))[1]

    return xr.apply_ufunc(
        kernel, steady["r"], steady["u"], steady["y"],
        input_core_dims=[pool + [cv.TIME, cv.INPUT], pool + [cv.TIME, cv.INPUT],
                         pool + [cv.SLOW_TIME, cv.OUTPUT]],
        output_core_dims=[[cv.SLOW_FREQUENCY, _Z, _Z2]], dask="parallelized",
        output_dtypes=[complex],
        dask_gufunc_kwargs={"output_sizes": {cv.SLOW_FREQUENCY: m, _Z: nz, _Z2: nz},
                            "allow_rechunk": True},
    )


def finish(out: xr.Dataset, the_plan: Plan, *, closed_loop: str, factor: int, y_units: str,
           u_units: str) -> xr.Dataset:
    """Add the nonparametric noise variances and the pooling attributes to the result.

    Parameters
    ----------
    out : xarray.Dataset
        FRF dataset fitted from ``the_plan.dataset``.
    the_plan : Plan
        From :func:`plan`.
    closed_loop : {"indirect", "direct"}
        Which rows ``Z`` has (lifted ``u`` and ``y``, or ``y`` only).
    factor : int
        ``F``.
    y_units, u_units : str
        Units of ``y`` and ``u`` (the variances are in their squares).

    Returns
    -------
    xarray.Dataset
        ``out`` with ``period_noise_variance_y`` (and ``_u``) and the pooling attributes.
    """
    noise = the_plan.noise_covariance
    if noise is not None:
        nu = out.sizes[cv.INPUT]
        diag = np.real(xr.apply_ufunc(np.diagonal, noise, input_core_dims=[[_Z, _Z2]],
                                      output_core_dims=[[_Z]], kwargs={"axis1": -2, "axis2": -1},
                                      dask="parallelized", output_dtypes=[complex]))
        fnu = factor * nu if closed_loop == "indirect" else 0
        out[cv.PERIOD_NOISE_VARIANCE_Y] = diag.isel({_Z: slice(fnu, None)}).rename({_Z: cv.OUTPUT}) \
            .assign_coords({cv.OUTPUT: out[cv.OUTPUT]}).assign_attrs(
                long_name="noise variance of the averaged output spectrum, from the spread over "
                          "the records", units=cv.squared_units(y_units))
        if closed_loop == "indirect":
            lifted = diag.isel({_Z: slice(0, fnu)}).data
            lifted = lifted.reshape(lifted.shape[:-1] + (factor, nu))
            out[cv.PERIOD_NOISE_VARIANCE_U] = xr.DataArray(
                lifted, dims=diag.dims[:-1] + (cv.LIFT_PHASE, cv.INPUT),
                coords={k: v for k, v in diag.coords.items()},
                attrs={"long_name": "noise variance of the averaged lifted input spectrum, from "
                                    "the spread over the records", "units": cv.squared_units(u_units)},
            ).assign_coords({cv.LIFT_PHASE: out[cv.LIFT_PHASE], cv.INPUT: out[cv.INPUT]})
        for name in cv.POOLED_VARIABLES:
            if name in out:
                out[name] = out[name].assign_coords({cv.SLOW_FREQUENCY: out[cv.SLOW_FREQUENCY]})
    out.attrs.update(the_plan.attrs)
    return out
