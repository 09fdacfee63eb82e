"""``select_settings``: pick, per experiment, the sweep settings with the lowest validation error.

Two criteria, both relative prediction errors of the measured lifted spectra
``Z = [U; Y]`` (``Y`` alone for ``closed_loop="direct"``), so inputs and outputs of very
different scales count alike:

``"cross"`` (two or more experiments; the default then)
    Held-out experiments.  The estimate of experiment ``e``, ``G_e = [S; PS_1]`` on the slow
    bins, predicts the spectra of every *other* experiment from its own excitation,
    ``Z_hat = G_e R_e'``; the score of ``e`` is the median over ``e' != e``, excited bins
    and rows of ``|Z_hat - Z_e'| / |Z_e'|``.  Model error (degrees too low, window too wide)
    and estimation noise (too many parameters, window too narrow) both raise it; the noise
    of ``e'`` and its transient set a floor common to all settings.  It assumes the
    experiments are repeated measurements of one system (other excitation or noise).

``"fpe"`` (one experiment)
    Akaike's final prediction error of the local model, per row and bin:
    ``FPE = sigma2 (1 + p / (2n + 1))`` with the residual variance ``sigma2 = SSR / dof``
    the sweep returns (``noise_variance_u``, ``noise_variance_y``), ``p`` the parameters
    per row and ``2n + 1`` the window bins.  It estimates the squared error of predicting a
    new measurement at the window's bins, and is asymptotically the leave-one-bin-out
    cross-validation error (Stone 1977), computed without refitting.  The score is the
    median over excited bins and rows of ``sqrt(FPE) / |Z|``.

Bins where an estimate is NaN (a failed bin, ``errors="ignore"``) count as infinite
error, so a setting that fails on more than half of the bins can never be chosen.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from lcmr_xr import conventions as cv
from lcmr_xr.scaleout.sweep import SETTING_DIMS

__all__ = ["select_settings", "CRITERIA"]

CRITERIA = ("auto", "cross", "fpe")
#: A slow bin counts as excited when the norm of the lifted excitation there exceeds this
#: fraction of its largest value (multisines leave the other bins at round-off level).
EXCITED_TOL = 1e-8


# ------------------------------------------------------------------ numpy (trailing axes)
def _excited(R: np.ndarray) -> np.ndarray:
    """(..., M) mask of the excited slow bins of lifted excitation spectra (..., M, nr)."""
    norm = np.linalg.norm(R, axis=-1)
    return norm > EXCITED_TOL * np.max(norm, axis=-1, keepdims=True)


def _relative(err: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """``|err| / |ref|``; NaN where ``ref`` is 0 (no information), inf where ``err`` is not finite."""
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(err) / np.abs(ref)
    rel = np.where(np.abs(ref) > 0, rel, np.nan)
    return np.where(np.isfinite(err) | (np.abs(ref) == 0), rel, np.inf)


def cross_prediction_scores(G: np.ndarray, R: np.ndarray, Z: np.ndarray) -> np.ndarray:
    """Cross-experiment validation score per estimate (pure numpy).

    Parameters
    ----------
    G : ndarray, complex, shape (..., E, M, nz, nr)
        Lifted estimates of every experiment on the slow bins (``...``: settings).
    R : ndarray, complex, shape (E, M, nr)
        Lifted excitation spectra of the experiments.
    Z : ndarray, complex, shape (E, M, nz)
        Measured lifted spectra ``[U; Y]`` of the experiments.

    Returns
    -------
    ndarray, float, shape (..., E)
        Median over the other experiments, their excited bins and the rows of
        ``|G_e R_e' - Z_e'| / |Z_e'|`` (dimensionless).

    Examples
    --------
    >>> G = np.ones((2, 4, 1, 1), complex)
    >>> R = np.ones((2, 4, 1), complex)
    >>> cross_prediction_scores(G, R, 2 * R).tolist()
    [0.5, 0.5]
    """
    n_exp = G.shape[-4]
    mask = _excited(R)  # (E, M)
    scores = np.empty(G.shape[:-3])
    for e in range(n_exp):
        pred = np.einsum("...mzr,fmr->...fmz", G[..., e, :, :, :], R)  # (..., E, M, nz)
        rel = _relative(pred - Z, Z)
        keep = mask[:, :, None] & (np.arange(n_exp) != e)[:, None, None]
        rel = np.where(keep, rel, np.nan)
        flat = rel.reshape(rel.shape[:-3] + (-1,))
        scores[..., e] = _nanmedian(flat)
    return scores


def fpe_scores(noise_variance: np.ndarray, Z: np.ndarray, R: np.ndarray,
               parameters: np.ndarray, window_bins: np.ndarray) -> np.ndarray:
    """Final-prediction-error score per estimate (pure numpy).

    Parameters
    ----------
    noise_variance : ndarray, float, shape (..., M, nz)
        Residual variance ``SSR / dof`` of each row of the local model per bin.
    Z : ndarray, complex, shape (..., M, nz)
        Measured lifted spectra ``[U; Y]``.
    R : ndarray, complex, shape (..., M, nr)
        Lifted excitation spectra (only to find the excited bins).
    parameters, window_bins : ndarray, int
        Parameters per row ``p`` and window bins ``2 n + 1``, broadcasting against ``...``.

    Returns
    -------
    ndarray, float, shape (...)
        Median over excited bins and rows of ``sqrt(sigma2 (1 + p / (2n + 1))) / |Z|``.

    Examples
    --------
    >>> s2 = np.full((4, 1), 0.03)
    >>> round(float(fpe_scores(s2, np.ones((4, 1)), np.ones((4, 1)), np.array(1), np.array(3))), 12)
    0.2
    """
    inflation = 1.0 + np.asarray(parameters, float) / np.asarray(window_bins, float)
    fpe = np.asarray(noise_variance) * inflation[..., None, None]
    rel = _relative(np.sqrt(fpe), Z)
    rel = np.where(_excited(R)[..., None], rel, np.nan)
    return _nanmedian(rel.reshape(rel.shape[:-2] + (-1,)))


def _nanmedian(x: np.ndarray) -> np.ndarray:
    """Median over the last axis ignoring NaN; NaN (not a warning) when nothing is left."""
    count = np.sum(~np.isnan(x), axis=-1)
    filled = np.where(np.isnan(x), np.inf, x)  # NaN (excluded) sorts after everything...
    srt = np.sort(filled, axis=-1)
    # ...so the median of the kept values sits at positions (count-1)//2 and count//2
    lo = np.take_along_axis(srt, np.maximum((count - 1) // 2, 0)[..., None], axis=-1)[..., 0]
    hi = np.take_along_axis(srt, np.maximum(count // 2, 0)[..., None], axis=-1)[..., 0]
    with np.errstate(invalid="ignore"):
        med = np.where(np.isinf(lo) | np.isinf(hi), np.maximum(lo, hi), 0.5 * (lo + hi))
    return np.where(count > 0, med, np.nan)


# ------------------------------------------------------------------ labelled layer
def _spectra(experiments: xr.Dataset, factor: int, closed_loop: str):
    """Lifted excitation ``R`` (..., M, nr) and measured ``Z`` (..., M, nz), as numpy."""
    from lcmr_xr.kernels.identification import experiment_spectra

    r, u = (experiments[v].transpose(..., cv.TIME, cv.INPUT).values for v in ("r", "u"))
    y = experiments["y"].transpose(..., cv.SLOW_TIME, cv.OUTPUT).values
    return experiment_spectra(r, u, y, factor=factor, closed_loop=closed_loop)


def _settings_first(da: xr.DataArray, core: list[str]) -> xr.DataArray:
    lead = [d for d in SETTING_DIMS if d in da.dims]
    rest = [d for d in da.dims if d not in lead and d not in core]
    return da.transpose(*lead, *rest, *core)


def _local_model(result: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """``G`` (settings..., [experiment], M, nz, nr) and its noise rows (..., M, nz), as numpy."""
    from lcmr_xr.identification.identify import EXCITATION, RESPONSE, stacked_local_model

    G, noise = stacked_local_model(result)
    return (_settings_first(G, [cv.SLOW_FREQUENCY, RESPONSE, EXCITATION]).values,
            _settings_first(noise, [cv.SLOW_FREQUENCY, RESPONSE]).values)


def _check_inputs(result, experiments):
    if not isinstance(result, xr.Dataset) or "PS" not in result or "noise_variance_y" not in result:
        raise TypeError("sweep_result must be the Dataset returned by lcmr_xr.scaleout.sweep "
                        "(with PS, noise_variance_y and the method/degrees/window dims).")
    missing = [d for d in SETTING_DIMS if d not in result.dims]
    if missing:
        raise ValueError(f"sweep_result lacks the setting dims {missing}; pass the result of "
                         "lcmr_xr.scaleout.sweep (it always has method, degrees and window).")
    if not isinstance(experiments, xr.Dataset) or "r" not in experiments:
        raise TypeError("experiments must be the experiment Dataset the sweep was computed from.")
    lead = [d for d in experiments["r"].dims if d not in (cv.TIME, cv.INPUT)]
    if lead not in ([], [cv.EXPERIMENT]):
        raise ValueError(f"experiments has leading dims {lead}; only 'experiment' is supported. "
                         "Select one value of the other dims first, e.g. experiments.isel(case=0).")
    extra = [d for d in result["PS"].dims if d not in SETTING_DIMS and d not in
             (cv.EXPERIMENT, cv.SLOW_FREQUENCY, cv.OUTPUT, cv.LIFT_PHASE2, cv.INPUT2)]
    if extra:
        raise ValueError(f"sweep_result has dims {extra} that experiments does not explain; "
                         "select them away first.")
    if (cv.EXPERIMENT in lead) != (cv.EXPERIMENT in result.dims):
        raise ValueError("experiments and sweep_result disagree on the 'experiment' dim; pass the "
                         "experiments the sweep was computed from.")
    if cv.EXPERIMENT in lead:
        if experiments.sizes[cv.EXPERIMENT] != result.sizes[cv.EXPERIMENT]:
            raise ValueError(
                f"experiments has {experiments.sizes[cv.EXPERIMENT]} experiments but sweep_result "
                f"{result.sizes[cv.EXPERIMENT]}; pass the experiments the sweep was computed from.")
        if cv.EXPERIMENT in experiments.coords and cv.EXPERIMENT in result.coords and not np.array_equal(
                experiments[cv.EXPERIMENT].values, result[cv.EXPERIMENT].values):
            raise ValueError("the experiment labels of experiments and sweep_result differ; pass "
                             "the experiments the sweep was computed from (same order).")
    m = experiments.sizes[cv.SLOW_TIME]
    if result.sizes[cv.SLOW_FREQUENCY] != m:
        raise ValueError(f"sweep_result has {result.sizes[cv.SLOW_FREQUENCY]} slow bins but the "
                         f"experiments {m}; pass the experiments the sweep was computed from.")
    return lead


def select_settings(sweep_result: xr.Dataset, experiments: xr.Dataset, *,
                    criterion: str = "auto") -> xr.Dataset:
    """Pick, per experiment, the settings of a sweep with the lowest validation error.

    Parameters
    ----------
    sweep_result : xarray.Dataset
        Result of :func:`lcmr_xr.scaleout.sweep` (lazy or computed; it is computed here
        on the current dask scheduler).
    experiments : xarray.Dataset
        The experiment dataset the sweep was computed from (leading dim ``experiment``
        or none).  Its spectra are loaded into memory.
    criterion : {"auto", "cross", "fpe"}, default "auto"
        ``"cross"``: predict the other experiments' measured lifted spectra from their
        excitation with each experiment's estimates (needs two or more experiments).
        ``"fpe"``: the local model's final prediction error (works with one).
        ``"auto"``: ``"cross"`` with two or more experiments, else ``"fpe"``.  See the
        module notes for the exact definitions.

    Returns
    -------
    xarray.Dataset
        ``score`` (``experiment``, ``method``, ``degrees``, ``window``): median relative
        prediction error (units ``1``; ``inf`` when most bins failed); ``best_method``,
        ``best_degrees``, ``best_window``, ``best_score`` (``experiment``): the chosen
        settings.  Ties go to the first setting in sweep order.  Attribute
        ``criterion``.  Without an ``experiment`` dim the ``best_*`` are scalars.

    Raises
    ------
    ValueError
        ``criterion="cross"`` with fewer than two experiments, inputs that do not belong
        together, or an experiment for which every setting failed.

    Examples
    --------
    >>> import xarray as xr
    >>> from lcmr_xr import hdd
    >>> from lcmr_xr.scaleout import sweep
    >>> exps = xr.concat([hdd.simulate(n_samples=1200, seed=s) for s in (0, 1)], "experiment")
    >>> res = sweep(exps, window=[20, 30], degrees=["1-1-1", "3-3-3"])
    >>> choice = select_settings(res, exps)
    >>> choice.score.dims
    ('experiment', 'method', 'degrees', 'window')
    >>> choice.attrs["criterion"]
    'cross'
    """
    if criterion not in CRITERIA:
        raise ValueError(f"criterion must be one of {CRITERIA}, got {criterion!r}.")
    lead = _check_inputs(sweep_result, experiments)
    n_exp = experiments.sizes[cv.EXPERIMENT] if lead else 1
    if criterion == "auto":
        criterion = "cross" if n_exp >= 2 else "fpe"
    if criterion == "cross" and n_exp < 2:
        raise ValueError(
            f"criterion='cross' predicts other experiments and needs at least two; got {n_exp}. "
            "Use criterion='fpe' (or 'auto') for a single experiment."
        )
    closed_loop = "indirect" if "S" in sweep_result else "direct"
    factor = int(np.asarray(experiments.attrs[cv.FACTOR]).item())
    if "G" in sweep_result and "noise_variance" in sweep_result:  # identify(..., stacked=True)
        wanted = ["G", "noise_variance"]
    else:
        wanted = ["PS", "noise_variance_y"] + (["S", "noise_variance_u"] if closed_loop == "indirect" else [])
    result = sweep_result[wanted].compute()
    R, Z = _spectra(experiments, factor, closed_loop)
    G, noise = _local_model(result)

    settings_shape = tuple(result.sizes[d] for d in SETTING_DIMS)
    if criterion == "cross":
        score = cross_prediction_scores(G, R, Z)
    else:
        ppr = sweep_result["parameters_per_row"].transpose("method", "degrees").values[:, :, None]
        bins = 2 * sweep_result["window"].values[None, None, :] + 1
        if lead:
            ppr, bins = ppr[..., None], bins[..., None]
        score = fpe_scores(noise, Z, R, ppr, bins)
    dims = list(SETTING_DIMS) + lead
    score_da = xr.DataArray(
        score.reshape(settings_shape + score.shape[len(settings_shape):]), dims=dims,
        coords={d: sweep_result[d] for d in SETTING_DIMS},
        attrs={"units": "1", "long_name": f"validation error ({criterion}): median relative "
                                          "prediction error of the lifted spectra"},
    )
    if lead and cv.EXPERIMENT in sweep_result.coords:
        score_da = score_da.assign_coords({cv.EXPERIMENT: sweep_result[cv.EXPERIMENT]})
    score_da = score_da.transpose(*lead, *SETTING_DIMS)
    return _choose(score_da, lead, criterion)


def _choose(score: xr.DataArray, lead: list[str], criterion: str) -> xr.Dataset:
    grid = [score[d].values for d in SETTING_DIMS]
    shape = tuple(len(g) for g in grid)
    values = score.transpose(*lead, *SETTING_DIMS).values.reshape(-1, int(np.prod(shape)))
    ranked = np.where(np.isnan(values), np.inf, values)
    failed = np.all(np.isinf(ranked), axis=-1)
    if failed.any():
        labels = (score[cv.EXPERIMENT].values[failed].tolist() if lead and cv.EXPERIMENT in score.coords
                  else np.flatnonzero(failed).tolist())
        raise ValueError(
            f"every setting failed on most bins for experiment(s) {labels} (score inf or NaN): "
            "check the flags s_singular/ill_posed of the sweep, and try wider windows or "
            "lower degrees."
        )
    best = np.argmin(ranked, axis=-1)  # first minimum: ties go to the earlier setting
    index = np.unravel_index(best, shape)  # per setting dim, the chosen position
    out_shape = tuple(score.sizes[d] for d in lead)

    def var(values, long_name):
        return (lead, np.asarray(values).reshape(out_shape), {"units": "1", "long_name": long_name})

    method, degrees, window = (grid[k][index[k]] for k in range(len(SETTING_DIMS)))
    return xr.Dataset({
        "score": score,
        "best_method": var(method.astype(str), "chosen local model"),
        "best_degrees": var(degrees.astype(str), "chosen degrees Rn-Rm-Rd"),
        "best_window": var(window.astype(int), "chosen window half-width n"),
        "best_score": var(ranked[np.arange(len(best)), best], f"validation error of the chosen settings ({criterion})"),
    }, attrs={"conventions": cv.CONVENTIONS, "criterion": criterion,
              "title": "sweep settings with the lowest validation error per experiment"})
