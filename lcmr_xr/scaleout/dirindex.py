"""The header index of a directory archive: what opening needs of each file, in one place.

Opening a directory archive reads every file's header (:mod:`lcmr_xr.scaleout.directory`,
about 4.6 ms a file, HDF5's own cost).  The library's writers of a directory archive
(:func:`lcmr_xr.scaleout.save_archive` with ``layout="files"``,
:func:`lcmr_xr.scaleout.append_to_archive` into a directory,
:func:`lcmr_xr.scaleout.index_archive`) therefore also keep an index of, per experiment
file, its name, size, modification and change times (ns) and inode, its archive order,
and a *summary*: the facts of its header that the open uses (file attributes, scalar
coordinates, shape, digests of its structure and of its variables' attributes), as JSON
with tags for the Python and numpy types that plain JSON would lose.

The index has two parts:

base (:data:`INDEX_NAME`)
    A small NetCDF-4 file listing the files, replaced atomically by a *compaction*
    (:func:`lcmr_xr.scaleout.index_archive`, and a writer when the journal has grown).
journal (:data:`JOURNAL_NAME`)
    A hidden directory of small JSON files, one per write (an append adds one file of one
    entry, written atomically), so that a write costs the same whatever the archive
    holds.  A compaction folds the journal files it read into a new base and then
    removes them; one holding more than :func:`compaction_due` allows triggers one.  It
    never removes a journal file it could not read: one of a newer version is left as
    it is (named in the base's :data:`KEPT_ATTR`: it does not count towards the next
    compaction), a damaged one set aside (:func:`set_aside`, renamed
    ``NAME.json.unreadable``: no longer a journal file).

Opening lists and stats the files; a file whose name, size, times and inode match an
entry (of the journal or of the base) takes its summary from it, any other file (added by
another tool, rewritten, or every file when there is no index) has its header read.  An
entry is also not trusted when its file's times are not older than the base or journal
file that holds it (git's "racy" rule).  Waiting out the tick of a file's times before
writing the index is not enough: a change of the file after its header was read, in the
same tick of coarse file times (4 ms on older Linux kernels, 1-2 s on some file systems),
leaves its size, times and inode as they were.  So the writers vouch only for entries no
later change can hide (:func:`_written_after`): a compaction reads the header of a file
changed in the tick of its read again once that tick is over (:func:`wait_past`), an
append renames its file into place only after the tick of its write, and an entry
without that guarantee (the clock did not pass in time; a write of several files then does
not wait again for its later ones) is written "racy" (not trusted).
The journal is read before the base, so that a compaction running meanwhile costs at
most header reads, never a wrong summary.  An index that cannot be read, or of another
version, and a journal file that cannot be read or holds summaries of another version
are ignored with a warning.  Opening never writes.

Versions: a base (or journal file) of a newer version than :data:`VERSION` is never
rewritten or removed by this library (it would drop what it cannot read): its writers
warn, naming the version and the remedy (upgrade lcmr_xr, or delete the base to let this
version rebuild it), add their journal files and take the next order from the base's
``order`` column (or from the files); :func:`lcmr_xr.scaleout.index_archive` refuses.
One of an older version is rewritten.

Concurrent writers: each write adds its own journal file, so two processes appending at
once keep each other's entries, and holds the directory's write lock (:func:`write_lock`,
an exclusive ``flock`` on the archive directory) from reading the next archive order to
writing its journal file, so that two never take the same order (nor the same label and
file name, appending without labels).  A compaction holds an exclusive ``flock`` on the
journal directory (a writer that finds it held leaves the compaction to the holder);
where locks are not available (some network file systems) two writers at once may take
one order (their files then ordered by name; two appends without labels then one label:
an append never replaces a file, so the later one fails with ``FileExistsError``, and
appending it again gives it the next label), and two compactions at once may drop
entries of files that then are read from their headers at open (correct, only slower)
until the next compaction.
"""

from __future__ import annotations

import contextlib
import hashlib
import itertools
import json
import os
import threading
import time
import warnings
from pathlib import Path

