"""Write files atomically: a temporary file in the target's directory, then ``os.replace``.

Readers never see a half-written file, a failed write leaves neither a partial file nor
the temporary one, and an existing file is replaced only once the new one is complete.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable


def target_directory(path: Path) -> Path:
    """The directory of ``path``; refuse, with the fix, one that does not exist."""
    directory = path.parent if str(path.parent) else Path(".")
    if not directory.is_dir():
        raise FileNotFoundError(
            f"cannot write {path}: directory {directory} does not exist; create it first "
            f"(os.makedirs)."
        )
    return directory


def atomic_write(path, write: Callable[[str], None]) -> Path:
    """Call ``write(temporary_path)``, make the bytes durable, then move them onto ``path``.

    Parameters
    ----------
    path : str or os.PathLike
        Destination file; its directory must exist.
    write : callable
        Writes the complete file to the temporary path it is given.

    Returns
    -------
    pathlib.Path
        ``path``.
    """
    path = Path(path)
    directory = target_directory(path)
    # same directory as the target: os.replace is atomic only within one file system
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        # mkstemp creates the file 0600; give it the mode a plain open() would have
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.remove(tmp)
        raise
    return path
