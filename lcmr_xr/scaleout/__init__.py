"""Scale-out: experiment archives, dask-parallel settings sweeps, and settings selection.

- :func:`save_archive` / :func:`open_archive` / :func:`append_to_archive`: one consolidated
  NetCDF file (or a directory of one file per experiment), opened as one lazy dataset with
  an ``experiment`` dim; :func:`consolidate_archive` turns a directory into one file;
  :func:`index_archive` writes a directory's header index (its writers keep it current).
- :func:`sweep`: identify every experiment for every (method, degrees, window), lazily;
  computing runs the tasks in parallel on the current dask scheduler.
- :func:`sweep_to_disk`: the same sweep, each task's result written to disk as it finishes
  (resumable, progress in experiments per second); :func:`local_cluster` for workers with
  the allocator settings that keep tasks as fast as in a plain process.
- :func:`select_settings`: the settings with the lowest validation error per experiment.
"""

from lcmr_xr.scaleout.archive import (append_to_archive, consolidate_archive, index_archive, open_archive,
                                      save_archive)
from lcmr_xr.scaleout.cluster import local_cluster
from lcmr_xr.scaleout.select import select_settings
from lcmr_xr.scaleout.stream import sweep_to_disk
from lcmr_xr.scaleout.sweep import degrees_label, parse_degrees, sweep

__all__ = ["open_archive", "save_archive", "append_to_archive", "consolidate_archive", "index_archive",
           "sweep_to_disk", "local_cluster", "sweep", "select_settings", "parse_degrees", "degrees_label"]
