"""``identify``: the paper's Procedure 1 on a labelled experiment dataset.

A thin layer: dimension names are mapped onto the trailing axes of
:func:`lcmr_xr.kernels.identification.identify_arrays` with ``xarray.apply_ufunc``
(``dask="parallelized"``, so leading dims such as ``experiment`` may be chunked), and
the arrays that come back are labelled per the data contract, ``docs/conventions.md``.
"""

from __future__ import annotations

__all__ = ["identify", "identify_single_rate", "output_specs", "output_sizes", "result_template",
           "stacked_local_model"]

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.identification import pooling
from lcmr_xr.kernels.identification import (
    checks_denominator_bias,
    twin_bins,
    excitation_rank,
    experiment_spectra,
    finish_packed,
    fit_packed,
    identify_spectra,
    finish_packed_auto,
    first_fit_window,
    _prediction,
    identify_spectra_auto,
    identify_window0_arrays,
    packed_width,
    window_dof,
)
from lcmr_xr.experiment.dataset import experiment_factor
from lcmr_xr.identification import _guards
from lcmr_xr.kernels.adaptive import candidate_windows
from lcmr_xr.kernels.local_models import parameters_per_row
from lcmr_xr.settings import (AUTO_WINDOW, DEFAULT_DENOMINATOR, DEFAULT_WINDOW, NO_DENOMINATOR,
                              POOLED_DEFAULT_DENOMINATOR, as_bool, as_integer,
                              auto_window_range, check_window_fits, estimator_settings)
from lcmr_xr.transforms._coords import even_spacing


def _validate(experiment):
    """The validated experiment and, for lazy data, :func:`_guards.periodic_spread` (give
    the results to :func:`_guards.gated`)."""
    from lcmr_xr.experiment import validate_experiment

    if not isinstance(experiment, xr.Dataset):
        raise TypeError(
            f"identify expects an experiment xarray.Dataset (variables r, u, y; see "
            f"lcmr_xr.experiment), got {type(experiment).__name__}. Build one with "
            f"lcmr_xr.experiment(r, u, y, factor=F, sampling_period=Th)."
        )
    lazy = any(experiment[v].chunks is not None for v in ("r", "u", "y") if v in experiment)
    # lazy data stay lazy: the NaN/inf check then happens in the kernel, at compute time
    ds = validate_experiment(experiment, check_values=not lazy)
    if not lazy:
        return ds, None
    # r's repetition over periods likewise: with the results (now if r is in memory)
    return _guards.rechunk_core(ds), _guards.periodic_spread(ds)


def _ratio_units(num: str, den: str) -> str:
    if den in ("1", ""):
        return num
    if any(c in den for c in " /*"):
        den = f"({den})"
    return f"{num}/{den}"


