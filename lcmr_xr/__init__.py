"""lcmr_xr: lifted closed-loop multirate FRF identification on labelled data.

Identify the fast-rate frequency response function of a system running in closed
loop with a slow-rate output, beyond the slow Nyquist frequency, from one experiment
(van Haren, Mae, Blanken and Oomen, Mechatronics 108:103311).
"""

from lcmr_xr.conventions import CONVENTIONS

__version__ = "0.1.0"

__all__ = ["CONVENTIONS", "__version__"]
