"""Lifting and the lifted-frequency-domain identities, on plain numpy arrays.

No labels here: every function works on trailing axes and broadcasts over leading ones.

Conventions (verified by the tests against simulations of known systems):

* Lifting by a factor ``F`` cuts a fast signal ``x(n)``, ``n = 0..N-1``, into
  ``M = N/F`` blocks; element ``[l, j]`` of the lifted signal is ``x(l F + j)``.
  A vector signal with ``c`` channels becomes a slow signal with ``F c`` channels,
  ordered phase-major: lifted channel ``j c_count + c`` is channel ``c`` at phase ``j``.
* DFTs are plain sums, as :func:`numpy.fft.fft`:
  ``X(k) = sum_n x(n) exp(-2j pi k n / N)``.
* Fast bin ``k`` (frequency ``k / (N Th)``) aliases onto slow bin ``k mod M``; the
  ``F`` fast bins on slow bin ``m`` are ``k_f = m + f M``, ``f = 0..F-1``.

The identities (proofs in the docstrings, numeric checks in ``tests/``):

* spectrum of a fast signal from the spectra of its lifted phases::

      X(k) = sum_j exp(-2j pi k j / N) X_j(k mod M)

* lifted FRF of a fast LTI system with FRF ``P`` (block ``[i, j]`` maps input
  phase ``j`` to output phase ``i``)::

      Pbar_ij(m) = 1/F sum_f P(k_f) exp(+2j pi k_f (i - j) / N)

* recovery of ``P`` from the first block row ``P1_j = Pbar_0j``::

      P(k) = sum_j exp(+2j pi k j / N) P1_j(k mod M)
"""

from __future__ import annotations

import numpy as np


def whole_factor(factor) -> int:
    """``factor`` as an int if it is a whole positive number: int(2.5) would lift by 2."""
    try:
        whole = not isinstance(factor, (bool, np.bool_)) and int(factor) == factor and factor >= 1
    except (TypeError, ValueError, OverflowError):
        whole = False
    if not whole:
        raise ValueError(f"factor must be a positive integer, got {factor!r}.")
    return int(factor)


def _check_factor(n_samples: int, factor: int) -> int:
    factor = whole_factor(factor)
    if n_samples % factor:
        raise ValueError(
            f"{n_samples} samples cannot be lifted by factor {factor}: the number of fast "
            f"samples must be a multiple of the factor. Trim the signal to "
            f"{n_samples - n_samples % factor} samples (x[..., :{n_samples - n_samples % factor}])."
        )
    return n_samples // factor


def lift(x: np.ndarray, factor: int) -> np.ndarray:
    """Lift the last axis: ``(..., N) -> (..., M, F)`` with ``out[..., l, j] = x[..., l F + j]``.

    Returns a view when possible (a reshape); the caller must copy before writing.
    """
    x = np.asarray(x)
    n = x.shape[-1]
    m = _check_factor(n, factor)
    return x.reshape(x.shape[:-1] + (m, int(factor)))


def unlift(x: np.ndarray) -> np.ndarray:
    """Inverse of :func:`lift`: ``(..., M, F) -> (..., M F)``."""
    x = np.asarray(x)
    return x.reshape(x.shape[:-2] + (x.shape[-2] * x.shape[-1],))


def phase_factors(n_fast: int, factor: int, sign: int = -1) -> np.ndarray:
    """``exp(sign 2j pi k j / N)`` for fast bins ``k = 0..N-1`` and phases ``j``; shape ``(N, F)``.

    Computed from ``(k j) mod N`` so the phases are exact for large ``N``.
    """
    k = np.arange(n_fast)[:, None]
    j = np.arange(int(factor))[None, :]
    return np.exp(sign * 2j * np.pi * ((k * j) % n_fast) / n_fast)


def fast_spectrum_from_lifted(x_lifted_spectrum: np.ndarray) -> np.ndarray:
    """Fast-rate DFT from the slow DFTs of the lifted phases.

    Parameters
    ----------
    x_lifted_spectrum : ndarray, shape (..., M, F)
        ``X_j(m)``, the ``M``-point DFT (along ``l``) of phase ``j`` of the lifted signal.

    Returns
    -------
    ndarray, shape (..., N)
        ``X(k) = sum_j exp(-2j pi k j / N) X_j(k mod M)``, equal to ``numpy.fft.fft`` of
        the fast signal.

    Notes
    -----
    ``X(k) = sum_j sum_l x(lF+j) exp(-2j pi k (lF+j)/N)``
    ``= sum_j exp(-2j pi k j/N) sum_l x_j(l) exp(-2j pi k l / M)``, and the inner
    sum is periodic in ``k`` with period ``M``.
    """
    xs = np.asarray(x_lifted_spectrum)
    m, factor = xs.shape[-2:]
    n = m * factor
    tiled = np.take(xs, np.arange(n) % m, axis=-2)  # (..., N, F)
    return np.einsum("...kj,kj->...k", tiled, phase_factors(n, factor, -1))