def identify(experiment: xr.Dataset, *, method: str = "lrm", window=DEFAULT_WINDOW, degrees=None,
             closed_loop: str = "indirect", covariance: bool = True, errors: str = "raise",
             frequency_chunks: int | None = None, stacked: bool = False,
             transient_periods: int | None = None, combine: str | None = None,
             denominator: str | None = None) -> xr.Dataset:
    """Identify the fast-rate FRF of a plant in multirate closed loop (paper, Procedure 1).

    The fast excitation ``r`` and plant input ``u`` are lifted by the factor ``F``, the
    lifted sensitivity ``S`` and first row of the process sensitivity ``PS_1`` are
    estimated with local models in a circular window of ``2 window + 1`` slow DFT bins,
    ``P_1 = PS_1 S^-1`` is formed and the fast FRF is recovered on every fast bin
    from DC to the fast Nyquist frequency.

    Parameters
    ----------
    experiment : xarray.Dataset
        Experiment dataset per the lcmr-xr-1 conventions (``r``, ``u`` on ``time``/``input``,
        ``y`` on ``slow_time``/``output``, attribute ``factor``); extra leading dims
        (e.g. ``experiment``) broadcast and may be dask-chunked.
    method : {"lrm", "lpm"}, default "lrm"
        Local rational model, or local polynomial model (denominator degree ``Rd = 0``).
    window : int or "auto", default "auto"
        Half-width ``n`` of the local window: each estimate uses ``2 n + 1`` slow bins.
        ``"auto"``: chosen per slow bin among a ladder of half-widths from the smallest
        one the degrees allow to 30 (the paper's) by a local mean-squared-error criterion
        (model error against noise; see ``docs/uncertainty.md`` and
        :mod:`lcmr_xr.kernels.adaptive`); the choice is returned as ``local_window`` and
        the estimated model error is part of ``P_std``.  With a least-squares LRM
        denominator (one record, the default) the widest window is
        also fitted by instrumental variables with its own prediction as instruments, and
        the two estimates' difference (a Hausman comparison) adds a noise-inflated upper
        term for least squares' errors-in-variables bias to ``P_bias`` at every bin.
        ``"auto"`` needs ``covariance=True`` (and ``frequency_chunks`` of at least the
        widest candidate, 30, plus the halo of ``denominator="iv"``'s first fit if any:
        42; the comparison's instruments come from the widest candidate's own chunks);
        with repeated periods
        each candidate's band uses the noise covariance from the periods.
        An integer window is a whole number (``30.0`` is 30; ``30.5`` is refused, not
        rounded).  The default is :data:`lcmr_xr.settings.DEFAULT_WINDOW`.
    degrees : (int, int, int) or str, optional
        ``(Rn, Rm, Rd)``: degrees of the numerator, transient and (diagonal) denominator
        polynomials in the local frequency variable, or the label ``"Rn-Rm-Rd"``.  Default
        ``(3, 3, 3)`` for LRM and ``(3, 3, 0)`` for LPM, whose ``Rd`` must be 0 (a pair
        ``(Rn, Rm)`` is accepted for LPM).  The rules: :mod:`lcmr_xr.settings`.
    closed_loop : {"indirect", "direct"}, default "indirect"
        ``"indirect"`` (the paper): estimate ``[S; PS_1]`` from the lifted excitation and
        form ``PS_1 S^-1`` -- unbiased under feedback.  ``"direct"``: local model from the
        lifted measured input to the output; biased under feedback because ``u`` is
        correlated with the noise (for comparison; see :func:`identify_single_rate` for
        the estimate that ignores the multirate structure).
    covariance : bool, default True
        Propagate the local-model covariance to ``P_std`` (first order).  ``False`` saves
        memory on very long records; ``P_std`` is then NaN.
    errors : {"raise", "ignore"}, default "raise"
        What to do when the estimated lifted sensitivity ``S`` cannot be inverted at
        some bins: raise a ``ValueError`` naming them, or return NaN there with the
        flag ``s_singular`` set (use "ignore" in sweeps).  Ill-conditioned local models
        are always returned as data (flag ``ill_posed``), never raised.
    frequency_chunks : int, optional
        Fit the local models lazily with dask in chunks of this many slow bins; each chunk
        is extended by a halo of ``window`` bins on both sides (wrapping around the unit
        circle, as the circular windows do), so the result equals the unchunked one to
        rounding.  Default: one chunk (leading dims such as ``experiment`` are still
        parallel when the experiment is dask-backed).  With ``combine="experiment"`` each
        chunk holds every experiment (one local model over them).  The singular-``S``
        check of ``errors="raise"`` runs only on computed (not lazy) results.
    stacked : bool, default False
        Also return the local-model estimate as the kernel fits it, one matrix per slow
        bin: ``G`` (``slow_frequency``, ``response``, ``excitation``) mapping the lifted
        excitation spectra (``F nu`` columns) to the spectra ``[U; Y]`` (rows; ``Y`` alone
        for ``"direct"``), its ``G_std`` and the residual variances of its rows
        ``noise_variance`` (``slow_frequency``, ``response``).  ``S``, ``PS`` and the
        ``noise_variance_u/y`` are the blocks of these.
    transient_periods : int, optional
        Records with a ``period`` dim (repeated periods of one periodic excitation, e.g.
        ``hdd.simulate(..., periods=P)``): number of leading periods dropped as transient;
        default 1.  The steady-state periods left are averaged, and with two or more of
        them the band uses the noise covariance estimated from the period-to-period spread
        (Pintelon and Schoukens, *System Identification: A Frequency Domain Approach*, 2nd
        ed., 2012, ch. 2 and 7: the robust LPM); see :mod:`lcmr_xr.identification.pooling`.
    combine : {None, "experiment"}, default None
        ``"experiment"``: one estimate from all experiments of the ``experiment`` dim.
        Experiments with the same excitation are averaged (like periods).  Experiments with
        different excitations: ``window=0`` with ``E >= F nu`` periodic experiments gives
        ``G(k) = Z(k) R(k)^+`` at every slow bin, no local model, with the band from the
        nonparametric noise (bins where the experiments' lifted excitations are not of full
        rank, e.g. the slow bin 0 of multisines without DC, are NaN and flagged
        ``ill_posed``); with a local window (fixed or ``"auto"``) they are fitted as ONE
        local model: ``G`` and the denominator shared, a transient term per experiment
        (``transient_y``/``transient_u`` keep the ``experiment`` dim), one noise
        covariance with ``E (2n + 1) - p`` degrees of freedom; attribute
        ``pooled_experiments``.  With a covariance and at least 4 experiments, the even-
        and odd-numbered experiments are also fitted apart and the covariance is scaled
        per slow bin by their spread (variable ``spread_calibration``, at least 1;
        docs/uncertainty.md); their ``P`` put a further factor on the variance of ``P``
        per fast bin and entry (``P_spread_calibration``, at least 1), and the band's
        factor for the nonlinearity of ``S^-1`` is the milder ``1 / (1 - k rho)``.  Lazy
        data work along the other leading dims (not with
        ``frequency_chunks``).  ``degrees`` with ``Rm = -1`` (no transient term) is
        accepted only for steady-state periodic records (a ``period`` dim, transient
        periods dropped).
    denominator : {None, "ls", "iv"}, optional
        How the LRM's denominator is estimated: ``"ls"`` least squares (the paper), or
        ``"iv"`` instrumental variables, whose instruments are a prediction of the spectra
        from a first least-squares fit in the narrowest window the degrees allow
        (``Zhat = G1 R + T1``), so that the noise on ``Z`` in the denominator's regressors
        no longer biases ``G`` (costs a second fit; the frequency-chunk halo grows by that
        window).  Default (None): ``"iv"`` where experiments are pooled in one local model
        (``combine="experiment"`` with different excitations: least squares' bias does not
        pool away), ``"ls"`` otherwise (one record: IV changes the error by a few per cent
        at 1.33-1.41x the CPU time at window 30, docs/uncertainty.md); :data:`lcmr_xr.settings.DEFAULT_DENOMINATOR`,
        :data:`lcmr_xr.settings.POOLED_DEFAULT_DENOMINATOR`.  A model without a
        denominator (``Rd = 0``: the LPM, window 0) is least squares, and ``"iv"`` is
        refused there.  Recorded as the attribute ``denominator``
        (``"ls"``, ``"iv"`` or ``"none"``).  What it changes, measured: ``docs/uncertainty.md``.

Returns
    -------
    xarray.Dataset
        ``P`` (``frequency``, ``output``, ``input``), complex: fast FRF at bins
        ``k / (N Th)``, ``k = 0..N/2``; ``P_std``: uncertainty of ``P`` calibrated so that
        the disc ``|P_hat - P| <= sqrt(ln 20) P_std`` is a 95 % region (first-order noise
        standard deviation ``P_std_linear`` times a small-sample factor and, for the
        indirect method, a factor for the nonlinearity of ``S^-1``, plus the model-error
        estimate ``P_bias`` with ``window="auto"``, which then also holds the estimated
        bias of a least-squares denominator); ``inf`` where ``P_undetermined``: the
        data do not determine the weakest direction of ``S`` there, so no finite band can
        be promised (``docs/uncertainty.md``).  ``P_flag``: bins that could not be
        estimated.  ``s_weak_rel_std`` (``slow_frequency``): relative standard deviation of
        the weakest direction of ``S``.  Lifted estimates on ``slow_frequency``: ``S`` (``lift_phase``, ``input``,
        ``lift_phase2``, ``input2``), ``PS`` (``output``, ``lift_phase2``, ``input2``) with
        ``S_std``, ``PS_std``; residual noise variances ``noise_variance_u``,
        ``noise_variance_y``; transients ``transient_u``, ``transient_y``; ``condition``,
        ``ill_posed``, ``s_condition``, ``s_singular``.  Attributes record every setting.
        Pooled estimates add ``period_noise_variance_u``, ``period_noise_variance_y`` (the
        nonparametric noise variances of the averaged spectra, when estimated) and the
        attributes ``combine``, ``periods``, ``transient_periods``, ``steady_periods``,
        ``records_averaged``, ``noise_estimate`` ("periods" or "residual") and ``noise_dof``.

    Raises
    ------
    TypeError
        ``experiment`` is not an experiment dataset, or a setting has the wrong type
        (``covariance="no"``, ``transient_periods="1"``).  The integer settings
        (``window``, ``frequency_chunks``, ``transient_periods``, the degrees) take ints
        and whole floats (``30.0``); a fraction (``30.5``) is a ``ValueError``, never rounded.
    ValueError
        Invalid settings (checked before the data are read, also for dask input; see
        :func:`lcmr_xr.settings.estimator_settings`), too few bins for the number of parameters, a window wider than
        the spectrum, an excitation that does not excite all ``F nu`` lifted channels, or
        (with ``errors="raise"``) a non-invertible estimated ``S``.

    Examples
    --------
    >>> import lcmr_xr
    >>> from lcmr_xr import hdd
    >>> exp = hdd.simulate(n_samples=3600, noise=False, seed=1)
    >>> frf = lcmr_xr.identify(exp, window=30, degrees=(3, 3, 3))
    >>> frf.P.dims
    ('frequency', 'output', 'input')
    >>> float(frf.frequency[-1])  # fast Nyquist frequency, Hz
    50400.0
    >>> pooled = lcmr_xr.identify(hdd.simulate(n_samples=1200, periods=3, seed=1), window=20,
    ...                           transient_periods=1)
    >>> pooled.attrs["steady_periods"], pooled.attrs["noise_estimate"]
    (2, 'periods')
    """
    window0 = pooling.is_window0(window)
    if transient_periods is not None:  # the integer rule of every setting (30.0 yes, 2.5 no)
        transient_periods = as_integer(transient_periods, "transient_periods", minimum=0, example=1)
    pooling.check_settings(window=window, transient_periods=transient_periods, combine=combine,
                           degrees=degrees)
    s = estimator_settings(method=method, window=1 if window0 else window, degrees=degrees,
                           closed_loop=closed_loop, covariance=covariance, errors=errors,
                           frequency_chunks=None if window0 else frequency_chunks,
                           no_transient=True, denominator=denominator)
    if window0 and denominator == "iv":
        raise ValueError("denominator='iv' instruments the denominator of a local model, but "
                         "window=0 fits no local model (G = Z R^+ per bin); drop denominator or "
                         "pass a local window (e.g. window=30).")
    stacked = as_bool(stacked, "stacked")
    ds, spread = _validate(experiment)
    factor = experiment_factor(ds)
    th = even_spacing(ds[cv.TIME].values, cv.TIME)[1]
    # ---- pooling hook: periods / experiments (lcmr_xr.identification.pooling).  Rm = -1
    # (no transient term) only for steady-state averaged records (checked below).
    plan = None
    if window0 or pooling.requested(ds, transient_periods, combine):
        plan = pooling.plan(ds, window=0 if window0 else s.window,
                            transient_periods=transient_periods, combine=combine,
                            closed_loop=s.closed_loop, covariance=s.covariance,
                            frequency_chunks=frequency_chunks)
        s = s._replace(window=0) if window0 else s
        if denominator is None and plan.experiments and not window0 \
                and s.denominator == DEFAULT_DENOMINATOR:
            # one local model over experiments: least squares' bias does not pool away
            s = s._replace(denominator=POOLED_DEFAULT_DENOMINATOR)
    if s.degrees[1] < 0 and (plan is None or plan.attrs[cv.TRANSIENT_PERIODS] < 1):
        raise ValueError(
            f"degrees={s.degrees} leaves the transient term out (Rm = -1), which is right only "
            "for steady-state periodic data: records with a 'period' dim whose transient "
            "period(s) are dropped (transient_periods >= 1, the default with a 'period' dim). "
            "These data are not: use non-negative degrees (Rm >= 0, e.g. degrees=(3, 3, 3))."
        )
    fit = ds if plan is None else plan.dataset
    if not window0:
        check_window_fits(s.window, s.degrees, factor * ds.sizes[cv.INPUT], ds.sizes[cv.SLOW_TIME])
    out = _estimate(fit["r"], fit["u"], fit["y"], s, factor=factor, stacked=stacked,
                    check_rank=not window0, plan=plan)
    out = _label(out, fit, factor=factor, th=th)
    if s.errors == "raise" and s.closed_loop == "indirect" and not _is_lazy(out):
        bad = np.asarray(out["s_singular"])
        if bad.any():
            idx = np.flatnonzero(bad.reshape(-1, bad.shape[-1]).any(axis=0))
            raise ValueError(
                f"the estimated lifted sensitivity S is not invertible at {idx.size} slow bin(s) "
                f"(first: {idx[:5].tolist()}), so P_1 = PS_1 S^-1 cannot be formed there. Check "
                f"that u was recorded at the plant input in closed loop and that the excitation "
                f"is strong enough there, or pass errors='ignore' to get NaN and the flag "
                f"s_singular at those bins."
            )
    out.attrs.update(_settings_attrs(ds, s, factor=factor, th=th))
    if plan is not None:
        out = pooling.finish(out, plan, closed_loop=s.closed_loop, factor=factor,
                             y_units=ds["y"].attrs.get("units", "1"),
                             u_units=ds["u"].attrs.get("units", "1"))
    return _guards.gated(out, spread)


