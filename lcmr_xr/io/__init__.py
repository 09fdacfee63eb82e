"""NetCDF input/output of experiment and FRF datasets (atomic writes, exact complex values)."""

from lcmr_xr.io.netcdf import open_dataset, open_experiment, open_frf, save

__all__ = ["open_dataset", "open_experiment", "open_frf", "save"]
