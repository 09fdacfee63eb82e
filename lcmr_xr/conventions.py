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
# Honest uncertainty (docs/uncertainty.md): P_std is calibrated so that
# |P_hat - P| <= sqrt(ln 20) P_std is a 95 % region, inf where P_UNDETERMINED.
P_STD_LINEAR = "P_std_linear"  # first-order noise standard deviation of P
P_UNDETERMINED = "P_undetermined"  # the data do not determine P (unbounded band)
P_BIAS = "P_bias"  # estimated model error of P (window="auto")
LOCAL_WINDOW = "local_window"  # half-width chosen per slow bin (window="auto")
S_WEAK_REL_STD = "s_weak_rel_std"  # relative std of the weakest direction of S

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
