"""Former home of the LTI kernels, now split by concern in :mod:`lcmr_xr.kernels.lti`.

Kept so that existing ``from lcmr_xr.kernels.ltisim import ...`` lines keep working; new
code imports from :mod:`lcmr_xr.kernels.lti`.
"""

from lcmr_xr.kernels.lti import *  # noqa: F401,F403  (re-export of the same objects)
from lcmr_xr.kernels.lti import __all__  # noqa: F401