import numpy as np

from lcmr_xr import conventions as cv
from lcmr_xr.io._guards import NETCDF_SUFFIXES

# The functions below serve lcmr_xr.scaleout.archive (the public API: index_archive,
# open_archive, save_archive); only this is public.
__all__ = ["Unindexable"]

#: Name of the index file in an archive directory (hidden; never an experiment file: :func:`plain_name`).
INDEX_NAME = cv.ARCHIVE_INDEX_FILE
#: Name of the journal directory next to it (hidden; its files are ``*.json``).
JOURNAL_NAME = cv.ARCHIVE_INDEX_JOURNAL
#: Key and version of a journal file (a file of another version is ignored with a warning).
JOURNAL_KEY, JOURNAL_VERSION = "lcmr_archive_index_journal", 1
#: The summary version (:data:`VERSION`, key :data:`INDEX_ATTR`) of a journal file that
#: does not say (written before journal files said it: session 9's first version).
JOURNAL_UNVERSIONED = 3
#: A compaction is due when the journal holds this many files, or a sixteenth of the base's
#: entries if that is more (an open reads every journal file; a compaction rewrites the base).
JOURNAL_FILES = 128
#: A write of this many files or more compacts at once (the base takes them in one go).
BULK_ROWS = 64
#: Base attribute: JSON list of the journal files that the compaction which wrote the base
#: listed and left (of a newer version, or unreadable for a reason of the file system):
#: they do not count towards the next compaction (:func:`journal_count`).
KEPT_ATTR = "lcmr_archive_index_journal_kept"
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


class Index(dict):
    """``{file name: [entry, ...]}`` of a directory's index, newest entry first.

    An entry is ``(stamp, summary text, written, order)``: ``written`` is the modification
    time (ns) of the base or journal file that holds it (the "racy" rule), ``order`` the
    file's archive order (None: unknown, in a base written before the order was kept;
    -1: the file has none).  ``base`` is whether a base of this version was read,
    ``base_rows`` its number of entries and ``ordered`` whether it keeps the orders.
    """

    base = False
    base_rows = 0
    ordered = False


def read_index(directory: Path, warn: bool = True, journal: list[str] | None = None,
               report: dict | None = None) -> Index | None:
    """The index of a directory: its journal files, then its base; None without either.

    An unreadable base, one of another version, and an unreadable journal file also warn
    if ``warn`` (a writer, which replaces them, does not).  ``journal``: the journal
    files to read (default: every one listed now).  ``report``: a dict that gets the
    journal files whose entries were read or are superseded (``"folded"``: a compaction
    may remove them) and those that are damaged (``"damaged"``: it sets them aside);
    the others (gone, of a newer version, unreadable now) are in neither.
    """
    directory = Path(directory)
    index = Index()
    found = False
    folded, damaged = [], []
    for name in (journal_files(directory) if journal is None else journal):
        rows, status = _read_journal(directory / JOURNAL_NAME / name, warn)
        if status in ("read", "older"):
            folded.append(name)
        elif status == "damaged":
            damaged.append(name)
        if rows is None:
            continue
        found = True
        for row in rows:
            index.setdefault(row[0], []).append(row[1:])
    for entries in index.values():  # the newest journal file first
        entries.sort(key=lambda e: e[2], reverse=True)  # (stamp, text, written, order)
    if report is not None:
        report.update(folded=folded, damaged=damaged)
    base = _read_base(directory, warn)
    if base is not None:
        found = True
        index.base, index.base_rows, index.ordered = True, len(base), base.ordered
        for name, entry in base:
            index.setdefault(name, []).append(entry)
    return index if found else None


class _Rows(list):
    ordered = False


