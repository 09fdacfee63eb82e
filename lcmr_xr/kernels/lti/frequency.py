"""Frequency response of a state-space system, from the resolvent (no polynomials)."""

from __future__ import annotations

import numpy as np

from lcmr_xr.kernels.lti.statespace import StateSpace


def frequency_response(sys: StateSpace, freqs_hz, *, chunk: int = 512) -> np.ndarray:
    """FRF ``C (zI - A)^-1 B + D`` at ``z = exp(2j pi f dt)``, from the state space.

    Parameters
    ----------
    sys : StateSpace
        The system.
    freqs_hz : array_like, shape (K,)
        Frequencies in Hz.
    chunk : int, optional
        Frequencies solved per batch (bounds memory to ``chunk n^2`` complex numbers);
        default 512.

    Returns
    -------
    ndarray of complex, shape (K, ny, nu)
        In output units per input unit.

    Notes
    -----
    One batched linear solve ``(zI - A) X = B`` per frequency; no polynomials, so high
    orders stay accurate.  At a frequency exactly on a pole (``zI - A`` singular, e.g. DC
    of an integrator) the response is infinite and returned as ``inf``.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import tf_q_inverse
    >>> g = tf_q_inverse([0.0, 1.0], [1.0], dt=1.0)   # one-sample delay
    >>> np.round(frequency_response(g, [0.25])[0, 0, 0], 12)
    np.complex128(-1j)
    """
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    z = np.exp(2j * np.pi * f * sys.dt)
    out = np.empty((f.size, sys.n_outputs, sys.n_inputs), dtype=complex)
    n = sys.n_states
    eye = np.eye(n)
    for start in range(0, f.size, chunk):
        zz = z[start:start + chunk]
        if n:
            out[start:start + chunk] = _resolvent_response(sys, zz, eye)
        else:
            out[start:start + chunk] = sys.D
    return out


def _resolvent_response(sys: StateSpace, zz: np.ndarray, eye: np.ndarray) -> np.ndarray:
    m = zz[:, None, None] * eye - sys.A
    rhs = np.broadcast_to(sys.B, (zz.size,) + sys.B.shape)
    try:
        return sys.C @ np.linalg.solve(m, rhs) + sys.D
    except np.linalg.LinAlgError:
        # A frequency sits exactly on a pole (e.g. DC of an integrator): solve one by one and
        # return an infinite response there instead of failing the whole batch.
        out = np.empty((zz.size, sys.n_outputs, sys.n_inputs), dtype=complex)
        for i in range(zz.size):
            try:
                out[i] = sys.C @ np.linalg.solve(m[i], sys.B) + sys.D
            except np.linalg.LinAlgError:
                out[i] = np.inf
        return out


def dc_gain(sys: StateSpace) -> np.ndarray:
    """Static gain ``C (I - A)^-1 B + D`` (``z = 1``).

    Parameters
    ----------
    sys : StateSpace
        System without a pole at ``z = 1``.

    Returns
    -------
    ndarray, shape (ny, nu)
        In output units per input unit.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import tf_q_inverse
    >>> float(dc_gain(tf_q_inverse([1.0], [1.0, -0.5], dt=1.0))[0, 0])
    2.0
    """
    if sys.n_states == 0:
        return sys.D.copy()
    return sys.C @ np.linalg.solve(np.eye(sys.n_states) - sys.A, sys.B) + sys.D
