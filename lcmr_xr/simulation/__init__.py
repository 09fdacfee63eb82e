"""Simulation of multirate closed-loop experiments on labelled data."""

from lcmr_xr.simulation.multirate import simulate_closed_loop

__all__ = ["simulate_closed_loop"]
