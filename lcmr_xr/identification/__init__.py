"""Identification: the paper's Procedure 1 and the estimators it is compared against."""

from lcmr_xr.identification.identify import identify, identify_single_rate

__all__ = ["identify", "identify_single_rate"]
