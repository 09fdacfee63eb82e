"""Controllers and multirate notch filters of the HDD benchmark, as used in the paper.

Slow controllers at ``Tl = 1/50400 s``; fast notch filters at ``Th = 1/100800 s``.
"""

from __future__ import annotations

import functools

from lcmr_xr.hdd.plants import FACTOR, FAST_PERIOD, SLOW_PERIOD, check_case, plant
from lcmr_xr.kernels.lti import (MultirateClosedLoop, StateSpace, block_diagonal,
                                 multirate_closed_loop, notch_filter, tf_q_inverse, vstack)

# The paper prints "- 0.63 q^-1" on the last numerator term of Cv; q^-2 is meant
# (a repeated q^-1 term would simply have been added to 0.020 q^-1).
VCM_CONTROLLER = ((0.65, 0.020, -0.63), (1.0, -1.4, 0.51))
PZT_CONTROLLER = ((0.01346, 0.01346), (1.0, -0.8825))

#: Notch sections (f Hz, zeta numerator, zeta denominator) of the fast filters.
VCM_NOTCHES = ((5650, .02, .09), (8000, .01, .02), (14800, .01, .03), (17400, .01, .05),
               (21000, .01, .15), (26000, .01, .05), (26600, .01, .05), (29000, .01, .05),
               (32200, .01, .10), (38300, .01, .05), (43300, .01, .05), (44800, .01, .05))
PZT_NOTCHES = ((15000, .03, .10), (21500, .03, .10), (29000, .05, .20), (40000, .02, .50),
               (43000, .05, .30))


@functools.lru_cache(maxsize=None)
def vcm_controller() -> StateSpace:
    """``Cv(q) = (0.65 + 0.020 q^-1 - 0.63 q^-2) / (1 - 1.4 q^-1 + 0.51 q^-2)`` at ``Tl``.

    Examples
    --------
    >>> vcm_controller().dt == 1 / 50400
    True
    """
    return tf_q_inverse(*VCM_CONTROLLER, SLOW_PERIOD)


@functools.lru_cache(maxsize=None)
def pzt_controller() -> StateSpace:
    """``Cp(q) = (0.01346 + 0.01346 q^-1) / (1 - 0.8825 q^-1)`` at ``Tl``.

    Examples
    --------
    >>> pzt_controller().n_states
    1
    """
    return tf_q_inverse(*PZT_CONTROLLER, SLOW_PERIOD)


@functools.lru_cache(maxsize=None)
def controller() -> StateSpace:
    """Parallel dual-stage controller ``[Cv; Cp]``: error (m) to (vcm, pzt) commands, at ``Tl``.

    Examples
    --------
    >>> c = controller()
    >>> c.n_inputs, c.n_outputs
    (1, 2)
    """
    return vstack(vcm_controller(), pzt_controller())


@functools.lru_cache(maxsize=None)
def vcm_filter() -> StateSpace:
    """Fast notch filter ``Fv`` (12 matched pole-zero sections, unit DC gain) at ``Th``.

    Examples
    --------
    >>> vcm_filter().n_states
    24
    """
    return notch_filter(VCM_NOTCHES, FAST_PERIOD)


@functools.lru_cache(maxsize=None)
def pzt_filter() -> StateSpace:
    """Fast notch filter ``Fp`` (5 matched pole-zero sections, unit DC gain) at ``Th``.

    Examples
    --------
    >>> pzt_filter().n_states
    10
    """
    return notch_filter(PZT_NOTCHES, FAST_PERIOD)


@functools.lru_cache(maxsize=None)
def notch_filters() -> StateSpace:
    """Both fast filters ``diag(Fv, Fp)`` (2 inputs, 2 outputs) at ``Th``.

    Examples
    --------
    >>> notch_filters().n_inputs
    2
    """
    return block_diagonal(vcm_filter(), pzt_filter())


def closed_loop(case: int = 2) -> MultirateClosedLoop:
    """The benchmark's multirate closed loop as one LTI system at ``Tl`` (stability checked).

    Parameters
    ----------
    case : int, optional
        Benchmark plant case 1..9; default 2.

    Returns
    -------
    MultirateClosedLoop
        See :func:`lcmr_xr.kernels.lti.multirate_closed_loop` for the signal ordering.

    Examples
    --------
    >>> closed_loop().spectral_radius < 1
    True
    """
    return _closed_loop(check_case(case))


@functools.lru_cache(maxsize=None)
def _closed_loop(case: int) -> MultirateClosedLoop:
    return multirate_closed_loop(plant(case), controller(), notch_filters(), FACTOR)