def lifted_spectrum_from_fast(x_spectrum: np.ndarray, factor: int) -> np.ndarray:
    """Inverse of :func:`fast_spectrum_from_lifted`: ``(..., N) -> (..., M, F)``.

    ``X_j(m) = 1/F sum_f X(k_f) exp(+2j pi k_f j / N)`` with ``k_f = m + f M``.
    """
    xs = np.asarray(x_spectrum)
    n = xs.shape[-1]
    m = _check_factor(n, factor)
    w = phase_factors(n, factor, +1)  # (N, F)
    terms = xs[..., :, None] * w  # (..., N, F) over k
    return terms.reshape(xs.shape[:-1] + (int(factor), m, int(factor))).sum(axis=-3) / factor


def lifted_frf(frf: np.ndarray, factor: int) -> np.ndarray:
    """Exact lifted FRF of a fast LTI system from its FRF on all ``N`` fast bins.

    Parameters
    ----------
    frf : ndarray, shape (..., N, ny, nu)
        ``P(k)`` at fast bins ``k = 0..N-1`` (the full circle, not one-sided).
    factor : int
        Lifting factor ``F``; ``N`` must be a multiple of it.

    Returns
    -------
    ndarray, shape (..., M, F ny, F nu)
        ``Pbar(m)``; block ``[i, j]`` (rows ``i ny:(i+1) ny``, columns ``j nu:(j+1) nu``) is
        ``1/F sum_f P(k_f) exp(+2j pi k_f (i - j) / N)``, ``k_f = m + f M``.

    Notes
    -----
    Block ``[i, j]`` has impulse response ``p(l F + i - j)`` at the slow rate (``y(lF+i)``
    from ``u(l'F+j)``); summing the fast FRF over the ``F`` aliases with the phase
    ``exp(+j w (i-j) Th)`` keeps exactly the samples ``n = i - j (mod F)``.  This is the
    paper's eq. (LiftedP) with ``xi = exp(-j w Th)``.
    """
    p = np.asarray(frf)
    n, ny, nu = p.shape[-3:]
    m = _check_factor(n, factor)
    f_ = int(factor)
    k = np.arange(n).reshape(f_, m)  # k_f = m + f M, indexed [f, m]
    i = np.arange(f_)
    shift = (i[:, None] - i[None, :])  # (F, F) = i - j
    # phase[f, m, i, j] = exp(2j pi k_f (i - j) / N), exact through the modulo
    phase = np.exp(2j * np.pi * ((k[:, :, None, None] * shift) % n) / n)
    pk = p.reshape(p.shape[:-3] + (f_, m, ny, nu))
    # out[..., m, i, a, j, b] = 1/F sum_f phase[f, m, i, j] P[..., f, m, a, b]
    out = np.einsum("fmij,...fmab->...miajb", phase, pk) / f_
    return out.reshape(p.shape[:-3] + (m, f_ * ny, f_ * nu))


def frf_from_first_block_row(first_row: np.ndarray, factor: int) -> np.ndarray:
    """Fast FRF on all ``N`` fast bins from the first block row of the lifted FRF.

    Parameters
    ----------
    first_row : ndarray, shape (..., M, ny, F nu)
        ``P1(m) = [P1_0(m), ..., P1_{F-1}(m)]``, the first block row of ``Pbar``.
    factor : int
        Lifting factor ``F``.

    Returns
    -------
    ndarray, shape (..., N, ny, nu)
        ``P(k) = sum_j exp(+2j pi k j / N) P1_j(k mod M)``, ``N = M F``.

    Notes
    -----
    With ``P1_j(m) = 1/F sum_f P(k_f) exp(-2j pi k_f j / N)`` (block ``[0, j]`` of
    :func:`lifted_frf`), ``sum_j exp(2j pi k j/N) P1_j`` keeps only ``f`` with ``k_f = k``.
    This is the paper's eq. (RecoverP) written with the sign convention of ``numpy.fft``.
    """
    p1 = np.asarray(first_row)
    m, ny, fnu = p1.shape[-3:]
    f_ = whole_factor(factor)
    if fnu % f_:
        raise ValueError(
            f"the first block row has {fnu} columns, which is not a multiple of factor {f_}."
        )
    nu = fnu // f_
    n = m * f_
    blocks = p1.reshape(p1.shape[:-1] + (f_, nu))  # (..., M, ny, F, nu)
    tiled = np.take(blocks, np.arange(n) % m, axis=-4)  # (..., N, ny, F, nu)
    return np.einsum("...kajb,kj->...kab", tiled, phase_factors(n, f_, +1))


def first_block_row_weights(n_fast: int, factor: int, bins: np.ndarray) -> np.ndarray:
    """Weights ``w[k, j] = exp(+2j pi k j / N)`` of :func:`frf_from_first_block_row` at ``bins``.

    Used to propagate covariances, since ``P(k)`` is linear in ``P1(k mod M)``.
    """
    bins = np.asarray(bins)
    j = np.arange(int(factor))
    return np.exp(2j * np.pi * ((bins[:, None] * j[None, :]) % n_fast) / n_fast)