def _read_base(directory: Path, warn: bool) -> _Rows | None:
    """``[(name, (stamp, text, written, order))]`` of the base, or None (none, or ignored)."""
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
                if newer(version):
                    _ignored(path, f"version {version!r}, written by a newer lcmr_xr; this library "
                                   f"reads version {VERSION}", warn, _UPGRADE)
                else:
                    _ignored(path, f"version {version!r}, this library reads version {VERSION}", warn)
                return None
            names = f["name"].asstr()[()]
            texts = f["summary"].asstr()[()]
            columns = [_integers(f[c][()], c).tolist() for c in _COLUMNS]
            # kept since session 9
            orders = _integers(f["order"][()], "order").tolist() if "order" in f else None
    except (OSError, KeyError, ValueError, TypeError) as err:
        _ignored(path, f"unreadable: {err}", warn)
        return None
    if not all(len(c) == len(names) for c in [texts, *columns, *([orders] if orders else [])]):
        _ignored(path, "columns of different lengths", warn)
        return None
    written = st.st_mtime_ns
    rows = _Rows((name, (stamp, text, written, order)) for name, stamp, text, order in zip(
        names.tolist(), zip(*columns), texts.tolist(), orders or [None] * len(names)))
    rows.ordered = orders is not None
    return rows


def _integers(values, column: str) -> np.ndarray:
    """A column of the base that must hold integers (stamps, orders); another tool's
    floats or text make the base unreadable (ignored, then rebuilt by the next write)."""
    values = np.asarray(values)
    if values.dtype.kind not in "iu":
        raise TypeError(f"column {column!r} holds {values.dtype}, not integers")
    return values


class BaseFacts:
    """What a writer needs of the base (see :func:`base_facts`)."""

    def __init__(self, base=False, ordered=False, base_rows=0, top=None, first=None, newer=None,
                 kept=frozenset()):
        self.base, self.ordered, self.base_rows, self.top = base, ordered, base_rows, top
        self.first, self.newer, self.kept = first, newer, kept


def newer(version) -> bool:
    """Whether ``version`` (of a base or of a journal file's summaries) is an integer
    version above this library's: written by a newer lcmr_xr, which this one never rewrites
    or removes (it would drop what it cannot read)."""
    return (isinstance(version, (int, np.integer)) and not isinstance(version, (bool, np.bool_))
            and version > VERSION)


def base_version(directory: Path):
    """The version attribute of the directory's base (None: no base, or unreadable)."""
    import h5py

    try:
        with h5py.File(Path(directory) / INDEX_NAME, "r") as f:
            version = f.attrs.get(INDEX_ATTR)
            return None if version is None else np.asarray(version).item()
    except (OSError, ValueError, TypeError):
        return None


def newer_message(path: Path, version, what: str) -> str:
    """Why a base of a newer version is not rewritten (``what``), and the remedies."""
    return (f"archive index {path} is of version {version}, written by a newer lcmr_xr (this one "
            f"writes version {VERSION}); {what}. Upgrade lcmr_xr to keep it current, or delete "
            f"{path} to let this version rebuild it (lcmr_xr.scaleout.index_archive).")


def base_facts(directory: Path) -> BaseFacts:
    """Whether the directory has a base of this version (``base``), whether it keeps the
    orders (``ordered``), its number of entries (``base_rows``) and the largest order it
    lists (``top``, None: none), the name of its first entry (``first``: the first file
    by name when it was written): its attributes, its ``order`` column and one name, not
    the entries (which a writer does not need)."""
    path = Path(directory) / INDEX_NAME
    if not path.exists():
        return BaseFacts()
    import h5py

    try:
        with h5py.File(path, "r") as f:
            version = f.attrs.get(INDEX_ATTR)
            version = None if version is None else np.asarray(version).item()
            if newer(version):  # never rewritten here; its order column, if it keeps one
                return _newer_facts(f, version)
            if version != VERSION:
                return BaseFacts()
            rows = f["name"].shape[0]
            if any(f[c].dtype.kind not in "iu" for c in _COLUMNS):  # the open ignores it
                return BaseFacts()
            if "order" not in f:
                return BaseFacts(True, False, rows)
            orders = _integers(f["order"][()], "order")
            first = f["name"].asstr()[0] if rows else None
            kept = _kept(f.attrs.get(KEPT_ATTR))
    except (OSError, KeyError, ValueError, TypeError):
        return BaseFacts()
    if first is not None and not plain_name(first):  # never a file outside the directory
        first = None
    top = int(orders.max()) if orders.size and orders.max() >= 0 else None
    return BaseFacts(True, True, rows, top, first, kept=kept)


