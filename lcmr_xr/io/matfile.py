"""MATLAB ``.mat`` files: read an experiment, write an FRF that MATLAB's ``frd`` takes in one line.

MATLAB stores every numeric variable as a matrix: a scalar comes back from
:func:`scipy.io.loadmat` as a ``(1, 1)`` array and a vector as ``(1, N)`` or ``(N, 1)``,
whichever the user had.  The reader accepts all of these (a signal's time runs along its
longer axis) and the writer produces what MATLAB users expect: ``ny x nu x nf`` complex
responses, column vectors, cell arrays of channel names.  v7.3 files (HDF5) are read with
h5py, which sees MATLAB's column-major matrices transposed; the longer-axis rule covers that.

What MATLAB's own rules say, the reader follows: channel names (``InputName``,
``OutputName``) and units are text (MATLAB's ``frd``/``iddata`` refuse numbers there), so a
number there is refused with the remedy (``cellstr(string(x))`` in MATLAB, or ``inputs=``),
never turned into ``"1.0"``; a char matrix gives one name per row, trailing blanks removed
(as MATLAB's ``cellstr``).  Signals are numbers: a ``logical`` array (true/false) is
refused, never read as 0.0/1.0 (a binary excitation is ``double(x)`` in MATLAB, or
``2*double(x) - 1`` for +-1); integer types (an ADC's ``int16``) are read as floats.
"""

from __future__ import annotations

from numbers import Real
from pathlib import Path

import numpy as np
import xarray as xr

from lcmr_xr.conventions import FACTOR, FREQUENCY, INPUT, OUTPUT, SAMPLING_PERIOD, SLOW_TIME, TIME
from lcmr_xr.io._atomic import atomic_write
from lcmr_xr.io._guards import MAT_SUFFIX

__all__ = ["open_mat_experiment", "save_mat"]

# Names of the variables save_mat writes (MATLAB's own property names where there is one).
SAMPLE_TIME = "Ts"
FACTOR_NAME = "F"
INPUT_NAME = "InputName"
OUTPUT_NAME = "OutputName"
INPUT_UNITS = "input_units"
OUTPUT_UNITS = "output_units"


def is_mat_path(path) -> bool:
    """True when ``path`` names a MATLAB file (suffix ``.mat``, any case)."""
    return Path(path).suffix.lower() == MAT_SUFFIX


# --- reading ---------------------------------------------------------------------------


def _load(path: Path) -> dict:
    """``{name: numpy array or str}`` of a v5/v7 or v7.3 MAT-file."""
    import scipy.io

    if not path.is_file():
        raise FileNotFoundError(f"no such file: {path}; check the path.")
    try:
        # mat_dtype: the classes MATLAB sees (a logical comes back as bool, not uint8)
        raw = scipy.io.loadmat(path, chars_as_strings=True, mat_dtype=True)
    except NotImplementedError:  # v7.3: HDF5 underneath
        return _load_hdf5(path)
    except (scipy.io.matlab.MatReadError, ValueError, TypeError, OSError) as err:
        raise ValueError(
            f"cannot read {path} as a MATLAB file ({err}); save it in MATLAB with "
            "save(..., '-v7') or '-v7.3'."
        ) from err
    return {k: v for k, v in raw.items() if not k.startswith("__")}


def _load_hdf5(path: Path) -> dict:
    import h5py

    try:
        return _read_hdf5(h5py, path)
    except (OSError, ValueError, KeyError) as err:  # HDF5 refuses a truncated or damaged file
        raise ValueError(
            f"cannot read {path} as a MATLAB -v7.3 file: HDF5 cannot read it ({err}): an "
            "incomplete copy or a damaged file. Copy it again, or save it again in MATLAB "
            "with save(..., '-v7.3') or '-v7'."
        ) from err


def _matlab_class(item) -> str:
    value = item.attrs.get("MATLAB_class", b"")
    return value.decode() if isinstance(value, bytes) else str(value)


def _hdf5_value(item):
    """A -v7.3 dataset as :func:`scipy.io.loadmat` gives it: char as text, logical as bool."""
    value = item[()]
    kind = _matlab_class(item)
    if kind == "char":
        if item.attrs.get("MATLAB_empty", 0):
            return ""
        codes = np.asarray(value)
        if codes.ndim == 2 and codes.shape[1] > 1:  # a char matrix, seen transposed: a row per name
            return np.array(["".join(map(chr, row)) for row in codes.T])
        return "".join(map(chr, codes.ravel()))
    if kind == "logical":
        return np.asarray(value).astype(bool)
    return value


