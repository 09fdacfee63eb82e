"""Discrete-time LTI building blocks: state space, realisations, interconnection,
frequency response, lifting, fast simulation and the multirate closed loop.

Pure numpy/scipy, no labels.  Time signals are arrays ``(..., N, channels)``: time on the
second-to-last axis, channels last, any leading axes broadcast (experiments, seeds).

One module per concern, each importing only those below it:

=================  =====================================================================
``statespace``     :class:`StateSpace`, :func:`static_gain`, stability checks
``interconnect``   :func:`series`, :func:`block_diagonal`, :func:`hstack`, :func:`vstack`
``realisation``    continuous ZOH (:func:`scipy.signal.cont2discrete`), modal sums,
                   ``q^-1`` transfer functions, notch filters
``frequency``      :func:`frequency_response`, :func:`dc_gain`
``lifted``         :func:`lift_statespace`
``simulate``       :func:`simulate_lti` (blocks of ``L`` samples, no per-sample loop)
``multirate``      :func:`multirate_closed_loop`, :func:`simulate_multirate`
=================  =====================================================================

Every public name is re-exported here: ``from lcmr_xr.kernels.lti import StateSpace``.
"""

from lcmr_xr.kernels.lti.frequency import dc_gain, frequency_response
from lcmr_xr.kernels.lti.interconnect import block_diagonal, hstack, series, vstack
from lcmr_xr.kernels.lti.lifted import lift_statespace
from lcmr_xr.kernels.lti.multirate import (MultirateClosedLoop, MultirateResponse,
                                           multirate_closed_loop, simulate_multirate)
from lcmr_xr.kernels.lti.realisation import (continuous_zoh, matched_notch, modal_zoh,
                                             notch_filter, tf_q_inverse)
from lcmr_xr.kernels.lti.simulate import simulate_lti
from lcmr_xr.kernels.lti.statespace import StateSpace, check_stable, spectral_radius, static_gain

__all__ = [
    "StateSpace",
    "MultirateClosedLoop",
    "MultirateResponse",
    "static_gain",
    "continuous_zoh",
    "modal_zoh",
    "tf_q_inverse",
    "matched_notch",
    "notch_filter",
    "series",
    "block_diagonal",
    "hstack",
    "vstack",
    "frequency_response",
    "dc_gain",
    "lift_statespace",
    "spectral_radius",
    "check_stable",
    "simulate_lti",
    "multirate_closed_loop",
    "simulate_multirate",
]
