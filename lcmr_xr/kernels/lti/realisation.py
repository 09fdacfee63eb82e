"""State-space realisations of the models the field writes down.

Continuous-time systems under a zero-order hold (general, or as a sum of second-order
modes), transfer functions in ``q^-1``, and matched pole-zero notch filters; every
result is a discrete :class:`~lcmr_xr.kernels.lti.statespace.StateSpace`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from lcmr_xr.kernels.lti.interconnect import series
from lcmr_xr.kernels.lti.statespace import StateSpace, static_gain


def continuous_zoh(A, B, C, D, dt: float) -> StateSpace:
    """Zero-order-hold discretisation of a continuous-time state-space system.

    Parameters
    ----------
    A, B, C, D : array_like
        Continuous-time matrices (``dx/dt = A x + B u``, ``y = C x + D u``).
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        ``Ad = exp(A dt)``, ``Bd = int_0^dt exp(A s) ds B``, same ``C`` and ``D``.

    Notes
    -----
    :func:`scipy.signal.cont2discrete` with ``method="zoh"``: one matrix exponential of
    ``[[A, B], [0, 0]] dt``.  Keep the system well scaled (modal blocks rather than a
    companion form): the exponential of a high-order companion matrix loses all accuracy.

    Examples
    --------
    >>> g = continuous_zoh([[-1.0]], [[1.0]], [[1.0]], [[0.0]], dt=0.5)
    >>> bool(np.isclose(g.A[0, 0], np.exp(-0.5)))
    True
    """
    a = np.atleast_2d(np.asarray(A, dtype=float))
    b = np.atleast_2d(np.asarray(B, dtype=float))
    # imported here: scipy.signal (and the scipy.stats it pulls in) takes about a second
    # to import, most of `import lcmr_xr`, and only building continuous models needs it
    import scipy.signal

    ad, bd, _, _, _ = scipy.signal.cont2discrete((a, b, C, D), dt, method="zoh")
    return StateSpace(ad, bd, C, D, dt)


def modal_zoh(gains, freqs_hz, dampings, dt: float) -> StateSpace:
    """ZOH discretisation of ``sum_i k_i / (s^2 + 2 z_i w_i s + w_i^2)``, ``w_i = 2 pi f_i``.

    Each mode is discretised on its own 2x2 block and the blocks are stacked
    block-diagonally.  A transfer function of the sum would be of high order with
    coefficients spanning hundreds of decades (``w^2 ~ 1e11`` per mode) and overflows or
    loses all precision; the modal blocks are each well conditioned.

    Parameters
    ----------
    gains : array_like, shape (K,)
        Modal gains ``k_i`` (output units per input unit times s^-2).
    freqs_hz : array_like, shape (K,)
        Natural frequencies ``f_i`` in Hz (``0`` with damping ``0`` is a rigid-body mode
        ``k/s^2``).
    dampings : array_like, shape (K,)
        Relative dampings ``z_i`` (1).
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        SISO, ``2 K`` states (``w_i q_i`` and ``dq_i/dt`` of each mode ``q_i``; plain
        position for a rigid-body mode), ``D = 0``.

    Examples
    --------
    >>> g = modal_zoh([1.0], [0.0], [0.0], dt=1.0)   # double integrator 1/s^2
    >>> g.B.ravel().tolist()
    [0.5, 1.0]
    """
    k = np.atleast_1d(np.asarray(gains, dtype=float))
    f = np.atleast_1d(np.asarray(freqs_hz, dtype=float))
    z = np.atleast_1d(np.asarray(dampings, dtype=float))
    if not (k.shape == f.shape == z.shape) or k.ndim != 1:
        raise ValueError(
            f"gains, freqs_hz and dampings must be 1-d and of equal length, got shapes "
            f"{k.shape}, {f.shape}, {z.shape}."
        )
    blocks_a, blocks_b, c = [], [], []
    for ki, fi, zi in zip(k, f, z):
        w = 2 * np.pi * fi
        # States (w q, dq/dt) instead of (q, dq/dt): every entry of A is then of order w, so
        # the exponential is cheap and accurate and the discrete blocks are well scaled.
        scale = w if w > 0 else 1.0
        mode = continuous_zoh([[0.0, scale], [-w * w / scale, -2 * zi * w]], [[0.0], [1.0]],
                              [[ki / scale, 0.0]], [[0.0]], dt)
        blocks_a.append(mode.A)
        blocks_b.append(mode.B)
        c.append(mode.C)
    from scipy.linalg import block_diag  # lazy: scipy.linalg takes ~0.3 s to import

    return StateSpace(block_diag(*blocks_a), np.vstack(blocks_b), np.hstack(c),
                      [[0.0]], dt)


def tf_q_inverse(num, den, dt: float) -> StateSpace:
    """SISO system from a transfer function in powers of ``q^-1``.

    ``(b0 + b1 q^-1 + ... ) / (a0 + a1 q^-1 + ...)``, realised in observable canonical form.

    Parameters
    ----------
    num, den : array_like
        Coefficients ``[b0, b1, ...]`` and ``[a0, a1, ...]``; ``a0 != 0``.  The shorter one is
        padded with zeros.
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import dc_gain
    >>> g = tf_q_inverse([0.0, 1.0], [1.0, -0.5], dt=1.0)   # q^-1 / (1 - 0.5 q^-1)
    >>> float(dc_gain(g)[0, 0])
    2.0
    """
    b = np.atleast_1d(np.asarray(num, dtype=float))
    a = np.atleast_1d(np.asarray(den, dtype=float))
    if a[0] == 0:
        raise ValueError(
            f"the leading denominator coefficient a0 must be nonzero (causal system), got {a}."
        )
    n = max(a.size, b.size)
    b = np.pad(b, (0, n - b.size)) / a[0]
    a = np.pad(a, (0, n - a.size)) / a[0]
    order = n - 1
    d0 = b[0]
    if order == 0:
        return static_gain(d0, dt)
    A = np.zeros((order, order))
    A[:, 0] = -a[1:]
    A[:-1, 1:] = np.eye(order - 1)
    B = (b[1:] - a[1:] * d0).reshape(order, 1)
    C = np.zeros((1, order))
    C[0, 0] = 1.0
    return StateSpace(A, B, C, [[d0]], dt)


def matched_notch(freq_hz: float, zeta_num: float, zeta_den: float, dt: float) -> StateSpace:
    """Matched pole-zero discretisation of ``(s^2 + 2 zn w s + w^2)/(s^2 + 2 zd w s + w^2)``.

    Zeros and poles are mapped by ``z = exp(s dt)``; the gain is chosen for unit DC gain.

    Parameters
    ----------
    freq_hz : float
        Notch frequency ``f = w / (2 pi)`` in Hz (below the Nyquist frequency ``1/(2 dt)``).
    zeta_num, zeta_den : float
        Relative dampings of the zeros and of the poles (1); ``zeta_num < zeta_den`` notches.
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        SISO, 2 states.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import dc_gain
    >>> g = matched_notch(1000.0, 0.01, 0.5, dt=1e-4)
    >>> round(float(dc_gain(g)[0, 0]), 12)
    1.0
    """
    if not 0 < freq_hz < 0.5 / dt:
        raise ValueError(
            f"notch frequency {freq_hz} Hz must lie between 0 and the Nyquist frequency "
            f"{0.5 / dt} Hz of dt={dt} s; drop the section or sample faster."
        )
    w = 2 * np.pi * freq_hz

    def mapped(zeta):
        # discrete polynomial [1, c1, c2] in z with roots exp(s_i dt) (real: roots conjugate)
        return np.real(np.poly(np.exp(np.roots([1.0, 2 * zeta * w, w * w]) * dt)))

    num, den = mapped(zeta_num), mapped(zeta_den)
    num = num * den.sum() / num.sum()  # unit gain at z = 1
    return tf_q_inverse(num, den, dt)  # z^-2 (num) / z^-2 (den) is the same ratio in q^-1


def notch_filter(sections: Sequence[tuple[float, float, float]], dt: float) -> StateSpace:
    """Cascade of :func:`matched_notch` sections ``(freq_hz, zeta_num, zeta_den)``.

    Parameters
    ----------
    sections : sequence of (float, float, float)
        Rows ``(f Hz, zn, zd)``.
    dt : float
        Sampling period in s.

    Returns
    -------
    StateSpace
        SISO, ``2 len(sections)`` states, unit DC gain.

    Examples
    --------
    >>> g = notch_filter([(1000.0, 0.01, 0.5), (2000.0, 0.01, 0.5)], dt=1e-4)
    >>> g.n_states
    4
    """
    systems = [matched_notch(f, zn, zd, dt) for f, zn, zd in sections]
    if not systems:
        return static_gain(1.0, dt)
    return series(*systems)