def _read_hdf5(h5py, path: Path) -> dict:
    out = {}
    with h5py.File(path, "r") as fh:
        for name, item in fh.items():
            if not isinstance(item, h5py.Dataset) or name.startswith("#"):
                continue  # groups are structs, #refs# holds cell contents: not signals
            if h5py.check_dtype(ref=item.dtype) is not None:
                if name in (INPUT_NAME, OUTPUT_NAME):  # cells of names, one per element
                    cells = np.empty(item.shape, dtype=object)
                    for index, ref in np.ndenumerate(item[()]):
                        cells[index] = _hdf5_value(fh[ref]) if ref else np.empty(0)
                    out[name] = cells
                continue  # other cell arrays are not signals
            out[name] = _hdf5_value(item)
    return out


def _variable(data: dict, name: str, path: Path, what: str):
    if name not in data:
        have = ", ".join(sorted(data)) or "none"
        raise ValueError(
            f"{path} has no variable {name!r} ({what}); its variables are: {have}. "
            f"Name the right one, e.g. {what.split()[0]}='...'."
        )
    return data[name]


def _signal(data: dict, name: str, path: Path, what: str) -> np.ndarray:
    """``(samples, channels)`` float array; time runs along the longer axis of a matrix."""
    value = np.asarray(_variable(data, name, path, what))
    if value.dtype.kind == "b":
        raise ValueError(
            f"{path}: variable {name!r} ({what}) is a MATLAB logical array (true/false), not a "
            f"signal; it is not read as 0/1. Give the numeric signal, or convert it in MATLAB "
            f"({name} = double({name}), or 2*double({name}) - 1 for a +-1 binary sequence) "
            f"and save again."
        )
    if value.dtype.kind not in "iuf":
        raise ValueError(
            f"{path}: variable {name!r} ({what}) is {value.dtype} (a "
            f"{'struct or cell' if value.dtype.kind in 'OV' else 'non-real'} array); it must "
            "be a real numeric vector or matrix."
        )
    value = np.squeeze(value)
    if value.ndim == 1:
        return value.astype(float)[:, None]
    if value.ndim != 2:
        raise ValueError(
            f"{path}: variable {name!r} ({what}) has shape {value.shape}; give a vector or a "
            "samples x channels matrix."
        )
    rows, columns = value.shape
    if rows == columns:
        raise ValueError(
            f"{path}: variable {name!r} ({what}) is {rows} x {columns}: cannot tell samples "
            "from channels; store one channel per column and one sample per row."
        )
    return (value if rows > columns else value.T).astype(float)


def _scalar(data: dict, value, path: Path, what: str, parameter: str):
    """A number given directly, or read from the (1, 1) variable named ``value``."""
    if isinstance(value, str):
        if value not in data:
            raise ValueError(
                f"{path} has no variable {value!r} for the {what}; pass {parameter}= the "
                f"number itself or the name of the variable that holds it "
                f"(variables: {', '.join(sorted(data)) or 'none'})."
            )
        array = np.asarray(data[value])
        if array.size != 1 or array.dtype.kind not in "iuf":
            raise ValueError(
                f"{path}: variable {value!r} ({what}) must be one real number, got shape "
                f"{array.shape} of {array.dtype}."
            )
        value = array.item()
    if isinstance(value, bool) or not isinstance(value, Real):
        raise TypeError(f"{parameter} must be a number or a variable name, got {value!r}.")
    # MATLAB stores every number as a double: 2.0 is the factor 2, 30.5 stays 30.5 and
    # is refused by experiment()
    return int(value) if parameter == "factor" and float(value).is_integer() else float(value)


def _not_text(path: Path, name: str, value, what: str, parameter: str, example: str):
    kind = np.asarray(value).dtype
    return ValueError(
        f"{path}: variable {name!r} ({what}) holds "
        f"{'numbers' if kind.kind in 'biufc' else f'no text (a {kind} array)'}, "
        f"not text: MATLAB keeps it as text ({name} = {example}), so a number is not read "
        f"as one. Save it as text in MATLAB ({name} = cellstr(string({name})) for names, "
        f"{name} = char(string({name})) for units), or pass {parameter}= to open_experiment."
    )


