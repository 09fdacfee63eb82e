"""``identify``: the paper's Procedure 1 on a labelled experiment dataset.

A thin layer: dimension names are mapped onto the trailing axes of
:func:`lcmr_xr.kernels.identification.identify_arrays` with ``xarray.apply_ufunc``
(``dask="parallelized"``, so leading dims such as ``experiment`` may be chunked), and
the arrays that come back are labelled per ``shared/conventions.md``.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.kernels.identification import (
    excitation_rank,
    experiment_spectra,
    finish_packed,
    fit_packed,
    identify_arrays,
    identify_arrays_auto,
    identify_single_rate_arrays,
    lifted_spectra,
    packed_width,
    window_dof,
)
from lcmr_xr.kernels.adaptive import candidate_windows
from lcmr_xr.kernels.local_models import parameters_per_row

METHODS = {"lrm": None, "lpm": 0}
DEFAULT_DEGREES = {"lrm": (3, 3, 3), "lpm": (3, 3, 0)}
ERRORS = ("raise", "ignore")


def _validate(experiment):
    from lcmr_xr.experiment import validate_experiment

    if not isinstance(experiment, xr.Dataset):
        raise TypeError(
            f"identify expects an experiment xarray.Dataset (variables r, u, y; see "
            f"lcmr_xr.experiment), got {type(experiment).__name__}. Build one with "
            f"lcmr_xr.experiment(r, u, y, factor=F, sampling_period=Th)."
        )
    lazy = any(experiment[v].chunks is not None for v in ("r", "u", "y") if v in experiment)
    # lazy data stay lazy: the NaN/inf check then happens in the kernel, at compute time
    return validate_experiment(experiment, check_values=not lazy)


def _resolve_degrees(method, degrees):
    if method not in METHODS:
        raise ValueError(f"method must be 'lrm' or 'lpm', got {method!r}.")
    if degrees is None:
        return DEFAULT_DEGREES[method]
    try:
        degrees = tuple(int(d) for d in degrees)
    except TypeError:
        raise TypeError(
            f"degrees must be a sequence (Rn, Rm, Rd) of three non-negative integers, got {degrees!r}."
        ) from None
    if len(degrees) == 2 and method == "lpm":
        degrees = degrees + (0,)
    if len(degrees) != 3 or min(degrees) < 0:
        raise ValueError(
            f"degrees must be (Rn, Rm, Rd), three non-negative integers, got {degrees!r}."
        )
    if method == "lpm" and degrees[2] != 0:
        raise ValueError(
            f"method='lpm' is the local polynomial model, whose denominator degree Rd is 0; "
            f"got degrees={degrees}. Pass degrees=({degrees[0]}, {degrees[1]}, 0) or method='lrm'."
        )
    return degrees


def _check_window(window, degrees, nr, m):
    window = int(window)
    if window < 1:
        raise ValueError(f"window (the half-width n of the 2n+1-bin local window) must be >= 1, got {window}.")
    p = parameters_per_row(nr, degrees)
    if 2 * window + 1 <= p:  # at least one degree of freedom is left for the noise estimate
        n_min = (p + 1) // 2
        raise ValueError(
            f"too few bins for the local model: window={window} gives 2n+1 = {2 * window + 1} bins "
            f"per row but degrees {degrees} with {nr} lifted excitation channels need "
            f"{p} parameters per row and at least one more bin for the noise estimate. "
            f"Use window >= {n_min} (or lower degrees)."
        )
    if 2 * window + 1 > m:
        raise ValueError(
            f"the local window (2n+1 = {2 * window + 1} bins for window={window}) is wider than the "
            f"spectrum ({m} slow bins). Use window <= {(m - 1) // 2} or a longer experiment."
        )
    return window


def _ratio_units(num: str, den: str) -> str:
    if den in ("1", ""):
        return num
    if any(c in den for c in " /*"):
        den = f"({den})"
    return f"{num}/{den}"


def identify(experiment: xr.Dataset, *, method: str = "lrm", window="auto", degrees=None,
             closed_loop: str = "indirect", covariance: bool = True, errors: str = "raise",
             frequency_chunks: int | None = None) -> xr.Dataset:
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
        the estimated model error is part of ``P_std``.
    degrees : (int, int, int), optional
        ``(Rn, Rm, Rd)``: degrees of the numerator, transient and (diagonal) denominator
        polynomials in the local frequency variable.  Default ``(3, 3, 3)`` for LRM and
        ``(3, 3, 0)`` for LPM (a pair ``(Rn, Rm)`` is accepted for LPM).
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
        parallel when the experiment is dask-backed).  The singular-``S`` check of
        ``errors="raise"`` runs only on computed (not lazy) results.

    Returns
    -------
    xarray.Dataset
        ``P`` (``frequency``, ``output``, ``input``), complex: fast FRF at bins
        ``k / (N Th)``, ``k = 0..N/2``; ``P_std``: uncertainty of ``P`` calibrated so that
        the disc ``|P_hat - P| <= sqrt(ln 20) P_std`` is a 95 % region (first-order noise
        standard deviation ``P_std_linear`` times a small-sample factor and, for the
        indirect method, a factor for the nonlinearity of ``S^-1``, plus the model-error
        estimate ``P_bias`` with ``window="auto"``); ``inf`` where ``P_undetermined``: the
        data do not determine the weakest direction of ``S`` there, so no finite band can
        be promised (``docs/uncertainty.md``).  ``P_flag``: bins that could not be
        estimated.  ``s_weak_rel_std`` (``slow_frequency``): relative standard deviation of
        the weakest direction of ``S``.  Lifted estimates on ``slow_frequency``: ``S`` (``lift_phase``, ``input``,
        ``lift_phase2``, ``input2``), ``PS`` (``output``, ``lift_phase2``, ``input2``) with
        ``S_std``, ``PS_std``; residual noise variances ``noise_variance_u``,
        ``noise_variance_y``; transients ``transient_u``, ``transient_y``; ``condition``,
        ``ill_posed``, ``s_condition``, ``s_singular``.  Attributes record every setting.

    Raises
    ------
    TypeError
        ``experiment`` is not an experiment dataset.
    ValueError
        Invalid settings, too few bins for the number of parameters, a window wider than
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
    """
    if errors not in ERRORS:
        raise ValueError(f"errors must be 'raise' or 'ignore', got {errors!r}.")
    ds = _validate(experiment)
    degrees = _resolve_degrees(method, degrees)
    factor = int(ds.attrs[cv.FACTOR])
    n = ds.sizes[cv.TIME]
    m = ds.sizes[cv.SLOW_TIME]
    nu = ds.sizes[cv.INPUT]
    ny = ds.sizes[cv.OUTPUT]
    nr = factor * nu  # lifted r (indirect) or lifted u (direct): F nu channels either way
    auto = isinstance(window, str)
    if auto:
        windows = _auto_windows(window, degrees, nr, m, frequency_chunks, covariance)
    else:
        window = _check_window(window, degrees, nr, m)
    th = float(ds[cv.TIME][1] - ds[cv.TIME][0])
    _check_excitation(ds, factor, closed_loop)

    core_in = [[cv.TIME, cv.INPUT], [cv.TIME, cv.INPUT], [cv.SLOW_TIME, cv.OUTPUT]]
    LP, IN2, LP2 = cv.LIFT_PHASE, cv.INPUT + cv.SECOND, cv.LIFT_PHASE + cv.SECOND
    FQ, SF = cv.FREQUENCY, cv.SLOW_FREQUENCY
    specs = [  # (name, core dims, dtype)
        ("P", [FQ, cv.OUTPUT, cv.INPUT], complex),
        ("P_std", [FQ, cv.OUTPUT, cv.INPUT], float),
        ("P_flag", [FQ], bool),
        ("PS", [SF, cv.OUTPUT, LP2, IN2], complex),
        ("PS_std", [SF, cv.OUTPUT, LP2, IN2], float),
        ("transient_y", [SF, cv.OUTPUT], complex),
        ("noise_variance_y", [SF, cv.OUTPUT], float),
        ("condition", [SF], float),
        ("ill_posed", [SF], bool),
        ("P_std_linear", [FQ, cv.OUTPUT, cv.INPUT], float),
        ("P_undetermined", [FQ], bool),
    ]
    if auto:
        specs += [("P_bias", [FQ, cv.OUTPUT, cv.INPUT], float), ("local_window", [SF], int)]
    if closed_loop == "indirect":
        specs += [
            ("S", [SF, LP, cv.INPUT, LP2, IN2], complex),
            ("S_std", [SF, LP, cv.INPUT, LP2, IN2], float),
            ("transient_u", [SF, LP, cv.INPUT], complex),
            ("noise_variance_u", [SF, LP, cv.INPUT], float),
            ("s_condition", [SF], float),
            ("s_singular", [SF], bool),
            ("s_weak_rel_std", [SF], float),
        ]

    def split(out):
        """The dict of :func:`identify_arrays` -> the tuple of ``specs``, with lifted dims."""
        lead = out["G"].shape[:-3]
        fnu = factor * nu
        G, G_sd = out["G"], np.sqrt(np.maximum(out["G_var"], 0.0))  # rounding can leave -0-ish
        pieces = {
            "P": out["P"],
            "P_std": np.sqrt(out["P_var"]),  # already clipped at 0
            "P_flag": out["P_bad"],
            "condition": out["condition"],
            "ill_posed": out["ill_posed"],
            "P_std_linear": np.sqrt(out["P_var_linear"]),
            "P_undetermined": out["P_undetermined"],
        }
        if auto:
            pieces["P_bias"] = out["P_bias"]
            pieces["local_window"] = out["window"]
        zy = slice(fnu, None) if closed_loop == "indirect" else slice(0, None)
        pieces["PS"] = G[..., zy, :].reshape(lead + (m, ny, factor, nu))
        pieces["PS_std"] = G_sd[..., zy, :].reshape(lead + (m, ny, factor, nu))
        pieces["transient_y"] = out["T"][..., zy]
        pieces["noise_variance_y"] = out["noise_variance"][..., zy]
        if closed_loop == "indirect":
            shape_s = lead + (m, factor, nu, factor, nu)
            pieces["S"] = G[..., :fnu, :].reshape(shape_s)
            pieces["S_std"] = G_sd[..., :fnu, :].reshape(shape_s)
            pieces["transient_u"] = out["T"][..., :fnu].reshape(lead + (m, factor, nu))
            pieces["noise_variance_u"] = out["noise_variance"][..., :fnu].reshape(lead + (m, factor, nu))
            pieces["s_condition"] = out["s_condition"]
            pieces["s_singular"] = out["s_singular"]
            pieces["s_weak_rel_std"] = out["s_weak_rel_std"]
        return tuple(pieces[name] for name, _, _ in specs)

    gufunc_kwargs = {
        "output_sizes": {FQ: n // 2 + 1, SF: m, LP: factor, LP2: factor, IN2: nu,
                         cv.INPUT: nu, cv.OUTPUT: ny},
        "allow_rechunk": False,
    }
    output_spec = dict(output_core_dims=[dims for _, dims, _ in specs], dask="parallelized",
                       output_dtypes=[dt for _, _, dt in specs],
                       dask_gufunc_kwargs=gufunc_kwargs, keep_attrs=False)
    if auto:
        def kernel(r, u, y):
            return split(identify_arrays_auto(r, u, y, factor=factor, windows=windows,
                                              degrees=degrees, closed_loop=closed_loop))

        results = xr.apply_ufunc(kernel, ds["r"], ds["u"], ds["y"], input_core_dims=core_in,
                                 **output_spec)
    elif frequency_chunks is None:
        def kernel(r, u, y):
            return split(identify_arrays(r, u, y, factor=factor, half_width=window,
                                         degrees=degrees, closed_loop=closed_loop,
                                         covariance=covariance))

        results = xr.apply_ufunc(kernel, ds["r"], ds["u"], ds["y"], input_core_dims=core_in,
                                 **output_spec)
    else:
        packed = _fit_frequency_chunked(ds, factor=factor, window=window, degrees=degrees,
                                        closed_loop=closed_loop, covariance=covariance,
                                        frequency_chunks=frequency_chunks)
        nz_, nr_ = packed.attrs["nz"], packed.attrs["nr"]

        def finish(p):
            p = np.ascontiguousarray(p).view(complex)
            return split(finish_packed(p, nz=nz_, nr=nr_, n_fast=n, factor=factor, nu=nu, ny=ny,
                                       closed_loop=closed_loop, covariance=covariance,
                                       dof=window_dof(window, nr_, degrees)))

        # the recovery gathers every slow bin (P(k) uses bin k mod M): one chunk along it
        results = xr.apply_ufunc(finish, packed.chunk({SF: -1}), input_core_dims=[[SF, "_packed"]],
                                 **output_spec)
    out = xr.Dataset({name: da for (name, _, _), da in zip(specs, results)})
    out = _label(out, ds, factor=factor, th=th, n=n, m=m)
    if errors == "raise" and closed_loop == "indirect" and not _is_lazy(out):
        bad = np.asarray(out["s_singular"])
        if bad.any():
            idx = np.flatnonzero(bad.reshape(-1, m).any(axis=0))
            raise ValueError(
                f"the estimated lifted sensitivity S is not invertible at {idx.size} slow bin(s) "
                f"(first: {idx[:5].tolist()}), so P_1 = PS_1 S^-1 cannot be formed there. Check "
                f"that u was recorded at the plant input in closed loop and that the excitation "
                f"is strong enough there, or pass errors='ignore' to get NaN and the flag "
                f"s_singular at those bins."
            )
    out.attrs.update({
        "conventions": cv.CONVENTIONS,
        "method": method,
        "closed_loop": closed_loop,
        "window": "auto" if auto else window,
        "window_bins": "auto" if auto else 2 * window + 1,
        "degrees": np.array(degrees, dtype=int),
        "factor": factor,
        "sampling_period": th,
        "slow_nyquist": 1.0 / (2 * factor * th),
        "n_samples": n,
        "parameters_per_row": parameters_per_row(nr, degrees),
        "covariance": int(bool(covariance)),
        "title": f"lifted {closed_loop} closed-loop {method.upper()} FRF estimate",
    })
    if auto:
        out.attrs["candidate_windows"] = np.array(windows, dtype=int)
    return out


