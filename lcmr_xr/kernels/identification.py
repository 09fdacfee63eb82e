"""The paper's Procedure 1 on plain arrays: lift, DFT, local model, indirect step, recovery.

Shapes (leading dims broadcast): ``r, u`` are ``(..., N, nu)`` fast signals, ``y`` is
``(..., M, ny)`` with ``M = N / F``.  Everything returned is a dict of arrays so the
labelled layer can map each one onto named dimensions.
"""

from __future__ import annotations

import numpy as np

from lcmr_xr.kernels.adaptive import (K95, UNDETERMINED_LIMIT, crowd_undetermined,
                                      denominator_bias, noise_share,
                                      nonlinearity_factor,
                                      pooled_nonlinearity_factor, second_order_factor,
                                      select_windows, small_sample_factor, weak_direction)
from lcmr_xr.kernels.closed_loop import frf_variance_from_first_row, indirect_first_row
from lcmr_xr.kernels.lifting import frf_from_first_block_row, lift
from lcmr_xr.kernels.local_models import (CovarianceBuffer, _restart_interval, fits_half,
                                          hermitian, local_model, parameters_per_row)
from lcmr_xr.kernels.pooling import (MIN_SPLIT_EXPERIMENTS, group_weight, half_variances,
                                     mean_and_covariance, nearest_correlation, p_spread_factor,
                                     pooled_least_squares,
                                     rescale_covariance, split_halves, spread_calibration,
                                     spread_ratio, window_mean)

#: The lifted excitation counts as rank deficient when its smallest singular value
#: (over all bins) is below this fraction of its largest.
EXCITATION_RANK_TOL = 1e-9

#: The closed-loop variants these kernels implement (the branches below).  The settings
#: table :data:`lcmr_xr.settings.CLOSED_LOOP` lists the same ones for users (a test keeps
#: the two equal); the kernels import nothing outside ``lcmr_xr.kernels``.
CLOSED_LOOP_METHODS = ("indirect", "direct")

#: How the local rational model's denominator is estimated: least squares (the paper) or
#: instrumental variables (:func:`denominator_instruments`).  The settings table
#: :data:`lcmr_xr.settings.DENOMINATOR` lists the same ones for users (a test keeps them
#: equal).  A model without a denominator (``Rd = 0``) is least squares either way.
DENOMINATOR_METHODS = ("ls", "iv")


def check_denominator(denominator: str, degrees) -> bool:
    """Whether ``denominator`` asks for instruments; refuses an unknown one, and ``"iv"``
    for a model without a denominator (``Rd = 0``)."""
    if denominator not in DENOMINATOR_METHODS:
        raise ValueError(f"denominator must be one of {DENOMINATOR_METHODS}, got {denominator!r}.")
    if denominator == "iv" and tuple(degrees)[2] < 1:
        raise ValueError(f"denominator='iv' needs a denominator (Rd > 0), got degrees "
                         f"{tuple(degrees)}; pass denominator='ls'.")
    return denominator == "iv"


#: The Hausman twin of ``window="auto"`` is fitted at every ``TWIN_STRIDE``-th slow bin
#: only (:func:`twin_bins`): its term is a local mean over the finite terms within
#: :data:`lcmr_xr.kernels.adaptive.BIAS_SMOOTHING` fast bins (4-5 of them instead of 13;
#: measured in docs/uncertainty.md, "The twin at every third bin").
TWIN_STRIDE = 3


def twin_bins(m: int) -> np.ndarray:
    """The slow bins (of ``m``) at which the Hausman twin of ``window="auto"`` is fitted:
    every :data:`TWIN_STRIDE`-th from bin 0 up to ``M/2`` and their mirrors ``M - k``
    (bool, shape (m,)), so that a fit of bins ``0..M/2`` mirrored (spectra of real
    signals) and a fit of every bin (frequency chunks) fit the same bins."""
    k = np.arange(m)
    return np.minimum(k, m - k) % TWIN_STRIDE == 0


def checks_denominator_bias(denominator: str, degrees, closed_loop: str = "indirect",
                            n_exp=None, known_noise: bool = False) -> bool:
    """Whether ``window="auto"`` estimates the bias of a least-squares denominator by the
    Hausman comparison (:func:`lcmr_xr.kernels.adaptive.denominator_bias`): one record of
    the indirect method with the residual noise estimate, least squares, a denominator
    (``Rd > 0``).  Pooled experiments (IV by default, their band calibrated by split
    halves), averaged periods (``known_noise``: the noise covariance from the periods,
    whose few degrees of freedom the bound form was also covering: with 2 steady periods
    the comparison's band covered 0.82-0.89 at 500-5000 Hz), IV, the LPM and the direct
    method keep the bound form of the nonlinearity factor."""
    return (denominator == "ls" and tuple(degrees)[2] > 0 and closed_loop == "indirect"
            and n_exp is None and not known_noise)


def first_fit_window(nr: int, degrees) -> int:
    """Half-width of the first fit that predicts ``Z`` for the instruments: the smallest
    window that leaves two degrees of freedom per row (``2 n + 1 >= p + 2``), where the
    local model is nearly free of model error (the pilot of ``window="auto"`` too)."""
    return parameters_per_row(nr, tuple(degrees)) // 2 + 1


def denominator_instruments(R, Z, *, degrees=(3, 3, 3), half_width: int | None = None,
                            circular: bool = True, experiment_axis: int | None = None
                            ) -> np.ndarray:
    """Instruments for the denominator regressors ``-rho^s Z_i``: ``Zhat = G1 R + T1``.

    ``G1``, ``T1`` come from a first least-squares fit of the same local model in the
    narrow window ``half_width`` (default :func:`first_fit_window`), pooled like the main
    fit (``experiment_axis``: the pooled ``G1`` and each experiment's own ``T1``).  The
    prediction is built from the excitation, so the noise on ``Z`` in the main window is
    (nearly) not in it, and ``local_model(..., instruments=Zhat)`` solves
    ``Phi^H A theta = Phi^H z`` with ``Phi`` the regression with ``Zhat`` in place of ``Z``:
    the errors-in-variables bias of least squares (noise in its own regressors) is gone
    to the extent that ``Zhat`` is free of the noise at the same bin (Soderstrom & Stoica,
    *System Identification*, 1989, ch. 8; docs/uncertainty.md measures it).

    Where the first fit gives no prediction (failed or flagged bins, and the ``half_width``
    bins at each end with ``circular=False``) the instrument is ``Z`` itself: least squares
    for those regressors.
    Spectra of real signals (conjugate-symmetric ``Z``) get a conjugate-symmetric
    prediction, so that the main fit still fits half the bins and mirrors them.

    Returns
    -------
    ndarray, complex, shape of ``Z`` (broadcast with ``R``'s leading dims)
    """
    n1 = first_fit_window(np.shape(R)[-1], degrees) if half_width is None else int(half_width)
    first = local_model(R, Z, half_width=n1, degrees=tuple(degrees), circular=circular,
                        covariance=None, experiment_axis=experiment_axis)
    return _prediction(first.G, first.T, R, Z, circular=circular,
                       experiment_axis=experiment_axis)


def _prediction(G, T, R, Z, *, circular: bool = True, experiment_axis: int | None = None):
    """The instruments of :func:`denominator_instruments` from a least-squares fit's ``G``
    and ``T`` (layout of :func:`lcmr_xr.kernels.local_models.local_model`), e.g. those of
    a fit with covariance: the local model's ``G`` and ``T`` do not depend on whether the
    covariance is computed, nor on the blocks of bins they were fitted in (bit for bit),
    so ``window="auto"`` takes its widest candidate's instead of fitting that window once
    more (:func:`identify_spectra_auto`)."""
    R, Z = np.asarray(R), np.asarray(Z)
    lead = np.broadcast_shapes(R.shape[:-2], Z.shape[:-2])
    R = np.broadcast_to(R, lead + R.shape[-2:])
    if experiment_axis is None:
        zhat = np.einsum("...mip,...mp->...mi", G, R) + T
    else:  # G1 (..., M, nz, nr) shared; T1 (..., E, M, nz) one per experiment
        zhat = np.einsum("...mip,...emp->...emi", G,
                         np.moveaxis(R, experiment_axis, -3)) + T
        zhat = np.moveaxis(zhat, -3, experiment_axis)
    zhat = np.where(np.isfinite(zhat), zhat, np.broadcast_to(Z, zhat.shape))
    m = zhat.shape[-2]
    if circular and hermitian(np.broadcast_to(Z, zhat.shape).reshape(-1, m, zhat.shape[-1])):
        # real signals: the prediction is conjugate-symmetric to the first fit's rounding;
        # exactly so, the main fit keeps its half-bins-and-mirror shortcut
        zhat = (zhat + np.conj(np.take(zhat, (-np.arange(m)) % m, axis=-2))) / 2
    return zhat


def lifted_spectra(x: np.ndarray, factor: int) -> np.ndarray:
    """DFT of the lifted signal: ``(..., N, c) -> (..., M, F c)``, phase-major channels."""
    x = np.asarray(x)
    n, c = x.shape[-2:]
    lifted = lift(np.moveaxis(x, -1, -2), factor)  # (..., c, M, F)
    spec = np.fft.fft(lifted, axis=-2)  # along slow time
    spec = np.moveaxis(spec, -3, -1)  # (..., M, F, c)
    return spec.reshape(spec.shape[:-2] + (factor * c,))


def excitation_rank(R: np.ndarray) -> tuple[int, np.ndarray]:
    """Numerical rank of the lifted excitation spectra over all bins, and the singular values.

    ``R`` is ``(..., M, nr)``; the rank is that of the ``(M, nr)`` matrix (the worst over
    leading dims).  Local modelling needs rank ``nr``: every lifted channel must be excited
    independently of the others.
    """
    sv = np.linalg.svd(np.asarray(R), compute_uv=False)  # (..., nr)
    rel = sv / np.maximum(sv[..., :1], np.finfo(float).tiny)
    rank = int((rel > EXCITATION_RANK_TOL).sum(axis=-1).min())
    return rank, sv


def experiment_spectra(r, u, y, *, factor: int, closed_loop: str = "indirect"):
    """Spectra of the local-model problem: ``R`` (..., M, nr) and ``Z`` (..., M, nz).

    ``"indirect"``: ``R`` = DFT of the lifted ``r`` (``F nu`` channels), ``Z`` = DFTs of the
    lifted ``u`` and of ``y`` (``F nu + ny``).  ``"direct"``: ``R`` = lifted ``u``, ``Z = Y``.
    """
    if closed_loop not in CLOSED_LOOP_METHODS:
        raise ValueError(
            f"closed_loop must be one of {CLOSED_LOOP_METHODS}, got {closed_loop!r}."
        )
    r = np.asarray(r, dtype=float)
    u = np.asarray(u, dtype=float)
    y = np.asarray(y, dtype=float)
    n = r.shape[-2]
    m = y.shape[-2]
    f_ = int(factor)
    if n != m * f_:
        raise ValueError(
            f"N = {n} fast samples and M = {m} slow samples do not match factor {f_} "
            f"(need N = M * F = {m * f_})."
        )
    U = lifted_spectra(u, f_)
    Y = np.fft.fft(y, axis=-2)
    if closed_loop == "indirect":
        return lifted_spectra(r, f_), np.concatenate([U, Y], axis=-1)
    return U, Y


def recover_frf(G, G_cov, *, n_fast: int, factor: int, nu: int, ny: int,
                closed_loop: str = "indirect", ill_posed=None, dof=None,
                neighbourhood: bool = False, noise_covariance=None) -> dict:
    """From the local-model ``G`` (..., M, nz, nr) per slow bin to the fast FRF.

    ``"indirect"``: ``P_1 = PS_1 S^-1`` with first-order covariance; ``"direct"``:
    ``P_1 = G``.  Then ``P(k) = sum_j exp(2j pi k j / N) P_1,j(k mod M)`` for
    ``k = 0..N/2``.

    ``P_var`` is calibrated for the 95 % disc ``|P_hat - P| <= sqrt(ln 20) sqrt(P_var)``
    (see :mod:`lcmr_xr.kernels.adaptive`): the first-order variance ``P_var_linear`` times
    the squared small-sample factor of ``dof`` (scalar or (..., M); None: 1) and, for the
    indirect method, the squared nonlinearity factor of the weakest direction of ``S``;
    ``inf`` where ``P`` is undetermined (``neighbourhood``, the fit of one record at a
    fixed window: also where most of the slow bins within +-6 are, :func:`finish_packed`).

    Two steps: :func:`slow_bin_terms` (per slow bin, the only step that reads ``G_cov``;
    the eager path runs it on blocks of bins) and the recovery over all bins from what it
    returns.  ``noise_covariance`` (..., M, nz, nz), optional: the local model's residual
    noise covariance behind ``G_cov`` (one record); given, the bins where ``cov(P_1)`` is
    not positive semidefinite are recomputed from it mended (:func:`_mend_indefinite`), as
    one record's ``identify`` does.

    Returns
    -------
    dict of ndarray
        ``P``, ``P_var``, ``P_var_linear`` (NaN when ``G_cov`` is None), ``P_bad``,
        ``P_undetermined``, ``s_condition``, ``s_singular``, ``s_weak_rel_std`` (NaN
        without ``G_cov`` or for the direct method).
    """
    terms = slow_bin_terms(G, G_cov, nr=int(factor) * nu, closed_loop=closed_loop)
    if noise_covariance is not None and G_cov is not None:
        terms.update(_mend_indefinite(terms, G, G_cov, noise_covariance,
                                      dict(nr=int(factor) * nu, closed_loop=closed_loop,
                                           mirrors=False)))
    return _recover(terms, n_fast=n_fast, factor=factor, nu=nu, ny=ny, closed_loop=closed_loop,
                    ill_posed=ill_posed, dof=dof, neighbourhood=neighbourhood)