def _kept(value) -> frozenset:
    """The journal file names of a base's :data:`KEPT_ATTR` (none when absent or malformed:
    they then count, as before the attribute was written)."""
    if isinstance(value, bytes):
        value = value.decode("utf-8", "replace")
    try:
        names = json.loads(value) if isinstance(value, str) else []
    except ValueError:
        return frozenset()
    return frozenset(n for n in names if type(n) is str) if type(names) is list else frozenset()


def journal_count(journal: list[str], facts: BaseFacts) -> int:
    """How many of the journal files ``journal`` a compaction would fold in: those that the
    compaction which wrote the base left (``facts.kept``: of a newer version) do not count,
    or with more than :data:`JOURNAL_FILES` of them every write would compact."""
    return len(journal) - len(facts.kept.intersection(journal)) if facts.kept else len(journal)


def _newer_facts(f, version) -> BaseFacts:
    """:class:`BaseFacts` of a base of a newer version (open h5py file ``f``): its largest
    ``order`` and first name where it keeps them as this version does (``ordered``),
    else none (the writer then takes the orders from the files)."""
    facts = BaseFacts(newer=version)
    try:
        orders = _integers(f["order"][()], "order")
        names = f["name"]
        first = names.asstr()[0] if names.shape[0] else None
    except (KeyError, ValueError, TypeError, OSError):
        return facts
    facts.ordered = orders.shape == names.shape
    if facts.ordered:
        facts.top = int(orders.max()) if orders.size and orders.max() >= 0 else None
        facts.first = first if first is not None and plain_name(first) else None
    return facts


def plain_name(name: str) -> bool:
    """Whether ``name`` can be an experiment file of the directory: a visible NetCDF name
    (ending in ``.nc``, ``.nc4`` or ``.netcdf``, any case: the names :func:`lcmr_xr.io.save`
    writes NetCDF-4 to, :data:`lcmr_xr.io._guards.NETCDF_SUFFIXES`; for a name that does not
    begin with a dot, ``endswith`` answers as the ``Path.suffix`` that save's check reads,
    at a fifth of the cost) without a directory part (an index never makes a writer open
    ``../x.nc`` or ``/x.nc``).  Hidden names (the index, its journal, the temporaries
    ``.NAME.*.tmp`` of atomic writes, a sweep's ``.OUTPUT.parts``) never are.  The one rule
    of what a directory archive holds: its listing, its index and its writers."""
    return (not name.startswith(".") and name.lower().endswith(NETCDF_SUFFIXES) and "/" not in name
            and os.sep not in name and (os.altsep is None or os.altsep not in name))


#: Every spelling of :data:`lcmr_xr.io._guards.NETCDF_SUFFIXES` in any mix of case (``.nc``,
#: ``.nC``, ``.Nc``, ``.NC``, ..., ``.NetCDF``, ...: 72 in all), for :func:`plain_names`.
_SUFFIX_SPELLINGS = tuple(dict.fromkeys(
    "".join(chars) for suffix in NETCDF_SUFFIXES
    for chars in itertools.product(*(sorted({c.lower(), c.upper()}) for c in suffix))))


def plain_names(stem: str) -> list[str]:
    """Every name of the directory's rule (:func:`plain_name`) that is ``stem`` and a NetCDF
    ending, in any case: ``run5`` gives ``run5.nc``, ``run5.NC``, ``run5.nc4``,
    ``run5.NetCDF``, ... (72 names; none for a hidden ``stem`` or one with a directory
    part).  A writer about to add ``STEM.nc`` looks these up (a ``stat`` each, 0.3 ms in
    all; no listing of the directory, whatever it holds): a file under one of them is read
    by the directory's open as an experiment of that name, a second file beside it."""
    return [name for name in (stem + suffix for suffix in _SUFFIX_SPELLINGS) if plain_name(name)]


