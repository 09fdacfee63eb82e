"""The kernel's large outputs live on pages numpy has not advised for huge pages
(lcmr_xr/kernels/pages.py says why: the first write stalled on memory compaction)."""

import gc
import sys
import weakref

import numpy as np
import pytest

from lcmr_xr.kernels.local_models import local_model
from lcmr_xr.kernels.pages import MMAP_THRESHOLD, empty_pages


def _vm_flags(array: np.ndarray) -> list[str]:
    """The VmFlags of the mapping that holds the middle of ``array`` (Linux smaps; numpy
    advises only the whole pages inside its buffer, so not the first byte's page)."""
    address = array.__array_interface__["data"][0] + array.nbytes // 2
    flags = None
    with open("/proc/self/smaps") as fh:
        inside = False
        for line in fh:
            head = line.split()[0]
            if "-" in head and not head.endswith(":"):
                lo, hi = (int(x, 16) for x in head.split("-"))
                inside = lo <= address < hi
            elif inside and head == "VmFlags:":
                flags = line.split()[1:]
                break
    assert flags is not None, "no mapping found for the array"
    return flags


def _numpy_advises_huge_pages() -> bool:
    if not sys.platform.startswith("linux"):
        return False
    try:
        from numpy._core.multiarray import _get_madvise_hugepage
    except ImportError:  # numpy < 2
        from numpy.core.multiarray import _get_madvise_hugepage
    return bool(_get_madvise_hugepage())


needs_advice = pytest.mark.skipif(
    not _numpy_advises_huge_pages(),
    reason="numpy does not advise huge pages here (not Linux, or disabled)")


@needs_advice
def test_numpy_advises_its_large_buffers_but_empty_pages_does_not():
    # The premise: numpy's own buffer of the same size carries the advice ("hg"),
    # so the check below can fail.
    reference = np.empty(MMAP_THRESHOLD // 8 + 1024)
    assert "hg" in _vm_flags(reference)
    ours = empty_pages(MMAP_THRESHOLD // 8 + 1024)
    assert "hg" not in _vm_flags(ours)


@needs_advice
def test_local_model_outputs_are_not_advised():
    rng = np.random.default_rng(0)
    m = 1 << 14  # G alone: 16384 x 2 x 2 x 16 B = 1 MB; noise_covariance the same
    R = rng.standard_normal((m, 2)) + 1j * rng.standard_normal((m, 2))
    Z = rng.standard_normal((m, 2)) + 1j * rng.standard_normal((m, 2))
    fit = local_model(np.stack([R] * 8), np.stack([Z] * 8), half_width=4, degrees=(1, 1, 1),
                      covariance="full")
    for name in ("G", "noise_covariance", "G_cov"):
        value = getattr(fit, name)
        assert value.nbytes >= MMAP_THRESHOLD, name
        assert "hg" not in _vm_flags(value), name


@pytest.mark.parametrize("shape, dtype", [((3, 5), complex), (0, float), (7, bool),
                                          ((MMAP_THRESHOLD // 16 + 3, 2), complex),
                                          (MMAP_THRESHOLD, np.int8),
                                          ((MMAP_THRESHOLD // 8,), np.int64)])
def test_empty_pages_is_a_writable_contiguous_empty(shape, dtype):
    a = empty_pages(shape, dtype)
    expected = np.empty(shape, dtype)
    assert a.shape == expected.shape and a.dtype == expected.dtype
    assert a.flags.c_contiguous and a.flags.writeable and a.flags.aligned
    a[...] = 1
    assert np.all(a == 1)


def test_the_map_is_released_with_the_last_view():
    a = empty_pages((MMAP_THRESHOLD // 8 + 1,))
    base = a.base
    while isinstance(base, np.ndarray):
        base = base.base
    gone = weakref.ref(base) if hasattr(base, "__weakref__") else None
    view = a[10:]
    del a, base
    gc.collect()
    view[...] = 2.0  # still backed while a view lives
    assert view.sum() == 2.0 * view.size
    del view
    gc.collect()
    if gone is not None:
        assert gone() is None