def _auto_windows(window, degrees, nr, m, frequency_chunks, covariance):
    """Candidate half-widths of ``window="auto"``, or a clear refusal."""
    if window != "auto":
        raise ValueError(f"window must be a positive integer or 'auto', got {window!r}.")
    if frequency_chunks is not None:
        raise ValueError("frequency_chunks is not supported with window='auto' (the window "
                         "choice needs every candidate's fit at every bin); pass an integer "
                         "window, or leave frequency_chunks unset.")
    if not covariance:
        raise ValueError("window='auto' chooses the window from the estimates' covariances; "
                         "pass covariance=True, or an integer window with covariance=False.")
    p = parameters_per_row(nr, degrees)
    n_min = p // 2 + 1  # 2n + 1 >= p + 2: at least two degrees of freedom
    n_max = (m - 1) // 2
    if n_min > n_max:
        raise ValueError(
            f"the experiment has {m} slow bins, too few for degrees {degrees} with {nr} lifted "
            f"excitation channels ({p} parameters per row need a window of {2 * n_min + 1} "
            f"bins). Use a longer experiment or lower degrees."
        )
    return candidate_windows(n_min, n_max)


def _fit_frequency_chunked(ds, *, factor, window, degrees, closed_loop, covariance,
                           frequency_chunks):
    """Lazy local-model fit in chunks along ``slow_frequency`` with wrapped halos.

    Returns a DataArray (..., ``slow_frequency``, ``_packed``) of :func:`fit_packed` columns.
    """
    import dask.array as da

    chunk = int(frequency_chunks)
    m = ds.sizes[cv.SLOW_TIME]
    if chunk < 1:
        raise ValueError(f"frequency_chunks must be a positive number of slow bins, got {chunk}.")
    if chunk < window:
        raise ValueError(
            f"frequency_chunks={chunk} is smaller than the halo the local window needs "
            f"(window={window} bins on each side); use frequency_chunks >= {window}."
        )
    nu, ny = ds.sizes[cv.INPUT], ds.sizes[cv.OUTPUT]
    nr = factor * nu
    nz = nr + ny if closed_loop == "indirect" else ny
    SF = cv.SLOW_FREQUENCY
    R, Z = xr.apply_ufunc(
        lambda r, u, y: experiment_spectra(r, u, y, factor=factor, closed_loop=closed_loop),
        ds["r"], ds["u"], ds["y"],
        input_core_dims=[[cv.TIME, cv.INPUT], [cv.TIME, cv.INPUT], [cv.SLOW_TIME, cv.OUTPUT]],
        output_core_dims=[[SF, "_r"], [SF, "_z"]], dask="parallelized",
        output_dtypes=[complex, complex],
        dask_gufunc_kwargs={"output_sizes": {SF: m, "_r": nr, "_z": nz}},
    )
    lead_chunks = {d: "auto" for d in R.dims if d not in (SF, "_r")}
    Rd = R.chunk({**{d: R.chunks[R.get_axis_num(d)] if R.chunks else -1 for d in lead_chunks},
                  SF: chunk, "_r": -1}).data
    Zd = Z.chunk({**{d: Z.chunks[Z.get_axis_num(d)] if Z.chunks else -1 for d in lead_chunks},
                  SF: chunk, "_z": -1}).data
    ax = Rd.ndim - 2
    depth = {i: 0 for i in range(Rd.ndim)}
    depth[ax] = window
    boundary = {i: "none" for i in range(Rd.ndim)}
    boundary[ax] = "periodic"
    Rg = da.overlap.overlap(Rd, depth=depth, boundary=boundary)
    Zg = da.overlap.overlap(Zd, depth=depth, boundary=boundary)
    width = packed_width(nz, nr, covariance)
    fitted = da.map_blocks(
        lambda rb, zb: fit_packed(rb, zb, half_width=window, degrees=degrees, circular=False,
                                  covariance=covariance),
        Rg, Zg, dtype=complex, chunks=Rg.chunks[:-1] + ((width,),),
    )
    trimmed = da.overlap.trim_internal(fitted, {**depth}, boundary=boundary)
    # a float view (pairs of re, im) so dask builds real metadata for the real outputs
    out = xr.DataArray(trimmed.view(float), dims=R.dims[:-1] + ("_packed",),
                       coords={k: v for k, v in R.coords.items() if k in R.dims[:-1]})
    out.attrs.update(nz=nz, nr=nr)
    return out