_REBUILD = ("Rebuild it with lcmr_xr.scaleout.index_archive(directory) or "
            "`lcmr-xr archive index DIR`.")
_UPGRADE = "Upgrade lcmr_xr to use it (this version leaves it as it is)."


def _ignored(path: Path, why: str, warn: bool, remedy: str = _REBUILD) -> None:
    if warn:
        warnings.warn(f"archive index {path} ignored ({why}); the files' headers are read "
                      f"instead (slower). {remedy}", RuntimeWarning, stacklevel=6)


def trusted(index: Index | None, name: str, st: os.stat_result):
    """``(summary text, order)`` of the newest entry of file ``name`` that matches ``st``
    (name, size, times, inode; not "racy"), else None."""
    if index is None:
        return None
    now = stamp(st)
    for stored, text, written, order in index.get(name, ()):
        if stored == now and max(stored[1], stored[2]) < written:
            return text, order
    return None


# ------------------------------------------------------------------ writing
#: Longest wait (s) for the file system's clock to pass a file's time (a tick of coarse
#: file times; where it does not pass in time the entry is written "racy": not trusted).
TICK_WAIT = 0.05


def fs_clock(directory: Path) -> int:
    """The file system's clock now (ns), as the modification time a write gets: the
    journal directory's, touched (its own time is not used)."""
    journal = Path(directory) / JOURNAL_NAME
    journal.mkdir(exist_ok=True)
    os.utime(journal)
    return os.stat(journal).st_mtime_ns


def wait_past(directory: Path, ns: int) -> bool:
    """Wait until the file system's clock (:func:`fs_clock`) is past ``ns``, at most
    :data:`TICK_WAIT`; whether it is."""
    deadline = time.monotonic() + TICK_WAIT
    try:
        while fs_clock(directory) <= ns:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.001)
    except OSError:  # no clock to read here: unsettled
        return False
    return True


def _written_after(tmp: str, rows, unsettled=()) -> None:
    """Give the index file ``tmp`` the modification time that the "racy" rule reads
    right (:func:`trusted`: an entry counts only if its file's times are older).

    A writer hands in only entries that no later change of their file can leave
    unseen: a header read after the tick of its file's last change ended (the file's
    times then change with any later change), or a file it wrote, renamed into place
    after the tick of its write ended.  For those the index file's time is put past
    every stamp (the renames may have fallen in its tick: waited out, at most
    :data:`TICK_WAIT`; what is still "racy" is only not trusted).  The entries of the
    files named in ``unsettled`` (no such guarantee: the clock did not pass their tick
    in time) must not be trusted: the time is set back to their oldest stamp instead.
    Waiting out the tick alone does not make an entry safe: a change in that tick,
    after the header was read, leaves the file's stamp as it was.
    """
    hot = [max(r[1][1], r[1][2]) for r in rows if r[0] in unsettled]
    if hot:
        oldest = min(hot)
        if os.stat(tmp).st_mtime_ns > oldest:
            os.utime(tmp, ns=(oldest, oldest))
        return
    newest = max((max(r[1][1], r[1][2]) for r in rows), default=None)
    if newest is None:
        return
    deadline = time.monotonic() + TICK_WAIT
    while os.stat(tmp).st_mtime_ns <= newest and time.monotonic() < deadline:
        time.sleep(0.001)
        os.utime(tmp)


