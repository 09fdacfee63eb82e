"""Write files atomically: a temporary file in the target's directory, then ``os.replace``
(or, with ``overwrite=False``, a hard link that never replaces an existing file).

Readers never see a half-written file, a failed write leaves neither a partial file nor
the temporary one, and an existing file is replaced only once the new one is complete.

A process killed mid-write (SIGKILL, power loss) cannot remove its temporary file.  The
temporary is named ``.NAME.HOST-PID.XXXXXXXX.tmp`` (hidden, next to ``NAME``, tagged with
a hash of the host name and the writing process id), and a later write of the same
``NAME`` removes the temporaries of ``NAME`` written on this host by a process that no
longer runs.  Temporaries from other hosts (a shared file system) or without a tag (older
versions) are removed once they are an hour old.  Temporaries of a live writer are never
touched.

Finding them costs a listing of the directory, which for a sweep writing thousands of
parts into one directory would make every write O(files) (19 ms per write among 20 000
files).  So each process lists a directory on its first write there and again after as
many writes as the directory had entries (at least :data:`RESCAN_WRITES`): O(1) per
write on average.  A write removes the stale temporaries of its ``NAME`` that the last
listing saw: those left before the process's first write into the directory are removed
by the next write of ``NAME``; those left later (a writer killed while this process
runs) by a write of ``NAME`` after the next listing.
"""

from __future__ import annotations

import os
import re
import socket
import tempfile
import threading
import time
import zlib
from pathlib import Path
from typing import Callable

#: Untagged temporaries (no process id in the name) count as stale after this many seconds.
UNTAGGED_STALE_SECONDS = 3600.0
#: A directory is listed again for temporaries after this many writes at least (see the notes).
RESCAN_WRITES = 64


def target_directory(path: Path) -> Path:
    """The directory of ``path``; refuse, with the fix, one that does not exist."""
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise FileNotFoundError(
            f"cannot write {path}: directory {directory} does not exist; create it first "
            f"(os.makedirs)."
        )
    return directory


def check_writable_target(path) -> Path:
    """Refuse, naming ``path``, a target that is a directory or lies in an unwritable one.

    Parameters
    ----------
    path : str or os.PathLike
        File about to be written.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    if path.is_dir():
        raise IsADirectoryError(
            f"cannot write {path}: it is a directory; give a file name, e.g. {path / 'result.nc'}."
        )
    directory = target_directory(path)
    if not os.access(directory, os.W_OK | os.X_OK):
        raise PermissionError(
            f"cannot write {path}: directory {directory} is not writable; choose another place "
            "or change its permissions."
        )
    return path


def _host_tag() -> str:
    return f"{zlib.crc32(socket.gethostname().encode()):08x}"


def temporary_prefix(path) -> str:
    """``.NAME.HOST-PID.``: how this process's temporaries of ``path`` begin."""
    return f".{Path(path).name}.{_host_tag()}-{os.getpid()}."


def _process_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # alive, owned by someone else
        return True
    return True


def stale_temporaries(path) -> list[Path]:
    """Temporaries of ``path`` left by writers that died (see the module notes).

    Parameters
    ----------
    path : str or os.PathLike
        Target file.

    Returns
    -------
    list of pathlib.Path
        Stale temporary files next to ``path`` (the directory is listed now).
    """
    path = Path(path)
    directory = path.parent if str(path.parent) else Path(".")
    try:
        names = [entry.name for entry in os.scandir(directory)]
    except OSError:
        return []
    return _stale_among(path, directory, names)


