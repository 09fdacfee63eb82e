"""Plants of the dual-stage HDD benchmark (Atsumi, IEEJ benchmark, user manual Ver. 1.0).

VCM and PZT actuators to head position (m), continuous modal models discretised with
zero-order hold at the fast period ``Th = 1/100800 s``, built as block-diagonal modal state
space (one 2x2 block per mode), for the nine plant cases of the benchmark.
"""

from __future__ import annotations

import functools

import numpy as np

from lcmr_xr.kernels.lti import StateSpace, hstack, modal_zoh

#: Slow (output) sampling period Tl in s: 7200 rpm, 420 sectors per revolution.
SLOW_PERIOD = 1.0 / 50400.0
#: Multirate factor F.
FACTOR = 2
#: Fast (input) sampling period Th = Tl / F in s.
FAST_PERIOD = SLOW_PERIOD / FACTOR
#: Track pitch in m (482 kTPI).
TRACK_PITCH = 52.697e-9
#: Stroke limit of the PZT actuator in m.
PZT_STROKE_LIMIT = 50e-9
#: Channel labels used by every labelled function of :mod:`lcmr_xr.hdd`.
INPUTS = ("vcm", "pzt")
OUTPUTS = ("position",)

VCM_GAIN = 3.7976e7
VCM_FREQS = np.array([0, 5300, 6100, 6500, 8050, 9600, 14800, 17400, 21000, 26000, 26600,
                      29000, 32200, 38300, 43300, 44800], dtype=float)
VCM_MODAL_GAINS = np.array([1, -1.0, 0.1, -0.1, 0.04, -0.7, -0.2, -1.0, 3.0, -3.2, 2.1, -1.5,
                            2.0, -0.2, 0.3, -0.5])
VCM_DAMPINGS = np.array([0, 0.02, 0.04, 0.02, 0.01, 0.03, 0.01, 0.02, 0.02, 0.012, 0.007, 0.01,
                         0.03, 0.01, 0.01, 0.01])

PZT_FREQS = np.array([14800, 21500, 28000, 40200, 42050, 44400, 46500, 100000], dtype=float)
PZT_MODAL_GAINS = np.array([-0.005, -0.01, -0.1, 0.8, 0.3, -0.25, 0.3, 10.0])
PZT_DAMPINGS = np.array([0.025, 0.03, 0.05, 0.008, 0.008, 0.01, 0.02, 0.3])

#: Temperature variations: (VCM frequency factor, PZT frequency factor, damping factor).
TEMPERATURES = {"LT": (1.04, 1.06, 0.8), "RT": (1.0, 1.0, 1.0), "HT": (0.96, 0.94, 1.2)}
#: Plant cases 1..9 of the benchmark: (temperature, PZT DC gain g).
CASES = {
    1: ("LT", 1.0), 2: ("RT", 1.0), 3: ("HT", 1.0),
    4: ("LT", 1.05), 5: ("RT", 1.05), 6: ("HT", 1.05),
    7: ("LT", 0.95), 8: ("RT", 0.95), 9: ("HT", 0.95),
}


def check_case(case) -> int:
    """Return ``case`` as an int after checking it is one of the benchmark cases 1..9.

    Parameters
    ----------
    case : int
        Benchmark plant case.

    Returns
    -------
    int
        The case.

    Raises
    ------
    ValueError
        If ``case`` is not a whole number in 1..9 (``2.0`` is 2; ``2.5`` is refused).
    TypeError
        If ``case`` is not a number (``"2"``, a bool).

    Examples
    --------
    >>> check_case(2)
    2
    """
    from lcmr_xr.settings import as_integer

    case = as_integer(case, "case", example=2)  # the integer rule: 2.0 is 2, "2" a TypeError
    if case not in CASES:
        raise ValueError(
            f"case must be one of the benchmark plant cases 1..9 (2 = room temperature, "
            f"nominal PZT gain), got {case!r}."
        )
    return int(case)


def vcm_plant(case: int = 2) -> StateSpace:
    """VCM actuator ``Pv``: input (benchmark units, ``1``) to head position (m), ZOH at ``Th``.

    ``Pv(s) = Kp sum_i k_i / (s^2 + 2 z_i w_i s + w_i^2)`` with the rigid-body mode
    ``Kp / s^2``; frequencies and dampings scaled by the case's temperature.

    Parameters
    ----------
    case : int, optional
        Benchmark plant case 1..9; default 2 (room temperature).

    Returns
    -------
    StateSpace
        SISO, 32 states, period ``FAST_PERIOD``.

    Examples
    --------
    >>> vcm_plant().n_states
    32
    """
    return _vcm_plant(check_case(case))


@functools.lru_cache(maxsize=None)  # systems are immutable: build each case once
def _vcm_plant(case: int) -> StateSpace:
    temperature, _ = CASES[case]
    f_scale, _, z_scale = TEMPERATURES[temperature]
    return modal_zoh(VCM_GAIN * VCM_MODAL_GAINS, VCM_FREQS * f_scale, VCM_DAMPINGS * z_scale,
                     FAST_PERIOD)


def pzt_plant(case: int = 2) -> StateSpace:
    """PZT actuator ``Pp``: input (``1``) to head position (m), ZOH at ``Th``, DC gain ``g``.

    ``Pp(s) = g [sum_i k_i / (s^2 + 2 z_i w_i s + w_i^2)] / |P_raw(0)|``, renormalised per case
    (after the temperature scaling of frequencies and dampings) so its DC gain is exactly the
    case's ``g`` (ZOH keeps the DC gain).

    Parameters
    ----------
    case : int, optional
        Benchmark plant case 1..9; default 2 (``g = 1``).

    Returns
    -------
    StateSpace
        SISO, 16 states, period ``FAST_PERIOD``.

    Examples
    --------
    >>> from lcmr_xr.kernels.lti import dc_gain
    >>> round(float(dc_gain(pzt_plant(5))[0, 0]), 12)
    1.05
    """
    return _pzt_plant(check_case(case))


@functools.lru_cache(maxsize=None)
def _pzt_plant(case: int) -> StateSpace:
    temperature, gain = CASES[case]
    _, f_scale, z_scale = TEMPERATURES[temperature]
    w = 2 * np.pi * PZT_FREQS * f_scale
    raw_dc = abs(np.sum(PZT_MODAL_GAINS / w**2))
    return modal_zoh(gain * PZT_MODAL_GAINS / raw_dc, PZT_FREQS * f_scale, PZT_DAMPINGS * z_scale,
                     FAST_PERIOD)


def plant(case: int = 2) -> StateSpace:
    """Dual-stage plant ``[Pv, Pp]``: inputs (vcm, pzt), output head position (m), at ``Th``.

    Parameters
    ----------
    case : int, optional
        Benchmark plant case 1..9; default 2.

    Returns
    -------
    StateSpace
        2 inputs, 1 output, 48 states (VCM first).

    Examples
    --------
    >>> g = plant()
    >>> g.n_inputs, g.n_outputs
    (2, 1)
    """
    return _plant(check_case(case))


@functools.lru_cache(maxsize=None)
def _plant(case: int) -> StateSpace:
    return hstack(_vcm_plant(case), _pzt_plant(case))