def write_index(directory: Path, rows: list[tuple[str, tuple, str, int]], unsettled=(),
                kept=()) -> Path:
    """Write the base of the index of ``directory`` atomically from
    ``[(name, stamp, summary text, order)]`` (order -1: the file has none; ``unsettled``:
    the names whose entries must not be trusted, see :func:`_written_after`; ``kept``: the
    journal files the compaction leaves, :data:`KEPT_ATTR`)."""
    import h5netcdf
    import h5py

    from lcmr_xr.io._atomic import atomic_write

    rows = [r for r in rows if r[2] is not None]
    text = h5py.string_dtype("utf-8")

    def write(tmp):
        with h5netcdf.File(tmp, "w") as f:
            f.attrs[INDEX_ATTR] = np.int64(VERSION)
            if kept:
                f.attrs[KEPT_ATTR] = json.dumps(sorted(kept))
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
            var = f.create_variable("order", ("file",), dtype=np.int64)
            var.attrs["long_name"] = "the file's lcmr_archive_index attribute (-1: none)"
            if rows:
                var[:] = np.array([r[3] for r in rows], dtype=np.int64)
        _written_after(tmp, rows, unsettled)

    return atomic_write(Path(directory) / INDEX_NAME, write)


def journal_files(directory: Path) -> list[str]:
    """Names of the journal files of ``directory`` (not the temporaries of their writes)."""
    try:
        names = os.listdir(Path(directory) / JOURNAL_NAME)
    except OSError:
        return []
    return sorted(n for n in names if n.endswith(".json") and not n.startswith("."))


def journal_max_order(names: list[str]) -> int | None:
    """The largest order among the journal files ``names`` (each name begins with its own)."""
    orders = []
    for name in names:
        head = name.split("-", 1)[0]
        if head.isdigit():
            orders.append(int(head))
    return max(orders) if orders else None


def append_journal(directory: Path, rows: list[tuple[str, tuple, str, int]],
                   unsettled=()) -> Path | None:
    """Add one journal file (atomically) holding the entries ``[(name, stamp, summary text,
    order)]``; its name begins with the largest order (so that a writer finds the next
    order from the names alone).  ``unsettled``: see :func:`_written_after`."""
    from lcmr_xr.io._atomic import atomic_write

    rows = [r for r in rows if r[2] is not None]
    if not rows:
        return None
    journal = Path(directory) / JOURNAL_NAME
    journal.mkdir(exist_ok=True)
    top = max(max(r[3] for r in rows), 0)
    name = f"{top:012d}-{os.getpid()}-{os.urandom(6).hex()}.json"
    data = {JOURNAL_KEY: JOURNAL_VERSION, INDEX_ATTR: VERSION,
            "rows": [[r[0], list(r[1]), int(r[3]), r[2]] for r in rows]}

    def write(tmp):
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(data, fh, separators=(",", ":"))
        _written_after(tmp, rows, unsettled)

    return atomic_write(journal / name, write)


def _read_journal(path: Path, warn: bool):
    """``(rows, status)`` of one journal file: ``rows`` ``[(name, stamp, text, written,
    order)]`` or None, ``status`` what a compaction may do with the file: ``"read"`` and
    ``"older"`` (summaries of an older version: superseded) it removes, ``"damaged"``
    (not JSON, or not a journal file) it sets aside, ``"gone"`` (a compaction folded it
    into the base), ``"newer"`` (a newer lcmr_xr's) and ``"unavailable"`` (an error of
    the file system, e.g. no permission) it leaves.  Unreadable files warn if ``warn``."""
    try:
        with open(path, "rb") as fh:
            written = os.fstat(fh.fileno()).st_mtime_ns
            data = json.loads(fh.read())
    except FileNotFoundError:
        return None, "gone"
    except OSError as err:
        _ignored(path, f"unreadable: {err}", warn)
        return None, "unavailable"
    except (ValueError, RecursionError) as err:  # RecursionError: nested too deep
        _ignored(path, f"unreadable: {err}", warn)
        return None, "damaged"
    try:
        form = data.get(JOURNAL_KEY)
        if form != JOURNAL_VERSION:
            later = type(form) is int and form > JOURNAL_VERSION
            _ignored(path, f"version {form!r}{', written by a newer lcmr_xr' if later else ''}, "
                           f"this library reads version {JOURNAL_VERSION}", warn,
                     _UPGRADE if later else _REBUILD)
            return None, "newer" if later else "damaged"
        summaries = data.get(INDEX_ATTR, JOURNAL_UNVERSIONED)
        if summaries != VERSION:  # what the summaries hold changed: not this library's
            later = newer(summaries)
            _ignored(path, f"summaries of version {summaries!r}"
                           f"{', written by a newer lcmr_xr' if later else ''}, this library reads "
                           f"version {VERSION}", warn, _UPGRADE if later else _REBUILD)
            return None, ("newer" if later else "older" if type(summaries) is int else "damaged")
        return [(str(name), tuple(int(v) for v in st), str(text), written, int(order))
                for name, st, order, text in data["rows"]], "read"
    except (AttributeError, KeyError, ValueError, TypeError) as err:
        _ignored(path, f"malformed: {err!r}", warn)
        return None, "damaged"


