"""Reference simulator of the multirate closed loop: plain loops, the block diagram literally.

Slow and obviously correct on purpose; the fast simulator in
:mod:`lcmr_xr.kernels.lti` is tested against it, and ``benchmarks/simulate.py`` times
the two against each other.  Works on 2-d signals ``(N, channels)`` only.

At fast sample ``n = lF + j``:

* ``j == 0``: sample ``y_l(l) = y(lF)`` and run the controller, ``v(l) = C(reference - y_l)``.
  ``y(lF)`` depends on ``v(l)`` through the feedthroughs of plant, filter and controller,
  so the pair ``(y_l, v)`` is solved from the two linear equations of the diagram.
* every ``n``: hold ``v_h(n) = v(l)``, filter ``w = Fi v_h``, record ``u_h = r_h + w``, plant
  input ``u_h + d_u``, output ``y = P(u_h + d_u) + d_y``; advance filter and plant.
"""

from __future__ import annotations

import numpy as np


def simulate_multirate_oracle(plant, controller, filter, factor, r, d_u=None, d_y=None,
                              reference=None):
    """Return ``(u_h (N, nu), y_l (N/F, ny), y (N, ny))`` of the multirate closed loop.

    ``plant``, ``controller`` and ``filter`` are anything with ``A, B, C, D`` attributes
    (``filter`` may be ``None`` for the identity).
    """
    F = int(factor)
    r = np.asarray(r, dtype=float)
    N, nu = r.shape
    ny = plant.D.shape[0]
    M = N // F
    d_u = np.zeros((N, nu)) if d_u is None else np.asarray(d_u, dtype=float)
    d_y = np.zeros((N, ny)) if d_y is None else np.asarray(d_y, dtype=float)
    reference = np.zeros((M, ny)) if reference is None else np.asarray(reference, dtype=float)
    if filter is None:
        Af, Bf, Cf, Df = np.zeros((0, 0)), np.zeros((0, nu)), np.zeros((nu, 0)), np.eye(nu)
    else:
        Af, Bf, Cf, Df = filter.A, filter.B, filter.C, filter.D
    Ap, Bp, Cp, Dp = plant.A, plant.B, plant.C, plant.D
    Ac, Bc, Cc, Dc = controller.A, controller.B, controller.C, controller.D

    xp = np.zeros(Ap.shape[0])
    xf = np.zeros(Af.shape[0])
    xc = np.zeros(Ac.shape[0])
    u_rec = np.zeros((N, nu))
    y_fast = np.zeros((N, ny))
    y_slow = np.zeros((M, ny))
    v = np.zeros(nu)
    for n in range(N):
        l, j = divmod(n, F)
        if j == 0:
            # Unknowns [y_l, v]:
            #   y_l = Cp xp + Dp (Cf xf + Df v + r + d_u) + d_y
            #   v   = Cc xc + Dc (reference - y_l)
            lhs = np.block([[np.eye(ny), -Dp @ Df], [Dc, np.eye(nu)]])
            rhs = np.concatenate([Cp @ xp + Dp @ (Cf @ xf + r[n] + d_u[n]) + d_y[n],
                                  Cc @ xc + Dc @ reference[l]])
            sol = np.linalg.solve(lhs, rhs)
            y_slow[l], v = sol[:ny], sol[ny:]
            xc = Ac @ xc + Bc @ (reference[l] - y_slow[l])
        w = Cf @ xf + Df @ v
        u_h = r[n] + w
        u_p = u_h + d_u[n]
        u_rec[n] = u_h
        y_fast[n] = Cp @ xp + Dp @ u_p + d_y[n]
        xf = Af @ xf + Bf @ v
        xp = Ap @ xp + Bp @ u_p
    return u_rec, y_slow, y_fast