def _is_lazy(ds):
    return any(v.chunks is not None for v in ds.data_vars.values())


def _check_excitation(ds, factor, closed_loop):
    """Refuse an excitation that does not excite every lifted channel (rank-deficient R)."""
    source = ds["r"] if closed_loop == "indirect" else ds["u"]
    if source.chunks is not None:
        return  # checked per block by the local model's condition numbers instead
    x = np.asarray(source.transpose(..., cv.TIME, cv.INPUT))
    R = lifted_spectra(x, factor)
    nr = R.shape[-1]
    rank, sv = excitation_rank(R)
    if rank < nr:
        name = "r" if closed_loop == "indirect" else "u"
        raise ValueError(
            f"the lifted {name} has rank {rank} < F*nu = {nr}: not every lifted channel is "
            f"excited independently (smallest/largest singular value "
            f"{float(np.min(sv[..., -1] / sv[..., 0])):.1e}). A signal held constant over each "
            f"slow period (or any signal whose F phases are linear combinations of each other) "
            f"cannot identify the fast plant. Excite at the fast rate over all fast bins, e.g. "
            f"lcmr_xr.multisine(N, sampling_period=Th, rms=...) per input."
        )


def _label(out, ds, *, factor, th, n, m):
    u_units = ds["u"].attrs.get("units", "1")
    y_units = ds["y"].attrs.get("units", "1")
    p_units = _ratio_units(y_units, u_units)
    coords = {
        cv.FREQUENCY: (cv.FREQUENCY, np.arange(n // 2 + 1) / (n * th), cv.frequency_attrs("frequency")),
        cv.SLOW_FREQUENCY: (cv.SLOW_FREQUENCY, np.arange(m) / (m * factor * th),
                            cv.frequency_attrs("slow-rate DFT frequency")),
        cv.LIFT_PHASE: (cv.LIFT_PHASE, np.arange(factor), cv.label_attrs("lift phase (fast sample within a slow period)")),
        cv.LIFT_PHASE + cv.SECOND: (cv.LIFT_PHASE + cv.SECOND, np.arange(factor), cv.label_attrs("lift phase of the excitation")),
        cv.INPUT: ds[cv.INPUT].variable,
        cv.OUTPUT: ds[cv.OUTPUT].variable,
        cv.INPUT + cv.SECOND: (cv.INPUT + cv.SECOND, ds[cv.INPUT].values, cv.label_attrs("excited input")),
    }
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
        "noise_variance_y": ("residual noise variance of the output spectrum", f"({y_units})2" if y_units != "1" else "1"),
        "noise_variance_u": ("residual noise variance of the lifted input spectrum", f"({u_units})2" if u_units != "1" else "1"),
        "condition": ("condition number of the local least-squares problem", "1"),
        "ill_posed": ("local model ill-posed", "1"),
        "s_condition": ("condition number of the estimated lifted sensitivity", "1"),
        "s_singular": ("lifted sensitivity not invertible", "1"),
        "s_weak_rel_std": ("relative standard deviation of the weakest direction of S", "1"),
        "P_std_linear": ("first-order noise standard deviation of P", p_units),
        "P_undetermined": ("P not determined by the data (unbounded band)", "1"),
        "P_bias": ("estimated model error of P", p_units),
        "local_window": ("chosen local window half-width n", "1"),
    }
    for name, (long_name, units) in meta.items():
        if name in out:
            out[name].attrs.update({"long_name": long_name, "units": units})
    return out


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
    degrees : (int, int, int), optional
        ``(Rn, Rm, Rd)``; default ``(3, 3, 3)`` (LRM) or ``(3, 3, 0)`` (LPM).
    covariance : bool, default True
        Return ``P_std`` from the local-model covariance.

    Returns
    -------
    xarray.Dataset
        ``P``, ``P_std``, ``P_flag`` on ``frequency`` = slow bins ``m / (M Tl)``,
        ``m = 0..M/2`` (Hz); attributes as :func:`identify`.
    """
    ds = _validate(experiment)
    degrees = _resolve_degrees(method, degrees)
    factor = int(ds.attrs[cv.FACTOR])
    m = ds.sizes[cv.SLOW_TIME]
    nu = ds.sizes[cv.INPUT]
    window = _check_window(window, degrees, nu, m)
    th = float(ds[cv.TIME][1] - ds[cv.TIME][0])
    FQ = cv.FREQUENCY

    def kernel(r, u, y):
        out = identify_single_rate_arrays(r, u, y, factor=factor, half_width=window,
                                          degrees=degrees, covariance=covariance)
        return out["P"], np.sqrt(out["P_var"]), out["P_bad"]

    P, P_std, flag = xr.apply_ufunc(
        kernel, ds["r"], ds["u"], ds["y"],
        input_core_dims=[[cv.TIME, cv.INPUT], [cv.TIME, cv.INPUT], [cv.SLOW_TIME, cv.OUTPUT]],
        output_core_dims=[[FQ, cv.OUTPUT, cv.INPUT], [FQ, cv.OUTPUT, cv.INPUT], [FQ]],
        dask="parallelized", output_dtypes=[complex, float, bool],
        dask_gufunc_kwargs={"output_sizes": {FQ: m // 2 + 1}},
    )
    p_units = _ratio_units(ds["y"].attrs.get("units", "1"), ds["u"].attrs.get("units", "1"))
    out = xr.Dataset({"P": P, "P_std": P_std, "P_flag": flag})
    out = out.assign_coords({FQ: (FQ, np.arange(m // 2 + 1) / (m * factor * th), cv.frequency_attrs())})
    out["P"].attrs.update(long_name="plant FRF (single-rate estimate)", units=p_units)
    out["P_std"].attrs.update(long_name="standard deviation of P", units=p_units)
    out["P_flag"].attrs.update(long_name="P could not be estimated", units="1")
    out.attrs.update({
        "conventions": cv.CONVENTIONS, "method": method, "closed_loop": "single-rate indirect",
        "window": window, "window_bins": 2 * window + 1, "degrees": np.array(degrees, dtype=int),
        "factor": factor, "sampling_period": th, "slow_nyquist": 1.0 / (2 * factor * th),
        "n_samples": ds.sizes[cv.TIME],
        "title": f"single-rate closed-loop {method.upper()} FRF estimate (ignores lifting)",
    })
    return out
