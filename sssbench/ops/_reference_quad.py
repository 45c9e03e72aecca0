"""The reference near field's Gauss–Legendre cell sums through the native quadrature
(``native/quad.c``), fused with the contraction against the neighbours' values.

:func:`native_cell_sums` computes what :func:`sssbench.ops._reference_near.hat_cell_sums`
computes for one block of cells with torch (the exponents as a matrix product, one ``exp``, the
quadrature reductions as products, then the contraction with the nine neighbours): per cell
and Gauss–Legendre Gaussian the node exponents from the cell's six features, their exp and the
quadrature and hat reductions in registers, never as an array of node values in memory. The
closed-form rules (``"flat"``, ``"narrow"``) stay torch code and are handed in as ``extra``.
The same terms summed in another order, and an exp within a few ulp of libm's
(:data:`QUAD_EXP_ULP`): equal to the torch sums to rounding (tests/ops/test_reference_quad.py:
against the direct contraction of ``hat_cell_weights``, 1e-13 relative).

Levels (:data:`QUAD_LEVELS`): the loop is compiled for SSE2 (any x86-64), AVX2 and AVX-512F
through target attributes and the widest the CPU has is used; every lane performs the same
IEEE operations (no fused multiply-add), so the levels agree bitwise (tested).

Split exponent (since 2026-12-05): a node's exponent is a part of its row node, a part of its
column node and a cross term ``ξ_s ξ_t 2h² t_x·t_y``; with the rules' nodes symmetric about 0
the native loop takes the node's value as the product of three exps, the cross one shared by
the four nodes ``(±ξ_s, ±ξ_t)`` (itself or its reciprocal): ``n²/4 + 2n`` exps and ``n²/4``
divisions per Gaussian and cell instead of ``n²`` exps, where every factor's exponent is at
most 30 (else one exp per node). Equal to the one-exp form to rounding (tested, with
:class:`split_exponent` as the switch; the error bound: a few ulp times the factors'
exponents). Measured on the cell sums of two 512² paper-benchmark scenes (one thread, both
builds alternated in one process): 0.76× the CPU time on ``pores`` at 0.3 mm/px (bilinear),
0.83× on ``face`` at 0.1 mm/px (box).
"""

from __future__ import annotations

import ctypes

import numpy as np
import torch

from sssbench.ops import native

__all__ = [
    "QUAD_LEVELS",
    "QUAD_EXP_ULP",
    "available",
    "native_cell_sums",
    "offset_fields",
    "quad_level",
    "quad_tables",
    "split_exponent",
]

#: the quadrature loop's instruction-set levels, narrowest first (``native/quad.c``)
QUAD_LEVELS = ("sse2", "avx2", "avx512")
#: the native exp's largest error against libm's (ulp of the result, where it is normal),
#: asserted by tests/ops/test_reference_quad.py
QUAD_EXP_ULP = 4


class _QuadArgs(ctypes.Structure):
    """``quad_args`` of ``native/quad.c`` (field order matters)."""

    _fields_ = [
        (name, ctypes.c_void_p)
        for name in (
            "geom",
            "extra",
            "values",
            "cells",
            "hat",
            "order",
            "xi",
            "red_t",
            "red_s",
            "coef",
            "w",
            "out",
        )
    ] + [("m", ctypes.c_int64), ("n_gauss", ctypes.c_int64), ("rows", ctypes.c_int64)]


def _library() -> ctypes.CDLL:
    """The native quadrature's library; ``RuntimeError`` where it cannot be had."""
    lib = native.quad_library()
    if lib is None:
        raise RuntimeError("the native reference quadrature is not available")
    return lib


def available() -> bool:
    """Whether the native quadrature can be used (the library built and loaded)."""
    return native.quad_library() is not None


