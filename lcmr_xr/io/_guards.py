"""Guards run before any computation: never write over an input or, unasked, an existing file.

Used by the command line (every sub-command checks all its outputs first, so a bad
``--plot f.xyz`` fails before minutes of work) and by :func:`lcmr_xr.io.save` (a lazy
dataset is never written over the file it is still reading).
"""

from __future__ import annotations

import os
from pathlib import Path

from lcmr_xr.io._atomic import check_writable_target
from lcmr_xr.settings import as_bool


#: File name endings of NetCDF files: what :func:`lcmr_xr.io.save` writes NetCDF-4 to, and
#: what the command line's NetCDF outputs (``-o``, ``--select``) and ``sweep_to_disk`` take.
NETCDF_SUFFIXES = (".nc", ".nc4", ".netcdf")
#: The ending of MATLAB files (:mod:`lcmr_xr.io.matfile`; ``save`` writes one for it).
MAT_SUFFIX = ".mat"


def check_suffix(path, suffixes, what: str = "cannot write") -> Path:
    """Refuse, naming ``path`` and every accepted ending, a file name whose suffix (any
    case) is not one of ``suffixes``: a ``.txt`` or a name without a suffix would
    otherwise be written in another format than its name says.

    Parameters
    ----------
    path : str or os.PathLike
        File about to be written.
    suffixes : sequence of str
        The accepted endings, with their dot (``(".nc", ".mat")``).
    what : str
        How the message begins, before the path.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    if path.suffix.lower() not in suffixes:
        accepted = (", ".join(suffixes[:-1]) + " or " if len(suffixes) > 1 else "") + suffixes[-1]
        example = path.with_name((path.stem or "result") + suffixes[0])
        raise ValueError(
            f"{what} {path}: unsupported file type {path.suffix or '(no suffix)'!r}; the file "
            f"name must end in {accepted}, e.g. {example}."
        )
    return path


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(os.path.realpath(path)))


def same_or_inside(path, other) -> bool:
    """``path`` is the file ``other`` (symlinks and ``..`` resolved) or lies inside directory ``other``."""
    a, b = _resolved(Path(path)), _resolved(Path(other))
    if a == b:
        return True
    try:
        if os.path.exists(a) and os.path.exists(b) and os.path.samefile(a, b):
            return True  # hard links
    except OSError:
        pass
    return Path(other).is_dir() and b in a.parents


def check_outputs(outputs: dict, *, inputs=(), overwrite: bool = False,
                  overwrite_hint: str = "pass --overwrite to replace it") -> None:
    """Refuse bad output paths before anything is computed or written.

    Parameters
    ----------
    outputs : dict
        ``{description: (path or None, suffixes or None)}``, e.g.
        ``{"-o": (Path("frf.nc"), (".nc",)), "--plot": (None, (".png",))}``; ``None`` paths
        are skipped.
    inputs : sequence of path
        Files or directories the command reads; no output may be one of them or lie inside
        one of the directories.
    overwrite : bool, default False
        Allow replacing existing output files.
    overwrite_hint : str
        How the caller lifts the refusal of an existing file (appended to the message).

    Raises
    ------
    ValueError
        A wrong suffix, an output that is an input, or two outputs that are the same file.
    FileExistsError
        An existing output without ``overwrite``.
    FileNotFoundError, IsADirectoryError, PermissionError
        A missing or unwritable directory, or an output that is a directory.
    TypeError
        ``overwrite`` not True or False.
    """
    # only True/False: overwrite="no" is truthy and would replace the user's files
    overwrite = as_bool(overwrite, "overwrite")
    seen = {}
    for what, (path, suffixes) in outputs.items():
        if path is None:
            continue
        path = Path(path)
        if suffixes:
            check_suffix(path, suffixes, what)
        for inp in inputs:
            if inp is not None and same_or_inside(path, inp):
                where = "inside the input directory" if Path(inp).is_dir() else "the input file"
                raise ValueError(
                    f"refusing to write {what} {path}: it is {where} {inp}, which this command "
                    "reads; choose another output path."
                )
        for other_what, other in seen.items():
            if same_or_inside(path, other):
                raise ValueError(f"{what} and {other_what} are the same file {path}; give each its own name.")
        check_writable_target(path)
        if path.exists() and not overwrite:
            raise FileExistsError(f"{what} {path} already exists; {overwrite_hint}, or choose another name.")
        seen[what] = path


def check_not_own_source(ds, path) -> None:
    """Refuse to write a lazy dataset over the file it still reads its data from.

    Parameters
    ----------
    ds : xarray.Dataset
        Dataset about to be saved; ``ds.encoding["source"]`` is where it was opened from.
    path : str or os.PathLike
        Target file.

    Raises
    ------
    ValueError
        If ``path`` is that source and some variable is still lazy (dask-backed), so its
        data would be read from the file while it is being replaced.
    """
    source = ds.encoding.get("source")
    if not source or not os.path.exists(source) or not same_or_inside(path, source):
        return
    if any(v.chunks is not None for v in ds.variables.values()):
        raise ValueError(
            f"refusing to write {path}: it is the file this lazy dataset still reads its data "
            "from, so replacing it would corrupt the data being written. Load the data first "
            "(ds = ds.load()) or write to another file."
        )
