"""The header index of a directory archive: what opening needs of each file, in one file.

Opening a directory archive reads every file's header (:mod:`lcmr_xr.scaleout.directory`,
about 4.6 ms a file, HDF5's own cost).  The library's writers of a directory archive
(:func:`lcmr_xr.scaleout.save_archive` with ``layout="files"``,
:func:`lcmr_xr.scaleout.append_to_archive` into a directory,
:func:`lcmr_xr.scaleout.index_archive`) therefore also write :data:`INDEX_NAME`, a small
NetCDF-4 file in the directory holding, per experiment file, its name, size,
modification and change times (ns) and inode, and a *summary*: the facts of its header
that the open uses (file attributes, scalar coordinates, shape, digests of its structure
and of its variables' attributes), as JSON with tags for the Python and numpy types that
plain JSON would lose.

Opening lists and stats the files; a file whose name, size, times and inode match its
entry takes its summary from the index, any other file (added by another tool, rewritten,
or every file when there is no index) has its header read.  An entry is also not trusted
when the file was modified in the same clock tick as the index was written (git's "racy"
rule: the index cannot tell that write from a later one).  An index that cannot be read,
or of another version, is ignored with a warning.  Opening never writes.

Two processes that write into one directory at once both replace the index atomically;
the one that writes last may not list the other's new files, which then are read from
their headers at open (correct, only slower) until the next write or
:func:`lcmr_xr.scaleout.index_archive` lists them again.
"""

from __future__ import annotations

import hashlib
import json
import os
import warnings
from pathlib import Path

import numpy as np

from lcmr_xr import conventions as cv

# The functions below serve lcmr_xr.scaleout.archive (the public API: index_archive,
# open_archive, save_archive); only this is public.
__all__ = ["Unindexable"]

#: Name of the index file in an archive directory (hidden; not a ``*.nc`` experiment).
INDEX_NAME = cv.ARCHIVE_INDEX_FILE
#: File attribute marking an index, and its version (an index of another version is ignored).
INDEX_ATTR = cv.ARCHIVE_INDEX_VERSION_ATTR
#: Raise it whenever what a summary holds or how it is computed changes (digests included):
#: one open may mix summaries from the index with summaries of headers read now.
VERSION = 3
#: Whether the library reads the index (False: every header is read, as without an index;
#: ``benchmarks/scale_out.py`` compares the two).
ENABLED = True
_COLUMNS = ("size", "mtime_ns", "ctime_ns", "inode")


class Unindexable(ValueError):
    """A value that the index cannot keep exactly (its file is read from its header)."""


# ------------------------------------------------------------------ exact JSON of the values
def encode(value):
    """``value`` as JSON-able data from which :func:`decode` gives it back exactly.

    Plain JSON keeps ``str``, ``int``, ``float`` (NaN and infinities included), ``bool``
    and ``None``; lists, tuples, dicts (in order), bytes, numpy scalars and numeric
    arrays are tagged.  Anything else raises :class:`Unindexable`.
    """
    kind = type(value)
    if value is None or kind in (bool, str, int, float):
        return value
    if kind is list:
        return {"l": [encode(v) for v in value]}
    if kind is tuple:
        return {"t": [encode(v) for v in value]}
    if kind is dict:
        if not all(type(k) is str for k in value):
            raise Unindexable("dict keys that are not strings")
        return {"d": [[k, encode(v)] for k, v in value.items()]}
    if kind is bytes:
        return {"b": value.hex()}
    if isinstance(value, np.generic) and value.dtype.kind in "biuf":
        return {"g": value.dtype.str, "v": value.item()}
    if kind is np.ndarray and value.dtype.kind in "biuf":
        return {"a": value.dtype.str, "s": list(value.shape), "v": value.ravel().tolist()}
    raise Unindexable(f"a value of type {kind.__name__}")


def decode(data):
    """The value that :func:`encode` turned into ``data``."""
    if type(data) is not dict:
        return data
    if "l" in data:
        return [decode(v) for v in data["l"]]
    if "t" in data:
        return tuple(decode(v) for v in data["t"])
    if "d" in data:
        return {k: decode(v) for k, v in data["d"]}
    if "b" in data:
        return bytes.fromhex(data["b"])
    if "g" in data:
        return np.dtype(data["g"]).type(data["v"])
    if "a" in data:
        return np.array(data["v"], dtype=np.dtype(data["a"])).reshape(data["s"])
    raise ValueError(f"unknown tag in {sorted(data)}")


def _one_level(obj: dict, arrays: dict):
    """:func:`decode` of one tagged object whose contents are decoded already (a
    ``json.loads`` object hook: the C parser calls it bottom-up); equal arrays are
    decoded once into ``arrays``."""
    if "d" in obj:
        return dict(obj["d"])
    if "l" in obj:
        return obj["l"]
    if "t" in obj:
        return tuple(obj["t"])
    if "g" in obj:
        return np.dtype(obj["g"]).type(obj["v"])
    if "a" in obj:
        key = (obj["a"], tuple(obj["s"]), tuple(obj["v"]))
        try:
            return arrays[key]
        except KeyError:
            pass
        except TypeError:  # unhashable values: not shared
            key = None
        value = np.array(obj["v"], dtype=np.dtype(obj["a"])).reshape(obj["s"])
        if key is not None and len(arrays) < 4096:
            arrays[key] = value
        return value
    if "b" in obj:
        return bytes.fromhex(obj["b"])
    raise ValueError(f"unknown tag in {sorted(obj)}")


def loader():
    """A function that turns stored summary texts into summaries: ``decode(json.loads(text))``
    in one pass of the JSON parser (one parser for all the texts of one open).

    An array equal to one that the same loader decoded before is returned as that same
    object, so that combining the attributes of thousands of files compares identities
    (:class:`lcmr_xr.scaleout.directory.DropConflicts`).
    """
    arrays: dict = {}
    return json.JSONDecoder(object_hook=lambda obj: _one_level(obj, arrays)).decode


