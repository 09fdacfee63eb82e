"""Large output buffers that do not stall the first write on huge-page compaction.

Why this exists
---------------
numpy asks Linux for transparent huge pages on every allocation of 4 MB or more
(``madvise(MADV_HUGEPAGE)``, numpy's ``alloc.c``).  Under the most common kernel setting
(``/sys/kernel/mm/transparent_hugepage/defrag`` = ``madvise``, the default of Ubuntu and
Fedora) a page fault in such a region may compact memory synchronously to find a free
2 MB page instead of falling back to 4 kB pages (numpy issue 31590).  The kernel's
outputs are written once, bin by bin, so every page is faulted exactly once: measured on
the 2-core test machine, ``local_model`` at M = 2^19 slow bins (430 MB of outputs) spent
1.3-1.5 s of system time with numpy's buffers against 0.3-0.4 s with buffers that are
not so advised, in the same process, alternating (user time equal).

An anonymous ``mmap`` is not advised: the system's own policy applies (``always`` still
gives huge pages where they are free, without the stall).  The mapping is a fresh one,
so the advice of numpy's heap memory never leaks into it, and it is returned to the
system when the last array that views it is freed.

Small buffers keep :func:`numpy.empty` (below numpy's 4 MB threshold nothing is
advised, and the heap is cheaper for them).
"""

from __future__ import annotations

import mmap

import numpy as np

__all__ = ["empty_pages"]

#: numpy advises huge pages from this size on (``alloc.c``); below it nothing to avoid.
MMAP_THRESHOLD = 4 << 20


def empty_pages(shape, dtype=float) -> np.ndarray:
    """An uninitialised, writable, C-contiguous array on pages numpy has not advised.

    Parameters
    ----------
    shape : int or tuple of int
        Shape of the array.
    dtype : data-type, default float
        Its dtype.

    Returns
    -------
    numpy.ndarray
        Like ``numpy.empty(shape, dtype)``; arrays of 4 MB or more view a private
        anonymous memory map (zero-filled by the system on first touch), smaller ones are
        ``numpy.empty``.

    Examples
    --------
    >>> a = empty_pages((1 << 20, 4), complex)
    >>> a.flags.c_contiguous and a.flags.writeable, a.nbytes
    (True, 67108864)
    """
    dtype = np.dtype(dtype)
    shape = (shape,) if np.ndim(shape) == 0 else tuple(shape)
    nbytes = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
    if nbytes < MMAP_THRESHOLD:
        return np.empty(shape, dtype)
    # The array's base keeps the map alive; freeing the last view unmaps it.
    return np.frombuffer(mmap.mmap(-1, nbytes), dtype=dtype).reshape(shape)
