"""The experiment dataset of the data contract: build it from arrays, validate it."""

from lcmr_xr.experiment.dataset import experiment, validate_experiment

__all__ = ["experiment", "validate_experiment"]