def loads(text: str):
    """``decode(json.loads(text))`` of one stored summary text (see :func:`loader`)."""
    return loader()(text)


def same(a, b) -> bool:
    """Whether ``a`` and ``b`` are equal in type (numpy dtypes included) and value (NaN = NaN)."""
    if type(a) is not type(b):
        return False
    if isinstance(a, np.ndarray):
        return (a.dtype == b.dtype and a.shape == b.shape
                and bool(np.array_equal(a, b, equal_nan=a.dtype.kind in "fc")))
    if isinstance(a, (list, tuple)):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict):
        return list(a) == list(b) and all(same(a[k], b[k]) for k in a)
    if isinstance(a, np.generic) and a.dtype != b.dtype:
        return False
    return bool(a == b) or (a != a and b != b)


def digest(value) -> str:
    """A digest of ``value`` that is the same in every process (JSON of :func:`encode`;
    ``repr`` for what it cannot encode)."""
    try:
        text = json.dumps(encode(value), separators=(",", ":"))
    except Unindexable:
        text = "repr:" + repr(value)
    return hashlib.sha1(text.encode("utf-8", "surrogatepass")).hexdigest()


def bytes_digest(values: np.ndarray) -> str:
    """A digest of an array's type, shape and values (its bytes; objects by ``repr``)."""
    values = np.asarray(values)
    data = (repr(values.tolist()).encode("utf-8", "surrogatepass") if values.dtype.hasobject
            else values.tobytes())
    return hashlib.sha1(f"{values.dtype.str}{values.shape}".encode() + data).hexdigest()


# ------------------------------------------------------------------ entries
def stamp(st: os.stat_result) -> tuple:
    """What identifies one version of a file: size, modification and change times, inode."""
    return (st.st_size, st.st_mtime_ns, st.st_ctime_ns, st.st_ino)


def summary_text(summary: dict) -> str | None:
    """``summary`` as stored in the index, or None when it cannot be stored exactly."""
    try:
        text = json.dumps(encode(summary), separators=(",", ":"))
    except (Unindexable, ValueError, TypeError):
        return None
    return text if same(decode(json.loads(text)), summary) else None


def read_index(directory: Path, warn: bool = True) -> tuple[dict, int] | None:
    """``({name: (stamp, summary text)}, index mtime_ns)`` of a directory's index, or None
    (no index; an unreadable one or one of another version also warns if ``warn``: a
    writer, which replaces it, does not)."""
    path = Path(directory) / INDEX_NAME
    try:
        st = os.stat(path)
    except OSError:
        return None
    import h5py

    try:
        with h5py.File(path, "r") as f:
            version = f.attrs.get(INDEX_ATTR)
            version = None if version is None else np.asarray(version).item()
            if version != VERSION:
                _ignored(path, f"version {version!r}, this library reads version {VERSION}", warn)
                return None
            names = f["name"].asstr()[()]
            texts = f["summary"].asstr()[()]
            columns = [f[c][()].tolist() for c in _COLUMNS]
    except (OSError, KeyError, ValueError, TypeError) as err:
        _ignored(path, f"unreadable: {err}", warn)
        return None
    if not all(len(c) == len(names) for c in [texts, *columns]):
        _ignored(path, "columns of different lengths", warn)
        return None
    entries = {str(name): (tuple(int(c[i]) for c in columns), text)
               for i, (name, text) in enumerate(zip(names.tolist(), texts.tolist()))}
    return entries, st.st_mtime_ns


def _ignored(path: Path, why: str, warn: bool) -> None:
    if warn:
        warnings.warn(f"archive index {path} ignored ({why}); the files' headers are read "
                      "instead (slower). Rebuild it with lcmr_xr.scaleout.index_archive(directory) "
                      "or `lcmr-xr archive index DIR`.", RuntimeWarning, stacklevel=5)


def trusted(entries_mtime, name: str, st: os.stat_result):
    """The stored summary text of file ``name`` if its entry matches ``st``, else None."""
    if entries_mtime is None:
        return None
    entries, index_mtime = entries_mtime
    entry = entries.get(name)
    if entry is None:
        return None
    stored, text = entry
    if stored != stamp(st) or max(stored[1], stored[2]) >= index_mtime:  # changed, or racy
        return None
    return text


def write_index(directory: Path, rows: list[tuple[str, tuple, str]]) -> Path:
    """Write the index of ``directory`` atomically from ``[(name, stamp, summary text)]``."""
    import h5netcdf
    import h5py

    from lcmr_xr.io._atomic import atomic_write

    rows = [r for r in rows if r[2] is not None]
    text = h5py.string_dtype("utf-8")

    def write(tmp):
        with h5netcdf.File(tmp, "w") as f:
            f.attrs[INDEX_ATTR] = np.int64(VERSION)
            f.attrs["title"] = ("header index of an lcmr-xr archive directory (lcmr_xr.scaleout."
                                "dirindex); safe to delete, rebuilt by the library's writers")
            f.dimensions = {"file": len(rows)}
            for name, values in (("name", [r[0] for r in rows]), ("summary", [r[2] for r in rows])):
                var = f.create_variable(name, ("file",), dtype=text)
                if rows:
                    var[:] = np.array(values, dtype=object)
            for i, column in enumerate(_COLUMNS):
                var = f.create_variable(column, ("file",), dtype=np.int64)
                if rows:
                    var[:] = np.array([r[1][i] for r in rows], dtype=np.int64)

    return atomic_write(Path(directory) / INDEX_NAME, write)