def _cell_text(cell):
    """The text of one cell (a char row), or None if it holds anything else."""
    if isinstance(cell, str):
        return cell
    cell = np.asarray(cell)
    if cell.size == 0:  # '' in MATLAB
        return ""
    if cell.dtype.kind == "U" and cell.size == 1:
        return str(cell.ravel()[0])
    return None


def _labels(data: dict, given, name: str, path: Path):
    """Channel names: a cell array of char rows (MATLAB's ``InputName``) or a char matrix."""
    if given is not None or name not in data:
        return given
    value = data[name]
    parameter, what = ("inputs", "the input names") if name == INPUT_NAME else ("outputs", "the output names")
    if isinstance(value, str):  # v7.3: one char row
        return [value]
    array = np.asarray(value)
    if array.dtype.kind == "U":  # a char matrix: one name per row, blank-padded (MATLAB's cellstr)
        return [str(row).rstrip() for row in array.ravel()]
    if array.dtype == object:
        labels = [_cell_text(cell) for cell in array.ravel()]
        if all(label is not None for label in labels):
            return labels
        array = next(np.asarray(c) for c, label in zip(array.ravel(), labels) if label is None)
    raise _not_text(path, name, array, what, parameter, "{'vcm', 'pzt'}")


def _text(data: dict, given, name: str, path: Path):
    """A units string: a char row, or one unit in a cell (``{'V'}``, as iddata's
    ``InputUnit``) or a char matrix (every row or cell the same unit)."""
    if given is not None or name not in data:
        return given
    value = data[name]
    array = np.asarray(value)
    if isinstance(value, str):
        texts = [value]
    elif array.dtype.kind == "U":  # a char row, or a char matrix: a unit per row
        texts = [str(row).rstrip() for row in array.ravel()]
    elif array.dtype == object:  # a cell array of char rows
        texts = [_cell_text(cell) for cell in array.ravel()]
    else:
        texts = [None]
    if texts and all(text is not None for text in texts):
        if len(set(texts)) > 1:
            signals = "r and u" if name == INPUT_UNITS else "y"
            raise ValueError(
                f"{path}: variable {name!r} holds {len(texts)} units ({', '.join(map(repr, texts))}); "
                f"it is one unit for {signals}: keep one in MATLAB ({name} = {texts[0]!r}) or pass "
                f"{name}= to open_experiment."
            )
        return texts[0]
    if array.dtype == object and array.size:  # name the cell that is not text
        array = next(np.asarray(c) for c, text in zip(array.ravel(), texts) if text is None)
    parameter = name  # input_units / output_units: the keyword has the variable's name
    raise _not_text(path, name, array, "a unit string", parameter, "'m'")


