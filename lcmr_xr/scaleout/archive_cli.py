"""``lcmr-xr archive``: consolidate a directory of per-experiment files into one archive
file, or write the header index of a directory.

    lcmr-xr archive consolidate ARCHIVE_DIR -o ARCHIVE.nc [--overwrite]
    lcmr-xr archive index ARCHIVE_DIR

The directory is left as it was; the new file is written atomically (temporary file, then
rename) and opens in a fraction of a second however many experiments it holds.  The output
is checked before anything is read: it may not lie inside the directory, and an existing
file is replaced only with ``--overwrite``.  Progress (experiments copied) is shown on
stderr, as plain lines when stderr is not a terminal.

``archive index`` writes (atomically) the hidden ``.lcmr_archive_index.nc`` of a directory
written by an older version or by other tools, from which ``open_archive`` takes the
files' header facts instead of reading every file (:mod:`lcmr_xr.scaleout.dirindex`);
the library's own writers keep it current.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from lcmr_xr._cli_support import (NETCDF_SUFFIXES, HelpFormatter, _is_terminal, add_overwrite,
                                  check_outputs, error_line)


def add_archive_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``archive`` sub-command (``archive consolidate``) to ``argparse`` sub-parsers.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        What ``ArgumentParser.add_subparsers()`` returned.

    Returns
    -------
    argparse.ArgumentParser
        The ``archive`` parser (its ``func`` default is :func:`run_archive`).

    Examples
    --------
    >>> import argparse
    >>> p = argparse.ArgumentParser(prog="lcmr-xr")
    >>> _ = add_archive_parser(p.add_subparsers(dest="command"))
    >>> args = p.parse_args(["archive", "consolidate", "runs", "-o", "runs.nc"])
    >>> args.action, str(args.directory), str(args.output), args.overwrite
    ('consolidate', 'runs', 'runs.nc', False)
    """
    arc = subparsers.add_parser(
        "archive", help="manage experiment archives (consolidate or index a directory)",
        formatter_class=HelpFormatter, description="Manage experiment archives.")
    actions = arc.add_subparsers(dest="action", required=True)
    con = actions.add_parser(
        "consolidate", help="copy a directory of per-experiment files into one archive file",
        formatter_class=HelpFormatter,
        description="Copy every experiment file of an archive directory, in archive order, into "
                    "one consolidated NetCDF archive (experiment dim, metadata as coordinates). "
                    "The directory is not changed.")
    con.add_argument("directory", type=Path, help="archive directory (one experiment per .nc, .nc4 or .netcdf file)")
    con.add_argument("-o", "--output", type=Path, required=True,
                     help="archive file to write (.nc; not inside the directory)")
    add_overwrite(con)
    idx = actions.add_parser(
        "index", help="write the header index of an archive directory (faster open_archive)",
        formatter_class=HelpFormatter,
        description="Write the hidden header index (.lcmr_archive_index.nc) of an archive "
                    "directory, so that open_archive takes each file's header facts from it "
                    "instead of reading every file. Entries that still match their files are "
                    "kept; the experiment files are not changed.")
    idx.add_argument("directory", type=Path, help="archive directory (one experiment per .nc, .nc4 or .netcdf file)")
    arc.set_defaults(func=run_archive)
    return arc


def run_archive(args) -> int:
    """Run ``lcmr-xr archive ...`` with parsed arguments; returns the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        From the parser of :func:`add_archive_parser`.

    Returns
    -------
    int
        0 on success, 2 when the input is wrong (one line on stderr says what; nothing is
        written then).

    Examples
    --------
    >>> import argparse
    >>> run_archive(argparse.Namespace(action="consolidate", directory=Path("no-such-dir"),
    ...                                output=Path("x.nc"), overwrite=False))
    2
    """
    from lcmr_xr.scaleout.archive import consolidate_archive, index_archive

    if args.action == "index":
        try:
            path = index_archive(args.directory)
        except (ValueError, FileNotFoundError, NotADirectoryError, OSError) as exc:
            print(error_line("archive", exc), file=sys.stderr)
            return 2
        print(f"wrote {path}")
        return 0
    terminal = _is_terminal(sys.stderr)
    shown = [0]

    def progress(done, total):
        if terminal:
            print(f"\rconsolidated {done}/{total} experiments", end="\n" if done == total else "",
                  file=sys.stderr, flush=True)
        elif done == total or 10 * done >= (shown[0] + 1) * total:  # a plain line per 10 %
            shown[0] = 10 * done // max(total, 1)
            print(f"consolidated {done}/{total} experiments", file=sys.stderr, flush=True)

    try:
        check_outputs({"-o": (args.output, NETCDF_SUFFIXES)}, inputs=[args.directory],
                      overwrite=args.overwrite)
        if args.directory.is_file():
            from lcmr_xr.scaleout.consolidated import is_consolidated

            if is_consolidated(args.directory):
                raise ValueError(f"{args.directory} is a consolidated archive file already (open it "
                                 "with open_archive); consolidate takes an archive directory.")
            raise ValueError(f"{args.directory} is a file, not an archive directory; consolidate "
                             "takes a directory of experiment .nc (.nc4, .netcdf) files.")
        path = consolidate_archive(args.directory, args.output, overwrite=args.overwrite,
                                   progress=progress)
    except (ValueError, TypeError, FileNotFoundError, FileExistsError, OSError) as exc:
        print(error_line("archive", exc), file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0