class quad_level:  # noqa: N801 - used as a context manager, like torch.no_grad
    """``with quad_level("avx2"): ...`` runs the block's native cell sums at that level
    (capped at the CPU's); ``as`` gives the level in use. For tests and timings."""

    def __init__(self, level: str) -> None:
        if level not in QUAD_LEVELS:
            raise ValueError(f"level must be one of {QUAD_LEVELS}, got {level!r}")
        self.level = level
        self.previous = -1

    def __enter__(self) -> str:
        lib = _library()
        self.previous = lib.quad_get_level()
        return QUAD_LEVELS[lib.quad_set_level(QUAD_LEVELS.index(self.level))]

    def __exit__(self, *exc: object) -> None:
        _library().quad_set_level(self.previous)


class split_exponent:  # noqa: N801 - used as a context manager, like quad_level
    """``with split_exponent(False): ...`` computes the block's native cell sums with one exp
    per node (``quad_direct``), not with the split exponent (``quad_split``, the default where
    it applies: ``native/quad.c``). For tests: the one-exp form is the split form's oracle."""

    def __init__(self, on: bool) -> None:
        self.on = bool(on)
        self.previous = 1

    def __enter__(self) -> None:
        lib = _library()
        self.previous = lib.quad_set_split(int(self.on))

    def __exit__(self, *exc: object) -> None:
        _library().quad_set_split(self.previous)


def native_exp(x: torch.Tensor) -> torch.Tensor:
    """The native quadrature's exp of a float64 tensor (for the test of its error)."""
    lib = _library()
    x = x.detach().to(torch.float64).contiguous().reshape(-1)
    y = torch.empty_like(x)
    lib.quad_exp_array(x.data_ptr(), y.data_ptr(), x.numel())
    return y


def _ptr(t: torch.Tensor | None) -> int | None:
    return None if t is None else t.data_ptr()


def native_cell_sums(
    geom: torch.Tensor,
    extra: torch.Tensor | None,
    values: torch.Tensor,
    cells: torch.Tensor,
    hat: torch.Tensor,
    tables: tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor],
    weights: torch.Tensor,
    rows: int,
) -> torch.Tensor:
    """The contracted cell sums ``(6, M)``: rows 0–2 ``Σ_j W_cj values[cell + hat_j, 1 + c]``,
    rows 3–5 ``Σ_j W_cj values[cell + hat_j, 0]``, ``W = Σ_g w_gc A Σ_ab … + extra``
    (``native/quad.c``, 001 eq. 7 by Gauss–Legendre per cell or quadrant).

    Args:
        geom: ``(6, M)`` float64: offset ``dx, dy, dz`` from the target, half-size, slopes
            (mm).
        extra: ``(3, rows², M)`` float64 added to the weights before the contraction (the
            closed-form rules), or ``None``.
        values: ``(N, 4)`` float64: stencil, then the channels times the stencil, per cell.
        cells: ``(M,)`` int64 rows of ``values``; ``hat`` ``(rows²,)`` int64 the neighbours'
            row shifts (``j = b · rows + a``).
        tables: per Gauss–Legendre Gaussian, concatenated: nodes per axis ``(G,)`` int64, the
            nodes ``(Σ n,)``, the row and column weights ``(Σ rows · n,)`` each (row-major
            ``(rows, n)`` per Gaussian) and ``-1 / 2v`` ``(G,)``, all float64 but the first.
        weights: ``(G, 3)`` float64 channel weights.
        rows: 3 (the bilinear reconstruction's hats) or 1 (the box's whole cell).
    """
    lib = _library()
    m = geom.shape[1]
    for name, t in (("geom", geom), ("values", values), ("weights", weights)):
        if t.dtype != torch.float64 or not t.is_contiguous():
            raise ValueError(f"{name} must be contiguous float64, got {t.dtype}")
    for name, t in (("cells", cells), ("hat", hat)):
        if t.dtype != torch.int64 or not t.is_contiguous():
            raise ValueError(f"{name} must be contiguous int64, got {t.dtype}")
    if m and (
        int(cells.min()) + int(hat.min()) < 0
        or int(cells.max()) + int(hat.max()) >= values.shape[0]
    ):  # the C loop reads values[cell + hat_j] unchecked
        raise IndexError(f"cells + hat must index the {values.shape[0]} rows of values")
    if extra is not None and (extra.shape != (3, rows * rows, m) or not extra.is_contiguous()):
        raise ValueError(f"extra must be contiguous (3, {rows * rows}, {m}), got {extra.shape}")
    order, xi, red_t, red_s, coef = tables
    out = geom.new_empty(6, m)
    args = _QuadArgs(
        _ptr(geom),
        _ptr(extra),
        _ptr(values),
        _ptr(cells),
        _ptr(hat),
        _ptr(order),
        _ptr(xi),
        _ptr(red_t),
        _ptr(red_s),
        _ptr(coef),
        _ptr(weights),
        _ptr(out),
        m,
        order.numel(),
        rows,
    )
    if lib.quad_cell_sums(ctypes.byref(args)) != 0:
        raise ValueError(
            f"native cell sums rejected their arguments (rows {rows}, nodes per axis "
            f"{order.tolist()}: rows must be 1 or 3 and every rule 1 to 64 nodes per axis)"
        )
    return out


