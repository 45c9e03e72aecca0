"""Workspaces in 2 MB pages (``sssbench.ops._pages``): what the kernel reports about the
mapping (``/proc/self/smaps``: its address range, ``THPeligible``), not what the code says
it asked for; and the fused sum of Gaussians, whose kept workspace it is, bitwise the same
with a workspace in 4 KB pages."""

from __future__ import annotations

import gc
import mmap
import sys

import pytest
import torch

from sssbench.gbuffer import GBuffer
from sssbench.ops import FusedSumOfGaussiansSSS
from sssbench.ops import sum_of_gaussians_fused as fused
from sssbench.ops._pages import HUGE_PAGE, huge_page_empty
from sssbench.profiles import SumOfGaussians

linux_thp = pytest.mark.skipif(
    not sys.platform.startswith("linux") or not hasattr(mmap, "MADV_HUGEPAGE"),
    reason="transparent huge pages are Linux's",
)


def _thp_mode() -> str:
    """The bracketed word of /sys/kernel/mm/transparent_hugepage/enabled ('' if absent)."""
    try:
        text = open("/sys/kernel/mm/transparent_hugepage/enabled").read()
    except OSError:
        return ""
    return text.split("[", 1)[1].split("]", 1)[0] if "[" in text else ""


def _mapping(address: int) -> dict[str, str] | None:
    """The smaps entry (its range and fields) of the mapping holding ``address``, or None."""
    entry: dict[str, str] | None = None
    with open("/proc/self/smaps") as f:
        for line in f:
            head = line.split()[0]
            if "-" in head and ":" not in head:  # a mapping's first line: lo-hi perms ...
                lo, hi = (int(v, 16) for v in head.split("-"))
                if entry is not None:
                    return entry
                if lo <= address < hi:
                    entry = {"lo": str(lo), "hi": str(hi)}
            elif entry is not None and ":" in head:
                entry[head.rstrip(":")] = line.split(":", 1)[1].strip()
    return entry


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_huge_page_tensor_is_a_writable_contiguous_tensor_of_its_shape(dtype):
    t = huge_page_empty((2, 3, 5, 7), dtype)
    assert t.shape == (2, 3, 5, 7) and t.dtype == dtype and t.is_contiguous()
    values = torch.arange(t.numel(), dtype=dtype).reshape(t.shape)
    t.copy_(values)
    assert torch.equal(t, values)
    assert t.sum().item() == t.numel() * (t.numel() - 1) / 2  # Gauss's sum, read back


@linux_thp
def test_a_huge_page_tensor_starts_on_a_2mb_boundary_of_its_own_advised_mapping():
    t = huge_page_empty((3, 1000, 1000), torch.float32)
    address = t.data_ptr()
    assert address % HUGE_PAGE == 0
    entry = _mapping(address)
    assert entry is not None
    assert int(entry["hi"]) >= address + t.numel() * 4  # the whole tensor in the mapping
    if _thp_mode() in ("always", "madvise") and "THPeligible" in entry:  # Linux >= 4.15
        assert entry["THPeligible"] == "1"  # the kernel's word: advised into huge pages


@linux_thp
def test_a_huge_page_tensor_is_unmapped_when_freed():
    t = huge_page_empty((4, 1 << 20), torch.float32)  # 16 MB
    address = t.data_ptr()
    assert _mapping(address) is not None
    del t
    gc.collect()
    entry = _mapping(address)
    assert entry is None or int(entry["hi"]) - int(entry["lo"]) < 16 << 20  # not ours


def test_other_dtypes_and_empty_shapes_are_plain_tensors():
    t = huge_page_empty((3, 4), torch.int64)
    assert t.shape == (3, 4) and t.dtype == torch.int64
    assert huge_page_empty((0, 5), torch.float32).shape == (0, 5)


def test_the_fused_method_is_bitwise_the_same_with_its_workspace_in_small_pages():
    torch.manual_seed(0)
    h, w = 64, 96
    depth = 300.0 + 20.0 * torch.rand(1, 1, h, w, dtype=torch.float64)
    mask = (torch.rand(1, 1, h, w, dtype=torch.float64) > 0.3).to(torch.float64)
    g = GBuffer(torch.rand(1, 3, h, w, dtype=torch.float64), depth, 0.5, mask=mask)
    op = FusedSumOfGaussiansSSS(SumOfGaussians.from_table("skin_deon6"), 7)
    kept = op(g)  # into this thread's kept workspace
    workspace = fused._SCRATCH.tensor
    if sys.platform.startswith("linux") and hasattr(mmap, "MADV_HUGEPAGE"):
        assert workspace.data_ptr() % HUGE_PAGE == 0
    fused._SCRATCH.tensor = torch.full_like(workspace, float("nan"))  # 4 KB pages, poisoned
    try:
        small = op(g)
    finally:
        fused._SCRATCH.tensor = workspace
    assert torch.equal(kept, small)
    assert torch.isfinite(small).all()
