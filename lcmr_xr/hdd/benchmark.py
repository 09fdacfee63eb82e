"""The paper's identification experiment on the HDD benchmark, and the true FRF to compare with."""

from __future__ import annotations

import reprlib

import numpy as np
import xarray as xr

from lcmr_xr.conventions import (FREQUENCY, INPUT, OUTPUT, PERIOD, SLOW_TIME, TIME,
                                 frequency_attrs, label_attrs, time_attrs)
from lcmr_xr.hdd.control import controller, notch_filters
from lcmr_xr.hdd.disturbances import fan_vibration, repeatable_runout, rotational_vibration
from lcmr_xr.hdd.plants import FACTOR, FAST_PERIOD, INPUTS, OUTPUTS, check_case, plant, pzt_plant, vcm_plant
from lcmr_xr.kernels.excitation import random_phase_multisine
from lcmr_xr.kernels.lti import frequency_response, simulate_lti
from lcmr_xr.settings import as_bool, as_integer
from lcmr_xr.simulation import simulate_closed_loop

BENCHMARK = "IEEJ dual-stage HDD benchmark (Atsumi 2022, MATLAB File Exchange 111515)"
#: rms of the excitation (vcm, pzt) used in the paper.
PAPER_RMS = (8.0e-8, 3.6e-9)


def _check_disturbances(disturbances, noise) -> tuple[str, ...]:
    """The chosen disturbances in :data:`DISTURBANCES` order (none without ``noise``)."""
    if isinstance(disturbances, str):
        raise TypeError(f"disturbances must be a sequence of names such as {list(DISTURBANCES)}, "
                        f"got the string {disturbances!r}; pass [{disturbances!r}] for one.")
    try:
        names = list(disturbances)
    except TypeError:
        raise TypeError(f"disturbances must be a sequence of names from {list(DISTURBANCES)}, "
                        f"got {disturbances!r}.") from None
    unknown = [n for n in names if not isinstance(n, str) or n not in DISTURBANCES]
    if unknown:
        raise ValueError(f"unknown disturbances {unknown!r}; choose from {list(DISTURBANCES)}.")
    if len(set(names)) != len(names):
        raise ValueError(f"disturbances names one twice: {names!r}; list each once.")
    if not noise:
        if names and set(names) != set(DISTURBANCES):
            raise ValueError("disturbances were chosen but noise=False switches them all off; "
                             "pass noise=True (the default) with the subset, or disturbances=[].")
        return ()
    return tuple(d for d in DISTURBANCES if d in names)


def _frequencies(frequency) -> np.ndarray:
    """``frequency`` (array_like or DataArray, Hz) as a flat float array; NaN, inf, text refused."""
    values = frequency.values if isinstance(frequency, xr.DataArray) else frequency
    try:
        f = np.asarray(values)
        if f.dtype.kind not in "iuf":
            raise TypeError
        f = f.astype(float).ravel()
    except (TypeError, ValueError):
        raise TypeError(f"frequency must be real numbers in Hz, got {reprlib.repr(values)}; pass e.g. "
                        f"frf.frequency or np.linspace(0, 50400, 100).") from None
    bad = ~np.isfinite(f)
    if bad.any():
        raise ValueError(f"frequency holds {int(bad.sum())} NaN or inf value(s) of {f.size} (first at "
                         f"index {int(np.flatnonzero(bad)[0])}); the FRF is only defined at finite "
                         f"frequencies: drop them first, e.g. f[np.isfinite(f)] or "
                         f"frequency.dropna('frequency').")
    return f


def true_frf(frequency, case: int = 2) -> xr.DataArray:
    """Exact fast-rate FRF of the ZOH-discretised HDD plant ``[Pv, Pp]`` at given frequencies.

    Parameters
    ----------
    frequency : array_like or xarray.DataArray
        Frequencies in Hz (a ``frequency`` coordinate of an FRF dataset works).
    case : int, optional
        Benchmark plant case 1..9; default 2.

    Returns
    -------
    xarray.DataArray
        Complex, dims (``frequency``, ``output``, ``input``), inputs ``"vcm"``, ``"pzt"``,
        output ``"position"``, units ``"m"`` per input unit; evaluated at
        ``z = exp(2j pi f Th)`` from the state space.  The VCM column is ``inf`` at 0 Hz
        (rigid-body double integrator).  Negative frequencies give the complex conjugates
        (a real system), frequencies beyond the Nyquist frequency those ``1 / Th`` lower.

    Raises
    ------
    TypeError
        ``frequency`` is not real numbers (text, complex).
    ValueError
        ``frequency`` holds NaN or inf; ``case`` is not one of 1..9.

    Examples
    --------
    >>> P = true_frf([0.0], case=5)
    >>> round(float(P.sel(input="pzt").real[0, 0]), 12)
    1.05
    """
    f = _frequencies(frequency)
    case = check_case(case)
    # one column per actuator, so the VCM's pole at DC (inf) leaves the PZT column finite
    values = np.concatenate([frequency_response(vcm_plant(case), f),
                             frequency_response(pzt_plant(case), f)], axis=2)
    return xr.DataArray(
        values, dims=(FREQUENCY, OUTPUT, INPUT), name="P",
        coords={FREQUENCY: (FREQUENCY, f, frequency_attrs()),
                OUTPUT: (OUTPUT, list(OUTPUTS), label_attrs("output channel")),
                INPUT: (INPUT, list(INPUTS), label_attrs("input channel"))},
        attrs={"units": "m", "long_name": f"true FRF of the HDD plant, case {case}",
               "case": int(case)},
    )


