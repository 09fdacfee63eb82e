"""Names, attributes and unit strings of the lcmr_xr data contract (``lcmr-xr-1``).

Every module reads dimension, variable and attribute names from here, so the contract
described in ``docs/conventions.md`` is written down once in code.  Nothing here computes
anything.  Extend, never rename: files written by earlier versions use these names.
"""

from __future__ import annotations

import re

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

# Variables of the experiment dataset: fast excitation, measured fast plant input,
# measured slow plant output.
EXCITATION = "r"
PLANT_INPUT = "u"
SLOW_OUTPUT = "y"
EXPERIMENT_VARIABLES = (EXCITATION, PLANT_INPUT, SLOW_OUTPUT)

# Variables of the FRF dataset.  An uncertainty is the variable's name + STD_SUFFIX.
P = "P"
STD_SUFFIX = "_std"
P_FLAG = "P_flag"  # bins where P could not be estimated (NaN there)
LIFTED_S = "S"
LIFTED_PS = "PS"
TRANSIENT_U = "transient_u"
TRANSIENT_Y = "transient_y"
NOISE_VARIANCE_U = "noise_variance_u"
NOISE_VARIANCE_Y = "noise_variance_y"
# Honest uncertainty (docs/uncertainty.md): P_std is calibrated so that
# |P_hat - P| <= sqrt(ln 20) P_std is a 95 % region, inf where P_UNDETERMINED.
P_STD_LINEAR = "P_std_linear"  # first-order noise standard deviation of P
P_UNDETERMINED = "P_undetermined"  # the data do not determine P (unbounded band)
P_BIAS = "P_bias"  # estimated model error of P (window="auto")
LOCAL_WINDOW = "local_window"  # half-width chosen per slow bin (window="auto")
S_WEAK_REL_STD = "s_weak_rel_std"  # relative std of the weakest direction of S
CONDITION = "condition"  # of the local least-squares problem, per slow bin
ILL_POSED = "ill_posed"  # flag: local model ill-conditioned
S_CONDITION = "s_condition"  # of the estimated lifted sensitivity, per slow bin
S_SINGULAR = "s_singular"  # flag: S not invertible, P_1 = PS_1 S^-1 not formed
# Every variable identify may return (the indirect estimate has all, "direct" has no
# S-side variables, the single-rate estimate only P, P_std and P_flag).
FRF_VARIABLES = (
    P, P + STD_SUFFIX, P_FLAG,
    LIFTED_S, LIFTED_S + STD_SUFFIX, LIFTED_PS, LIFTED_PS + STD_SUFFIX,
    TRANSIENT_U, TRANSIENT_Y, NOISE_VARIANCE_U, NOISE_VARIANCE_Y,
    CONDITION, ILL_POSED, S_CONDITION, S_SINGULAR,
    P_STD_LINEAR, P_UNDETERMINED, S_WEAK_REL_STD,
)
# window="auto" adds these two.
AUTO_WINDOW_VARIABLES = (P_BIAS, LOCAL_WINDOW)

# Pooled estimates (identify on a ``period`` dim or with combine="experiment"): the noise
# variances of the averaged spectra estimated from the spread over the records.
PERIOD_NOISE_VARIANCE_U = "period_noise_variance_u"
PERIOD_NOISE_VARIANCE_Y = "period_noise_variance_y"
POOLED_VARIABLES = (PERIOD_NOISE_VARIANCE_U, PERIOD_NOISE_VARIANCE_Y)
# Experiments pooled in one local model (combine="experiment"): the factor on the
# covariance from the spread between the even- and odd-numbered experiments' fits
# (docs/uncertainty.md, "Pooled experiments"), per slow bin.
SPREAD_CALIBRATION = "spread_calibration"
# ... and the factor on the band of P from the two halves' own P, per fast bin and entry.
P_SPREAD_CALIBRATION = "P_spread_calibration"
COMBINED_VARIABLES = (SPREAD_CALIBRATION, P_SPREAD_CALIBRATION)

# Attribute names.
CONVENTIONS_ATTR = "conventions"  # value CONVENTIONS, on experiment and FRF datasets
SLOW_NYQUIST = "slow_nyquist"
SAMPLING_PERIOD = "sampling_period"
FACTOR = "factor"
DFT_SCALING = "dft_scaling"
DFT_SCALING_VALUE = "sum"  # X(k) = sum_n x(n) exp(-2j pi k n / N), as numpy.fft.fft

