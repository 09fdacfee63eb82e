"""The dual-stage hard-disk-drive benchmark (IEEJ, Atsumi 2022) as identified in the paper.

``import lcmr_xr.hdd as hdd`` gives the plants of the nine benchmark cases (ZOH at
``Th = 1/100800 s``), the paper's slow controllers and fast notch filters, the
disturbances, the exact FRF, and :func:`simulate` for the paper's experiment.
"""

from lcmr_xr.hdd.benchmark import BENCHMARK, DISTURBANCES, PAPER_RMS, simulate, true_frf
from lcmr_xr.hdd.control import (closed_loop, controller, notch_filters, pzt_controller,
                                 pzt_filter, vcm_controller, vcm_filter)
from lcmr_xr.hdd.disturbances import (fan_filter, fan_vibration, repeatable_runout,
                                      rotational_filter, rotational_vibration, stationary_std)
from lcmr_xr.hdd.plants import (CASES, FACTOR, FAST_PERIOD, INPUTS, OUTPUTS, PZT_STROKE_LIMIT,
                                SLOW_PERIOD, TRACK_PITCH, check_case, plant, pzt_plant, vcm_plant)

__all__ = [
    "BENCHMARK", "CASES", "DISTURBANCES", "FACTOR", "FAST_PERIOD", "INPUTS", "OUTPUTS", "PAPER_RMS",
    "PZT_STROKE_LIMIT", "SLOW_PERIOD", "TRACK_PITCH", "check_case", "closed_loop", "controller",
    "fan_filter", "fan_vibration", "notch_filters", "plant", "pzt_controller", "pzt_filter",
    "pzt_plant", "repeatable_runout", "rotational_filter", "rotational_vibration", "simulate",
    "stationary_std", "true_frf", "vcm_controller", "vcm_filter", "vcm_plant",
]
