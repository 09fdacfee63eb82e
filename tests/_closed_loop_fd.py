"""Exact multirate closed loops in the lifted frequency domain (test support).

Builds periodic steady-state experiments from the *lifted FRFs* of known blocks, an
independent route from the time-domain simulators: if identification inverts it exactly,
the lifting, the DFT convention and the indirect step agree with each other.

Loop (per the paper's figure): ``e = -y_l``, ``c = C e`` (slow), ``v = F_i ZOH(c)`` (fast),
``u = r + v`` (measured), ``y = P u``, ``y_l(l) = y(l F)``.
"""

from __future__ import annotations

import numpy as np
from scipy import signal

from lcmr_xr.kernels.lifting import lift, lifted_frf, unlift


def tf_frf(b, a, n_bins: int) -> np.ndarray:
    """FRF of ``b(q^-1)/a(q^-1)`` at ``w_k = 2 pi k / n_bins``, ``k = 0..n_bins-1``."""
    w = 2 * np.pi * np.arange(n_bins) / n_bins
    return signal.freqz(b, a, worN=w)[1]


def matrix_frf(entries, n_bins: int) -> np.ndarray:
    """``(n_bins, rows, cols)`` FRF from a nested list of ``(b, a)`` pairs (``None``: zero)."""
    rows, cols = len(entries), len(entries[0])
    out = np.zeros((n_bins, rows, cols), complex)
    for i in range(rows):
        for j in range(cols):
            if entries[i][j] is not None:
                out[:, i, j] = tf_frf(*entries[i][j], n_bins)
    return out


def lifted_loop(P, C, Fi, factor):
    """Lifted ``S`` (M, F nu, F nu) and ``PS_1`` (M, ny, F nu) of the loop.

    ``P`` (N, ny, nu) and ``Fi`` (N, nu, nu) on all fast bins; ``C`` (M, nu, ny) on slow bins.
    """
    _, ny, nu = P.shape
    Pbar = lifted_frf(P, factor)
    Fbar = lifted_frf(Fi, factor)
    hold = np.kron(np.ones((factor, 1)), np.eye(nu))  # ZOH upsampler, lifted
    first = np.zeros((ny, factor * ny))
    first[:, :ny] = np.eye(ny)
    K = Fbar @ hold @ C  # (M, F nu, ny)
    S = np.linalg.inv(np.eye(factor * nu) + K @ first @ Pbar)
    PS1 = first @ Pbar @ S
    return S, PS1, Pbar


def periodic_experiment(P, C, Fi, factor, r, periods: int = 1):
    """Periodic steady-state ``u`` (N, nu) and ``y_l`` (M, ny) for excitation ``r`` (N, nu).

    With ``periods > 1`` the excitation and responses are repeated (exactly periodic).
    """
    S, PS1, _ = lifted_loop(P, C, Fi, factor)
    n, nu = r.shape
    R = np.fft.fft(lift(r.T, factor), axis=-2)  # (nu, M, F)
    R = np.moveaxis(R, 0, -1).reshape(n // factor, factor * nu)  # phase-major
    U = np.einsum("mij,mj->mi", S, R)
    Y = np.einsum("mij,mj->mi", PS1, R)
    u_lift = np.real(np.fft.ifft(U, axis=0)).reshape(n // factor, factor, nu)
    u = unlift(np.moveaxis(u_lift, -1, 0)).T  # (N, nu)
    y = np.real(np.fft.ifft(Y, axis=0))
    return np.tile(u, (periods, 1)), np.tile(y, (periods, 1))