def remove_journal(directory: Path, names: list[str]) -> None:
    """Remove the journal files ``names`` (after a compaction folded them into the base)."""
    journal = Path(directory) / JOURNAL_NAME
    for name in names:
        try:
            os.unlink(journal / name)
        except FileNotFoundError:
            pass


#: Suffix of a damaged journal file set aside by a compaction (kept, never read again).
DAMAGED_SUFFIX = cv.ARCHIVE_INDEX_DAMAGED_SUFFIX


def set_aside(directory: Path, names: list[str]) -> None:
    """Rename the damaged journal files ``names`` to ``NAME.unreadable`` (no ``.json``: no
    reader takes them again; their bytes are kept), with a warning naming them.  Their
    files' entries come from the files' headers (read by the compaction)."""
    journal = Path(directory) / JOURNAL_NAME
    for name in names:
        try:
            os.replace(journal / name, journal / (name + DAMAGED_SUFFIX))
        except FileNotFoundError:
            continue
        warnings.warn(f"archive index journal file {journal / name} is unreadable (damaged); set "
                      f"aside as {journal / (name + DAMAGED_SUFFIX)} (kept, no longer read: the "
                      "entries of its files were taken from their headers). Delete it once "
                      "inspected.", RuntimeWarning, stacklevel=4)