def open_mat_experiment(path, *, r="r", u="u", y="y", factor=FACTOR_NAME,
                        sampling_period=SAMPLE_TIME, inputs=None, outputs=None,
                        input_units=None, output_units=None) -> xr.Dataset:
    """Read an experiment from a MATLAB ``.mat`` file (v5, v7 or v7.3).

    Parameters
    ----------
    path : str or os.PathLike
        The ``.mat`` file.
    r, u, y : str, optional
        Names of the variables holding the fast excitation, the fast plant input (``N``
        samples) and the slow output (``N / F`` samples); default ``"r"``, ``"u"``, ``"y"``.
        Vectors may be rows or columns; a matrix holds one channel per column or per row
        (time runs along its longer axis).  Numeric classes only: integer types are read
        as floats, a ``logical`` array is refused (``double(x)`` in MATLAB).
    factor : int or str, optional
        Multirate factor ``F``, or the name of the ``(1, 1)`` variable holding it
        (default ``"F"``).
    sampling_period : float or str, optional
        Fast sampling period ``Th`` in s, or the name of the variable holding it
        (default ``"Ts"``).
    inputs, outputs : sequence of str, optional
        Channel labels.  Default None: the file's cell arrays ``InputName`` /
        ``OutputName`` when present (as :func:`save_mat` writes them; v7.3 too; a char
        matrix gives one name per row), else ``u0, ...`` and ``y0, ...``.  Names in the
        file must be text, as MATLAB's ``InputName`` is: numbers there are refused, not
        turned into names such as ``"1.0"``.
    input_units, output_units : str, optional
        Units of ``r``/``u`` and of ``y``.  Default None: the file's ``input_units`` /
        ``output_units`` strings when present (a char row, or one unit in a cell such as
        iddata's ``{'V'}``; different units in one are refused), else ``"1"``.

    Returns
    -------
    xarray.Dataset
        A validated experiment dataset (``lcmr-xr-1``), as :func:`lcmr_xr.experiment` builds.

    Raises
    ------
    FileNotFoundError
        If the file does not exist.
    ValueError
        If the file is not a MAT-file, a variable is missing (the message lists the
        file's variables), not real numeric (or ``logical``), or of a shape that is not a
        signal, channel names or units that are not text, or the experiment is invalid (``N != F M`` and the other checks of ``experiment``).
    TypeError
        If ``factor`` or ``sampling_period`` is neither a number nor a variable name.

    Examples
    --------
    >>> import numpy as np, scipy.io, tempfile, os
    >>> with tempfile.TemporaryDirectory() as d:
    ...     p = os.path.join(d, "x.mat")  # as MATLAB writes it: row vectors, 1 x 1 scalars
    ...     scipy.io.savemat(p, {"r": np.ones((1, 8)), "u": np.ones((1, 8)),
    ...                          "y": np.ones((1, 4)), "Ts": 1e-3, "F": 2.0})
    ...     ds = open_mat_experiment(p)
    >>> ds.sizes["time"], ds.sizes["slow_time"], ds.attrs["factor"]
    (8, 4, 2)
    """
    from lcmr_xr.experiment import experiment

    path = Path(path)
    data = _load(path)
    signals = [_signal(data, name, path, what) for name, what in
               ((r, "r, the fast excitation"), (u, "u, the fast plant input"),
                (y, "y, the slow output"))]
    # read before the call: their messages name the file already
    f = _scalar(data, factor, path, "multirate factor F", "factor")
    th = _scalar(data, sampling_period, path, "fast sampling period Th", "sampling_period")
    names = {"inputs": _labels(data, inputs, INPUT_NAME, path),
             "outputs": _labels(data, outputs, OUTPUT_NAME, path),
             "input_units": _text(data, input_units, INPUT_UNITS, path),
             "output_units": _text(data, output_units, OUTPUT_UNITS, path)}
    try:
        return experiment(*signals, factor=f, sampling_period=th, **names)
    except ValueError as err:  # experiment()'s checks do not know the file
        raise ValueError(f"{path}: {err}") from err


# --- writing ---------------------------------------------------------------------------


def _cellstr(labels) -> np.ndarray:
    """A column cell array of char rows (MATLAB's InputName/OutputName)."""
    cells = np.empty((len(labels), 1), dtype=object)
    for k, label in enumerate(labels):
        cells[k, 0] = str(label)
    return cells


def _one_case(ds: xr.Dataset, dims: tuple, what: str) -> None:
    for name in ds.data_vars:
        extra = [d for d in ds[name].dims if d not in dims]
        if extra and name in ("P", "P_std", "r", "u", "y"):
            raise ValueError(
                f"save to .mat writes one {what}; {name!r} has the extra dim(s) {extra}. "
                f"Select one first, e.g. ds.isel({extra[0]}=0), or save to NetCDF (.nc)."
            )


def _frf_variables(ds: xr.Dataset) -> dict:
    _one_case(ds, (FREQUENCY, OUTPUT, INPUT), "FRF")
    if SAMPLING_PERIOD not in ds.attrs:
        raise ValueError(
            "the FRF has no 'sampling_period' attribute (Th, the Ts of MATLAB's frd); set it "
            "with frf.assign_attrs(sampling_period=Th)."
        )
    order = (OUTPUT, INPUT, FREQUENCY)  # MATLAB's frd: ny x nu x nf
    out = {
        "P": np.asarray(ds["P"].transpose(*order).values),
        "frequency": np.asarray(ds[FREQUENCY].values, dtype=float)[:, None],
        "FrequencyUnit": "Hz",
        SAMPLE_TIME: float(ds.attrs[SAMPLING_PERIOD]),
        INPUT_NAME: _cellstr(ds[INPUT].values),
        OUTPUT_NAME: _cellstr(ds[OUTPUT].values),
        "P_units": str(ds["P"].attrs.get("units", "1")),
    }
    if "P_std" in ds.data_vars:
        out["P_std"] = np.asarray(ds["P_std"].transpose(*order).values, dtype=float)
    return out


