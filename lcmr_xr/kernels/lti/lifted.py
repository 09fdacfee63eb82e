"""Lifting of a state-space system by a factor ``F``.

The lifted channels are ordered phase-major as in :mod:`lcmr_xr.kernels.lifting`: lifted
channel ``j c + ch`` is channel ``ch`` at phase ``j``, so for ``(N, c)`` arrays lifting is
the plain reshape to ``(N/F, F c)``.
"""

from __future__ import annotations

import numpy as np

from lcmr_xr.kernels.lti.statespace import StateSpace


def lift_statespace(sys: StateSpace, factor: int) -> StateSpace:
    """Lifted system at period ``factor dt``.

    With ``u_bar(l) = [u(lF); u(lF+1); ...; u(lF+F-1)]`` (lifted channel
    ``phase n_inputs + channel``, as :mod:`lcmr_xr.kernels.lifting`), and likewise ``y_bar``:

    ``A^F``, ``[A^{F-1} B, ..., A B, B]``, ``[C; C A; ...; C A^{F-1}]`` and the block
    lower-triangular Toeplitz ``D_bar[i, j] = C A^{i-j-1} B`` (``i > j``), ``D`` on the diagonal.

    Parameters
    ----------
    sys : StateSpace
        Fast system.
    factor : int
        Lifting factor ``F >= 1``.

    Returns
    -------
    StateSpace
        ``n`` states, ``F nu`` inputs, ``F ny`` outputs, ``dt = F sys.dt``; the state is
        ``x(lF)``.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import tf_q_inverse
    >>> g = lift_statespace(tf_q_inverse([0.0, 1.0], [1.0], dt=1.0), 2)
    >>> g.D.tolist()   # y(2l+1) = u(2l)
    [[0.0, 0.0], [1.0, 0.0]]
    """
    F = int(factor)
    if F < 1:
        raise ValueError(f"factor must be a positive integer, got {factor}.")
    n, nu, ny = sys.n_states, sys.n_inputs, sys.n_outputs
    powers = [np.eye(n)]
    for _ in range(F):
        powers.append(powers[-1] @ sys.A)
    obs = np.vstack([sys.C @ powers[i] for i in range(F)]) if n else np.zeros((F * ny, 0))
    ctrb = np.hstack([powers[F - 1 - j] @ sys.B for j in range(F)])
    # Markov parameters h[0] = D, h[k] = C A^{k-1} B
    markov = [sys.D] + [sys.C @ powers[k - 1] @ sys.B for k in range(1, F)]
    D = np.zeros((F * ny, F * nu))
    for i in range(F):
        for j in range(i + 1):
            D[i * ny:(i + 1) * ny, j * nu:(j + 1) * nu] = markov[i - j]
    return StateSpace(powers[F], ctrb, obs, D, F * sys.dt)