def _settings_attrs(ds, s, *, factor, th) -> dict:
    """The attributes that record the settings of a result of :func:`identify`."""
    if s.window == AUTO_WINDOW:
        attrs = _settings_attrs(ds, s._replace(window=1), factor=factor, th=th)
        windows = _candidate_windows(s, factor * ds.sizes[cv.INPUT], ds.sizes[cv.TIME] // factor)
        attrs.update({"window": AUTO_WINDOW, "window_bins": AUTO_WINDOW,
                      cv.CANDIDATE_WINDOWS: np.array(windows, dtype=int)})
        return attrs
    return {
        "conventions": cv.CONVENTIONS,
        "method": s.method,
        "closed_loop": s.closed_loop,
        "window": s.window,
        "window_bins": 2 * s.window + 1,
        "degrees": np.array(s.degrees, dtype=int),
        "factor": factor,
        "sampling_period": th,
        "slow_nyquist": 1.0 / (2 * factor * th),
        "n_samples": ds.sizes[cv.TIME],
        "parameters_per_row": parameters_per_row(factor * ds.sizes[cv.INPUT], s.degrees),
        "covariance": int(s.covariance),
        cv.DENOMINATOR: s.denominator,
        **({cv.IV_FIRST_WINDOW: first_fit_window(factor * ds.sizes[cv.INPUT], s.degrees)}
           if s.denominator == "iv" else {}),
        "title": f"lifted {s.closed_loop} closed-loop {s.method.upper()} FRF estimate",
    } if s.window > 0 else {  # window 0: no local model, G = Z R^+ per bin (nr parameters per row)
        "conventions": cv.CONVENTIONS, "method": "pooled", "closed_loop": s.closed_loop,
        "window": 0, "window_bins": 1, "degrees": np.array([0, -1, 0]), "factor": factor,
        "sampling_period": th, "slow_nyquist": 1.0 / (2 * factor * th),
        "n_samples": ds.sizes[cv.TIME], "parameters_per_row": factor * ds.sizes[cv.INPUT],
        "covariance": int(s.covariance), cv.DENOMINATOR: NO_DENOMINATOR,
        "title": f"lifted {s.closed_loop} closed-loop FRF, bin by bin over experiments",
    }


LP, IN2, LP2 = cv.LIFT_PHASE, cv.INPUT2, cv.LIFT_PHASE2
FQ, SF = cv.FREQUENCY, cv.SLOW_FREQUENCY
#: Dims of the stacked local model ``G`` (rows: spectra Z, columns: excitation spectra R).
RESPONSE, EXCITATION = "response", "excitation"


def output_specs(closed_loop: str, stacked: bool = False,
                 auto: bool = False, pooled: bool = False) -> list[tuple[str, list[str], type]]:
    """``(name, core dims, dtype)`` of every variable :func:`identify` returns.

    The one description of the result's layout: :func:`identify` fills it, and
    :func:`lcmr_xr.scaleout.sweep` derives its lazy template from it without computing.

    Parameters
    ----------
    closed_loop : {"indirect", "direct"}
        The estimator (``"direct"`` has no ``S`` and its by-products).
    stacked : bool, default False
        Include the stacked local model ``G``, ``G_std``, ``noise_variance``.
    auto : bool, default False
        ``window="auto"``: include ``P_bias`` and ``local_window``.
    pooled : bool, default False
        Experiments pooled in one local model: the transients keep the ``experiment`` dim.

    Returns
    -------
    list of (str, list of str, type)
        Variable name, its core dims (leading dims such as ``experiment`` come in front),
        its dtype.
    """
    ex = [cv.EXPERIMENT] if pooled else []
    specs = [
        ("P", [FQ, cv.OUTPUT, cv.INPUT], complex),
        ("P_std", [FQ, cv.OUTPUT, cv.INPUT], float),
        ("P_flag", [FQ], bool),
        ("PS", [SF, cv.OUTPUT, LP2, IN2], complex),
        ("PS_std", [SF, cv.OUTPUT, LP2, IN2], float),
        ("transient_y", [SF] + ex + [cv.OUTPUT], complex),
        ("noise_variance_y", [SF, cv.OUTPUT], float),
        ("condition", [SF], float),
        ("ill_posed", [SF], bool),
        ("P_std_linear", [FQ, cv.OUTPUT, cv.INPUT], float),
        ("P_undetermined", [FQ], bool),
    ]
    if auto:
        specs += [("P_bias", [FQ, cv.OUTPUT, cv.INPUT], float), ("local_window", [SF], int)]
    if pooled:
        specs += [(cv.SPREAD_CALIBRATION, [SF], float),
                  (cv.P_SPREAD_CALIBRATION, [FQ, cv.OUTPUT, cv.INPUT], float)]
    if closed_loop == "indirect":
        specs += [
            ("S", [SF, LP, cv.INPUT, LP2, IN2], complex),
            ("S_std", [SF, LP, cv.INPUT, LP2, IN2], float),
            ("transient_u", [SF] + ex + [LP, cv.INPUT], complex),
            ("noise_variance_u", [SF, LP, cv.INPUT], float),
            ("s_condition", [SF], float),
            ("s_singular", [SF], bool),
            ("s_weak_rel_std", [SF], float),
        ]
    if stacked:
        specs += [
            ("G", [SF, RESPONSE, EXCITATION], complex),
            ("G_std", [SF, RESPONSE, EXCITATION], float),
            ("noise_variance", [SF, RESPONSE], float),
        ]
    return specs


def output_sizes(*, factor: int, n: int, nu: int, ny: int, closed_loop: str) -> dict:
    """Size of every core dim of :func:`output_specs`.

    Parameters
    ----------
    factor : int
        Multirate factor ``F`` of the estimate.
    n : int
        Fast samples ``N`` of the experiment.
    nu, ny : int
        Plant inputs and outputs.
    closed_loop : {"indirect", "direct"}
        The estimator (sets the rows of ``G``).

    Returns
    -------
    dict of str to int
    """
    fnu = factor * nu
    return {FQ: n // 2 + 1, SF: n // factor, LP: factor, LP2: factor, IN2: nu,
            cv.INPUT: nu, cv.OUTPUT: ny, RESPONSE: fnu + ny if closed_loop == "indirect" else ny,
            EXCITATION: fnu}


def _split(out: dict, specs, *, factor: int, nu: int, ny: int, closed_loop: str) -> tuple:
    """The dict of :func:`identify_spectra` -> the tuple of ``specs``, with lifted dims."""
    G = out["G"]
    lead_m = G.shape[:-2]
    fnu = factor * nu
    G_sd = np.sqrt(np.maximum(out["G_var"], 0.0))  # rounding can leave -0-ish
    pieces = {
        "P": out["P"],
        "P_std": np.sqrt(out["P_var"]),  # already clipped at 0
        "P_flag": out["P_bad"],
        "condition": out["condition"],
        "ill_posed": out["ill_posed"],
        "G": G,
        "G_std": G_sd,
        "noise_variance": out["noise_variance"],
        "P_std_linear": np.sqrt(out["P_var_linear"]),
        "P_undetermined": out["P_undetermined"],
    }
    zy = slice(fnu, None) if closed_loop == "indirect" else slice(0, None)
    pieces["PS"] = G[..., zy, :].reshape(lead_m + (ny, factor, nu))
    pieces["PS_std"] = G_sd[..., zy, :].reshape(lead_m + (ny, factor, nu))
    pieces["transient_y"] = out["T"][..., zy]
    pieces["noise_variance_y"] = out["noise_variance"][..., zy]
    if closed_loop == "indirect":
        shape_s = lead_m + (factor, nu, factor, nu)
        pieces["S"] = G[..., :fnu, :].reshape(shape_s)
        pieces["S_std"] = G_sd[..., :fnu, :].reshape(shape_s)
        pieces["transient_u"] = out["T"][..., :fnu].reshape(out["T"].shape[:-1] + (factor, nu))
        pieces["noise_variance_u"] = out["noise_variance"][..., :fnu].reshape(lead_m + (factor, nu))
        pieces["s_condition"] = out["s_condition"]
        pieces["s_singular"] = out["s_singular"]
        pieces["s_weak_rel_std"] = out["s_weak_rel_std"]
    # pooled experiments: the split-half factor on the covariance (NaN where none was
    # computed: no covariance, fewer than 4 experiments, or window 0, no local model)
    pieces[cv.SPREAD_CALIBRATION] = out.get("spread_calibration", np.full(lead_m, np.nan))
    # and the halves' factor on the band of P (the same cases NaN)
    pieces[cv.P_SPREAD_CALIBRATION] = out.get("P_spread_calibration",
                                              np.full(out["P"].shape, np.nan))
    if "window" in out:  # window="auto"
        pieces["P_bias"] = out["P_bias"]
        pieces["local_window"] = out["window"]
    return tuple(pieces[name] for name, _, _ in specs)


def _estimate(r: xr.DataArray, u: xr.DataArray, y: xr.DataArray, s, *, factor: int,
              stacked: bool, check_rank: bool, plan=None) -> xr.Dataset:
    """The pipeline shared by :func:`identify` and :func:`identify_single_rate` (unlabelled).

    ``r``, ``u`` on (``time``, ``input``) with ``N = M factor`` samples, ``y`` on
    (``slow_time``, ``output``).  Eager data: the spectra are computed once, the excitation
    rank is checked on them (``check_rank``) and the local models are fitted from them.
    ``plan`` (:func:`lcmr_xr.identification.pooling.plan`): window 0 over the experiments'
    steady-state periods, or the nonparametric noise covariance for the band.
    """
    n, nu = r.sizes[cv.TIME], r.sizes[cv.INPUT]
    ny = y.sizes[cv.OUTPUT]
    auto = s.window == AUTO_WINDOW
    pooled = plan is not None and plan.experiments  # one local model over the experiments
    specs = output_specs(s.closed_loop, stacked, auto, pooled)
    ex = [cv.EXPERIMENT] if pooled else []
    core_in = [ex + [cv.TIME, cv.INPUT], ex + [cv.TIME, cv.INPUT], ex + [cv.SLOW_TIME, cv.OUTPUT]]
    sizes = output_sizes(factor=factor, n=n, nu=nu, ny=ny, closed_loop=s.closed_loop)
    if pooled:
        sizes[cv.EXPERIMENT] = r.sizes[cv.EXPERIMENT]
    exp_axis = -3 if pooled else None  # R, Z (..., E, M, channels)
    used = {d for _, dims, _ in specs for d in dims}
    gufunc_kwargs = {"output_sizes": {d: k for d, k in sizes.items() if d in used},
                     "allow_rechunk": False}
    output_spec = dict(output_core_dims=[dims for _, dims, _ in specs], dask="parallelized",
                       output_dtypes=[dt for _, _, dt in specs],
                       dask_gufunc_kwargs=gufunc_kwargs, keep_attrs=False)
    split = dict(specs=specs, factor=factor, nu=nu, ny=ny, closed_loop=s.closed_loop)
    lazy = any(v.chunks is not None for v in (r, u, y))
    noise = plan.noise_covariance if plan is not None else None
    th = even_spacing(r[cv.TIME].values, cv.TIME)[1]
    if plan is not None and plan.window0:  # G bin by bin over the experiments' periods
        def kernel(r_, u_, y_):
            _guards.check_finite(r_, u_, y_, th=th, factor=factor)
            return _split(identify_window0_arrays(r_, u_, y_, factor=factor,
                                                  closed_loop=s.closed_loop,
                                                  covariance=s.covariance), **split)

        pooled_dims = [cv.EXPERIMENT, cv.PERIOD]
        results = xr.apply_ufunc(kernel, r, u, y, input_core_dims=[pooled_dims + c for c in core_in],
                                 **output_spec)
    elif s.frequency_chunks is None:
        windows = _candidate_windows(s, factor * nu, n // factor) if auto else None

        kernel = record_kernel(s, factor=factor, n=n, nu=nu, th=th, windows=windows,
                               check_rank=check_rank and not lazy and not pooled,
                               experiment_axis=exp_axis, split=split)
        extra = [] if noise is None else [noise]
        extra_core = [] if noise is None else [[SF, "_z", "_z2"]]
        results = xr.apply_ufunc(kernel, r, u, y, *extra, input_core_dims=core_in + extra_core,
                                 **output_spec)
    else:
        n_exp = r.sizes[cv.EXPERIMENT] if pooled else None
        windows = _candidate_windows(s, factor * nu, n // factor) if auto else (s.window,)
        # window="auto" with a least-squares denominator: the widest window's IV twin
        # (kernels.adaptive.denominator_bias), whose instruments are that window's own
        # least-squares prediction G R + T, from the widest candidate's chunked fit (as the
        # eager path takes it from that candidate: no first fit of its own)
        twin = auto and checks_denominator_bias(_kernel_denominator(s), s.degrees,
                                                s.closed_loop, n_exp,
                                                known_noise=noise is not None)
        halo = max(windows) + _first_fit_halo(s, factor * nu)
        if halo > s.frequency_chunks:
            what = (f"the widest candidate window of window='auto' ({max(windows)} bins"
                    if auto else f"the window ({s.window} bins")
            if halo > max(windows):
                what += f" plus {halo - max(windows)} for the first fit of denominator='iv'"
            raise ValueError(
                f"frequency_chunks={s.frequency_chunks} is smaller than the halo of {what} on "
                f"each side); use frequency_chunks >= {halo}."
            )
        # the spectra once, for every candidate (and the twin)
        R, Z = _chunked_spectra(r, u, y, factor=factor, closed_loop=s.closed_loop,
                                check_rank=check_rank)
        # one chunked fit per candidate window (one for a fixed window), stacked in front;
        # auto's candidates of one record with their covariance from their residuals (the
        # fits the resolution floor applies to) also carry their terms without the floor,
        # from which the choice is made, as on the eager path
        unfloored = auto and not pooled and noise is None
        fits = [_fit_frequency_chunked(R, Z, s._replace(window=w), factor=factor, noise=noise,
                                       pooled=pooled, unfloored=unfloored) for w in windows]
        if twin:
            zhat = _chunked_prediction(fits[-1], R, Z, chunk=s.frequency_chunks)
            iv = _fit_frequency_chunked(R, Z, s._replace(window=max(windows), denominator="iv"),
                                        factor=factor, pooled=pooled, instruments=zhat,
                                        select=twin_bins(R.sizes[SF]))
            # (padded to the candidates' columns to stack with them; finish_packed reads
            # its own columns only)
            fits.append(iv.pad({"_packed": (0, fits[0].sizes["_packed"] - iv.sizes["_packed"])}))
        packed = xr.concat(fits, "_candidate")
        nz_, nr_ = packed.attrs["nz"], packed.attrs["nr"]
        shape = dict(nz=nz_, nr=nr_, n_fast=n, factor=factor, nu=nu, ny=ny,
                     closed_loop=s.closed_loop)

        def finish(p):
            p = np.moveaxis(np.ascontiguousarray(p).view(complex), -3, 0)  # candidates first
            if auto:
                return _split(finish_packed_auto(p[:len(windows)], windows=windows,
                                                 degrees=s.degrees, n_exp=n_exp,
                                                 twin=p[len(windows)] if twin else None,
                                                 known_noise=noise is not None,
                                                 unfloored=unfloored, **shape), **split)
            return _split(finish_packed(p[0], covariance=s.covariance, n_exp=n_exp,
                                        dof=window_dof(s.window, nr_, s.degrees, n_exp or 1),
                                        neighbourhood=not pooled and noise is None,
                                        **shape), **split)

        # the recovery gathers every slow bin (P(k) uses bin k mod M): one chunk along it
        results = xr.apply_ufunc(finish, packed.chunk({SF: -1, "_candidate": -1, "_packed": -1}),
                                 input_core_dims=[["_candidate", SF, "_packed"]], **output_spec)
    return xr.Dataset({name: da for (name, _, _), da in zip(specs, results)})


def record_kernel(s, *, factor: int, n: int, nu: int, th: float, split: dict, check_rank: bool,
                  windows=None, experiment_axis=None):
    """The eager kernel of :func:`identify`: ``kernel(r, u, y[, noise_covariance])`` on numpy
    arrays (trailing axes (``N``, ``nu``), (``N``, ``nu``), (``M``, ``ny``)) returning the
    unlabelled outputs of ``split["specs"]`` (:func:`output_specs`) in order.

    Checks NaN/inf (naming the variable and time range), the excitation rank
    (``check_rank``), scales data of extreme magnitude by powers of two, fits and finishes.
    ``windows``: the candidates of ``window="auto"`` (None: ``s.window``).  A sweep task
    calls it once per experiment and labels its block once
    (:func:`lcmr_xr.scaleout.sweep._identify_block`).
    """
    def fit(r_, u_, y_, noise_covariance=None):
        R, Z = experiment_spectra(r_, u_, y_, factor=factor, closed_loop=s.closed_loop)
        # lazy: the local model's condition numbers flag it; pooled: only the
        # experiments together need to excite every lifted channel (flagged likewise)
        if check_rank:
            _check_excitation_rank(R, "r" if s.closed_loop == "indirect" else "u")
        if windows is not None:  # a window per slow bin (kernels.adaptive), same guards as below
            return identify_spectra_auto(R, Z, n_fast=n, factor=factor, nu=nu,
                                         windows=windows, degrees=s.degrees,
                                         closed_loop=s.closed_loop,
                                         noise_covariance=noise_covariance,
                                         experiment_axis=experiment_axis,
                                         denominator=_kernel_denominator(s))
        return identify_spectra(R, Z, n_fast=n, factor=factor, nu=nu, half_width=s.window,
                                degrees=s.degrees, closed_loop=s.closed_loop,
                                covariance=s.covariance, noise_covariance=noise_covariance,
                                experiment_axis=experiment_axis, denominator=_kernel_denominator(s))

    def kernel(r_, u_, y_, *noise_cov):
        # lazy data were not checked by the validation: name the variable and time range
        _guards.check_finite(r_, u_, y_, th=th, factor=factor)
        # data of extreme magnitude are fitted scaled by powers of two (exact), then unscaled
        return _split(_guards.scaled_call(fit, r_, u_, y_, closed_loop=s.closed_loop,
                                          noise_covariance=noise_cov[0] if noise_cov else None),
                      **split)

    return kernel


def _candidate_windows(s, n_excitation: int, n_bins: int) -> tuple[int, ...]:
    """The half-widths ``window="auto"`` chooses from (settings already checked to fit)."""
    return candidate_windows(*auto_window_range(s.degrees, n_excitation, n_bins))


def _chunked_spectra(r, u, y, *, factor, closed_loop, check_rank):
    """The spectra ``R`` (..., ``slow_frequency``, ``_r``) and ``Z`` (..., ``_z``) of
    :func:`_fit_frequency_chunked`, lazy for lazy data, with the NaN/inf and magnitude
    checks of the chunked path; on eager data the excitation rank is checked on them
    (``check_rank``)."""
    m = y.sizes[cv.SLOW_TIME]
    nu, ny = r.sizes[cv.INPUT], y.sizes[cv.OUTPUT]
    nr = factor * nu
    nz = nr + ny if closed_loop == "indirect" else ny
    th = even_spacing(r[cv.TIME].values, cv.TIME)[1]

    def spectra(r, u, y):
        _guards.check_finite(r, u, y, th=th, factor=factor)
        if _guards.scales(r, u, y) != (1.0, 1.0, 1.0):
            raise ValueError(
                f"r, u or y has magnitudes beyond {_guards.SAFE_MAGNITUDE:g} or below "
                f"{1 / _guards.SAFE_MAGNITUDE:g}, where products of spectra overflow or underflow; "
                "frequency_chunks does not rescale: drop frequency_chunks (identify then scales "
                "internally) or express the data in other units."
            )
        return experiment_spectra(r, u, y, factor=factor, closed_loop=closed_loop)

    R, Z = xr.apply_ufunc(
        spectra,
        r, u, y,
        input_core_dims=[[cv.TIME, cv.INPUT], [cv.TIME, cv.INPUT], [cv.SLOW_TIME, cv.OUTPUT]],
        output_core_dims=[[SF, "_r"], [SF, "_z"]], dask="parallelized",
        output_dtypes=[complex, complex],
        dask_gufunc_kwargs={"output_sizes": {SF: m, "_r": nr, "_z": nz}},
    )
    if check_rank and R.chunks is None:
        _check_excitation_rank(R.values, "r" if closed_loop == "indirect" else "u")
    return R, Z


def _chunked_prediction(packed, R, Z, *, chunk):
    """The instruments ``G R + T`` (:func:`lcmr_xr.kernels.identification._prediction`,
    not circular) from a least-squares chunked fit ``packed`` of :func:`_fit_frequency_chunked`
    (one record), lazily, chunk by chunk along ``slow_frequency`` (``chunk`` bins)."""
    nz, nr = packed.attrs["nz"], packed.attrs["nr"]

    def predict(p, r_, z_):
        p = np.ascontiguousarray(p).view(complex)
        G = p[..., : nz * nr].reshape(p.shape[:-1] + (nz, nr))
        return _prediction(G, p[..., nz * nr: nz * nr + nz], r_, z_, circular=False)

    def along(x):
        return x.chunk({SF: chunk})

    return xr.apply_ufunc(predict, packed, along(R), along(Z),
                          input_core_dims=[["_packed"], ["_r"], ["_z"]],
                          output_core_dims=[["_z"]], dask="parallelized",
                          output_dtypes=[complex])


def _fit_frequency_chunked(R, Z, s, *, factor, noise=None, pooled=False, instruments=None,
                           select=None, unfloored: bool = False):
    """Lazy local-model fit in chunks along ``slow_frequency`` with wrapped halos.

    ``R``, ``Z``: the spectra of :func:`_chunked_spectra`.  ``noise`` (..., ``slow_frequency``,
    ``_z``, ``_z2``), optional: the noise covariance known per bin (periods), haloed like
    the spectra.  ``pooled``: one local model over the ``experiment`` dim (kept in one
    chunk; the fitted blocks drop it).  With ``denominator="iv"`` the halo is ``window`` plus
    that of the instruments' first fit (:func:`_first_fit_halo`).  ``instruments`` (..., ``slow_frequency``, ``_z``),
    optional, one record: those of ``denominator="iv"`` (:func:`_chunked_prediction`),
    haloed like the spectra; then there is no first fit and the halo is ``window``.
    ``select`` (``slow_frequency``,) bool, optional: fit only those bins, the others NaN
    (the twin's :func:`lcmr_xr.kernels.identification.twin_bins`).  ``unfloored``: also the
    terms without the resolution floor (:func:`lcmr_xr.kernels.identification.fit_packed`),
    for ``window="auto"``'s choice.

    Returns a DataArray (..., ``slow_frequency``, ``_packed``) of :func:`fit_packed` columns.
    """
    import dask.array as da

    chunk, window, closed_loop = s.frequency_chunks, s.window, s.closed_loop
    nr, nz = R.sizes["_r"], Z.sizes["_z"]
    # the instruments' first fit (IV without given instruments) needs its own halo
    halo = window + (0 if instruments is not None else _first_fit_halo(s, nr))

    def one_chunk(d, x):  # pooled: every experiment in each block (one local model)
        return -1 if (pooled and d == cv.EXPERIMENT) or x.chunks is None \
            else x.chunks[x.get_axis_num(d)]

    lead = [d for d in R.dims if d not in (SF, "_r")]
    Rd = R.chunk({**{d: one_chunk(d, R) for d in lead}, SF: chunk, "_r": -1}).data
    Zd = Z.chunk({**{d: one_chunk(d, Z) for d in lead}, SF: chunk, "_z": -1}).data
    ax = Rd.ndim - 2
    depth = {i: 0 for i in range(Rd.ndim)}
    depth[ax] = halo
    boundary = {i: "none" for i in range(Rd.ndim)}
    boundary[ax] = "periodic"
    Rg = da.overlap.overlap(Rd, depth=depth, boundary=boundary)
    Zg = da.overlap.overlap(Zd, depth=depth, boundary=boundary)
    exp_ax = R.dims.index(cv.EXPERIMENT) if pooled else None
    n_exp = R.sizes[cv.EXPERIMENT] if pooled else 1
    width = packed_width(nz, nr, s.covariance, n_exp, closed_loop, unfloored)
    blocks = [Rg, Zg]
    if instruments is not None:
        Wd = instruments.transpose(*R.dims[:-1], "_z").chunk(
            {**dict(zip(R.dims[:-1], Rd.chunks[:-1])), "_z": -1}).data
        blocks.append(da.overlap.overlap(Wd, depth=depth, boundary=boundary))
    if noise is not None:  # (..., SF, nz nz) flat, so its blocks line up with R's and Z's
        if pooled:  # one noise covariance for all experiments: repeated along their dim
            noise = noise.expand_dims({cv.EXPERIMENT: n_exp})
        flat = noise.transpose(*R.dims[:-1], "_z", "_z2").stack(_zz=("_z", "_z2"))
        flat = flat.drop_vars(["_zz", "_z", "_z2"], errors="ignore")
        Nd = flat.chunk({**dict(zip(R.dims[:-1], Rd.chunks[:-1])), "_zz": -1}).data
        blocks.append(da.overlap.overlap(Nd, depth=depth, boundary=boundary))

    # where each haloed block's own bins start: from the overlapped chunks, not Rd's, since
    # dask's overlap re-chunks chunks smaller than the halo (e.g. a last chunk of 8 bins
    # is merged), which shifts every later block's first bin
    starts = np.cumsum((0,) + tuple(c - 2 * halo for c in Rg.chunks[ax]))
    m = R.sizes[SF]

    def fit_block(rb, zb, *nb, block_id=None):
        sb = None
        if select is not None:  # this block's bins, haloed (wrapped) like the spectra
            # (block_id is the output block's: pooled, without the experiment axis)
            first = starts[block_id[ax - (pooled and exp_ax < ax)]] - halo
            sb = np.take(select, np.arange(first, first + rb.shape[ax]) % m)
        wb = None
        if instruments is not None:
            wb, nb = nb[0], nb[1:]
        known = nb[0].reshape(nb[0].shape[:-1] + (nz, nz)) if nb else None
        if known is not None and pooled:
            known = np.take(known, 0, axis=exp_ax)
        return fit_packed(rb, zb, half_width=window, degrees=s.degrees, circular=False,
                          covariance=s.covariance, noise_covariance=known,
                          experiment_axis=exp_ax, denominator=_kernel_denominator(s),
                          closed_loop=closed_loop, instruments=wb, select=sb,
                          unfloored=unfloored)

    chunks = Rg.chunks[:-1] + ((width,),)
    if pooled:  # the fit pools the experiment axis away
        chunks = chunks[:exp_ax] + chunks[exp_ax + 1:]
        depth = {i: depth[j] for i, j in enumerate(k for k in range(Rd.ndim) if k != exp_ax)}
        boundary = {i: boundary[j] for i, j in
                    enumerate(k for k in range(Rd.ndim) if k != exp_ax)}
    fitted = da.map_blocks(fit_block, *blocks, dtype=complex, chunks=chunks,
                           drop_axis=[exp_ax] if pooled else [])
    trimmed = da.overlap.trim_internal(fitted, {**depth}, boundary=boundary)
    # a float view (pairs of re, im) so dask builds real metadata for the real outputs
    dims = [d for d in R.dims[:-1] if d != cv.EXPERIMENT or not pooled]
    out = xr.DataArray(trimmed.view(float), dims=tuple(dims) + ("_packed",),
                       coords={k: v for k, v in R.coords.items()
                               if k in dims and cv.EXPERIMENT not in R[k].dims})
    out.attrs.update(nz=nz, nr=nr)
    return out


def _kernel_denominator(s) -> str:
    """The kernels' ``denominator`` for settings ``s`` (no denominator: least squares)."""
    return "iv" if s.denominator == "iv" else "ls"


def _first_fit_halo(s, n_excitation: int) -> int:
    """Extra halo bins the first fit of ``denominator="iv"`` needs (0 for least squares)."""
    return first_fit_window(n_excitation, s.degrees) if s.denominator == "iv" else 0


def _is_lazy(ds):
    # the data's own attribute: ``Variable.chunks`` checks a runtime Protocol (~0.1 ms per
    # variable, 2 ms per identify result)
    return any(hasattr(ds.variables[name].data, "chunks") for name in ds.data_vars)


def _check_excitation_rank(R, name: str) -> None:
    """Refuse an excitation that does not excite every lifted channel (rank-deficient R)."""
    nr = R.shape[-1]
    rank, sv = excitation_rank(R)
    if rank < nr:
        raise ValueError(
            f"the lifted {name} has rank {rank} < F*nu = {nr}: not every lifted channel is "
            f"excited independently (smallest/largest singular value "
            f"{float(np.min(sv[..., -1] / np.maximum(sv[..., 0], np.finfo(float).tiny))):.1e}). A signal held constant over each "
            f"slow period (or any signal whose F phases are linear combinations of each other) "
            f"cannot identify the fast plant. Excite at the fast rate over all fast bins, e.g. "
            f"lcmr_xr.multisine(N, sampling_period=Th, rms=...) per input."
        )


def _label(out, ds, *, factor, th):
    """Coordinates, ``long_name`` and ``units`` of an (un)computed result of :func:`_estimate`.

    ``ds`` is the experiment the estimate came from, ``th`` its fast sampling period;
    ``factor`` is that of the estimate (``1`` for the single-rate one, whose "fast" samples
    are the slow ones).  Only what ``out`` holds is labelled.
    """
    m = out.sizes[cv.SLOW_FREQUENCY]
    n = m * factor  # samples of the estimate's fast grid
    record = ds.sizes[cv.TIME] * th  # record length N Th = M Tl, s
    u_units = ds["u"].attrs.get("units", "1")
    y_units = ds["y"].attrs.get("units", "1")
    p_units = _ratio_units(y_units, u_units)
    coords = {
        cv.FREQUENCY: (cv.FREQUENCY, np.arange(n // 2 + 1) / record, cv.frequency_attrs("frequency")),
        cv.SLOW_FREQUENCY: (cv.SLOW_FREQUENCY, np.arange(m) / record,
                            cv.frequency_attrs("slow-rate DFT frequency")),
        cv.LIFT_PHASE: (cv.LIFT_PHASE, np.arange(factor), cv.label_attrs("lift phase (fast sample within a slow period)")),
        cv.LIFT_PHASE2: (cv.LIFT_PHASE2, np.arange(factor), cv.label_attrs("lift phase of the excitation")),
        cv.INPUT: ds[cv.INPUT].variable,
        cv.OUTPUT: ds[cv.OUTPUT].variable,
        cv.INPUT2: (cv.INPUT2, ds[cv.INPUT].values, cv.label_attrs("excited input")),
    }
    if RESPONSE in out.dims:
        rows, columns = _stacked_labels(ds, factor, out.sizes[RESPONSE])
        coords[RESPONSE] = (RESPONSE, rows, cv.label_attrs("spectrum fitted: lifted u (phase, input), then y"))
        coords[EXCITATION] = (EXCITATION, columns, cv.label_attrs("excitation spectrum: lifted (phase, input)"))
    out = out.assign_coords({k: v for k, v in coords.items() if k in out.dims or k in (cv.INPUT, cv.OUTPUT)})
    for name in ds.coords:
        if name not in out.coords and set(ds[name].dims) <= set(out.dims):
            out = out.assign_coords({name: ds[name]})
    ru = ds["r"].attrs.get("units", "1")
    meta = {
        "P": ("plant FRF", p_units),
        "P_std": ("uncertainty of P (95 % disc radius / sqrt(ln 20))", p_units),
        "P_flag": ("P could not be estimated", "1"),
        "PS": ("lifted process sensitivity, first block row", _ratio_units(y_units, ru)),
        "PS_std": ("standard deviation of PS", _ratio_units(y_units, ru)),
        "S": ("lifted sensitivity", _ratio_units(u_units, ru)),
        "S_std": ("standard deviation of S", _ratio_units(u_units, ru)),
        "transient_y": ("local transient of the output spectrum", y_units),
        "transient_u": ("local transient of the lifted input spectrum", u_units),
        "noise_variance_y": ("residual noise variance of the output spectrum", cv.squared_units(y_units)),
        "noise_variance_u": ("residual noise variance of the lifted input spectrum", cv.squared_units(u_units)),
        "condition": ("condition number of the local least-squares problem", "1"),
        "ill_posed": ("local model ill-posed", "1"),
        "s_condition": ("condition number of the estimated lifted sensitivity", "1"),
        "s_singular": ("lifted sensitivity not invertible", "1"),
        cv.S_WEAK_REL_STD: ("relative standard deviation of the weakest direction of S", "1"),
        "P_std_linear": ("first-order noise standard deviation of P", p_units),
        "P_undetermined": ("P not determined by the data (unbounded band)", "1"),
        "P_bias": ("estimated model error of P", p_units),
        "local_window": ("chosen local window half-width n", "1"),
        cv.SPREAD_CALIBRATION: ("factor on the pooled covariance from the split-half spread", "1"),
        cv.P_SPREAD_CALIBRATION: ("factor on the pooled variance of P from the split halves' P",
                                  "1"),
        "G": ("lifted local model [S; PS] (rows: response, columns: excitation)",
              f"{_ratio_units(u_units, ru)} (u rows), {_ratio_units(y_units, ru)} (y rows)"),
        "G_std": ("standard deviation of G",
                  f"{_ratio_units(u_units, ru)} (u rows), {_ratio_units(y_units, ru)} (y rows)"),
        "noise_variance": ("residual noise variance of the response spectra",
                           f"{cv.squared_units(u_units)} (u rows), {cv.squared_units(y_units)} (y rows)"),
    }
    for name, (long_name, units) in meta.items():
        if name in out:
            out[name].attrs.update({"long_name": long_name, "units": units})
    return out


def _stacked_labels(ds, factor, n_rows):
    """Labels of the rows (``u:phase:input`` then ``y:output``) and columns of ``G``."""
    name = "r" if n_rows > ds.sizes[cv.OUTPUT] else "u"  # direct: G maps lifted u to y
    inputs = [str(i) for i in ds[cv.INPUT].values]
    lifted = [f"{{}}:{j}:{i}" for j in range(factor) for i in inputs]
    rows = [s.format("u") for s in lifted] if name == "r" else []
    rows += [f"y:{o}" for o in ds[cv.OUTPUT].values]
    return rows, [s.format(name) for s in lifted]


def identify_single_rate(experiment: xr.Dataset, *, method: str = "lrm", window: int = 30,
                         degrees=None, covariance: bool = True) -> xr.Dataset:
    """Single-rate closed-loop estimate that ignores the multirate structure (for comparison).

    ``r`` and ``u`` are sampled at the slow rate (``x(l F)``) and the ordinary indirect
    local model ``P = PS S^-1`` is formed from ``[U_l; Y_l]`` on the slow DFT grid.  It
    only reaches the slow Nyquist frequency ``1 / (2 F Th)``, and fast dynamics alias onto
    it: this is the estimate the lifted method (:func:`identify`) improves on.

    Parameters
    ----------
    experiment : xarray.Dataset
        Experiment dataset (lcmr-xr-1 conventions).
    method : {"lrm", "lpm"}, default "lrm"
        Local rational or polynomial model.
    window : int, default 30
        Half-width ``n`` of the local window (``2 n + 1`` slow bins).
    degrees : (int, int, int) or str, optional
        ``(Rn, Rm, Rd)`` or ``"Rn-Rm-Rd"``; default ``(3, 3, 3)`` (LRM) or ``(3, 3, 0)`` (LPM),
        the rules of :func:`identify`.
    covariance : bool, default True
        Return ``P_std`` from the local-model covariance.

    Returns
    -------
    xarray.Dataset
        ``P``, ``P_std``, ``P_flag`` on ``frequency`` = slow bins ``m / (M Tl)``,
        ``m = 0..M/2`` (Hz); attributes as :func:`identify`.
    """
    s = estimator_settings(method=method, window=window, degrees=degrees, covariance=covariance)
    if s.window == AUTO_WINDOW:
        raise ValueError("identify_single_rate takes an integer window (the comparison estimate "
                         "of the paper, e.g. window=30); window='auto' is for identify.")
    ds, spread = _validate(experiment)
    factor = experiment_factor(ds)
    check_window_fits(s.window, s.degrees, ds.sizes[cv.INPUT], ds.sizes[cv.SLOW_TIME])
    th = even_spacing(ds[cv.TIME].values, cv.TIME)[1]
    # the lifted pipeline with F = 1 on the slow samples x(l F) of r and u
    slow = {cv.TIME: slice(None, None, factor)}
    out = _estimate(ds["r"].isel(slow), ds["u"].isel(slow), ds["y"], s, factor=1, stacked=False,
                    check_rank=False)
    out = _label(out, ds, factor=1, th=th)[["P", "P_std", "P_flag"]]
    out["P"].attrs["long_name"] = "plant FRF (single-rate estimate)"
    attrs = _settings_attrs(ds, s, factor=factor, th=th)
    for key in ("parameters_per_row", "covariance"):  # not recorded for this estimate
        attrs.pop(key)
    attrs.update({"closed_loop": "single-rate indirect",
                  "title": f"single-rate closed-loop {s.method.upper()} FRF estimate (ignores lifting)"})
    out.attrs.update(attrs)
    return _guards.gated(out, spread)


def result_template(ds: xr.Dataset, s, *, stacked: bool = False) -> xr.Dataset:
    """Lazy zeros shaped, labelled and chunked like ``identify(ds, ...)``, computing nothing.

    Derived from :func:`output_specs` and :func:`output_sizes`: what
    :func:`xarray.map_blocks` needs as the template of a blockwise ``identify``
    (:func:`lcmr_xr.scaleout.sweep`).  Leading dims of ``ds["r"]`` keep their chunks.

    Parameters
    ----------
    ds : xarray.Dataset
        Experiment dataset (may be dask-backed).
    s : lcmr_xr.settings.EstimatorSettings
        Validated settings (:func:`lcmr_xr.settings.estimator_settings`).
    stacked : bool, default False
        As in :func:`identify`.

    Returns
    -------
    xarray.Dataset
        Dask zeros with the variables, dims, coords and attributes of the result.
    """
    import dask.array as dsa

    factor = experiment_factor(ds)
    th = even_spacing(ds[cv.TIME].values, cv.TIME)[1]
    r = ds["r"]
    lead = [d for d in r.dims if d not in (cv.TIME, cv.INPUT, cv.PERIOD)]  # periods: averaged
    lead_shape = tuple(ds.sizes[d] for d in lead)
    lead_chunks = tuple(r.chunks[r.get_axis_num(d)] if r.chunks else (ds.sizes[d],) for d in lead)
    sizes = output_sizes(factor=factor, n=ds.sizes[cv.TIME], nu=ds.sizes[cv.INPUT],
                         ny=ds.sizes[cv.OUTPUT], closed_loop=s.closed_loop)
    variables = {}
    for name, dims, dtype in output_specs(s.closed_loop, stacked):
        shape = tuple(sizes[d] for d in dims)
        data = dsa.zeros(lead_shape + shape, dtype=dtype, chunks=lead_chunks + tuple((k,) for k in shape))
        variables[name] = (tuple(lead) + tuple(dims), data)
    out = _label(xr.Dataset(variables), ds, factor=factor, th=th)
    out.attrs.update(_settings_attrs(ds, s, factor=factor, th=th))
    if cv.PERIOD in ds.dims:  # identify averages the periods: its pooling outputs, lazily
        plan = pooling.plan(ds, window=s.window, transient_periods=None, combine=None,
                            closed_loop=s.closed_loop, covariance=s.covariance,
                            frequency_chunks=None)
        out = pooling.finish(out, plan, closed_loop=s.closed_loop, factor=factor,
                             y_units=ds["y"].attrs.get("units", "1"),
                             u_units=ds["u"].attrs.get("units", "1"))
    return out


def stacked_local_model(result: xr.Dataset) -> tuple[xr.DataArray, xr.DataArray]:
    """The local-model estimate ``G`` and the residual variances of its rows, stacked.

    ``G`` (..., ``slow_frequency``, ``response``, ``excitation``) maps the lifted excitation
    spectra to the spectra ``[U; Y]`` (``Y`` alone for ``closed_loop="direct"``);
    ``noise_variance`` (..., ``slow_frequency``, ``response``).  Taken as they are from a
    result of ``identify(..., stacked=True)``; otherwise (a result of
    :func:`lcmr_xr.scaleout.sweep`, say) rebuilt from its blocks ``S``, ``PS``,
    ``noise_variance_u`` and ``noise_variance_y`` -- the inverse of how :func:`identify`
    cuts them.

    Parameters
    ----------
    result : xarray.Dataset
        A result of :func:`identify` or :func:`lcmr_xr.scaleout.sweep` (extra leading dims
        such as ``experiment`` or the sweep's settings are kept, in front).

    Returns
    -------
    (xarray.DataArray, xarray.DataArray)
        ``G`` and ``noise_variance``, computed if ``result`` is.
    """
    if "G" in result and "noise_variance" in result:
        return (result["G"].transpose(..., SF, RESPONSE, EXCITATION),
                result["noise_variance"].transpose(..., SF, RESPONSE))
    ps = result["PS"].transpose(..., SF, cv.OUTPUT, LP2, IN2)
    lead = list(ps.dims[:-4])
    G = ps.data.reshape(ps.shape[:-2] + (-1,))
    noise = result["noise_variance_y"].transpose(*lead, SF, cv.OUTPUT).data
    if "S" in result:  # indirect: the rows of the lifted u come first
        S = result["S"].transpose(*lead, SF, LP, cv.INPUT, LP2, IN2)
        rows = S.shape[-4] * S.shape[-3]
        G = _concat([S.data.reshape(S.shape[:-4] + (rows, -1)), G], axis=-2)
        nu_ = result["noise_variance_u"].transpose(*lead, SF, LP, cv.INPUT).data
        noise = _concat([nu_.reshape(nu_.shape[:-2] + (rows,)), noise], axis=-1)
    coords = {d: result[d] for d in lead + [SF] if d in result.coords}
    return (xr.DataArray(G, dims=lead + [SF, RESPONSE, EXCITATION], coords=coords),
            xr.DataArray(noise, dims=lead + [SF, RESPONSE], coords=coords))


def _concat(arrays, axis):
    """``numpy.concatenate`` that stays lazy for dask arrays."""
    if any(hasattr(a, "dask") for a in arrays):
        import dask.array as dsa

        return dsa.concatenate(arrays, axis=axis)
    return np.concatenate(arrays, axis=axis)