# Settings recorded on an FRF dataset; METHOD, DEGREES and WINDOW are also the dims
# (and coordinates) of a sweep result.
METHOD = "method"
CLOSED_LOOP = "closed_loop"
WINDOW = "window"
WINDOW_BINS = "window_bins"
DEGREES = "degrees"
N_SAMPLES = "n_samples"
PARAMETERS_PER_ROW = "parameters_per_row"
COVARIANCE = "covariance"
DENOMINATOR = "denominator"  # "ls", "iv" or "none": how the LRM's denominator was estimated
TITLE = "title"
FRF_ATTRS = (
    CONVENTIONS_ATTR, METHOD, CLOSED_LOOP, WINDOW, WINDOW_BINS, DEGREES, FACTOR,
    SAMPLING_PERIOD, SLOW_NYQUIST, N_SAMPLES, PARAMETERS_PER_ROW, COVARIANCE, DENOMINATOR, TITLE,
)
# Added to FRF_ATTRS by denominator="iv": the half-width of the first fit (instruments).
IV_FIRST_WINDOW = "iv_first_window"
# Added to FRF_ATTRS by window="auto" (then WINDOW and WINDOW_BINS are the string "auto").
CANDIDATE_WINDOWS = "candidate_windows"  # int array: the half-widths chosen from
# Added to FRF_ATTRS by a pooled estimate.
COMBINE = "combine"
PERIODS = "periods"
TRANSIENT_PERIODS = "transient_periods"
STEADY_PERIODS = "steady_periods"
RECORDS_AVERAGED = "records_averaged"
NOISE_ESTIMATE = "noise_estimate"
NOISE_DOF = "noise_dof"
POOLED_ATTRS = (COMBINE, PERIODS, TRANSIENT_PERIODS, STEADY_PERIODS, RECORDS_AVERAGED,
                NOISE_ESTIMATE, NOISE_DOF)
# Added by combine="experiment" with a local window over different excitations (one local
# model, G shared, a transient per experiment): the number of experiments pooled.
POOLED_EXPERIMENTS = "pooled_experiments"


# ---- archives (lcmr_xr.scaleout): docs/conventions.md, "Files and archives"
ARCHIVE_KIND_ATTR = "lcmr_archive"  # file attribute that marks a consolidated archive
ARCHIVE_KIND = "consolidated-1"  # its value (layout version)
ARCHIVE_COUNT_ATTR = "lcmr_archive_count"  # complete experiments in a consolidated archive
ARCHIVE_ORDER_ATTR = "lcmr_archive_index"  # order of a file in an archive directory
ARCHIVE_INDEX_FILE = ".lcmr_archive_index.nc"  # header index of an archive directory (hidden)
ARCHIVE_INDEX_VERSION_ATTR = "lcmr_archive_index_version"  # its file attribute: format version
ARCHIVE_INDEX_JOURNAL = ".lcmr_archive_index.journal"  # its journal: one JSON file per write (hidden dir)
ARCHIVE_INDEX_DAMAGED_SUFFIX = ".unreadable"  # a damaged journal file set aside by a compaction
ARCHIVE_METADATA = ("seed", "case", "date", "drive_id")  # attrs that become coords along experiment
ARCHIVE_PARTS_SUFFIX = ".parts"  # sweep_to_disk keeps finished tasks in .OUTPUT.parts/
EXPERIMENT_ERROR = "experiment_error"  # sweep output: why an experiment failed ("" if it did not)


def time_attrs(long_name: str = "time") -> dict:
    """Attributes of a time coordinate, in seconds (CF: standard_name, axis)."""
    return {"units": "s", "long_name": long_name, "standard_name": "time", "axis": "T"}


def frequency_attrs(long_name: str = "frequency") -> dict:
    """Attributes of a frequency coordinate, in hertz."""
    return {"units": "Hz", "long_name": long_name}


def label_attrs(long_name: str) -> dict:
    """Attributes of a string (channel label) coordinate."""
    return {"units": "1", "long_name": long_name}


def squared_units(units: str) -> str:
    """UDUNITS string of the square of ``units`` (the units of a variance).

    A plain symbol takes the exponent 2 as UDUNITS writes it (``m`` -> ``m2``, ``V`` ->
    ``V2``), a symbol with an integer exponent doubles it (``m2`` -> ``m4``, ``s-1`` ->
    ``s-2``; appending 2 would read ``m22``), ``1`` (and an empty string) stays ``1``, and
    anything else is parenthesised (``m/s`` -> ``(m/s)2``, ``m s-1`` -> ``(m s-1)2``).
    Until session 16 every unit was parenthesised (``(m)2``, the same UDUNITS unit).

    Parameters
    ----------
    units : str
        The ``units`` attribute of the signal.

    Returns
    -------
    str
        The units of its square.

    Examples
    --------
    >>> [squared_units(u) for u in ("m", "m2", "s-1", "m/s", "1")]
    ['m2', 'm4', 's-2', '(m/s)2', '1']
    """
    units = str(units).strip()
    if units in ("", "1"):
        return "1"
    match = re.fullmatch(r"([^\W\d_]+)(?:\^|\*\*)?([+-]?\d+)?", units)
    if match:
        symbol, power = match.group(1), int(match.group(2) or 1)
        return "1" if power == 0 else f"{symbol}{2 * power}"
    return f"({units})2"


def frequency_dim_for(time_dim: str) -> str:
    """Name of the frequency dimension that replaces ``time_dim`` in a DFT.

    ``time`` -> ``frequency``, ``slow_time`` -> ``slow_frequency``; any other
    name ``d`` -> ``freq_d``.
    """
    if time_dim.endswith("time"):
        return time_dim[: -len("time")] + "frequency"
    return f"freq_{time_dim}"