#: Names of the benchmark disturbances, for ``simulate(..., disturbances=...)``: rotational
#: vibration at the VCM input, fan vibration at the head position, repeatable run-out.
DISTURBANCES = ("rotational", "fan", "runout")


def check_n_samples(n_samples, name: str = "n_samples") -> int:
    """The record length ``N`` that :func:`simulate` takes: a whole number (the integer
    rule, :func:`lcmr_xr.settings.as_integer`), a multiple of :data:`FACTOR` and at least
    two slow samples.

    Parameters
    ----------
    n_samples : int
        Number of fast samples.
    name : str, default ``"n_samples"``
        The argument's name in the message (the command line says ``"--samples"``).

    Returns
    -------
    int

    Examples
    --------
    >>> check_n_samples(3600.0)
    3600
    """
    n_samples = as_integer(n_samples, name, example=3600)
    if n_samples < 2 * FACTOR or n_samples % FACTOR:
        raise ValueError(f"{name} must be a multiple of the factor {FACTOR} and at least "
                         f"{2 * FACTOR}, got {n_samples}; give e.g. 3600.")
    return n_samples


def check_seed(seed, name: str = "seed") -> int:
    """The seed that :func:`simulate` takes: a whole number, at least 0.

    Parameters
    ----------
    seed : int
        Seed of the excitation and the disturbances.
    name : str, default ``"seed"``
        The argument's name in the message (the command line says ``"--seed"``).

    Returns
    -------
    int

    Examples
    --------
    >>> check_seed(4.0)
    4
    """
    return as_integer(seed, name, minimum=0, example=0)


