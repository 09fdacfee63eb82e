"""Labelled transforms: lifting (fast <-> slow-and-phase) and DFTs with frequency coordinates."""

from lcmr_xr.transforms.lifting import lift, unlift
from lcmr_xr.transforms.spectra import dft, fast_spectrum_from_lifted, idft

__all__ = ["lift", "unlift", "dft", "idft", "fast_spectrum_from_lifted"]
