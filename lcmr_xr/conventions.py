"""Names, attributes and unit strings of the lcmr_xr data contract (``lcmr-xr-1``).

Every module reads dimension names and attributes from here, so the contract in
``shared/conventions.md`` is written down once.  Nothing here computes anything.
"""

from __future__ import annotations

CONVENTIONS = "lcmr-xr-1"

# Dimensions and coordinates of the contract.
TIME = "time"
SLOW_TIME = "slow_time"
LIFT_PHASE = "lift_phase"
FREQUENCY = "frequency"
SLOW_FREQUENCY = "slow_frequency"
INPUT = "input"
OUTPUT = "output"
CHANNEL = "channel"
EXPERIMENT = "experiment"
# Repeated periods of one periodic excitation: ``time`` then runs within a period and
# ``period`` counts the periods (the loop runs on across them).
PERIOD = "period"

# When a result carries the same dimension twice (a lifted matrix), the second copy
# (the column side) gets this suffix, as in xarray-einstats.
SECOND = "2"

LIFT_PHASE2 = LIFT_PHASE + SECOND
INPUT2 = INPUT + SECOND

# Variables of the FRF dataset.
P = "P"
STD_SUFFIX = "_std"
LIFTED_S = "S"
LIFTED_PS = "PS"
NOISE_VARIANCE_U = "noise_variance_u"
NOISE_VARIANCE_Y = "noise_variance_y"

# Attribute names.
SLOW_NYQUIST = "slow_nyquist"
SAMPLING_PERIOD = "sampling_period"
FACTOR = "factor"
DFT_SCALING = "dft_scaling"
DFT_SCALING_VALUE = "sum"  # X(k) = sum_n x(n) exp(-2j pi k n / N), as numpy.fft.fft


def time_attrs(long_name: str = "time") -> dict:
    """Attributes of a time coordinate, in seconds (CF: standard_name, axis)."""
    return {"units": "s", "long_name": long_name, "standard_name": "time", "axis": "T"}


def frequency_attrs(long_name: str = "frequency") -> dict:
    """Attributes of a frequency coordinate, in hertz."""
    return {"units": "Hz", "long_name": long_name}


def label_attrs(long_name: str) -> dict:
    """Attributes of a string (channel label) coordinate."""
    return {"units": "1", "long_name": long_name}


def frequency_dim_for(time_dim: str) -> str:
    """Name of the frequency dimension that replaces ``time_dim`` in a DFT.

    ``time`` -> ``frequency``, ``slow_time`` -> ``slow_frequency``; any other
    name ``d`` -> ``freq_d``.
    """
    if time_dim.endswith("time"):
        return time_dim[: -len("time")] + "frequency"
    return f"freq_{time_dim}"