def slow_bin_terms(G, G_cov, *, nr: int, closed_loop: str = "indirect",
                   mirrors: bool = True, first_row_only: bool = False) -> dict:
    """Per slow bin, what the recovery of the fast FRF reads of the local model.

    Everything :func:`recover_frf` needs from ``G_cov``, reduced bin by bin, so that the
    covariance of a block of bins can be dropped once this has run (the eager path fits
    long records in blocks of bins, ``_fit_blocks``).

    Parameters
    ----------
    G : ndarray, complex, shape (..., M, nz, nr)
    G_cov : ndarray, complex, shape (..., M, nz nr, nz nr), or None
    nr : int
        ``F nu``.
    closed_loop : {"indirect", "direct"}
    mirrors : bool, default True
        The bins are the whole circle: an exactly mirrored estimate is computed on half of
        them (:func:`lcmr_xr.kernels.closed_loop.indirect_first_row`).  False for a block.
    first_row_only : bool, default False
        Only ``P1``, ``P1_cov``, ``s_condition`` and ``s_singular``: what the fast ``P`` and
        its first-order variance read (the Hausman twin of :func:`identify_spectra_auto`);
        no weak direction of ``S``, no variances of ``G``.

    Returns
    -------
    dict of ndarray
        ``P1`` (..., M, ny, nr) and ``P1_cov`` (..., M, ny nr, ny nr) (None without
        ``G_cov``); ``s_condition``, ``s_singular``, ``rho``, ``rho_v`` (..., M) (the
        last two NaN without ``G_cov`` or for the direct method,
        :func:`lcmr_xr.kernels.adaptive.weak_direction`); ``G_var`` (..., M, nz, nr), the
        variances of ``G`` (NaN without ``G_cov``).
    """
    G = np.asarray(G)
    if closed_loop == "indirect":
        # (first_row_only: no weak direction, so the SVD of S without its vectors)
        ind = indirect_first_row(G, nr, G_cov, mirrors=mirrors, s_vectors=not first_row_only)
        P1, P1_cov, s_cond, s_sing = ind.first_row, ind.first_row_cov, ind.s_condition, ind.singular
    else:
        P1, P1_cov = G, G_cov
        s_cond = np.ones(G.shape[:-2])
        s_sing = np.zeros(G.shape[:-2], dtype=bool)
    if first_row_only:
        return {"P1": P1, "P1_cov": P1_cov, "s_condition": s_cond, "s_singular": s_sing}
    rho = rho_v = np.full(G.shape[:-2], np.nan)
    if G_cov is not None and closed_loop == "indirect":
        S_cov = G_cov[..., : nr * nr, : nr * nr]
        src = ind.mirror  # G and G_cov exact mirrors (checked once, in the indirect step)
        # S's SVD from the indirect step (on half the bins or all), if it is of the
        # same matrices: the identity where G is not finite there, where S or S_cov
        # is not finite in weak_direction
        same = np.array_equal(np.isfinite(G).all(axis=(-2, -1)),
                              np.isfinite(G[..., :nr, :]).all(axis=(-2, -1))
                              & np.isfinite(S_cov).all(axis=(-2, -1)))
        u, sv, vh, on_half = ind.s_svd if same else (None, None, None, None)
        if src is not None:
            # conjugation leaves rho unchanged: half the SVDs (about 10 us each)
            half = slice(0, G.shape[-3] // 2 + 1)
            rho, rho_v = (np.take(x, src, axis=-1) for x in
                          weak_direction(G[..., half, :nr, :], S_cov[..., half, :, :],
                                         svd=(u, sv, vh) if on_half is True else None))
        else:
            rho, rho_v = weak_direction(G[..., :nr, :], S_cov,
                                        svd=(u, sv, vh) if on_half is False else None)
    if G_cov is not None:
        G_var = np.real(np.diagonal(G_cov, axis1=-2, axis2=-1)).reshape(G.shape)
    else:
        G_var = np.full(G.shape, np.nan)
    return {"P1": P1, "P1_cov": P1_cov, "s_condition": s_cond, "s_singular": s_sing,
            "rho": rho, "rho_v": rho_v, "G_var": G_var}


def _recover(terms, *, n_fast, factor, nu, ny, closed_loop, ill_posed, dof,
             calibration=None, halves=None, neighbourhood: bool = False) -> dict:
    """The fast FRF from :func:`slow_bin_terms` of every slow bin (:func:`recover_frf`).

    ``calibration`` (..., M), optional: the pooled fits' factor on ``G_cov``
    (:func:`lcmr_xr.kernels.pooling.spread_calibration`), applied here to what the terms
    derive from it: ``P1_cov`` scales with it, ``rho`` and ``rho_v`` with its square root.
    ``halves`` (with ``calibration``): the split halves' first block rows ``P1_a``, ``P1_b``
    (each (..., M, ny, nr)) and the weight of their difference (..., M)
    (:func:`split_half_spread`): their ``P`` against the calibrated ``P_var_linear`` gives
    :func:`lcmr_xr.kernels.pooling.p_spread_factor`, which multiplies ``P_var`` (returned
    as ``P_spread_calibration``), and the nonlinearity factor is then the milder pooled
    form (:func:`lcmr_xr.kernels.adaptive.pooled_nonlinearity_factor`).
    ``neighbourhood`` (``terms`` of every slow bin, one record at a fixed window): a bin
    where more than half of the slow bins within
    :data:`lcmr_xr.kernels.adaptive.BIAS_SMOOTHING` (on their circle) fail the test is
    undetermined too (:func:`lcmr_xr.kernels.adaptive.crowd_undetermined`, as
    ``window="auto"`` takes the widest window's test, :func:`_finish_choice`).
    """
    f_ = int(factor)
    p_factor = None
    P1, s_sing = terms["P1"], terms["s_singular"]
    mild = halves is not None and calibration is not None
    slow = _slow_recovery(terms, closed_loop=closed_loop, ill_posed=ill_posed, dof=dof,
                          calibration=calibration, mild=mild)
    P1_cov, undetermined = terms["P1_cov"], slow["undetermined"]
    if neighbourhood:  # a saturated ratio's lucky draw among failing neighbours
        undetermined = undetermined | (crowd_undetermined(undetermined, circular=True)
                                       & ~s_sing)
    if calibration is not None and P1_cov is not None:
        P1_cov = P1_cov * calibration[..., None, None]
    m = s_sing.shape[-1]
    bins = np.arange(n_fast // 2 + 1)
    P = frf_from_first_block_row(P1, f_)[..., : n_fast // 2 + 1, :, :]
    if P1_cov is not None:
        P_var_lin = frf_variance_from_first_row(P1_cov, n_fast, f_, bins, ny, nu)
        fast_factor = np.take(np.where(undetermined, 1.0, slow["factor"]), bins % m, axis=-1)
        P_var = P_var_lin * fast_factor[..., None, None] ** 2
        fast_undetermined = np.take(undetermined, bins % m, axis=-1)
        if mild:
            P_halves = [frf_from_first_block_row(h, f_)[..., : n_fast // 2 + 1, :, :]
                        for h in halves[:2]]
            p_factor = p_spread_factor(*P_halves, P_var_lin, fast_undetermined,
                                       weight=np.take(halves[2], bins % m, axis=-1))
            P_var = P_var * p_factor
        # unbounded where undetermined (also where the first-order variance is 0 or NaN)
        P_var = np.where(fast_undetermined[..., None, None], np.inf, P_var)
    else:
        P_var_lin = P_var = np.full(P.shape, np.nan)
    extra = {} if p_factor is None else {"P_spread_calibration": p_factor}
    return {**extra,
        "P": P,
        "P_var": P_var,
        "P_var_linear": P_var_lin,
        "P_bad": np.take(slow["bad"], bins % m, axis=-1),
        "P_undetermined": np.take(undetermined, bins % m, axis=-1),
        "s_condition": terms["s_condition"],
        "s_singular": s_sing,
        "s_weak_rel_std": slow["rho"],
    }


def _slow_recovery(terms, *, closed_loop, ill_posed, dof, calibration=None,
                   mild: bool = False) -> dict:
    """The per-slow-bin part of :func:`_recover`, bin by bin (so that the values at a
    subset of the bins are those of all bins there): ``rho`` with the ``calibration``
    applied, the ``factor`` turning the first-order standard deviation into the calibrated
    one (``mild``: a pooled fit's band calibrated by its halves' ``P``, the pooled form of
    the nonlinearity factor; the flag is the same), ``undetermined`` and ``bad``
    (ill-posed or ``S`` singular).  Of
    ``terms["P1_cov"]`` only whether it is None is read."""
    s_sing, covariance = terms["s_singular"], terms["P1_cov"] is not None
    rho, rho_v = terms["rho"], terms["rho_v"]
    if calibration is not None and covariance:
        root = np.sqrt(calibration)
        rho, rho_v = rho * root, rho_v * root
    lead_m = s_sing.shape
    slow_factor = np.ones(lead_m)
    undetermined = np.zeros(lead_m, dtype=bool)
    if dof is not None:
        slow_factor = slow_factor * small_sample_factor(dof)
    if covariance and closed_loop == "indirect":
        # pooled fits calibrated by split halves: the milder form (their P calibrates the band)
        nl, undetermined = (pooled_nonlinearity_factor(rho) if mild
                            else nonlinearity_factor(rho, rho_v))
        undetermined = undetermined & ~s_sing
        slow_factor = slow_factor * nl
    return {"rho": rho, "factor": slow_factor, "undetermined": undetermined,
            "bad": s_sing if ill_posed is None else (ill_posed | s_sing)}


def packed_width(nz: int, nr: int, covariance: bool, n_exp: int = 1,
                 closed_loop: str = "indirect", unfloored: bool = False) -> int:
    """Length of the last axis of :func:`fit_packed`'s output (``n_exp`` transients; with
    ``n_exp >= MIN_SPLIT_EXPERIMENTS`` and ``covariance``, more columns for the split-half
    spread ratio and the halves' first block rows; with ``unfloored`` and ``covariance``,
    the unfloored ``rho``, ``rho_v`` and ``vec(cov(P_1))``)."""
    ny = nz - nr if closed_loop == "indirect" else nz
    spread = 2 + 2 * ny * nr if covariance and n_exp >= MIN_SPLIT_EXPERIMENTS else 0
    reduced = nz * nr + 2 + (ny * nr) ** 2 if covariance else 0
    raw = 2 + (ny * nr) ** 2 if covariance and unfloored else 0
    return nz * nr + (n_exp + 1) * nz + 2 + spread + ny * nr + 2 + reduced + raw


def fit_packed(R, Z, *, half_width: int, degrees=(3, 3, 3), circular: bool = True,
               covariance: bool = True, noise_covariance=None,
               experiment_axis: int | None = None, denominator: str = "ls",
               closed_loop: str = "indirect", instruments=None, select=None,
               unfloored: bool = False) -> np.ndarray:
    """Local model per bin, reduced to what the recovery reads and packed into one complex
    array ``(..., M, K)``.

    One array (rather than a tuple) so that a frequency-chunked dask computation can run
    the fit with ``map_overlap``-style halos: columns are ``vec(G)`` (``nz nr``), ``T``
    (``nz``), the noise variances (``nz``), the condition number, the ill-posed flag,
    with ``covariance`` and pooled experiments (``E >= MIN_SPLIT_EXPERIMENTS``) the
    split-half spread ratio (:func:`split_half_spread`), the weight of the halves'
    difference and the two halves' ``vec(P_1)`` (``ny nr`` each), then :func:`slow_bin_terms`:
    ``vec(P_1)`` (``ny nr``), the condition and the singular flag of ``S`` and, with
    ``covariance``, the variances of ``G`` (``nz nr``), ``rho``, ``rho_v`` and
    ``vec(cov(P_1))`` (``(ny nr)^2``).  ``G_cov`` itself is not kept: :func:`finish_packed`
    needs none of it.  ``closed_loop`` as :func:`identify_arrays` (``R``, ``Z`` are the
    spectra of :func:`experiment_spectra` for it).

    ``noise_covariance`` (..., M, nz, nz), optional: a noise covariance known per bin
    (e.g. from the spread over periods, :func:`lcmr_xr.kernels.pooling.mean_and_covariance`).
    ``G_cov`` is then built from its mean over the local window (the local model assumes
    the noise constant over the window, as its residual estimate does) instead of the
    residual estimate; the residual noise variances are still returned.

    ``experiment_axis``: pool that leading axis of ``R``, ``Z`` into one model (see
    :func:`lcmr_xr.kernels.local_models.local_model`); the ``E`` transients are packed
    experiment-major (``E nz`` columns).

    ``denominator="iv"``: instrumental variables (:func:`denominator_instruments`).  With
    ``circular=False`` its first fit needs :func:`first_fit_window` more halo bins: the
    ``half_width + first_fit_window`` bins at each end are not those of the circular fit
    (trim them).  ``instruments``
    (..., M, nz), optional: those of ``denominator="iv"`` on the same (haloed) bins when
    the caller has them (the Hausman twin of ``window="auto"`` takes the widest candidate's
    prediction); then there is no first fit and the halo is ``half_width``.  ``select``
    (M,) bool, optional: fit only those bins (of the haloed bins given), the others NaN
    (:func:`lcmr_xr.kernels.local_models.local_model`; the twin fits :func:`twin_bins`).
    ``unfloored`` (with ``covariance``; ``window="auto"``'s candidates): three more columns,
    ``rho``, ``rho_v`` and ``vec(cov(P_1))`` without the resolution floor
    (:func:`_fit_terms`; the floored ones' values where it changes no bin), from which
    :func:`finish_packed` recovers the variances the window choice reads.
    """
    known = None
    if covariance and noise_covariance is not None:
        known = window_mean(np.asarray(noise_covariance), half_width, axis=-3, circular=circular)
    terms = _fit_terms(R, Z, half_width=half_width, degrees=degrees, circular=circular,
                       covariance=covariance, known_covariance=known,
                       experiment_axis=experiment_axis, denominator=denominator,
                       closed_loop=closed_loop, instruments=instruments, select=select,
                       unfloored=unfloored)
    lead_m = terms["G"].shape[:-2]
    names = ["G", "T", "noise_variance", "condition", "ill_posed", "spread_ratio", "half_weight",
             "P1_half_a", "P1_half_b", "P1", "s_condition", "s_singular"]
    if covariance:
        names += ["G_var", "rho", "rho_v", "P1_cov"]
    if covariance and unfloored:
        for k in _UNFLOORED:
            terms.setdefault(f"{k}_unfloored", terms[k])
        names += [f"{k}_unfloored" for k in ("rho", "rho_v", "P1_cov")]
    return np.concatenate([np.asarray(terms[k], dtype=complex).reshape(lead_m + (-1,))
                           for k in names if k in terms], axis=-1)


def _fit_terms(R, Z, *, half_width, degrees, circular, covariance, known_covariance,
               experiment_axis, closed_loop, denominator="ls", instruments=None,
               halves_instruments=None, bins=None, spread=True, first_row_only=False,
               select=None, buffers=None, unfloored: bool = False) -> dict:
    """The local model at every bin (``bins``: those of the circle) reduced by
    :func:`slow_bin_terms`: ``G``, ``T`` (pooled: (..., M, E, nz)), ``noise_variance``,
    ``condition``, ``ill_posed`` and the terms; ``G_cov`` is dropped.  ``G_cov`` is
    rebuilt from ``known_covariance`` (the window mean of a known noise covariance, on
    the fitted bins) when given.  ``instruments``: those of ``denominator="iv"`` when the
    caller has them already.  ``spread``: also the pooled fits' split-half spread ratio
    (on these bins: the caller does it otherwise).  ``first_row_only``: of the terms only
    those of :func:`slow_bin_terms` with ``first_row_only``.  ``select`` (M,) bool (of the
    circle with ``bins``): fit and reduce only those bins, the others NaN (not fitted).
    ``buffers``: a :class:`lcmr_xr.kernels.local_models.CovarianceBuffer` for ``G_cov``
    (nothing returned views it).  ``unfloored`` (one record with its covariance from its
    residuals): where :func:`_resolution_floor` changes a bin, also ``P1_cov``, ``rho``
    and ``rho_v`` without it (``P1_cov_unfloored``, ...; returned only then), for
    ``window="auto"``'s choice: the floor bounds the band, it is no variance estimate."""
    if check_denominator(denominator, degrees) and instruments is None:
        instruments = denominator_instruments(R, Z, degrees=degrees, circular=circular,
                                              experiment_axis=experiment_axis)
    if known_covariance is not None:  # (rebuilt from every bin's: a fresh G_cov, blanked)
        buffers = None
    fit = local_model(R, Z, half_width=half_width, degrees=tuple(degrees), circular=circular,
                      covariance="full" if covariance else None, experiment_axis=experiment_axis,
                      instruments=instruments if denominator == "iv" else None, bins=bins,
                      select=select, **({} if buffers is None else {"buffers": buffers}))
    G_cov = fit.G_cov
    n_exp = _n_experiments(R, Z, experiment_axis)
    if covariance and known_covariance is not None:
        G_cov = rescale_covariance(G_cov, fit.noise_covariance, known_covariance)
    elif covariance and n_exp is not None:
        # pooled: the residual noise covariance made positive semidefinite (its entries
        # are estimated one by one), so that G_cov is a covariance
        G_cov = _positive_semidefinite(G_cov, fit.noise_covariance)
    out = {"G": fit.G, "T": fit.T if n_exp is None else np.moveaxis(fit.T, -3, -2),
           "noise_variance": fit.noise_variance, "condition": fit.condition,
           "ill_posed": fit.ill_posed}
    # (a block of the circle or a chunk: no mirror there, the caller mirrors)
    terms = dict(nr=np.shape(R)[-1], closed_loop=closed_loop, mirrors=False,
                 first_row_only=first_row_only)
    on = None if select is None else np.asarray(select, dtype=bool)
    if on is not None and bins is not None:
        on = on[bins[0]:bins[1]]
    if on is None or on.all():
        out.update(slow_bin_terms(fit.G, G_cov, **terms))
    else:  # the terms of the bins fitted; the others those of a bin not fitted (NaN)
        cut = lambda x, at: None if x is None else x[..., at, :, :]  # noqa: E731
        blank = slow_bin_terms(cut(fit.G, [0]) * np.nan, None if G_cov is None else
                               np.full(cut(G_cov, [0]).shape, np.nan, G_cov.dtype), **terms)
        fitted = slow_bin_terms(cut(fit.G, on), cut(G_cov, on), **terms) if on.any() else {}
        for name, value in blank.items():
            ax = _BIN_AXES[name]
            out[name] = np.repeat(value, on.size, axis=ax)
            if name in fitted:
                out[name][_bins_at(ax, on)] = fitted[name]
    if covariance and n_exp is None and known_covariance is None:
        # one record: residuals below the moments' resolution give G_cov no width there
        level = _resolution_level(Z, half_width=half_width, dof=fit.dof, circular=circular,
                                  bins=bins)
        before, G_cov0 = dict(out), G_cov
        floored, G_cov, s = _resolution_floor(out, fit, G_cov, R, Z, terms, level=level,
                                              half_width=half_width, degrees=degrees,
                                              circular=circular, bins=bins, select=select,
                                              instruments=instruments if denominator == "iv"
                                              else None)
        out.update(floored)

        def mend(d, cov, noise):
            """The mend where cov(P_1) is not a covariance (below) and rho's rounding floor."""
            d.update(_mend_indefinite(d, fit.G, cov, noise, terms))
            if closed_loop == "indirect" and not first_row_only:
                d["rho"] = _rounding_floor(d["rho"], d["s_condition"], fit.noise_variance,
                                           Z, half_width=half_width, dof=fit.dof,
                                           circular=circular, bins=bins, level=level)

        mend(out, G_cov, s)
        if unfloored and floored:  # the terms as they were without the floor, mended
            # alike; nothing more where it changes no bin (noisy records)
            mend(before, G_cov0, fit.noise_covariance)
            out.update({f"{k}_unfloored": before[k] for k in _UNFLOORED if k in before})
        del before, G_cov0
    if buffers is not None:  # (G_var is a view of G_cov's diagonal: the next fit reuses it)
        out = {k: v.copy() if isinstance(v, np.ndarray) and np.may_share_memory(v, fit.G_cov)
               else v for k, v in out.items()}
    del G_cov, fit
    if spread and covariance and not first_row_only and (n_exp or 0) >= MIN_SPLIT_EXPERIMENTS:
        out.update(_spread_ratio(R, Z, out, half_width=half_width, degrees=degrees,
                                 circular=circular, experiment_axis=experiment_axis,
                                 denominator=denominator, instruments=halves_instruments,
                                 closed_loop=closed_loop))
    return out


def _resolution_level(Z, *, half_width, dof, circular, bins=None):
    """``eps (2 n + 1) mean_window |Z_i|^2 / dof`` (..., B, nz): the smallest residual
    noise variance of row ``i`` that the local model's moments resolve (its residual
    energy is a difference of sums of ``|Z|^2``).  ``bins``: the block ``(start, stop)``
    of the circle ``Z``; ``circular=False``: ``Z`` padded as the fit's."""
    n = int(half_width)
    Z = np.asarray(Z)
    if bins is not None:  # the block and its halo only
        a, b = bins
        Z = np.take(Z, np.arange(a - n, b + n) % Z.shape[-2], axis=-2)
        circular = False
    mean = window_mean(np.abs(Z) ** 2, n, axis=-2, circular=circular)
    if bins is not None:
        mean = mean[..., n:mean.shape[-2] - n, :]
    dof = np.asarray(dof, dtype=float)
    eps = np.finfo(float).eps
    with np.errstate(invalid="ignore", divide="ignore"):
        return eps * (2 * n + 1) * mean / (dof[..., None] if dof.ndim else dof)


#: Relative amplitude of the probe added to ``Z`` by :func:`_resolution_floor` to read
#: the local model's regression factor where a row's residual is unresolved.
PROBE_AMPLITUDE = 1e-6


def _resolution_floor(out, fit, G_cov, R, Z, terms, *, half_width, degrees, circular,
                      bins=None, select=None, level=None, instruments=None):
    """One record's :func:`slow_bin_terms` ``out`` recomputed at the bins where a row's
    residual noise variance is below the floor of what the local model's moments resolve,
    with ``G_cov`` rebuilt from a diagonal noise covariance raised to that floor.

    The residual energy is a difference of sums of ``|Z|^2``, so a row's residual of energy
    below ``eps sum_window |Z_i|^2`` is rounding (:func:`_resolution_level` is that over
    ``dof``: the variance resolved).  The fit's error from such an unresolved equation
    error ``e`` (rounding of the moments, or a model error the residual does not resolve)
    is not white: ``|dtheta_p| = |k_p^H e| <= |k_p| |e|`` (Cauchy-Schwarz, ``k_p^H`` the row
    of the regression's inverse), so the noise variance is floored at
    ``eps sum_window |Z_i|^2`` (the resolution level times ``dof``), not the white-noise
    share of it.  An unresolved row's correlations are rounding and are dropped; the
    resolved rows keep theirs (made a covariance by :func:`nearest_correlation`).  Noiseless HDD records: P_std exactly
    0 at 1750 released fast-bin entries (N = 36 000, window 30) before; docs/uncertainty.md,
    "Slow DC and fast N/2".

    The local model's ``G_cov`` is ``s_ij X_ij`` (:func:`rescale_covariance`); where
    ``s_ii`` is rounding (often exactly 0 or negative) ``X_ii`` cannot be read back
    from ``G_cov``, so it is read from a second fit of those bins only, on ``Z`` plus a
    deterministic probe of relative amplitude :data:`PROBE_AMPLITUDE` (its residuals are
    resolved; ``X`` moves by that relative amount times the fit's condition).  Every other
    bin's terms are left bit for bit (the HDD's noisy records: no bin is below the floor).
    Returns the recomputed entries (copies), and ``G_cov`` and the noise covariance with
    those bins replaced (the arguments themselves where nothing is).  ``level``: the
    :func:`_resolution_level`, when the caller has it.  ``instruments``: those of the fit
    (``denominator="iv"``): the refit uses them, so that ``X`` is the fit's own."""
    s = fit.noise_covariance
    if G_cov is None:
        return {}, G_cov, s
    if level is None:
        level = _resolution_level(Z, half_width=half_width, dof=fit.dof, circular=circular,
                                  bins=bins)
    floor = level * (np.asarray(fit.dof, dtype=float)[..., None] if np.ndim(fit.dof)
                     else float(fit.dof))
    var = np.real(np.diagonal(s, axis1=-2, axis2=-1))
    bad = np.any(var < floor, axis=-1) & np.isfinite(fit.G).all(axis=(-2, -1))
    if not np.any(bad):
        return {}, G_cov, s
    Z = np.asarray(Z)
    m, nz = Z.shape[-2:]
    start = 0 if bins is None else bins[0]
    on = np.zeros(m, dtype=bool)
    on[start:start + bad.shape[-1]] = np.any(bad.reshape(-1, bad.shape[-1]), axis=0)
    if select is not None:
        on &= np.asarray(select, dtype=bool)
    # a deterministic probe of unit modulus (golden-ratio phases) times the local rms
    # (circular=False, a haloed block of the frequency chunks: the block's bins, its rms
    # wrapped at the ends, only the probe of the bins near them differs from the circle's)
    k = np.arange(m)[:, None] * nz + np.arange(nz)
    phase = np.exp(2j * np.pi * ((k * 0.6180339887498949) % 1.0))
    rms = np.sqrt(window_mean(np.abs(Z) ** 2, int(half_width), axis=-2, circular=True))
    probed = local_model(R, Z + PROBE_AMPLITUDE * rms * phase, half_width=half_width,
                         degrees=tuple(degrees), circular=circular, covariance="full",
                         bins=bins, select=on, instruments=instruments)
    # every row's variance at least the floor; an unresolved row's correlations
    # (rounding) dropped, the resolved rows' kept, made a covariance
    eye = np.eye(nz, dtype=bool)
    low = var < level
    s_new = np.where((low[..., :, None] | low[..., None, :]) & ~eye, 0, s)
    s_new = nearest_correlation(np.where(eye, np.maximum(var, floor)[..., :, None], s_new))
    sp = probed.noise_covariance
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.where(sp != 0, s_new / sp, 0)
    nr = np.shape(R)[-1]
    C = probed.G_cov.reshape(probed.G_cov.shape[:-2] + (nz, nr, nz, nr))
    floored = (C * ratio[..., :, None, :, None]).reshape(probed.G_cov.shape)
    G_cov = np.where(bad[..., None, None], floored, G_cov)
    s = np.where(bad[..., None, None], s_new, s)
    fixed = slow_bin_terms(fit.G[bad], G_cov[bad], **terms)
    return _replaced_at(out, fixed, bad), G_cov, s


def _rounding_floor(rho, s_condition, noise_variance, Z, *, half_width, dof, circular,
                    bins=None, level=None):
    """``rho`` (..., B) of one record's fit raised to the rounding floor of its weakest
    direction at the bins where that floor alone leaves the weak direction undetermined
    (``K95 * floor > UNDETERMINED_LIMIT``) and the residuals are below the resolution of
    the local model's moments; every other bin's ``rho`` is returned bit for bit.

    The local model forms its residual energy from moments (a difference of sums of
    ``|Z|^2``), so a row's noise variance is resolved only above
    ``eps * sum_window |Z_i|^2 / dof``; below it (noiseless data fitted to that level:
    the HDD at N = 180 000, at 99 % of the bins) the residual covariance is rounding, and
    the weak-direction test reads it (``rho`` 0, or a covariance that happens to pass as
    one).  The data are then known to a relative ``delta = sqrt(eps (2 n + 1) / dof)`` at
    best, so ``S`` to about ``delta |S|`` and its weakest direction to ``delta cond(S)``
    relative: a lower bound (the HDD's ``P`` at such bins was off by about
    ``2e-7 cond(S)``, ten times ``delta cond(S)``).  Where even that exceeds the limit, the
    arithmetic does not determine the weakest direction (the HDD's slow DC at
    N = 180 000, ``cond(S)`` 2.3e7-2.8e7, where the VCM's double integrator makes the true
    ``S`` singular: released before with a zero-width band and ``P`` off by 4-7x at the
    fast bins 0 and N/2).  ``bins``: the block ``(start, stop)`` of the circle
    that ``rho`` holds (``Z`` is the whole circle); ``circular=False``: ``Z`` is padded as
    the fit's (bins without a full window are NaN and left alone).  ``level``: its
    :func:`_resolution_level`, when the caller has it."""
    n = int(half_width)
    if level is None:
        level = _resolution_level(Z, half_width=n, dof=dof, circular=circular, bins=bins)
    dof = np.asarray(dof, dtype=float)
    eps = np.finfo(float).eps
    with np.errstate(invalid="ignore", divide="ignore"):
        unresolved = np.any(noise_variance < level, axis=-1)
        floor = np.sqrt(eps * (2 * n + 1) / dof) * s_condition
    raise_ = unresolved & (K95 * floor > UNDETERMINED_LIMIT)
    if not np.any(raise_):
        return rho
    return np.where(raise_, np.maximum(rho, floor), rho)


def _positive_semidefinite(G_cov, noise_covariance):
    """``G_cov`` (..., M, nz nr, nz nr) of a fit (one record or pooled) rebuilt from the
    :func:`lcmr_xr.kernels.pooling.nearest_correlation` of its residual
    ``noise_covariance`` (..., M, nz, nz) (:func:`lcmr_xr.kernels.pooling.rescale_covariance`)
    at the bins where that changes it; the others are left bit for bit.  Every
    ``Cov(G_i, G_j) = s_ij h_i h_j^H`` is then a covariance (a positive semidefinite ``s``
    and the Schur product theorem): the first-order variance of ``P`` is never negative.
    ``G`` (and so ``P`` of a fixed window) is not touched.
    Measured on the HDD benchmark (8 experiments, IV, window 19): correlations above 1.01
    at 65 % of the bins (median of the largest per bin 1.025) before, and exact zeros of
    ``P``'s first-order variance (negative ones clipped) at window 12 (docs/uncertainty.md,
    "A pooled noise covariance that is a covariance"); one record, window 12: such zeros at
    released bins (LS and IV; docs/uncertainty.md, "... and one record's")."""
    new = nearest_correlation(noise_covariance)
    # (an entry estimated exactly 0 gives no factor to rescale, NaN: such a bin is left as
    # it is; noiseless HDD, N = 36 000, window 30: 102 bins, which had flagged 26 fast bins)
    changed = np.any(new != noise_covariance, axis=(-2, -1)) \
        & np.all(np.isfinite(noise_covariance) & (noise_covariance != 0), axis=(-2, -1))
    if not np.any(changed):
        return G_cov
    return np.where(changed[..., None, None],
                    rescale_covariance(G_cov, noise_covariance, new), G_cov)


def _mend_indefinite(out, G, G_cov, noise_covariance, terms) -> dict:
    """One record's :func:`slow_bin_terms` ``out`` recomputed, at the bins where
    ``cov(P_1)`` has a negative eigenvalue (some variance of ``P`` would come out negative,
    and :func:`lcmr_xr.kernels.closed_loop.frf_variance_from_first_row` clip it to 0: a
    released band of zero width), from ``G_cov`` rebuilt by :func:`_positive_semidefinite`;
    the other bins' terms are left bit for bit.  Returns the recomputed entries (copies).

    Only there, not at every bin as for pooled fits: mended at every bin, the band moved at
    80-93 % of the bins (median ratio 1.000) and ``window="auto"``'s choice with it, and the
    HDD records of ``tests/test_adaptive.py`` covered 0.992 at PZT 500-5000 Hz (0.990
    before; goal 0.90-0.99) (docs/uncertainty.md, "... and one record's")."""
    C = out.get("P1_cov")
    if C is None:
        return {}
    ok = np.all(np.isfinite(C), axis=(-2, -1))
    lam = np.linalg.eigvalsh(np.where(ok[..., None, None], C, np.eye(C.shape[-1])))[..., 0]
    bad = ok & (lam < 0)
    if not np.any(bad):
        return {}
    fixed = slow_bin_terms(G[bad], _positive_semidefinite(G_cov[bad], noise_covariance[bad]),
                           **terms)
    return _replaced_at(out, fixed, bad)


def _replaced_at(out, fixed, bad):
    """Copies of the terms of ``out`` with their values at the bins ``bad`` replaced by
    ``fixed`` (terms of those bins only, as :func:`slow_bin_terms` returns them); terms
    missing on either side are left out."""
    mended = {}
    for name, value in fixed.items():
        if value is None or out.get(name) is None:
            continue
        mended[name] = np.array(out[name], copy=True)
        mended[name][bad] = value
    return mended


def _spread_ratio(R, Z, terms, **kwargs) -> dict:
    """:func:`split_half_spread` of a pooled fit's ``terms`` (the pool's own ill-posed
    bins, ``P_bad``, have no variance to check): ``spread_ratio`` and the halves' first
    block rows ``P1_half_a``, ``P1_half_b`` and the weight of their difference
    ``half_weight``."""
    G_var = np.where(terms["ill_posed"][..., None, None], np.nan, terms["G_var"])
    ratio, (a, b), weight = split_half_spread(R, Z, G_var, **kwargs)
    return {"spread_ratio": ratio, "P1_half_a": a, "P1_half_b": b, "half_weight": weight}


#: The eager path (:func:`identify_spectra`) fits the local models in blocks of slow bins
#: holding about this much of their covariance (``(nz nr)^2`` complex per bin and record)
#: at a time, reducing each block to :func:`slow_bin_terms` before the next: one
#: identify's memory is then bounded by the record's per-bin results, not by its
#: covariance (115 MB for an N = 36 000 HDD record).  Blocks start on multiples of the
#: local model's moment restart interval, so the results are those of one fit over all
#: bins, bit for bit.
BLOCK_BYTES = 8 << 20


def _block_plan(R, Z, *, half_width, degrees, covariance, noise_covariance, experiment_axis,
                instruments, fitted_half=None) -> dict:
    """How :func:`_fit_blocks` cuts the circle for ``half_width`` (``instruments``: those of
    ``denominator="iv"``, None for least squares): ``known`` (the window mean of a known
    noise covariance, or None), ``half`` (the blocks cover bins ``0..M/2`` and the others
    are mirrored), ``last`` (bins fitted), ``align`` (the moment restart interval, on
    which every block starts) and ``edges`` (of the blocks).  ``fitted_half``: the
    :func:`lcmr_xr.kernels.local_models.fits_half` of these spectra (and instruments) when
    the caller has it (``window="auto"`` checks the spectra once for every candidate)."""
    known = None
    if covariance and noise_covariance is not None:
        known = window_mean(np.asarray(noise_covariance), half_width, axis=-3, circular=True)
    m, nr, nz = R.shape[-2], R.shape[-1], Z.shape[-1]
    n_exp = _n_experiments(R, Z, experiment_axis)
    lead = np.broadcast_shapes(R.shape[:-2], Z.shape[:-2])
    records = int(np.prod(lead, dtype=int)) // (n_exp or 1)  # outputs per bin
    half = fits_half(R, Z, half_width=half_width, instruments=instruments) \
        if fitted_half is None else bool(fitted_half)
    if half and known is not None:  # bin M - k rebuilt from its own known covariance unless mirrored
        half = hermitian(np.reshape(np.asarray(noise_covariance), (-1, m, nz * nz)))
    last = m // 2 + 1 if half else m  # bins fitted; the others mirrored
    align = _restart_interval(int(half_width))
    per_bin = 16 * records * ((nz * nr) ** 2 if covariance else nz * nr)
    step = align * max(1, BLOCK_BYTES // (per_bin * align))
    # the last block ends on the restart grid too (or at M): the few bins past M/2 it
    # fits are dropped for the mirror
    edges = list(range(0, last, step)) + [min(m, -(-last // align) * align)]
    return {"known": known, "half": half, "last": last, "align": align, "edges": edges}


def _block_terms(R, Z, a, b, *, known, covariance, half_width, degrees, experiment_axis,
                 closed_loop, denominator, instruments, first_row_only=False,
                 select=None, buffers=None, unfloored: bool = False) -> dict:
    """:func:`_fit_terms` of the slow bins ``a..b-1`` of the circle (a block of
    :func:`_fit_blocks`, or a refit of :func:`_refit_chosen`), with those bins' window
    mean ``known`` of a known noise covariance; without the split-half spread, which
    needs every bin."""
    return _fit_terms(R, Z, half_width=half_width, degrees=degrees, circular=True,
                      covariance=covariance,
                      known_covariance=None if known is None else known[..., a:b, :, :],
                      experiment_axis=experiment_axis, closed_loop=closed_loop,
                      denominator=denominator, instruments=instruments, bins=(a, b),
                      spread=False, first_row_only=first_row_only, select=select,
                      buffers=buffers, unfloored=unfloored)


def _fit_blocks(R, Z, *, half_width, degrees, covariance, noise_covariance, experiment_axis,
                closed_loop, denominator="ls", instruments=None, halves_instruments=None,
                first_row_only=False, select=None, fitted_half=None, buffers=None,
                unfloored: bool = False) -> dict:
    """:func:`_fit_terms` of every slow bin of the circle, fitted in blocks of bins
    (:data:`BLOCK_BYTES`).  Spectra of real signals: the blocks cover bins ``0..M/2``
    and the others are their mirrors, as in one fit over all bins
    (:func:`lcmr_xr.kernels.local_models.fits_half`).  ``first_row_only``: the terms of
    :func:`slow_bin_terms` with ``first_row_only``, no split-half spread.  ``fitted_half``
    as :func:`_block_plan`; ``buffers`` and ``unfloored`` as :func:`_fit_terms` (the
    unfloored terms of every bin, the floored ones' values where a block has none, returned
    if any block has them)."""
    R, Z = np.asarray(R), np.asarray(Z)
    iv = check_denominator(denominator, degrees)
    if iv and instruments is None:
        instruments = denominator_instruments(R, Z, degrees=degrees,
                                              experiment_axis=experiment_axis)
    plan = _block_plan(R, Z, half_width=half_width, degrees=degrees, covariance=covariance,
                       noise_covariance=noise_covariance, experiment_axis=experiment_axis,
                       instruments=instruments if iv else None, fitted_half=fitted_half)
    known, half, last, edges = plan["known"], plan["half"], plan["last"], plan["edges"]
    m = R.shape[-2]
    n_exp = _n_experiments(R, Z, experiment_axis)
    out = axes = None
    for a, b in zip(edges[:-1], edges[1:]):
        block = _block_terms(R, Z, a, b, known=known, covariance=covariance,
                             half_width=half_width, degrees=degrees,
                             experiment_axis=experiment_axis, closed_loop=closed_loop,
                             denominator=denominator, instruments=instruments,
                             first_row_only=first_row_only, select=select, buffers=buffers,
                             unfloored=unfloored)
        if out is None:  # every per-bin output, all M bins: the bin axis of each
            axes = {k: _bin_axis(k, n_exp) for k, v in block.items() if v is not None}
            out = {k: (None if v is None else
                       np.empty(v.shape[:v.ndim + axes[k]] + (m,) + v.shape[v.ndim + axes[k] + 1:],
                                v.dtype)) for k, v in block.items()}
        for k in [k for k in block if k.endswith("_unfloored") and k not in out]:
            # the first block with floored bins: the earlier blocks' unfloored terms are
            # their floored ones (the later bins of the copy are written below)
            base = k.removesuffix("_unfloored")
            out[k], axes[k] = out[base].copy(), axes[base]
        keep = min(b, last) - a
        for k, ax in axes.items():
            src = block[k] if k in block else block[k.removesuffix("_unfloored")]
            out[k][_bins_at(ax, slice(a, a + keep))] = src[_bins_at(ax, slice(0, keep))]
        del block
    if half:  # bins M/2+1..M-1 are the conjugates of (M-1)/2..1 (as local_model mirrors)
        for k, ax in axes.items():
            src = out[k][_bins_at(ax, slice((m - 1) // 2, 0, -1))]
            dst = out[k][_bins_at(ax, slice(m // 2 + 1, m))]
            if dst.dtype.kind == "c":
                np.conjugate(src, out=dst)
            else:
                dst[...] = src
    if covariance and not first_row_only and (n_exp or 0) >= MIN_SPLIT_EXPERIMENTS:
        out.update(_spread_ratio(R, Z, out, half_width=half_width, degrees=degrees,
                                 circular=True, experiment_axis=experiment_axis,
                                 denominator=denominator, instruments=halves_instruments,
                                 closed_loop=closed_loop))
    return out


def _bin_axis(name, n_exp) -> int:
    """The slow-bin axis (negative) of a per-bin output of :func:`_fit_terms`."""
    name = name.removesuffix("_unfloored")
    if name == "T":  # (..., M, nz), pooled (..., M, E, nz)
        return -2 if n_exp is None else -3
    return _BIN_AXES[name]


#: The slow-bin axis of each per-bin output of :func:`_fit_terms` (``T``: :func:`_bin_axis`).
_BIN_AXES = {"G": -3, "noise_variance": -2, "condition": -1, "ill_posed": -1, "P1": -3,
             "P1_cov": -3, "s_condition": -1, "s_singular": -1, "rho": -1, "rho_v": -1,
             "G_var": -3, "spread_ratio": -1, "P1_half_a": -3, "P1_half_b": -3,
             "half_weight": -1}


def _bins_at(axis: int, bins: slice) -> tuple:
    """Index selecting ``bins`` on the (negative) ``axis``."""
    return (Ellipsis, bins) + (slice(None),) * (-axis - 1)


def split_half_spread(R, Z, G_var, *, half_width, degrees, circular=True,
                      experiment_axis: int, denominator="ls", instruments=None,
                      closed_loop: str | None = None):
    """Per bin, the random-group variance of a pooled fit over the variance it reports.

    The even- and odd-numbered experiments (:func:`lcmr_xr.kernels.pooling.split_halves`)
    are each fitted as ``identify`` would fit them pooled (same window, degrees and
    denominator; IV from each half's own first fit; no covariance), and
    :func:`lcmr_xr.kernels.pooling.spread_ratio` compares the variance their difference
    implies for the whole pool (weighted per entry by the halves' excitation Grams,
    :func:`lcmr_xr.kernels.pooling.half_variances`) with ``G_var``, the variances of
    ``vec(G)`` the pooled fit reports.  The experiments are independent replicates, so this checks the local
    model's covariance without its noise model: on the HDD benchmark it reads about 2
    below 500 Hz, where the first-order covariance is too small (docs/uncertainty.md,
    "Pooled bands: the covariance checked by split halves").

    ``instruments``: the halves' own (:func:`half_instruments`) when the caller has them.

    ``closed_loop`` (``"indirect"`` or ``"direct"``): also return the halves' first block
    rows ``P_1`` (their ``G`` through the indirect step; NaN where a half is ill-posed)
    and the weight of their difference, from which
    :func:`lcmr_xr.kernels.pooling.p_spread_factor` calibrates the band of ``P`` (no
    further fit: the halves' ``G`` are those of the ratio).

    Returns
    -------
    ndarray, real, shape (..., M); with ``closed_loop``: ``(ratio, (P1_a, P1_b), weight)``,
    the first rows (..., M, ny, nr) (bins of a block, ``circular=False``: computed bin by
    bin) and per slow bin the mean over ``G``'s entries of the Gram weight
    ``V_a V_b / (V_a + V_b)^2`` (1/4 for equal halves of one design; NaN where no entry
    has one)
    """
    R, Z = _broadcast_leading(R, Z)
    if instruments is None:
        instruments = half_instruments(R, Z, degrees=degrees, circular=circular,
                                       experiment_axis=experiment_axis, denominator=denominator)
    n_exp = _n_experiments(R, Z, experiment_axis)
    halves = split_halves(n_exp)
    fits = [local_model(np.take(R, idx, axis=experiment_axis),
                        np.take(Z, idx, axis=experiment_axis), half_width=half_width,
                        degrees=tuple(degrees), circular=circular, covariance=None,
                        experiment_axis=experiment_axis, instruments=zhat)
            for idx, zhat in zip(halves, instruments)]
    # A half flagged ill-posed (e.g. its experiments excite two lifted channels nearly
    # alike, which the pool's others tell apart) returns a finite G of no meaning: its
    # difference from the other half is no spread of the pool, and the smoothing would
    # carry it to the neighbouring bins.  Such bins give no ratio (NaN).
    G = [np.where(f.ill_posed[..., None, None], np.nan, f.G) for f in fits]
    # Weight per entry from each half's own excitation: halves of unequal information
    # (another excitation level or design) are not n_a n_b / E^2 (docs/uncertainty.md).
    V = [half_variances(np.moveaxis(np.take(R, idx, axis=experiment_axis), experiment_axis, -3),
                        half_width, circular=circular)[..., None, :] for idx in halves]
    weight = group_weight(V[0], V[1])
    ratio = spread_ratio(G[0], G[1], G_var, weight)
    if closed_loop is None:
        return ratio
    nr = np.shape(R)[-1]
    if closed_loop == "indirect":
        with np.errstate(all="ignore"):  # (NaN where ill-posed: indirect_first_row flags it)
            rows = tuple(indirect_first_row(g, nr, mirrors=circular).first_row for g in G)
    else:
        rows = tuple(G)
    # the weight of the halves' difference per slow bin for P: the mean over G's columns
    # (exact for Grams proportional to each other, where every entry of P has it)
    w = np.broadcast_to(weight, G_var.shape)
    ok = np.isfinite(w)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean_w = np.where(ok, w, 0.0).sum(axis=(-2, -1)) / ok.sum(axis=(-2, -1))
    return ratio, rows, mean_w


def half_instruments(R, Z, *, degrees, circular=True, experiment_axis: int,
                     denominator="ls") -> tuple:
    """The instruments of the two halves of :func:`split_half_spread` (each half's own
    first fit; ``(None, None)`` for least squares)."""
    if not check_denominator(denominator, degrees):
        return None, None
    R, Z = _broadcast_leading(R, Z)
    return tuple(denominator_instruments(np.take(R, idx, axis=experiment_axis),
                                         np.take(Z, idx, axis=experiment_axis),
                                         degrees=degrees, circular=circular,
                                         experiment_axis=experiment_axis)
                 for idx in split_halves(_n_experiments(R, Z, experiment_axis)))


def _broadcast_leading(R, Z):
    """``R`` and ``Z`` with their leading dims broadcast to each other."""
    lead = np.broadcast_shapes(np.shape(R)[:-2], np.shape(Z)[:-2])
    return (np.broadcast_to(R, lead + np.shape(R)[-2:]),
            np.broadcast_to(Z, lead + np.shape(Z)[-2:]))


def finish_packed(packed, *, nz: int, nr: int, n_fast: int, factor: int, nu: int, ny: int,
                  closed_loop: str = "indirect", covariance: bool = True, dof=None,
                  n_exp: int | None = None, neighbourhood: bool = False,
                  unfloored: bool = False) -> dict:
    """Unpack :func:`fit_packed` and recover the fast FRF (see :func:`identify_arrays`).

    ``dof``: degrees of freedom per row of the local model (scalar or per slow bin), for the
    small-sample factor of ``P_var``; None leaves it out.  ``n_exp``: the number of pooled
    experiments (``T`` is then (..., M, E, nz)); None: not pooled.  ``neighbourhood``: the
    fit of one record at a fixed window, whose own covariance (from its residuals) also
    flags a bin most of whose neighbours fail the weak-direction test (:func:`_recover`;
    :func:`identify_spectra` does so).  Not for ``window="auto"``'s candidates, whose
    choice reads each one's own test (:func:`_finish_choice` then takes the widest one's
    neighbourhood).  ``unfloored``: ``packed`` is of :func:`fit_packed` with ``unfloored``;
    where those terms differ from the floored ones, also ``P_var_choice`` and
    ``P_var_linear_choice`` (:func:`_finish`).
    """
    packed = np.asarray(packed)
    lead_m = packed.shape[:-1]
    ne = 1 if n_exp is None else n_exp
    widths = [("G", nz * nr, (nz, nr)), ("T", ne * nz, (nz,) if n_exp is None else (ne, nz)),
              ("noise_variance", nz, (nz,)), ("condition", 1, ()), ("ill_posed", 1, ())]
    if covariance and ne >= MIN_SPLIT_EXPERIMENTS:
        widths += [("spread_ratio", 1, ()), ("half_weight", 1, ()),
                   ("P1_half_a", ny * nr, (ny, nr)),
                   ("P1_half_b", ny * nr, (ny, nr))]
    widths += [("P1", ny * nr, (ny, nr)), ("s_condition", 1, ()), ("s_singular", 1, ())]
    if covariance:
        widths += [("G_var", nz * nr, (nz, nr)), ("rho", 1, ()), ("rho_v", 1, ()),
                   ("P1_cov", (ny * nr) ** 2, (ny * nr, ny * nr))]
        if unfloored:
            widths += [(f"{name}_unfloored", k, shape) for name, k, shape in widths[-3:]]
    complex_ = {"G", "T", "P1", "P1_cov", "P1_half_a", "P1_half_b", "P1_cov_unfloored"}
    terms, o = {"P1_cov": None}, 0
    for name, k, shape in widths:
        # copies, not views: a view would keep all of ``packed`` alive for as long as the
        # small results live
        x = packed[..., o: o + k].reshape(lead_m + shape)
        terms[name] = x.copy() if name in complex_ else x.real.copy()
        o += k
    terms["ill_posed"] = terms["ill_posed"] != 0
    terms["s_singular"] = terms["s_singular"] != 0
    raw = {k: terms.pop(f"{k}_unfloored") for k in _UNFLOORED if f"{k}_unfloored" in terms}
    if any(not np.array_equal(raw[k], terms[k], equal_nan=True) for k in raw):
        # (as the eager fits: only where the floor changed a bin does _finish recover them)
        terms.update({f"{k}_unfloored": v for k, v in raw.items()})
    del raw
    if not covariance:
        terms["G_var"] = np.full(terms["G"].shape, np.nan)
        terms["rho"] = terms["rho_v"] = np.full(lead_m, np.nan)
    return _finish(terms, n_fast=n_fast, factor=factor, nu=nu, ny=ny, closed_loop=closed_loop,
                   dof=dof, neighbourhood=neighbourhood)


def _finish(fit: dict, *, n_fast, factor, nu, ny, closed_loop, dof,
            neighbourhood: bool = False) -> dict:
    """The fast FRF and the per-bin outputs from the fitted terms (:func:`_fit_terms`;
    ``T`` as :func:`finish_packed` returns it).  Pooled experiments
    (``fit["spread_ratio"]``): the covariance is scaled per bin by
    :func:`lcmr_xr.kernels.pooling.spread_calibration`, so the band of ``P``, the
    weak-direction test of ``S`` and ``G_var`` see the spread the halves show; the halves'
    ``P`` put a further factor on ``P_var`` (``P_spread_calibration``,
    :func:`lcmr_xr.kernels.pooling.p_spread_factor`) and the nonlinearity factor takes the
    pooled form (:func:`lcmr_xr.kernels.adaptive.pooled_nonlinearity_factor`).
    ``neighbourhood`` as :func:`finish_packed`."""
    calibration = halves = None
    if fit["P1_cov"] is not None and "spread_ratio" in fit:
        calibration = spread_calibration(fit["spread_ratio"])
        if "P1_half_a" in fit:
            halves = (fit["P1_half_a"], fit["P1_half_b"], fit["half_weight"])
    out = _recover(fit, n_fast=n_fast, factor=factor, nu=nu, ny=ny, closed_loop=closed_loop,
                   ill_posed=fit["ill_posed"], dof=dof, calibration=calibration, halves=halves,
                   neighbourhood=neighbourhood)
    G_var = fit["G_var"] if calibration is None else fit["G_var"] * calibration[..., None, None]
    out.update({"G": fit["G"], "G_var": G_var, "T": fit["T"],
                "noise_variance": fit["noise_variance"], "condition": fit["condition"],
                "ill_posed": fit["ill_posed"]})
    if calibration is not None:
        out["spread_calibration"] = calibration
    if "P1_cov_unfloored" in fit:  # window="auto"'s choice reads the unfloored variances
        raw = {k: fit[f"{k}_unfloored"] for k in _UNFLOORED}
        choice = _recover(
            {**fit, **raw}, n_fast=n_fast, factor=factor, nu=nu, ny=ny,
            closed_loop=closed_loop, ill_posed=fit["ill_posed"], dof=dof,
            calibration=calibration, halves=halves, neighbourhood=neighbourhood)
        out["P_var_choice"] = choice["P_var"]
        out["P_var_linear_choice"] = choice["P_var_linear"]
    return out


#: The terms of :func:`_fit_terms` that ``unfloored`` also returns without the
#: resolution floor (:func:`_finish` recovers ``window="auto"``'s choice from them).
_UNFLOORED = ("P1_cov", "rho", "rho_v")


def _fit_and_finish(R, Z, *, half_width, degrees, covariance, noise_covariance, experiment_axis,
                    n_fast, factor, nu, ny, closed_loop, n_exp, denominator="ls",
                    instruments=None, halves_instruments=None, fitted_half=None,
                    buffers=None, neighbourhood: bool = False, unfloored: bool = False) -> dict:
    """The local model in blocks of bins (:func:`_fit_blocks`), then :func:`_finish`
    (``neighbourhood`` as :func:`finish_packed`; ``unfloored`` as :func:`_fit_terms`, and
    :func:`_finish` then also returns ``P_var_choice`` and ``P_var_linear_choice`` where
    a bin was floored)."""
    fit = _fit_blocks(R, Z, half_width=half_width, degrees=degrees, covariance=covariance,
                      noise_covariance=noise_covariance, experiment_axis=experiment_axis,
                      closed_loop=closed_loop, denominator=denominator,
                      instruments=instruments, halves_instruments=halves_instruments,
                      fitted_half=fitted_half, buffers=buffers, unfloored=unfloored)
    return _finish(fit, n_fast=n_fast, factor=factor, nu=nu, ny=ny, closed_loop=closed_loop,
                   dof=window_dof(half_width, R.shape[-1], degrees, n_exp or 1),
                   neighbourhood=neighbourhood)


def identify_arrays(r, u, y, *, factor: int, half_width: int, degrees=(3, 3, 3),
                    closed_loop: str = "indirect", covariance: bool = True,
                    noise_covariance=None) -> dict:
    """Fast FRF of a plant in multirate closed loop from ``r``, ``u`` (fast) and ``y`` (slow).

    Parameters
    ----------
    r, u : ndarray, shape (..., N, nu)
        Fast-rate excitation and measured plant input.
    y : ndarray, shape (..., M, ny)
        Slow-rate measured output, ``y(l) = y_h(l F)``.
    factor : int
        Multirate factor ``F = N / M``.
    half_width : int
        Local window half-width ``n`` (``2 n + 1`` slow bins).
    degrees : (int, int, int), default (3, 3, 3)
        ``(Rn, Rm, Rd)``: numerator, transient and denominator degrees (``Rd = 0``: LPM).
    closed_loop : {"indirect", "direct"}, default "indirect"
        ``"indirect"``: ``G = [S; PS_1]`` from the lifted ``r``, then ``P_1 = PS_1 S^-1``
        (unbiased under feedback).  ``"direct"``: local model from the lifted ``u`` to
        ``y`` (biased under feedback; kept for comparison).
    covariance : bool, default True
        Propagate the local-model covariance to ``P`` (costs ``(nz nr)^2`` per bin).
    noise_covariance : ndarray, shape (..., M, nz, nz), optional
        Noise covariance of the spectra ``Z`` known per slow bin (periodic data: the
        spread over periods); used for the covariance instead of the residual estimate
        (see :func:`fit_packed`).

    Returns
    -------
    dict of ndarray
        ``P`` (..., N/2+1, ny, nu) at fast bins ``k = 0..N/2``; ``P_var`` (same, real,
        ``E|dP|^2``; NaN without covariance); ``P_bad`` (..., N/2+1) bool; ``G`` (..., M, nz, nr);
        ``G_var`` (..., M, nz, nr); ``T`` (..., M, nz); ``noise_variance`` (..., M, nz);
        ``condition``, ``ill_posed``, ``s_condition``, ``s_singular`` (..., M).
    """
    R, Z = experiment_spectra(r, u, y, factor=factor, closed_loop=closed_loop)
    return identify_spectra(R, Z, n_fast=np.shape(r)[-2], factor=factor, nu=np.shape(r)[-1],
                            half_width=half_width, degrees=degrees, closed_loop=closed_loop,
                            covariance=covariance, noise_covariance=noise_covariance)


def identify_spectra(R, Z, *, n_fast: int, factor: int, nu: int, half_width: int,
                     degrees=(3, 3, 3), closed_loop: str = "indirect",
                     covariance: bool = True, noise_covariance=None,
                     experiment_axis: int | None = None, denominator: str = "ls",
                     neighbourhood: bool | None = None) -> dict:
    """:func:`identify_arrays` from the spectra of :func:`experiment_spectra` (computed once).

    ``R`` (..., M, nr) and ``Z`` (..., M, nz); ``n_fast`` is ``N``, ``nu`` the number of
    plant inputs; ``noise_covariance`` as in :func:`identify_arrays`.  Returns the dict of
    :func:`identify_arrays`.  ``experiment_axis``: pool that leading axis (``E``
    experiments, shared ``G``, a transient each; ``T`` is then (..., M, E, nz)).
    ``denominator``: ``"ls"`` (least squares) or ``"iv"`` (instrumental variables,
    :func:`denominator_instruments`); ``"iv"`` needs ``Rd > 0``.

    ``neighbourhood`` (None: one record whose covariance comes from its residuals, no
    ``experiment_axis``, no ``noise_covariance``): ``P_undetermined`` also where more than
    half of the slow bins within +-6 fail the weak-direction test (:func:`finish_packed`;
    False: the window's own test only, as ``window="auto"`` finishes its candidates):
    where the weak direction of ``S`` is drowned in noise its estimated ratio saturates near
    1 and scatters, and a draw under the limit released bins with bands 40-150 times too
    narrow (HDD below 500 Hz, docs/uncertainty.md, "A saturated ratio").
    """
    nz, nr = Z.shape[-1], R.shape[-1]
    ny = nz - nr if closed_loop == "indirect" else nz
    return _fit_and_finish(R, Z, half_width=half_width, degrees=degrees, covariance=covariance,
                           noise_covariance=noise_covariance, experiment_axis=experiment_axis,
                           n_fast=n_fast, factor=factor, nu=nu, ny=ny, closed_loop=closed_loop,
                           n_exp=_n_experiments(R, Z, experiment_axis), denominator=denominator,
                           neighbourhood=(experiment_axis is None and noise_covariance is None)
                           if neighbourhood is None else neighbourhood)


def _n_experiments(R, Z, experiment_axis):
    """``E`` of a pooled fit (None: not pooled)."""
    if experiment_axis is None:
        return None
    lead = np.broadcast_shapes(np.shape(R)[:-2], np.shape(Z)[:-2])
    return (lead + (0, 0))[experiment_axis]


def window_dof(half_width, nr: int, degrees, n_exp: int = 1) -> np.ndarray:
    """Degrees of freedom per row of the local model: ``2 n + 1 - parameters_per_row``;
    pooling ``n_exp`` experiments (a transient each): ``E (2 n + 1) - p``."""
    rm = tuple(degrees)[1]
    return n_exp * (2 * np.asarray(half_width) + 1) - parameters_per_row(nr, tuple(degrees)) \
        - (n_exp - 1) * (rm + 1)


def identify_spectra_auto(R, Z, *, n_fast: int, factor: int, nu: int, windows,
                          degrees=(3, 3, 3), closed_loop: str = "indirect",
                          noise_covariance=None, experiment_axis: int | None = None,
                          denominator: str = "ls") -> dict:
    """:func:`identify_spectra` with a window chosen per slow bin among ``windows``.

    Every candidate half-width (ascending) is fitted with its covariance, its fast FRF and
    calibrated variance recovered, and :func:`lcmr_xr.kernels.adaptive.select_windows`
    picks one per slow bin; every returned array is then the chosen window's, bin by bin
    (a fast bin ``k`` from the choice at slow bin ``k mod M``).  The squared model-error
    estimate of the chosen window is added to ``P_var``.  Where
    :func:`checks_denominator_bias` (one least-squares LRM record), the widest window is
    also fitted by IV with its own least-squares prediction as instruments (at the slow
    bins of :func:`twin_bins` only: the term is a local mean), and the
    Hausman upper term for least squares' bias (:func:`lcmr_xr.kernels.adaptive.
    denominator_bias`) joins the model error at every bin, with the
    second-order nonlinearity factor (:func:`_finish_choice`).

    Memory (issue 18): of the candidates fitted before the widest, only what the choice
    reads is kept (``P``, ``P_var``, ``P_var_linear`` on the fast bins, and the pooled
    fits' calibration per slow bin); the widest candidate's outputs are kept whole, and
    the bins where a narrower window wins are fitted again, in blocks of bins on that
    window's restart grid (:func:`_refit_chosen`), which gives the values of its first
    fit bit for bit.  The result is that of finishing every candidate and gathering
    (:func:`finish_packed_auto` does so), without holding every candidate's per-bin
    outputs at once.

    Returns
    -------
    dict of ndarray
        As :func:`identify_arrays`, plus ``window`` (..., M) int, the chosen half-width per
        slow bin, and ``P_bias`` (..., N/2+1, ny, nu), the model-error estimate (same
        units as ``P``).  ``noise_covariance`` (periods) as in :func:`identify_arrays`:
        every candidate's covariance is built from it, averaged over that candidate's window.
        ``denominator`` as :func:`identify_spectra`: one first fit's instruments serve
        every candidate.
    """
    R, Z = np.asarray(R), np.asarray(Z)
    windows = sorted(int(w) for w in windows)
    instruments = denominator_instruments(R, Z, degrees=degrees, experiment_axis=experiment_axis) \
        if check_denominator(denominator, degrees) else None
    nz, nr, m = Z.shape[-1], R.shape[-1], R.shape[-2]
    ny = nz - nr if closed_loop == "indirect" else nz
    n_exp = _n_experiments(R, Z, experiment_axis)
    # the split halves' first fits (pooled experiments, IV) also serve every candidate
    halves = half_instruments(R, Z, degrees=degrees, experiment_axis=experiment_axis,
                              denominator=denominator) \
        if (n_exp or 0) >= MIN_SPLIT_EXPERIMENTS else None
    # whether the blocks cover bins 0..M/2 and mirror (spectra of real signals): the same
    # for every candidate (a scalar window is symmetric), checked once
    half = fits_half(R, Z, half_width=windows[0], instruments=instruments)
    fit = dict(degrees=degrees, noise_covariance=noise_covariance,
               experiment_axis=experiment_axis, closed_loop=closed_loop,
               denominator=denominator, instruments=instruments, fitted_half=half)
    # a record whose fits take one block each (short records): every fit's covariance in
    # one buffer, each reduced before the next fit (fresh pages: about 7 ms of system time
    # per fit at N = 3600, a tenth of a fixed-window identify).  Longer records keep fresh
    # blocks: the buffer, all of it resident, raised their peak of memory (the twin writes
    # a third of its rows, the last block is shorter), and their fits outweigh the faults
    fit["buffers"] = CovarianceBuffer() if all(
        len(_block_plan(R, Z, half_width=w, degrees=degrees, covariance=True,
                        noise_covariance=noise_covariance, experiment_axis=experiment_axis,
                        instruments=instruments, fitted_half=half)["edges"]) == 2
        for w in windows) else None
    fast = calibrations = None  # (J, ..., K, ny, nu) per fast name; per candidate or None
    held, held_bytes = {}, 0  # narrower candidates kept whole (within HELD_BYTES)
    for j, w in enumerate(windows):
        out = _fit_and_finish(R, Z, half_width=w, covariance=True, n_fast=n_fast,
                              factor=factor, nu=nu, ny=ny, n_exp=n_exp,
                              halves_instruments=halves, unfloored=True, **fit)
        for k in ("P_var", "P_var_linear"):  # the same where no bin was floored
            out.setdefault(f"{k}_choice", out[k])
        if fast is None:
            fast = {k: np.empty((len(windows),) + out[k].shape, out[k].dtype)
                    for k in _FAST if k in out}
            calibrations = [None] * len(windows)
        for k in fast:
            fast[k][j] = out.pop(k)
        calibrations[j] = out.get("spread_calibration")
        size = sum(v.nbytes for v in out.values())
        if j < len(windows) - 1 and held_bytes + size <= HELD_BYTES:
            held[j], held_bytes = out, held_bytes + size
        if j < len(windows) - 1:
            out = None  # (not held while the next candidate is fitted)
    # the choice from the variances without the resolution floor (a bound for the band,
    # not a variance: with it every candidate's band at the floor, the widest won every
    # bin of noiseless records); the band released is the chosen window's floored one
    choice, bias2 = select_windows(fast["P"], fast.pop("P_var_choice", fast["P_var"]),
                                   fast.pop("P_var_linear_choice", fast["P_var_linear"]), m)
    fast_choice = np.take(choice, np.arange(bias2.shape[-3]) % m, axis=-1)
    twin = None
    if checks_denominator_bias(denominator, degrees, closed_loop, n_exp,
                               known_noise=noise_covariance is not None):
        # least squares' errors-in-variables bias at the widest window, by its IV twin
        # whose instruments are that window's own least-squares prediction
        # (the instruments of denominator_instruments(half_width=windows[-1]), from that
        # candidate's own G and T; of the IV fit only P and its first-order variance)
        zhat = _prediction(out["G"], out["T"], R, Z, experiment_axis=experiment_axis)
        iv = _fit_blocks(R, Z, half_width=windows[-1], degrees=degrees, covariance=True,
                         noise_covariance=None, experiment_axis=experiment_axis,
                         closed_loop=closed_loop, denominator="iv", instruments=zhat,
                         first_row_only=True, select=twin_bins(m),
                         fitted_half=half and hermitian(zhat.reshape(-1, m, nz)),
                         buffers=fit["buffers"])
        # the variance at the fast bins of the slow bins fitted only (NaN elsewhere)
        bins = np.flatnonzero(twin_bins(m)[np.arange(n_fast // 2 + 1) % m])
        var_iv = np.full(fast["P_var_linear"][-1].shape, np.nan)
        var_iv[..., bins, :, :] = frf_variance_from_first_row(iv["P1_cov"], n_fast, factor,
                                                              bins, ny, nu)
        twin = denominator_bias(
            fast["P"][-1], frf_from_first_block_row(iv["P1"], factor)[..., : n_fast // 2 + 1, :, :],
            fast["P_var_linear"][-1], var_iv,
            determined=np.isfinite(fast["P_var"][-1]))
        del iv, zhat
    # the fits that share the buffer are done: the refits (long records) take fresh memory,
    # as sized to their runs of bins, and the buffer does not raise the peak of the gather
    del fit["buffers"]
    idx = fast_choice[None, ..., None, None]
    for k in fast:  # the chosen candidate's, fast bin by fast bin
        fast[k] = np.take_along_axis(fast[k], idx, axis=0)[0]
    # ``out`` is the widest candidate's; the bins another window won are gathered from it
    # if it is held, else fitted again
    widest_undetermined = out["P_undetermined"].copy()
    # its residual variance and rho (the test of its flag, _finish_choice; not with a
    # known noise)
    widest_noise = (out["noise_variance"].copy(), out["s_weak_rel_std"].copy()) \
        if noise_covariance is None else None
    for j, o in held.items():
        for name, value in o.items():
            at = choice if value.shape[choice.ndim - 1] == m else fast_choice
            np.copyto(out[name], value, where=(at == j).reshape(at.shape + (1,) * (value.ndim - at.ndim)))
    refit = [j for j in range(len(windows) - 1) if j not in held and np.any(choice == j)]
    del held
    flags = {k: np.zeros(choice.shape, dtype=bool) for k in ("P_bad", "P_undetermined")}
    for j in refit:
        _refit_chosen(out, flags, choice == j, R, Z, half_width=windows[j], n_exp=n_exp,
                      dof=window_dof(windows[j], nr, degrees, n_exp or 1),
                      calibration=calibrations[j], **fit)
    for k, slow in flags.items():  # the fast bins of the slow bins refitted
        np.copyto(out[k], np.take(slow, np.arange(n_fast // 2 + 1) % m, axis=-1),
                  where=np.isin(fast_choice, refit))
    out.update(fast)
    return _finish_choice(out, choice, fast_choice, bias2, widest_undetermined,
                          np.asarray(windows, dtype=int), twin=twin, nr=nr, degrees=degrees,
                          widest_noise=widest_noise, n_exp=n_exp)


#: ``window="auto"`` (:func:`identify_spectra_auto`) keeps the per-bin outputs of narrower
#: candidates whole while they take at most this many bytes together (short records: no
#: second fit); beyond, only what the window choice reads, and the bins a narrower window
#: wins are fitted again.
HELD_BYTES = 8 << 20

#: The outputs of :func:`_finish` on the fast bins (what the window choice reads, and the
#: pooled fits' factor on ``P_var``, which is smoothed over fast bins).
_FAST = ("P", "P_var", "P_var_linear", "P_spread_calibration", "P_var_choice",
         "P_var_linear_choice")


def _refit_chosen(out, flags, chosen, R, Z, *, half_width, degrees, noise_covariance,
                  experiment_axis, closed_loop, denominator, instruments, n_exp, dof,
                  calibration, fitted_half=None) -> None:
    """Write the per-slow-bin outputs of the candidate ``half_width`` into ``out`` (the
    outputs of :func:`_finish` of another candidate, over all bins) where ``chosen``
    (..., M), and its slow-bin ``P_bad`` and ``P_undetermined`` into ``flags``.

    Record by record (each record's own choice), the local model is fitted again in the
    blocks of :func:`_fit_blocks` that hold a chosen bin (or the bin a chosen bin
    mirrors), each cut down to the runs of the restart interval that do: a block starting
    and ending on that grid gives the values of the whole fit at its bins, bit for bit
    (:func:`lcmr_xr.kernels.local_models.local_model`, ``bins=``), and the per-bin steps
    after the fit (:func:`slow_bin_terms`, :func:`_slow_recovery`) are bin by bin.
    Whether the bins past ``M/2`` are mirrors is decided for all records at once, as the
    first fit did.  ``calibration``: the candidate's pooled spread calibration per slow
    bin (from its first fit; it is smoothed over bins).  ``fitted_half`` as
    :func:`_block_plan`.
    """
    iv = check_denominator(denominator, degrees)
    plan = _block_plan(R, Z, half_width=half_width, degrees=degrees, covariance=True,
                       noise_covariance=noise_covariance, experiment_axis=experiment_axis,
                       instruments=instruments if iv else None, fitted_half=fitted_half)
    lead = chosen.shape[:-1]
    R, Z = _broadcast_leading(R, Z)  # (..., [E,] M, channels), ``...`` = ``lead``
    known = plan.pop("known")
    if known is not None:
        known = np.broadcast_to(known, lead + known.shape[-3:])
    if instruments is not None:
        instruments = np.broadcast_to(instruments, Z.shape)
    for i in np.ndindex(lead):
        _refit_record({k: v[i] for k, v in out.items()}, {k: v[i] for k, v in flags.items()},
                      chosen[i], R[i], Z[i], half_width=half_width, degrees=degrees,
                      experiment_axis=experiment_axis, closed_loop=closed_loop,
                      denominator=denominator,
                      instruments=None if instruments is None else instruments[i],
                      known=None if known is None else known[i], n_exp=n_exp, dof=dof,
                      calibration=None if calibration is None else calibration[i], **plan)


def _refit_record(out, flags, chosen, R, Z, *, half_width, degrees, experiment_axis,
                  closed_loop, denominator, instruments, known, n_exp, dof, calibration,
                  half, last, align, edges) -> None:
    """:func:`_refit_chosen` of one record (``chosen`` (M,); ``out``, ``flags`` its views)."""
    m = R.shape[-2]
    need = chosen[:last].copy()  # fitted bins whose own value is chosen ...
    if half:  # ... or whose mirror's is: bin M - t for t = M/2+1..M-1
        need[1:(m - 1) // 2 + 1] |= chosen[m // 2 + 1:][::-1]
    names = ("G", "T", "noise_variance", "condition", "ill_posed", "s_condition",
             "s_singular", "G_var", "rho", "rho_v", "P1_cov")
    for a, b in _chosen_runs(need, edges, align):
        terms = _block_terms(R, Z, a, b, known=known, covariance=True,
                             half_width=half_width, degrees=degrees,
                             experiment_axis=experiment_axis, closed_loop=closed_loop,
                             denominator=denominator, instruments=instruments)
        # its own bins a..min(b, last)-1; with ``half`` also bins t = M/2+1..M-1 whose
        # mirror M - t is in a..b-1 (their terms are the conjugates, as _fit_blocks has them)
        t = np.arange(max(m // 2 + 1, m - b + 1), min(m - 1, m - a) + 1) if half else np.arange(0)
        for bins_, src in ((np.arange(a, min(b, last)), None), (t, m - t)):
            keep = chosen[bins_]
            if not keep.any():
                continue
            bins_, src = bins_[keep], (None if src is None else src[keep])
            at = {}
            for name in names:
                v = np.take(terms[name], (bins_ if src is None else src) - a,
                            axis=_bin_axis(name, n_exp))
                at[name] = np.conj(v) if src is not None and v.dtype.kind == "c" else v
            cal = None if calibration is None else calibration[bins_]
            slow = _slow_recovery(at, closed_loop=closed_loop, ill_posed=at["ill_posed"],
                                  dof=dof, calibration=cal)
            # the per-slow-bin outputs of _finish (and of _recover) at these bins
            got = {name: at[name] for name in names[:7]}
            got.update(s_weak_rel_std=slow["rho"], P_bad=slow["bad"],
                       P_undetermined=slow["undetermined"],
                       G_var=at["G_var"] if cal is None else at["G_var"] * cal[..., None, None])
            if cal is not None:
                got["spread_calibration"] = cal
            for name, value in got.items():
                dst, ax = (flags[name], -1) if name in flags else (out[name],
                                                                   _slow_axis(name, n_exp))
                np.moveaxis(dst, ax, 0)[bins_] = np.moveaxis(value, ax, 0)
        del terms


def _chosen_runs(need, edges, align):
    """The ``(start, stop)`` of the runs of restart intervals (``align`` bins) within the
    blocks ``edges`` that hold a bin where ``need``: start on the grid, stop on it or at
    the block's end (on the grid or ``M``)."""
    runs = []
    for a, b in zip(edges[:-1], edges[1:]):
        starts = np.arange(a, b, align)
        hit = np.array([need[s:min(s + align, b)].any() for s in starts], dtype=bool)
        first = len(runs)  # (runs do not cross blocks: a block's covariance at most)
        for i in np.flatnonzero(hit):
            s, e = int(starts[i]), min(int(starts[i]) + align, b)
            if len(runs) > first and runs[-1][1] == s:
                runs[-1] = (runs[-1][0], e)
            else:
                runs.append((s, e))
    return runs


def _slow_axis(name, n_exp) -> int:
    """The slow-bin axis (negative) of a per-slow-bin output of :func:`_finish`."""
    if name in ("s_weak_rel_std", "spread_calibration"):
        return -1
    return _bin_axis(name, n_exp)


def finish_packed_auto(packed, *, windows, nz: int, nr: int, n_fast: int, factor: int, nu: int,
                       ny: int, closed_loop: str = "indirect", degrees=(3, 3, 3),
                       n_exp: int | None = None, twin=None, known_noise: bool = False,
                       unfloored: bool = False) -> dict:
    """The window choice of :func:`identify_spectra_auto` from its candidates' fits.

    ``packed`` (J, ..., M, K): :func:`fit_packed` of every candidate half-width in
    ``windows`` (ascending, with covariance), e.g. fitted in frequency chunks.  ``twin``
    (..., M, K), where :func:`checks_denominator_bias`: :func:`fit_packed` of the widest
    window with ``denominator="iv"``, ``select`` :func:`twin_bins` (NaN at the other bins)
    and as ``instruments`` the widest candidate's own
    prediction ``G R + T`` (:func:`_prediction`), the Hausman twin of :func:`identify_spectra_auto`.
    ``known_noise``: the fits' covariance was built from a known noise covariance
    (periods), not from their residuals.  ``unfloored``: the candidates' fits carry their
    terms without the resolution floor (:func:`fit_packed` with ``unfloored``; one record
    with its covariance from its residuals): the choice reads the variances recovered from
    them, as :func:`identify_spectra_auto` does.  Returns the dict of
    :func:`identify_spectra_auto`.
    """
    windows = np.asarray(windows, dtype=int)
    if np.any(np.diff(windows) <= 0) or len(windows) != len(packed):
        raise ValueError(f"windows must be ascending, one per packed fit; got {windows.tolist()} "
                         f"for {len(packed)} fits.")
    shape = dict(nz=nz, nr=nr, n_fast=n_fast, factor=factor, nu=nu, ny=ny,
                 closed_loop=closed_loop, covariance=True)
    outs = [finish_packed(p, dof=window_dof(w, nr, degrees, n_exp or 1), n_exp=n_exp,
                          unfloored=unfloored, **shape) for p, w in zip(packed, windows)]
    bias = None
    if twin is not None:
        iv = finish_packed(twin, dof=None, n_exp=n_exp, **shape)
        bias = denominator_bias(outs[-1]["P"], iv["P"], outs[-1]["P_var_linear"],
                                iv["P_var_linear"], determined=np.isfinite(outs[-1]["P_var"]))
    return _choose_windows(outs, windows, packed.shape[-2], twin=bias, nr=nr, degrees=degrees,
                           n_exp=n_exp, known_noise=known_noise)


def _choose_windows(outs, windows, m, *, twin=None, nr=None, degrees=None, n_exp=None,
                    known_noise: bool = False) -> dict:
    """Choose per slow bin among the finished candidates ``outs`` (ascending ``windows``)
    and gather every array from the chosen one (module notes of ``kernels.adaptive``).
    The candidates' arrays are released as they are gathered (``outs`` is emptied).
    ``known_noise``: their covariance is built from a known noise covariance.  The choice
    reads a candidate's ``P_var_choice``, ``P_var_linear_choice`` where it has them (the
    variances without the resolution floor, :func:`_finish`), as
    :func:`identify_spectra_auto`; the band gathered is the floored one."""
    P = np.stack([o["P"] for o in outs])
    P_var = np.stack([o.pop("P_var_choice", o["P_var"]) for o in outs])
    P_lin = np.stack([o.pop("P_var_linear_choice", o["P_var_linear"]) for o in outs])
    choice, bias2 = select_windows(P, P_var, P_lin, m)
    del P, P_var, P_lin
    fast_choice = np.take(choice, np.arange(bias2.shape[-3]) % m, axis=-1)
    widest_undetermined = outs[-1]["P_undetermined"]
    widest_noise = None if known_noise else (outs[-1]["noise_variance"].copy(),
                                             outs[-1]["s_weak_rel_std"].copy())

    def gather(name):
        """The chosen candidate's array, bin by bin (slow or fast bins), without a stack
        of all candidates' (each candidate's array is dropped once read)."""
        lead = choice.ndim  # (..., M) or (..., K): the bin axis is the last of ``lead``
        first = outs[0][name]
        idx = choice if first.shape[lead - 1] == m else fast_choice
        idx = idx.reshape(idx.shape + (1,) * (first.ndim - lead))
        out = outs[-1].pop(name).copy()
        for j, o in enumerate(outs[:-1]):
            np.copyto(out, o.pop(name), where=idx == j)
        return out

    out = {name: gather(name) for name in list(outs[0])}
    return _finish_choice(out, choice, fast_choice, bias2, widest_undetermined, windows,
                          twin=twin, nr=nr, degrees=degrees, widest_noise=widest_noise,
                          n_exp=n_exp)


def _finish_choice(out, choice, fast_choice, bias2, widest_undetermined, windows, *,
                   twin=None, nr=None, degrees=None, widest_noise=None, n_exp=None) -> dict:
    """The chosen candidate's outputs ``out`` (gathered bin by bin) with the model error
    ``bias2`` of :func:`lcmr_xr.kernels.adaptive.select_windows` added to ``P_var``,
    ``P_bias`` and ``window``.

    ``twin`` (..., K, ny, nu), where :func:`checks_denominator_bias`: the noise-inflated
    upper term for the squared bias of the widest window's least-squares denominator
    (:func:`lcmr_xr.kernels.adaptive.denominator_bias`).  It is added to ``bias2`` at every
    bin, whatever window is chosen: least squares is biased at every window, the bias grows
    with the window (0.00 / 0.05 / 0.18-0.21 of ``G_var`` at windows 12 / 19 / 30,
    docs/uncertainty.md), so the widest window's term bounds a narrower one's.  The band's
    factor for the nonlinearity of ``S^-1`` is then the second-order one
    (:func:`lcmr_xr.kernels.adaptive.second_order_factor`) instead of the bound form that
    was covering that bias.  (Window-19 bins above 500 Hz, VCM/PZT per band, cases 1-9 x 4
    seeds: 0.84-0.94 covered with the term only where the widest window is chosen,
    0.86-1.00 with the bound form kept there, 0.94-0.98 with it everywhere;
    docs/uncertainty.md.)  The window choice itself is made as before (same ``P``).

    ``widest_noise``: the widest candidate's residual noise variances (..., M, nz) and
    ``rho`` (``s_weak_rel_std``, (..., M)); None where the covariance comes from a known
    noise covariance.  Where the widest window's residual variance of the rows of ``S``
    exceeds the chosen window's beyond noise, only a share of it can be noise
    (:func:`lcmr_xr.kernels.adaptive.noise_share`), the rest is its model error, and its
    weak-direction test is taken with ``rho`` scaled to that share: its flag is carried
    over only where the noise alone leaves the weak direction undetermined (noiseless
    HDD, N = 3600: the widest window flagged 28-84 Hz from its model error, where the
    chosen window 12's estimate is covered by its own band).  A bin where more than half
    of the slow bins within :data:`lcmr_xr.kernels.adaptive.BIAS_SMOOTHING` (on their
    circle) fail the widest window's test (so taken) is undetermined too
    (:func:`lcmr_xr.kernels.adaptive.crowd_undetermined`: where the weak direction is
    drowned in noise its estimated ratio saturates near 1 and scatters, and a draw under
    the limit released bins 99.5 % off with bands 40-150 times too narrow, HDD below
    500 Hz)."""
    b2 = np.take_along_axis(
        bias2, fast_choice.reshape((1,) + fast_choice.shape + (1, 1)), axis=0)[0]
    if twin is not None:
        b2 = b2 + twin
        m = choice.shape[-1]
        k = np.arange(fast_choice.shape[-1])
        rho = np.take(out["s_weak_rel_std"], k % m, axis=-1)
        dof = window_dof(np.asarray(windows)[fast_choice], nr, degrees)
        factor = small_sample_factor(dof) * second_order_factor(rho)[0]
        with np.errstate(invalid="ignore", over="ignore"):
            out["P_var"] = out["P_var_linear"] * (factor ** 2)[..., None, None]
    # The widest candidate has the most data: where even it cannot determine the weakest
    # direction of S, a narrower window that seems to is a lucky draw (choosing among noisy
    # determinacy tests), so the bin stays undetermined; unless the widest window's residual
    # variance is mostly its model error and the noise alone passes its test (above).
    m = choice.shape[-1]
    if widest_noise is not None and nr is not None and widest_noise[0].shape[-1] > nr:
        dof = lambda w: window_dof(w, nr, degrees, n_exp or 1)  # noqa: E731
        variance, rho = widest_noise
        share = noise_share(variance[..., :nr].sum(-1), out["noise_variance"][..., :nr].sum(-1),
                            dof(windows[-1]), dof(np.asarray(windows)[choice]))
        noisy = ~(K95 * rho * np.sqrt(share) <= UNDETERMINED_LIMIT)  # its test, noise only
        widest_undetermined = widest_undetermined & np.take(
            noisy, np.arange(fast_choice.shape[-1]) % m, axis=-1)
    # and where most of its neighbourhood fails that test (a saturated ratio's lucky draw)
    k = np.arange(fast_choice.shape[-1])
    slow = np.zeros(widest_undetermined.shape[:-1] + (m,), dtype=bool)
    slow[..., k % m] = widest_undetermined  # (a fast bin carries its slow bin's flag)
    if k.size < m:  # F = 1: the fast bins reach slow bin M/2; past it, the mirrors M - t
        past = np.arange(k.size, m)
        slow[..., past] = slow[..., m - past]
    undetermined = out["P_undetermined"] | widest_undetermined | np.take(
        crowd_undetermined(slow, circular=True), k % m, axis=-1)
    out["P_undetermined"] = undetermined
    out["P_var"] = np.where(undetermined[..., None, None], np.inf, out["P_var"] + b2)
    out["P_bias"] = np.sqrt(b2)
    out["window"] = windows[choice]
    return out


def identify_window0_arrays(r, u, y, *, factor: int, closed_loop: str = "indirect",
                            covariance: bool = True) -> dict:
    """Fast FRF from pooled periodic experiments, ``G(k) = Z(k) R(k)^+`` at every slow bin.

    No local model and no transient term: the data must be steady-state periodic (drop
    the transient periods first).  The periods of each experiment are averaged; the noise
    covariance of each experiment's average comes from the spread over its periods
    (:func:`lcmr_xr.kernels.pooling.mean_and_covariance`), or, with one period, from the
    residuals over the experiments.

    Parameters
    ----------
    r, u : ndarray, shape (..., E, P, N, nu)
        ``E`` experiments of ``P`` steady-state periods; ``r`` must repeat over periods.
    y : ndarray, shape (..., E, P, M, ny)
        Slow outputs.
    factor : int
        ``F``.
    closed_loop : {"indirect", "direct"}, default "indirect"
        As :func:`identify_arrays`.
    covariance : bool, default True
        Propagate the noise covariance to ``P``.

    Returns
    -------
    dict of ndarray
        As :func:`identify_arrays`; ``T`` is 0 (no transient term) and ``noise_variance``
        the noise variance used (mean over experiments).
    """
    R, Z = experiment_spectra(r, u, y, factor=factor, closed_loop=closed_loop)  # (..., E, P, M, c)
    n_periods = R.shape[-3]
    R = R.mean(axis=-3)  # identical periods: the mean is R itself (to rounding)
    Z, C = mean_and_covariance(Z, 1)
    fit = pooled_least_squares(R, Z, C if n_periods > 1 else None, covariance=covariance)
    nz, nr = fit.G.shape[-2:]
    out = recover_frf(fit.G, fit.G_cov, n_fast=np.shape(r)[-2], factor=factor,
                      nu=np.shape(r)[-1], ny=np.shape(y)[-1], closed_loop=closed_loop,
                      ill_posed=fit.ill_posed)
    # s_singular means "S estimated but not invertible": where the experiments do not
    # determine G at all, ill_posed says so (and P_bad carries both)
    out["s_singular"] = out["s_singular"] & ~fit.ill_posed
    rows = np.arange(nz)
    if covariance:
        G_var = np.real(np.diagonal(fit.G_cov, axis1=-2, axis2=-1)).reshape(fit.G.shape)
    else:
        G_var = np.full(fit.G.shape, np.nan)
    out.update({"G": fit.G, "G_var": G_var, "T": np.zeros(fit.G.shape[:-1], complex),
                "noise_variance": np.real(fit.noise_covariance[..., rows, rows]),
                "condition": fit.condition, "ill_posed": fit.ill_posed})
    return out


def identify_single_rate_arrays(r, u, y, *, factor: int, half_width: int,
                                degrees=(3, 3, 3), covariance: bool = True) -> dict:
    """Single-rate indirect estimate that ignores the multirate structure (for comparison).

    ``r`` and ``u`` are downsampled to the slow rate (``x(l F)``) and the ordinary
    closed-loop local model ``[S; PS] = LRM(R_l -> [U_l; Y_l])``, ``P = PS S^-1`` is
    formed.  It reaches only the slow Nyquist frequency, and the fast dynamics alias
    onto it: this is what the lifted method avoids.  It is the lifted estimate with
    ``F = 1`` on the slow samples: ``identify_arrays(r[..., ::F, :], u[..., ::F, :], y,
    factor=1)``.

    Returns
    -------
    dict of ndarray
        As :func:`identify_arrays` with ``F = 1``: ``P`` (..., M//2+1, ny, nu) at slow bins
        ``m = 0..M/2``, ``P_var``, ``P_bad``, and the local-model arrays on the slow bins.
    """
    f_ = int(factor)
    return identify_arrays(np.asarray(r)[..., ::f_, :], np.asarray(u)[..., ::f_, :], y,
                           factor=1, half_width=half_width, degrees=degrees,
                           closed_loop="indirect", covariance=covariance)
