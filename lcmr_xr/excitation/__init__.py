"""Labelled excitation signals (periodic multisines) for identification experiments."""

from lcmr_xr.excitation.multisine import bins_for_band, multisine, orthogonal_multisines

__all__ = ["bins_for_band", "multisine", "orthogonal_multisines"]