def offset_fields(fields: torch.Tensor, centre: torch.Tensor, shift: torch.Tensor) -> torch.Tensor:
    """The neighbour fields of the reference's near field, ``(F, C, E)``:
    ``fields[f, centre[i] + shift[j]]``, minus ``fields[f, centre[i]]`` for ``f < 3`` (the
    offset from the centre, mm) — what ``torch.gather`` and one subtraction give, the same
    values (tested), in one pass over the indices (``native/quad.c: quad_offset_fields``).

    Args:
        fields: ``(F, N)`` float64, field-major (contiguous).
        centre: ``(E,)`` int64 flat indices; ``shift`` ``(C,)`` int64 flat offsets.
    """
    lib = _library()
    if fields.dtype != torch.float64 or not fields.is_contiguous() or fields.ndim != 2:
        raise ValueError(f"fields must be contiguous (F, N) float64, got {fields.dtype}")
    for name, t in (("centre", centre), ("shift", shift)):
        if t.dtype != torch.int64 or not t.is_contiguous() or t.ndim != 1:
            raise ValueError(f"{name} must be a contiguous 1D int64 tensor")
    nf, n = fields.shape
    e, c = centre.numel(), shift.numel()
    if (
        e
        and c
        and (
            int(centre.min()) + int(shift.min()) < 0
            or int(centre.max()) + int(shift.max()) >= n
            or int(centre.min()) < 0
            or int(centre.max()) >= n
        )
    ):  # the C loop reads unchecked
        raise IndexError(f"centre + shift must index the {n} columns of fields")
    out = fields.new_empty(nf, c, e)
    lib.quad_offset_fields(
        fields.data_ptr(), nf, n, centre.data_ptr(), e, shift.data_ptr(), c, out.data_ptr()
    )
    return out


def quad_tables(
    parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, float]],
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The ``tables`` of :func:`native_cell_sums` from, per Gauss–Legendre Gaussian, its nodes
    per axis ``(n,)`` in [−1, 1], its row and column weights ``(R, n)`` and its variance ``v``
    (mm²): nodes per axis, the nodes, the weights (each ``(R, n)`` row-major) concatenated
    over the Gaussians, and ``−1/2v``."""

    def cat(arrays: list[np.ndarray]) -> torch.Tensor:
        flat = [np.ascontiguousarray(a, dtype=np.float64).ravel() for a in arrays]
        return torch.from_numpy(np.concatenate(flat) if flat else np.zeros(0))

    order = torch.tensor([p[0].size for p in parts], dtype=torch.int64)
    coef = torch.tensor([-0.5 / p[3] for p in parts], dtype=torch.float64)
    return (
        order,
        cat([p[0] for p in parts]),
        cat([p[1] for p in parts]),
        cat([p[2] for p in parts]),
        coef,
    )
