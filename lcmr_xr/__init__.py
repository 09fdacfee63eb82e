"""lcmr_xr: lifted closed-loop multirate FRF identification on labelled data.

Identify the fast-rate frequency response function of a system running in closed
loop with a slow-rate output, beyond the slow Nyquist frequency, from one experiment
(van Haren, Mae, Blanken and Oomen, Mechatronics 108:103311).

Functions are the API (``lcmr_xr.identify(ds)``); the ``.lcmr`` accessor on DataArrays
and Datasets forwards to them (``ds.lcmr.identify()``).
"""

from lcmr_xr import accessor as _accessor  # noqa: F401  (registers the .lcmr accessor)
from lcmr_xr.conventions import CONVENTIONS
from lcmr_xr.excitation import multisine, orthogonal_multisines
from lcmr_xr.experiment import experiment, validate_experiment
from lcmr_xr.identification import identify, identify_single_rate
from lcmr_xr.identification.lifted_system import frf_from_first_block_row, lifted_frf
from lcmr_xr.io import from_frd, open_dataset, open_experiment, open_frf, save, to_frd
from lcmr_xr.simulation import simulate_closed_loop
from lcmr_xr.transforms import dft, fast_spectrum_from_lifted, idft, lift, unlift

__version__ = "0.1.0"

__all__ = [
    "CONVENTIONS",
    "__version__",
    "dft",
    "experiment",
    "fast_spectrum_from_lifted",
    "frf_from_first_block_row",
    "from_frd",
    "identify",
    "identify_single_rate",
    "idft",
    "lift",
    "lifted_frf",
    "multisine",
    "open_dataset",
    "open_experiment",
    "open_frf",
    "orthogonal_multisines",
    "save",
    "simulate_closed_loop",
    "to_frd",
    "unlift",
    "validate_experiment",
]