def _experiment_variables(ds: xr.Dataset) -> dict:
    from lcmr_xr.experiment import validate_experiment

    ds = validate_experiment(ds)
    _one_case(ds, (TIME, SLOW_TIME, INPUT, OUTPUT), "experiment")
    time = np.asarray(ds[TIME].values, dtype=float)
    return {
        "r": np.asarray(ds["r"].transpose(TIME, INPUT).values, dtype=float),
        "u": np.asarray(ds["u"].transpose(TIME, INPUT).values, dtype=float),
        "y": np.asarray(ds["y"].transpose(SLOW_TIME, OUTPUT).values, dtype=float),
        SAMPLE_TIME: float(time[1] - time[0]) if time.size > 1 else float(ds.attrs[SAMPLING_PERIOD]),
        FACTOR_NAME: float(ds.attrs[FACTOR]),  # MATLAB numbers are doubles
        INPUT_NAME: _cellstr(ds[INPUT].values),
        OUTPUT_NAME: _cellstr(ds[OUTPUT].values),
        INPUT_UNITS: str(ds["r"].attrs.get("units", "1")),
        OUTPUT_UNITS: str(ds["y"].attrs.get("units", "1")),
    }


def save_mat(ds: xr.Dataset, path) -> Path:
    """Write an FRF or experiment dataset to a MATLAB ``.mat`` file (v5 format), atomically.

    Parameters
    ----------
    ds : xarray.Dataset
        An FRF dataset (with ``P``) or an experiment dataset (with ``r``, ``u``, ``y``),
        one case (select leading dims first).
    path : str or os.PathLike
        Target file ending in ``.mat``; its directory must exist.  An existing file is
        replaced only once the new one is complete.

    Returns
    -------
    pathlib.Path
        The path written.

    Raises
    ------
    ValueError
        If ``ds`` is neither an FRF nor an experiment dataset, has leading dims, or an
        FRF lacks its ``sampling_period`` attribute.

    Notes
    -----
    An FRF file holds ``P`` (complex, ``ny x nu x nf``), ``P_std`` (same shape, when
    present), ``frequency`` (Hz, ``nf x 1``), ``Ts`` (``Th`` in s), ``FrequencyUnit``
    (``'Hz'``), ``InputName``/``OutputName`` (cell arrays) and ``P_units``, so that in
    MATLAB::

        S = load("frf.mat");
        G = frd(S.P, S.frequency, S.Ts, "FrequencyUnit", "Hz", "InputName", S.InputName, "OutputName", S.OutputName);

    An experiment file holds ``r``, ``u`` (``N x nu``), ``y`` (``N/F x ny``), ``Ts``,
    ``F``, the channel names and ``input_units``/``output_units``;
    :func:`open_mat_experiment` reads it back.

    Examples
    --------
    >>> import numpy as np, xarray as xr, scipy.io, tempfile, os
    >>> frf = xr.Dataset({"P": (("frequency", "output", "input"), np.ones((3, 1, 2), complex))},
    ...                  coords={"frequency": [0.0, 1.0, 2.0], "output": ["y"], "input": ["a", "b"]},
    ...                  attrs={"sampling_period": 0.25})
    >>> with tempfile.TemporaryDirectory() as d:
    ...     m = scipy.io.loadmat(save_mat(frf, os.path.join(d, "frf.mat")))
    >>> m["P"].shape, m["frequency"].shape, m["Ts"].item()
    ((1, 2, 3), (3, 1), 0.25)
    """
    import scipy.io

    if not isinstance(ds, xr.Dataset):
        raise TypeError(
            f"save writes an xarray.Dataset, got {type(ds).__name__}; for a DataArray use "
            "x.to_dataset(name='...')."
        )
    if not is_mat_path(path):
        raise ValueError(f"save_mat writes MATLAB files; give a path ending in '.mat', got {str(path)!r}.")
    if "P" in ds.data_vars:
        variables = _frf_variables(ds)
    elif all(name in ds.data_vars for name in ("r", "u", "y")):
        variables = _experiment_variables(ds)
    else:
        raise ValueError(
            f"save to .mat writes an FRF dataset (variable 'P') or an experiment dataset "
            f"('r', 'u', 'y'); this one has {sorted(ds.data_vars)}. Save it to NetCDF (.nc)."
        )

    def write(tmp):
        with open(tmp, "wb") as fh:  # a file object: savemat would append .mat to the name
            scipy.io.savemat(fh, variables, oned_as="column", do_compression=True)

    return atomic_write(path, write)
