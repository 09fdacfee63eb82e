"""The multirate closed loop as ONE slow-rate LTI system, and its fast simulation.

Fast plant, slow controller, zero-order hold and fast filter form a loop that is
periodically time-varying at the fast rate but LTI at the slow rate once lifted; it is
built here as one slow-rate state-space system and simulated with
:func:`~lcmr_xr.kernels.lti.simulate.simulate_lti`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from lcmr_xr.kernels.lifting import whole_factor
from lcmr_xr.kernels.lti.lifted import lift_statespace
from lcmr_xr.kernels.lti.simulate import simulate_lti
from lcmr_xr.kernels.lti.statespace import (StateSpace, check_stable, same_period,
                                            spectral_radius, static_gain)


@dataclass(frozen=True, eq=False)
class MultirateClosedLoop:
    """The multirate closed loop as one slow-rate LTI system (see :func:`multirate_closed_loop`).

    Parameters
    ----------
    system : StateSpace
        At the slow period ``Tl = F Th``.  Inputs, in this order: lifted ``r_h`` (``F nu``),
        lifted ``d_u`` (``F nu``), lifted ``d_y`` (``F ny``), ``reference`` (``ny``).
        Outputs: lifted ``u_h`` (``F nu``), ``y_l`` (``ny``), lifted ``y_h`` (``F ny``).
        States: ``[filter, plant]`` at ``x(lF)``, then the controller.
    factor : int
        ``F``.
    n_inputs, n_outputs : int
        ``nu`` and ``ny`` of the plant.
    spectral_radius : float
        Largest ``|eigenvalue|`` of ``system.A``.
    """

    system: StateSpace
    factor: int
    n_inputs: int
    n_outputs: int
    spectral_radius: float


class MultirateResponse(NamedTuple):
    """Signals of :func:`simulate_multirate`.

    Parameters
    ----------
    u : ndarray, shape (..., N, nu)
        Fast plant input as measured (before ``d_u`` is added).
    y_slow : ndarray, shape (..., M, ny)
        Slow measured output ``y_l(l) = y(lF)``.
    y : ndarray, shape (..., N, ny)
        Fast output (not measured; for stroke checks).
    """

    u: np.ndarray
    y_slow: np.ndarray
    y: np.ndarray


def _check_period(sys: StateSpace, name: str, expected: float, what: str):
    if not same_period(sys.dt, expected):
        raise ValueError(
            f"the {name} has sampling period {sys.dt} s but the loop needs {what} = {expected} s; "
            f"discretise the {name} at {expected} s."
        )


def multirate_closed_loop(plant: StateSpace, controller: StateSpace, filter: StateSpace | None,
                          factor: int, *, check_stability: bool = True) -> MultirateClosedLoop:
    """Build the multirate closed loop as ONE LTI system at the slow rate.

    Block diagram (fast period ``Th = plant.dt``, slow period ``Tl = F Th``)::

        e(l)   = reference(l) - y_l(l),        y_l(l) = y(lF)
        v(l)   = C e(l)                        slow controller
        v_h(n) = v(floor(n / F))               upsampler + zero-order hold
        u_h(n) = r_h(n) + (Fi v_h)(n)          fast filter; u_h is what is recorded
        y(n)   = P (u_h + d_u)(n) + d_y(n)     fast plant, input and output disturbances

    Parameters
    ----------
    plant : StateSpace
        ``P``, ``nu`` inputs, ``ny`` outputs, period ``Th``.
    controller : StateSpace
        ``C``, ``ny`` inputs (the error), ``nu`` outputs, period ``F Th``.
    filter : StateSpace or None
        ``Fi``, ``nu`` inputs and outputs, period ``Th``; ``None`` for the identity.
    factor : int
        ``F >= 1``.
    check_stability : bool, optional
        Refuse an unstable loop (default True).

    Returns
    -------
    MultirateClosedLoop
        The lifted closed loop; see its attributes for the input/output ordering.

    Raises
    ------
    ValueError
        On a factor that is not a positive whole number, mismatched sizes or periods, an
        ill-posed algebraic loop (``I + D_P D_Fi D_C`` singular at phase 0) or an unstable
        loop.
    TypeError
        If ``plant``, ``controller`` or ``filter`` (unless None) is not a StateSpace.

    Notes
    -----
    The fast part ``[v_h, r_h, d_u, d_y] -> [u_h, y]`` (filter then plant) is lifted by
    ``F``; the hold makes ``v_h`` equal ``v(l)`` at every phase, so its lifted input matrix is
    the sum over phases.  A direct feedthrough from ``v`` to ``y(lF)`` (plant with ``D != 0``)
    closes an algebraic loop at the slow rate, solved exactly:
    ``(I + D_yv D_C) y_l = ...``.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import static_gain, tf_q_inverse
    >>> P = tf_q_inverse([0.0, 0.5], [1.0, -0.9], dt=0.5)
    >>> C = static_gain(0.2, dt=1.0)
    >>> loop = multirate_closed_loop(P, C, None, 2)
    >>> loop.system.n_inputs, loop.system.n_outputs   # [r(2), d_u(2), d_y(2), ref(1)], [u(2), y_l, y(2)]
    (7, 5)
    """
    # 2.5 is refused, never truncated to 2 (a controller at 2 Th would then pass the check)
    F = whole_factor(factor)
    for name, sys in (("plant", plant), ("controller", controller), ("filter", filter)):
        if not isinstance(sys, StateSpace) and not (name == "filter" and sys is None):
            raise TypeError(f"the {name} must be a StateSpace (lcmr_xr.kernels.lti), got "
                            f"{type(sys).__name__}; build it with tf_q_inverse, modal_zoh or "
                            f"static_gain.")
    nu, ny = plant.n_inputs, plant.n_outputs
    th = plant.dt
    if filter is None:
        filter = static_gain(np.eye(nu), th)
    if (controller.n_inputs, controller.n_outputs) != (ny, nu):
        raise ValueError(
            f"the controller maps the error ({ny} plant outputs) to the {nu} plant inputs, so it "
            f"needs {ny} inputs and {nu} outputs; got {controller.n_inputs} inputs and "
            f"{controller.n_outputs} outputs."
        )
    if (filter.n_inputs, filter.n_outputs) != (nu, nu):
        raise ValueError(
            f"the filter sits between the controller and the {nu} plant inputs, so it needs {nu} "
            f"inputs and outputs; got {filter.n_inputs} and {filter.n_outputs}."
        )
    _check_period(filter, "filter", th, "the plant period Th")
    _check_period(controller, "controller", F * th, f"F Th (F={F})")

    # Fast part G: inputs [v_h, r, d_u, d_y], outputs [u_h, y], states [x_filter, x_plant].
    Af, Bf, Cf, Df = filter.A, filter.B, filter.C, filter.D
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    nf, npl = filter.n_states, plant.n_states
    z = np.zeros
    A_g = np.block([[Af, z((nf, npl))], [Bp @ Cf, Ap]])
    B_g = np.block([[Bf, z((nf, nu)), z((nf, nu)), z((nf, ny))],
                    [Bp @ Df, Bp, Bp, z((npl, ny))]])
    C_g = np.block([[Cf, z((nu, npl))], [Dp @ Cf, Cp]])
    D_g = np.block([[Df, np.eye(nu), z((nu, nu)), z((nu, ny))],
                    [Dp @ Df, Dp, Dp, np.eye(ny)]])
    g = lift_statespace(StateSpace(A_g, B_g, C_g, D_g, th), F)

    n_in, n_out = 2 * nu + nu + ny, nu + ny
    phase = np.arange(F)[:, None]
    cols_v = (phase * n_in + np.arange(nu)).ravel()
    cols_w = np.concatenate([(phase * n_in + off + np.arange(width)).ravel()
                             for off, width in ((nu, nu), (2 * nu, nu), (3 * nu, ny))])
    rows_u = (phase * n_out + np.arange(nu)).ravel()
    rows_y = (phase * n_out + nu + np.arange(ny)).ravel()
    rows_z = np.concatenate([rows_u, rows_y[:ny], rows_y])  # [u_bar, y_l, y_bar]
    # The hold repeats v(l) at every phase: sum the lifted columns over phases.
    B_v = g.B[:, cols_v].reshape(-1, F, nu).sum(axis=1)
    D_v = g.D[:, cols_v].reshape(-1, F, nu).sum(axis=1)
    B_w, D_w = g.B[:, cols_w], g.D[:, cols_w]
    nw = cols_w.size

    Ac, Bc, Cc, Dc = controller.A, controller.B, controller.C, controller.D
    ng, nc = g.n_states, controller.n_states
    # Everything below is a linear map of s = [x_g, x_c, w, ref].
    ns = ng + nc + nw + ny
    sel_xg, sel_xc = slice(0, ng), slice(ng, ng + nc)
    sel_w, sel_ref = slice(ng + nc, ng + nc + nw), slice(ng + nc + nw, ns)

    def embed(**parts):
        m = np.zeros((next(iter(parts.values())).shape[0], ns))
        for key, val in parts.items():
            m[:, {"xg": sel_xg, "xc": sel_xc, "w": sel_w, "ref": sel_ref}[key]] = val
        return m

    y0 = slice(nu, nu + ny)  # y at phase 0 = rows nu..nu+ny of the lifted output
    C_y, D_yv, D_yw = g.C[y0], D_v[y0], D_w[y0]
    loop_matrix = np.eye(ny) + D_yv @ Dc
    if np.linalg.cond(loop_matrix) > 1e12:
        raise ValueError(
            "the multirate loop has an ill-posed algebraic loop: I + D_P D_Fi D_C (direct "
            "feedthrough from controller output to y(lF)) is singular. Add a delay to the "
            "controller or the plant, or change the feedthrough gains."
        )
    y_l = np.linalg.solve(loop_matrix, embed(xg=C_y, xc=D_yv @ Cc, w=D_yw, ref=D_yv @ Dc))
    v = embed(xc=Cc, ref=Dc) - Dc @ y_l
    x_g_next = embed(xg=g.A, w=B_w) + B_v @ v
    x_c_next = embed(xc=Ac, ref=Bc) - Bc @ y_l
    out = (embed(xg=g.C, w=D_w) + D_v @ v)[rows_z]
    out[F * nu:F * nu + ny] = y_l  # identical to the phase-0 rows; keep the solved form
    state_rows = np.vstack([x_g_next, x_c_next])
    nx = ng + nc
    system = StateSpace(state_rows[:, :nx], state_rows[:, nx:], out[:, :nx], out[:, nx:], F * th)
    if check_stability:
        rho = check_stable(
            system, f"multirate closed loop (plant, controller, filter, F={F})",
            "Check the controller sign (e = reference - y_l, negative feedback), the loop "
            "gains, the filter, and that controller and plant are sampled at F Th and Th.")
    else:
        rho = spectral_radius(system.A)
    return MultirateClosedLoop(system, F, nu, ny, rho)


def _signal(x, shape_tail: tuple, name: str, lead: tuple) -> np.ndarray:
    if x is None:
        return np.zeros(lead + shape_tail)
    a = np.asarray(x, dtype=float)
    if a.shape[-2:] != shape_tail:
        raise ValueError(f"{name} must have shape (..., {shape_tail[0]}, {shape_tail[1]}), "
                         f"got {a.shape}.")
    return np.broadcast_to(a, lead + shape_tail)


def simulate_multirate(loop: MultirateClosedLoop, r, d_u=None, d_y=None, reference=None,
                       *, block_length: int | None = None) -> MultirateResponse:
    """Simulate the multirate closed loop from rest, all at once at the slow rate.

    Parameters
    ----------
    loop : MultirateClosedLoop
        From :func:`multirate_closed_loop`.
    r : array_like, shape (..., N, nu)
        Fast excitation ``r_h`` added at the plant input; ``N`` a multiple of ``F``.
    d_u : array_like, shape (..., N, nu), optional
        Fast input disturbance, added after ``u_h`` is measured; default zero.
    d_y : array_like, shape (..., N, ny), optional
        Fast output disturbance; default zero.
    reference : array_like, shape (..., N/F, ny), optional
        Slow reference (e.g. run-out), enters as ``e = reference - y_l``; default zero.
    block_length : int, optional
        Passed to :func:`simulate_lti` (slow samples per block).

    Returns
    -------
    MultirateResponse
        ``u`` (..., N, nu), ``y_slow`` (..., N/F, ny), ``y`` (..., N, ny).

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import static_gain, tf_q_inverse
    >>> P = tf_q_inverse([0.0, 0.5], [1.0, -0.9], dt=0.5)
    >>> loop = multirate_closed_loop(P, static_gain(0.2, dt=1.0), None, 2)
    >>> out = simulate_multirate(loop, np.ones((8, 1)))
    >>> out.u.shape, out.y_slow.shape, out.y.shape
    ((8, 1), (4, 1), (8, 1))
    """
    F, nu, ny = loop.factor, loop.n_inputs, loop.n_outputs
    r = np.asarray(r, dtype=float)
    if r.ndim < 2 or r.shape[-1] != nu:
        raise ValueError(f"r must have shape (..., N, {nu}) (time, plant inputs), got {r.shape}.")
    N = r.shape[-2]
    if N % F:
        raise ValueError(
            f"{N} fast samples cannot be lifted by factor {F}; trim r to {N - N % F} samples.")
    M = N // F
    lead = np.broadcast_shapes(*[np.shape(x)[:-2] for x in (r, d_u, d_y, reference)
                                 if x is not None])
    parts = [_signal(r, (N, nu), "r", lead), _signal(d_u, (N, nu), "d_u", lead),
             _signal(d_y, (N, ny), "d_y", lead)]
    # (N, c) -> (M, F c) is exactly the phase-major lifting of the kernels.
    lifted = [p.reshape(lead + (M, F * p.shape[-1])) for p in parts]
    lifted.append(_signal(reference, (M, ny), "reference", lead))
    out = simulate_lti(loop.system, np.concatenate(lifted, axis=-1), block_length=block_length)
    u = out[..., :F * nu].reshape(lead + (N, nu))
    y_slow = out[..., F * nu:F * nu + ny]
    y = out[..., F * nu + ny:].reshape(lead + (N, ny))
    return MultirateResponse(u, y_slow, y)