def compaction_due(index: Index | BaseFacts | None, journal: int, new_rows: int) -> bool:
    """Whether a write that added ``new_rows`` entries, with ``journal`` journal files now
    (that a compaction would fold in: :func:`journal_count`), compacts: no base of this
    version, a base without the orders, a bulk write, or a journal grown past
    :data:`JOURNAL_FILES` (or a sixteenth of the base's entries)."""
    if getattr(index, "newer", None) is not None:  # never rewritten by this version
        return False
    if index is None or not index.base or not index.ordered:
        return True
    return new_rows >= BULK_ROWS or journal > max(JOURNAL_FILES, index.base_rows // 16)


_held = threading.local()  # {(st_dev, st_ino) of a directory: depth} of this thread's write locks
#: {descriptor: owning pid} of the lock descriptors (write and compaction locks) this process
#: holds open; a child forked meanwhile closes its inherited copies (:func:`_forget_locks`).
_lock_fds: dict[int, int] = {}
#: Held while a lock descriptor is opened and registered, or unregistered and closed, and
#: across ``fork``: a fork between ``os.open`` and the registration left the child an
#: unregistered copy, which :func:`_forget_locks` did not close, so the child kept the
#: parent's lock alive after the parent released it (a ``flock`` lasts until the last copy
#: of its open file closes).
_lock_fds_guard = threading.Lock()


def _forget_locks() -> None:
    """In a child just forked (``os.register_at_fork``): close the inherited copies of the
    parent's lock descriptors and forget the locks held.  The child did not take them: it
    must wait for them like any other process (with the held-state copied, it took the
    re-entrant path and wrote at the same time as its siblings), and an inherited copy
    left open would keep a lock alive after the parent released it.  The parent's own
    descriptors keep holding its locks (a ``flock`` lasts until the last copy closes)."""
    for fd in list(_lock_fds):
        try:
            os.close(fd)
        except OSError:
            pass
    _lock_fds.clear()
    _held.__dict__.pop("depths", None)  # the forking thread's, the only one in the child


def _forget_locks_in_child() -> None:
    _lock_fds_guard.release()  # taken by the forking thread before the fork
    _forget_locks()


if hasattr(os, "register_at_fork"):
    os.register_at_fork(before=_lock_fds_guard.acquire, after_in_parent=_lock_fds_guard.release,
                        after_in_child=_forget_locks_in_child)


def _release(fd: int | None) -> None:
    """Close a lock descriptor this process opened (releases the lock); nothing in a
    forked child, which closed its inherited copy already (the number may be reused)."""
    if fd is None:
        return
    with _lock_fds_guard:  # no fork between the two: the child would inherit an unlisted copy
        if _lock_fds.get(fd) == os.getpid():
            del _lock_fds[fd]
            os.close(fd)


@contextlib.contextmanager
def write_lock(directory: Path):
    """Hold the directory's write lock (an exclusive ``flock`` on the archive directory
    itself), waiting for it: a writer holds it from reading the next archive order (and
    whether its files exist) until its journal file lists its files, so two writers never
    take one order or replace each other's new file.  Where locks are not available it
    proceeds without one (see the module notes).

    Re-entrant within a thread: a thread that holds the lock of a directory (the same
    directory however spelled: its device and inode) and takes it again, e.g. a tool
    that calls :func:`lcmr_xr.scaleout.save_archive` inside ``write_lock``, goes on
    holding it (a second ``flock`` of the same process on another descriptor would wait
    for itself forever); the lock is released when the outermost ``with`` ends.  Other
    threads and processes wait for it as before, processes forked while it is held
    included (they do not inherit it: :func:`_forget_locks`).
    """
    try:
        st = os.stat(directory)
        key = (st.st_dev, st.st_ino)
    except OSError:
        key = None
    depths = _held.__dict__.setdefault("depths", {})
    pid = os.getpid()
    held = depths.get(key) if key is not None else None
    if held is not None and held[0] == pid:  # (pid, depth): never a parent's, after a fork
        held[1] += 1
        try:
            yield
        finally:
            held[1] -= 1
        return
    fd = _open_to_lock(Path(directory))
    if key is not None:
        depths[key] = [pid, 1]
    try:
        if fd is not None:
            try:
                import fcntl

                fcntl.flock(fd, fcntl.LOCK_EX)
            except (ImportError, OSError):  # no locks here: proceed without
                pass
        yield  # outside any except clause: the writer's errors are not chained to the lock's
    finally:
        if key is not None and depths.get(key) is not None and depths[key][0] == pid:
            depths.pop(key, None)
        _release(fd)


@contextlib.contextmanager
def compaction_lock(directory: Path, blocking: bool):
    """Hold the directory's compaction lock (an exclusive ``flock`` on its journal
    directory); yields False when ``blocking`` is False and another process holds it.
    Where locks are not available, yields True without one (see the module notes)."""
    journal = Path(directory) / JOURNAL_NAME
    try:
        journal.mkdir(exist_ok=True)
    except OSError:
        pass  # then no lock either (below)
    fd, held = _open_to_lock(journal), True
    try:
        if fd is not None:
            try:
                import fcntl

                fcntl.flock(fd, fcntl.LOCK_EX | (0 if blocking else fcntl.LOCK_NB))
            except BlockingIOError:
                held = False
            except (ImportError, OSError):  # no locks here: proceed without
                pass
        yield held  # outside any except clause (see write_lock)
    finally:
        _release(fd)


def _open_to_lock(directory: Path) -> int | None:
    """A descriptor of ``directory`` to ``flock``, or None where it cannot be opened
    (Windows, no permission): the lock is then not taken."""
    with _lock_fds_guard:  # no fork between the open and the registration (see _lock_fds_guard)
        try:
            fd = os.open(directory, os.O_RDONLY)
        except OSError:
            return None
        _lock_fds[fd] = os.getpid()
    return fd