def _stale_among(path: Path, directory: Path, names) -> list[Path]:
    """Of the file ``names`` in ``directory``, the stale temporaries of ``path``."""
    tagged = re.compile(rf"^\.{re.escape(path.name)}\.([0-9a-f]{{8}})-(\d+)\.[A-Za-z0-9_]+\.tmp$")
    untagged = re.compile(rf"^\.{re.escape(path.name)}\.[A-Za-z0-9_]+\.tmp$")
    stale = []
    now, host = time.time(), _host_tag()
    for name in names:
        match = tagged.match(name)
        if match and match.group(1) == host:
            if not _process_alive(int(match.group(2))):
                stale.append(directory / name)
        elif match or untagged.match(name):
            try:
                if now - os.stat(directory / name).st_mtime > UNTAGGED_STALE_SECONDS:
                    stale.append(directory / name)
            except OSError:
                pass
    return stale


#: Per directory written by this process: the temporaries its last listing saw, the writes
#: since, and after how many writes it is listed again.
_LISTINGS: dict = {}
_LISTINGS_LOCK = threading.Lock()


def _listed_temporaries(directory: Path) -> set:
    """Names of the hidden ``*.tmp`` files of ``directory``, listed again when due (module notes)."""
    key = os.path.abspath(directory)
    with _LISTINGS_LOCK:
        state = _LISTINGS.get(key)
        if state is not None and state["writes"] < state["every"]:
            state["writes"] += 1
            return set(state["temporaries"])
    try:
        names = [entry.name for entry in os.scandir(directory)]
    except OSError:
        names = []
    temporaries = {n for n in names if n.startswith(".") and n.endswith(".tmp")}
    with _LISTINGS_LOCK:
        _LISTINGS[key] = {"temporaries": temporaries, "writes": 1,
                          "every": max(RESCAN_WRITES, len(names))}
    return set(temporaries)


def _forget_temporaries(directory: Path, paths) -> None:
    with _LISTINGS_LOCK:
        state = _LISTINGS.get(os.path.abspath(directory))
        if state is not None:
            state["temporaries"].difference_update(p.name for p in paths)


def atomic_write(path, write: Callable[[str], None], *, overwrite: bool = True) -> Path:
    """Call ``write(temporary_path)``, make the bytes durable, then move them onto ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file; its directory must exist.
    write : callable
        Writes the complete file to the temporary path it is given.
    overwrite : bool, optional
        Replace an existing ``path`` (default True).  With False the complete file is put
        in place by a hard link, which the file system refuses atomically if ``path``
        exists by then (a file another process wrote meanwhile is never replaced): that
        raises ``FileExistsError`` and leaves nothing behind.  Where hard links are not
        supported, it falls back to checking for ``path`` just before the rename.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = check_writable_target(path)
    directory = target_directory(path)
    stale = _stale_among(path, directory, _listed_temporaries(directory))
    for old in stale:
        try:
            old.unlink()
        except OSError:  # another writer cleaned it first, or it is not ours to delete
            pass
    _forget_temporaries(directory, stale)
    # same directory as the target: os.replace is atomic only within one file system
    try:
        fd, tmp = tempfile.mkstemp(dir=directory, prefix=temporary_prefix(path), suffix=".tmp")
    except OSError as err:
        raise type(err)(err.errno, f"cannot write {path}: {err.strerror} in directory "
                                   f"{directory}; choose another place") from err
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp creates the file 0600; give it the mode a plain open() would have
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        if overwrite:
            os.replace(tmp, path)
        else:
            _place_new(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return path


def _place_new(tmp: str, path: Path) -> None:
    """Move the complete ``tmp`` to ``path`` only if ``path`` does not exist (atomically
    where hard links work: ``link`` fails on an existing name, ``rename`` would replace it)."""
    try:
        os.link(tmp, path)
        exists = False
    except FileExistsError:
        exists = True
    except OSError:  # no hard links on this file system: check, then rename (a small race)
        exists = os.path.lexists(path)
        if not exists:
            os.replace(tmp, path)
            return
    if exists:
        raise FileExistsError(
            f"cannot write {path}: the file exists (another process wrote it while this one "
            "was writing); nothing was replaced: choose another name or write again.")
    os.remove(tmp)
