"""Files and exchange: NetCDF (atomic writes, exact complex values), MATLAB ``.mat`` files,
and python-control frequency-response data."""

from lcmr_xr.io.frd import from_frd, to_frd
from lcmr_xr.io.matfile import open_mat_experiment, save_mat
from lcmr_xr.io.netcdf import open_dataset, open_experiment, open_frf, save

__all__ = [
    "from_frd", "open_dataset", "open_experiment", "open_frf", "open_mat_experiment", "save",
    "save_mat", "to_frd",
]