def simulate(n_samples: int = 3600, case: int = 2, noise: bool = True, seed: int = 0,
             rms=PAPER_RMS, *, fast_output: bool = False, periods: int | None = None,
             disturbances=DISTURBANCES) -> xr.Dataset:
    """Simulate the paper's closed-loop identification experiment on the HDD benchmark.

    Random-phase multisines with flat amplitude on every fast bin ``1..N/2`` (one period of
    ``N`` samples) excite the VCM and PZT inputs; the loop runs the paper's slow controllers
    ``Cv``, ``Cp`` at ``Tl = 1/50400 s`` and the fast notch filters at ``Th = 1/100800 s``,
    starting from rest.  With ``noise``, the benchmark disturbances act: rotational
    vibration at the VCM input (after ``u`` is measured), fan vibration at the head
    position, repeatable run-out as the slow reference (see :mod:`lcmr_xr.hdd.disturbances`
    for the ``Th``-instead-of-``Tsc`` approximation and the ``sqrt(1/10)`` scaling).

    Parameters
    ----------
    n_samples : int, optional
        Fast samples ``N`` (even); default 3600 as in the paper.
    case : int, optional
        Benchmark plant case 1..9; default 2.
    noise : bool, optional
        Include the disturbances; default True.
    disturbances : sequence of str, optional
        Which disturbances act with ``noise``: any of :data:`DISTURBANCES`
        (``"rotational"``, ``"fan"``, ``"runout"``); default all three, the benchmark.  Each
        draws from its own stream, so a subset gets the same realisations as the full
        benchmark (the loop is linear: the responses add up), which shows what each
        disturbance costs the estimate.  The dataset's ``disturbances`` attribute lists
        them (space-separated) when any acts; with none, the experiment is the noiseless one
        (``noise`` attribute 0).
    seed : int, optional
        Seed of everything random; default 0.  Excitation and each disturbance draw from
        their own child stream (``numpy.random.SeedSequence(seed).spawn``), so switching
        ``noise`` keeps the excitation.
    rms : (float, float), optional
        Root-mean-square values of the (vcm, pzt) excitation in input units; default ``(8.0e-8, 3.6e-9)``.
    fast_output : bool, optional
        Also return ``y_fast`` (fast head position, m) and ``pzt_displacement`` (the PZT's
        own displacement ``Pp u_pzt``, m, for the 50 nm stroke check); default False.
    periods : int, optional
        Apply ``periods`` periods of the one multisine (``n_samples`` samples each) in one
        run from rest: the loop and the disturbances run on across the periods (the
        disturbances are drawn as one record of ``periods * n_samples`` samples).  The
        result gets a ``period`` dim (coordinate ``0..P-1``); ``time`` and ``slow_time``
        count within a period.  The first period carries the loop's transient from rest:
        drop it in :func:`lcmr_xr.identify` with ``transient_periods=1``.  Default: one
        period and no ``period`` dim (the paper's experiment).  Without ``noise``, period 0
        equals the record of ``periods=None`` (to rounding).

    Returns
    -------
    xarray.Dataset
        Experiment dataset (``lcmr-xr-1``): ``r``, ``u`` (input units ``"1"``), ``y`` (m);
        attributes ``benchmark``, ``case``, ``seed``, ``rms``, ``noise`` (1 on, 0 off) and,
        with ``periods``, ``periods``.

    Raises
    ------
    TypeError
        ``n_samples``, ``seed`` or ``periods`` not a number (or a bool), ``noise`` or ``fast_output``
        not True/False (``"no"`` would read as True), ``rms`` not numbers,
        ``disturbances`` a string or not a sequence.
    ValueError
        A fractional ``n_samples`` or ``seed`` (``3600.5`` is refused, never truncated),
        ``n_samples`` odd or below 4, a negative ``seed``, ``case`` outside 1..9, ``rms``
        not positive or not one value per input, ``periods`` fractional or below 1,
        unknown or repeated ``disturbances`` (or some chosen with ``noise=False``).

    Examples
    --------
    >>> ds = simulate(n_samples=400, noise=False)
    >>> ds.sizes["time"], ds.sizes["slow_time"], ds.input.values.tolist()
    (400, 200, ['vcm', 'pzt'])
    >>> dict(simulate(n_samples=400, noise=False, periods=3).y.sizes)
    {'period': 3, 'slow_time': 200, 'output': 1}
    >>> simulate(n_samples=400, disturbances=["rotational"]).attrs["disturbances"]
    'rotational'
    """
    case = check_case(case)
    # whole numbers only (3600.5 is refused, never truncated), flags only True/False
    # (bool("no") is True): a wrong type gets this library's message, not numpy's
    n_samples = check_n_samples(n_samples)
    noise = as_bool(noise, "noise")
    chosen = _check_disturbances(disturbances, noise)
    seed = check_seed(seed)
    fast_output = as_bool(fast_output, "fast_output")
    try:
        rms = np.asarray(rms, dtype=float)
    except (TypeError, ValueError):
        raise TypeError(f"rms must be numbers (the rms of the vcm and pzt excitation in input "
                        f"units), got {rms!r}; pass e.g. rms={PAPER_RMS}.") from None
    excitation_rng, fan_rng, rotation_rng, runout_rng = (
        np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4))
    bins = np.arange(1, n_samples // 2 + 1)
    time = (TIME, np.arange(n_samples) * FAST_PERIOD, time_attrs())
    r = xr.DataArray(random_phase_multisine(n_samples, len(INPUTS), bins, rms, excitation_rng),
                     dims=(TIME, INPUT), coords={TIME: time, INPUT: list(INPUTS)},
                     attrs={"units": "1", "long_name": "fast-rate excitation"})
    if periods is not None:  # whole numbers only, as n_samples (2.0 yes, 2.5 no)
        periods = as_integer(periods, "periods", minimum=1, example=2)
    n_periods = 1 if periods is None else periods
    n_total = n_periods * n_samples  # the disturbances are one continuous record

    def shaped(x, dims):  # (P L, c) -> (P, L, c) with a period dim, or (L, c) without
        if periods is None:
            return xr.DataArray(x, dims=dims, attrs={"units": "m"})
        return xr.DataArray(x.reshape((n_periods, -1) + x.shape[1:]), dims=(PERIOD,) + dims,
                            attrs={"units": "m"})

    disturbances = {}
    if "rotational" in chosen:
        d_f = np.zeros((n_total, len(INPUTS)))
        d_f[:, 0] = rotational_vibration(n_total, rotation_rng)
        disturbances["d_u"] = shaped(d_f, (TIME, INPUT)).assign_coords(
            {INPUT: list(INPUTS)}).assign_attrs(units="1")
    if "fan" in chosen:
        disturbances["d_y"] = shaped(fan_vibration(n_total, fan_rng)[:, None], (TIME, OUTPUT))
    if "runout" in chosen:
        disturbances["reference"] = shaped(
            repeatable_runout(n_total // FACTOR, runout_rng)[:, None], (SLOW_TIME, OUTPUT))
    attrs = {"benchmark": BENCHMARK, "case": case, "seed": int(seed), "rms": rms,
             "noise": int(bool(chosen)), "excitation": "random-phase multisine, bins 1..N/2"}
    if chosen:  # (noise=True with no disturbance is the noiseless experiment, attrs too)
        attrs["disturbances"] = " ".join(chosen)
    if periods is not None:
        attrs["periods"] = n_periods
    ds = simulate_closed_loop(plant(case), controller(), notch_filters(), FACTOR, r,
                              outputs=list(OUTPUTS), output_units="m", fast_output=fast_output,
                              attrs=attrs, periods=periods, **disturbances)
    if fast_output:
        u_pzt = ds.u.sel(input="pzt").values.reshape(-1, 1)  # periods run on: one record
        stroke = simulate_lti(pzt_plant(case), u_pzt)[:, 0].reshape(ds.u.sel(input="pzt").shape)
        ds["pzt_displacement"] = xr.DataArray(
            stroke, dims=ds.u.sel(input="pzt").dims,
            attrs={"units": "m", "long_name": "PZT displacement Pp u_pzt"})
    return ds
