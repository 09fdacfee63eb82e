"""Response of a discrete LTI system to an input, without a per-sample Python loop.

Time is cut into blocks of ``L`` samples and the ``L``-lifted system is used: outputs of
all blocks at once are one batched matmul with the block-Toeplitz impulse-response matrix
plus the observability matrix times the block-start states, and only the block-start
states follow a Python loop over ``N/L`` blocks.
"""

from __future__ import annotations

import functools

import numpy as np

from lcmr_xr.kernels.lti.lifted import lift_statespace
from lcmr_xr.kernels.lti.statespace import StateSpace


def _default_block_length(sys: StateSpace) -> int:
    # Cost per sample: Toeplitz part ~ L nu ny, state part ~ n (nu + ny), plus a Python
    # step per block.  L ~ 2 n / sqrt(nu ny) balances the first two; clipped so tiny
    # systems still amortise the Python loop and big ones keep the Toeplitz matrix small.
    n = max(sys.n_states, 1)
    width = np.sqrt(max(sys.n_inputs * sys.n_outputs, 1))
    return int(np.clip(2 * n / width, 16, 256))


@functools.lru_cache(maxsize=16)
def _lifted_for_blocks(sys: StateSpace, block_length: int) -> StateSpace:
    """:func:`lift_statespace` memoised per system object (hashed by identity: systems are
    immutable), so Monte-Carlo runs on one loop pay for the block matrices once."""
    return lift_statespace(sys, block_length)


def simulate_lti(sys: StateSpace, u, x0=None, *, block_length: int | None = None) -> np.ndarray:
    """Response of a discrete LTI system to an input signal, without a per-sample Python loop.

    Parameters
    ----------
    sys : StateSpace
        The system (stable or not; growth is the caller's business).
    u : array_like, shape (..., N, nu)
        Input, time on axis -2; leading axes are independent experiments.
    x0 : array_like, shape (..., n), optional
        Initial state (broadcast over the leading axes of ``u``); default zero.
    block_length : int, optional
        Samples per block ``L``; default balances matmul and loop costs for ``sys``.

    Returns
    -------
    ndarray, shape (..., N, ny)
        Output, in output units.

    Notes
    -----
    With the ``L``-lifted system ``(A^L, Bbar, Obs, T)``: ``x_{b+1} = A^L x_b + Bbar u_b``
    over blocks ``b`` (a Python loop over ``N/L`` blocks, one small matmul each), then
    ``y_b = Obs x_b + T u_b`` for all blocks at once.  The input is zero-padded to a whole
    number of blocks; causality makes the padding harmless.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import tf_q_inverse
    >>> g = tf_q_inverse([1.0], [1.0, -0.5], dt=1.0)
    >>> simulate_lti(g, np.ones((4, 1)))[:, 0].tolist()
    [1.0, 1.5, 1.75, 1.875]
    """
    u = np.asarray(u, dtype=float)
    if u.ndim < 2 or u.shape[-1] != sys.n_inputs:
        raise ValueError(
            f"u must have shape (..., N, {sys.n_inputs}) (time, then the {sys.n_inputs} inputs "
            f"of the system), got {u.shape}."
        )
    lead, N = u.shape[:-2], u.shape[-2]
    n, nu, ny = sys.n_states, sys.n_inputs, sys.n_outputs
    L = int(block_length) if block_length is not None else _default_block_length(sys)
    if L < 1:
        raise ValueError(f"block_length must be a positive integer, got {block_length}.")
    L = max(1, min(L, N))
    nb = -(-N // L)
    batch = int(np.prod(lead, dtype=int))
    ub = np.zeros((batch, nb * L, nu))
    ub[:, :N] = u.reshape(batch, N, nu)
    ub = ub.reshape(batch, nb, L * nu)  # lifted by L: channel = phase nu + input

    lifted = _lifted_for_blocks(sys, L)
    yb = ub @ lifted.D.T  # (batch, nb, L ny)
    x = np.zeros((batch, n)) if x0 is None else np.broadcast_to(
        np.asarray(x0, dtype=float), lead + (n,)).reshape(batch, n).copy()
    if n:
        drive = ub @ lifted.B.T  # (batch, nb, n): Bbar u_b for every block
        states = np.empty((batch, nb, n))
        a_t = lifted.A.T
        for b in range(nb):
            states[:, b] = x
            x = x @ a_t + drive[:, b]
        yb += states @ lifted.C.T
    return yb.reshape(batch, nb * L, ny)[:, :N].reshape(lead + (N, ny))
