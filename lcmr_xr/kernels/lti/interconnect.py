"""Interconnections of state-space systems: cascade, side by side, summed, split.

``hstack`` and ``vstack`` are :func:`block_diagonal` in series with a static summer or
splitter (a state-free system), so every interconnection goes through :func:`series`.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from lcmr_xr.kernels.lti.statespace import StateSpace, same_period, static_gain


def _same_dt(systems: Sequence[StateSpace]) -> float:
    dt = systems[0].dt
    for s in systems[1:]:
        if not same_period(s.dt, dt):
            raise ValueError(
                f"cannot interconnect systems with sampling periods {dt} s and {s.dt} s; "
                "discretise every part at the same period (or lift the faster one)."
            )
    return dt


def series(*systems: StateSpace) -> StateSpace:
    """Cascade in signal-flow order: ``series(G1, G2)`` is ``u -> G1 -> G2 -> y`` (``G2 G1``).

    Parameters
    ----------
    *systems : StateSpace
        At least one; outputs of each must match inputs of the next.

    Returns
    -------
    StateSpace
        States ordered ``[x1, x2, ...]``.

    Examples
    --------
    >>> g = series(static_gain(2.0, 1.0), static_gain(3.0, 1.0))
    >>> float(g.D[0, 0])
    6.0
    """
    if not systems:
        raise ValueError("series needs at least one system.")
    dt = _same_dt(systems)
    out = systems[0]
    for g in systems[1:]:
        if g.n_inputs != out.n_outputs:
            raise ValueError(
                f"series: a system with {out.n_outputs} outputs cannot feed one with "
                f"{g.n_inputs} inputs; check the order (signal flow, first system first)."
            )
        n1, n2 = out.n_states, g.n_states
        A = np.block([[out.A, np.zeros((n1, n2))], [g.B @ out.C, g.A]])
        B = np.vstack([out.B, g.B @ out.D])
        C = np.hstack([g.D @ out.C, g.C])
        out = StateSpace(A, B, C, g.D @ out.D, dt)
    return out


def block_diagonal(*systems: StateSpace) -> StateSpace:
    """Systems side by side: inputs and outputs stacked, no coupling.

    Parameters
    ----------
    *systems : StateSpace
        At least one, all with the same ``dt``.

    Returns
    -------
    StateSpace

    Examples
    --------
    >>> block_diagonal(static_gain(1.0, 1.0), static_gain(2.0, 1.0)).D.tolist()
    [[1.0, 0.0], [0.0, 2.0]]
    """
    if not systems:
        raise ValueError("block_diagonal needs at least one system.")
    dt = _same_dt(systems)
    from scipy.linalg import block_diag as bd  # lazy: scipy.linalg takes ~0.3 s to import
    return StateSpace(bd(*[s.A for s in systems]), bd(*[s.B for s in systems]),
                      bd(*[s.C for s in systems]), bd(*[s.D for s in systems]), dt)


def _shared_width(systems: Sequence[StateSpace], attribute: str, name: str) -> int:
    """The common ``n_outputs`` / ``n_inputs`` of ``systems``, or a ValueError naming ``name``."""
    width = getattr(systems[0], attribute)
    if any(getattr(s, attribute) != width for s in systems):
        side = attribute.removeprefix("n_")
        raise ValueError(f"{name}: every system must have the same number of {side}.")
    return width


def hstack(*systems: StateSpace) -> StateSpace:
    """``y = G1 u1 + G2 u2 + ...``: inputs concatenated, outputs summed (e.g. ``[Pv, Pp]``).

    Parameters
    ----------
    *systems : StateSpace
        At least one, all with the same number of outputs and the same ``dt``.

    Returns
    -------
    StateSpace
        States stacked in argument order.

    Examples
    --------
    >>> hstack(static_gain(1.0, 1.0), static_gain(2.0, 1.0)).D.tolist()
    [[1.0, 2.0]]
    """
    g = block_diagonal(*systems)  # refuses an empty list or mixed periods first
    ny = _shared_width(systems, "n_outputs", "hstack")
    summer = np.hstack([np.eye(ny)] * len(systems))
    return series(g, static_gain(summer, g.dt))


def vstack(*systems: StateSpace) -> StateSpace:
    """``[y1; y2; ...] = [G1; G2; ...] u``: one shared input, outputs concatenated.

    Parameters
    ----------
    *systems : StateSpace
        At least one, all with the same number of inputs and the same ``dt``.

    Returns
    -------
    StateSpace
        States stacked in argument order.

    Examples
    --------
    >>> vstack(static_gain(1.0, 1.0), static_gain(2.0, 1.0)).D.tolist()
    [[1.0], [2.0]]
    """
    g = block_diagonal(*systems)  # refuses an empty list or mixed periods first
    nu = _shared_width(systems, "n_inputs", "vstack")
    splitter = np.vstack([np.eye(nu)] * len(systems))
    return series(static_gain(splitter, g.dt), g)
