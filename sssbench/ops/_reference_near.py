"""Hat-weighted cell integrals: the bilinear reconstruction's near field in closed form.

One module because the three cell rules below (flat, narrow tilted, Gauss–Legendre per
quadrant) are one derivation: the box reference's cell rules
(:func:`sssbench.profiles.sum_of_gaussians.cell_rules`) with the bilinear weights inside the
integral.

With the bilinear reconstruction (:func:`sssbench.ops.reference.reference_sss`) the field on
the cell ``n`` at ``p_n + s t_x + t t_y`` (``|s|, |t| ≤ h``) is
``Σ_{a,b ∈ {−1,0,1}} Λ_a(s) Λ_b(t) q_{n+(a,b)}`` with the hat weights
``Λ_0(s) = 1 − |s|/2h``, ``Λ_{±1}(s) = max(0, ±s/2h)`` (they sum to 1). So the cell's
contribution to a target is ``Σ_ab W_ab q_{n+(a,b)}`` with nine weights
``W_ab = ∫_cell Λ_a(s) Λ_b(t) G(v, |Δ + s t_x + t t_y|) dA`` per Gaussian, instead of the box
reconstruction's one weight ``∫_cell G dA = Σ_ab W_ab``. The nine weights come from the same
rule the box reference uses for the cell:

- ``"flat"`` (no slope): the Gaussian factorises, ``W_ab = e^{−dz²/2v} m_a(dx) m_b(dy)`` with
  the 1D hat masses of :func:`hat_masses` (erfc and the normal density: exact).
- ``"narrow"`` (σ < h/2 on a tilted cell): the box rule's completed square along each tangent
  (:func:`~sssbench.profiles.sum_of_gaussians.narrow_tilted_cell_mass`), whose 1D factors are
  Gaussians in ``s`` and ``t``: their hat masses, scaled by the box rule's cap (so the nine
  weights sum to the box weight exactly).
- an int ``n`` (Gauss–Legendre): the hat weights have a kink at the cell centre, so each cell is
  split into its four quadrants (where they are linear) with an ``n``-point rule per half axis:
  the integrand per quadrant is as smooth as the box rule's on the whole cell.

The reference uses :func:`hat_cell_sums`: the same weights, contracted with the neighbours'
values block by block in cache, with the per-quadrant hat sums factorised over the two axes.
:func:`hat_cell_weights` (all nine weights of every cell, one (27, nodes) product) is the
direct form, kept as its oracle (equal to rounding, tests/ops/test_reference_near.py).
"""

from __future__ import annotations

import math

import numpy as np
import torch

from sssbench.ops import _reference_quad as _quad
from sssbench.ops._reference_quad import native_cell_sums, quad_tables
from sssbench.profiles.base import _gauss_legendre
from sssbench.profiles.sum_of_gaussians import (
    SumOfGaussians,
    flat_cell_mass,
    interval_mass,
    narrow_tilted_cell_mass,
)

__all__ = ["HAT_OFFSETS", "box_cell_sums", "hat_masses", "hat_cell_weights", "hat_cell_sums"]

#: the nine neighbour offsets ``(a, b)`` of the bilinear reconstruction, in the order of the
#: weights' second axis (column offset ``a``, row offset ``−b``: ``t`` runs upward)
HAT_OFFSETS = tuple((a, b) for b in (-1, 0, 1) for a in (-1, 0, 1))
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
#: cells × quadrature nodes per block of :func:`_quadrant_gauss_legendre` (in cache)
_NODE_ELEMS = 1 << 18


def _density(x: torch.Tensor) -> torch.Tensor:
    """The standard normal density ``φ(x)``."""
    return torch.exp(-0.5 * x * x) * _INV_SQRT_2PI


def hat_masses(
    mu: torch.Tensor, sigma: torch.Tensor, h: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``∫_{−h}^{h} Λ_a(s) φ((s − μ)/σ)/σ ds`` for ``a = −1, 0, 1`` (broadcast shapes).

    With ``P(l, u) = Φ((u−μ)/σ) − Φ((l−μ)/σ)`` (:func:`interval_mass`, no cancellation in the
    tails) and ``∫_l^u s φ((s−μ)/σ)/σ ds = μ P(l, u) + σ (φ((l−μ)/σ) − φ((u−μ)/σ))``:
    ``m_{+1} = (1/2h) ∫_0^h s …``, ``m_{−1} = −(1/2h) ∫_{−h}^0 s …``, and ``m_0 = P(−h, h) −
    m_{−1} − m_{+1}`` (the hats sum to 1). 0 where ``h = 0`` (a cell off the surface).
    """
    on = h > 0
    hs = torch.where(on, h, torch.ones_like(h))
    lo, mid, hi = (-hs - mu) / sigma, -mu / sigma, (hs - mu) / sigma
    p_lo, p_hi = interval_mass(lo, mid), interval_mass(mid, hi)
    f_lo, f_mid, f_hi = _density(lo), _density(mid), _density(hi)
    first_hi = mu * p_hi + sigma * (f_mid - f_hi)  # ∫_0^h s …
    first_lo = mu * p_lo + sigma * (f_lo - f_mid)  # ∫_{−h}^0 s …
    m_pos = (first_hi / (2 * hs)).clamp_min(0)
    m_neg = (-first_lo / (2 * hs)).clamp_min(0)
    m_0 = interval_mass(lo, hi) - m_pos - m_neg
    zero = torch.zeros_like(m_0)
    return (torch.where(on, m_neg, zero), torch.where(on, m_0, zero), torch.where(on, m_pos, zero))


def _outer9(mx: tuple[torch.Tensor, ...], my: tuple[torch.Tensor, ...], f: torch.Tensor):
    """``(9, M)``: ``f · mx_a · my_b`` in the order of :data:`HAT_OFFSETS`."""
    return torch.stack([f * my[b + 1] * mx[a + 1] for a, b in HAT_OFFSETS])


def _flat_hat(dx, dy, dz, hh, v: float) -> torch.Tensor:
    """The ``"flat"`` rule: ``(9, M)`` (001 eq. 7 factorised, r² = x² + y² + dz²)."""
    s = torch.full_like(dx, math.sqrt(v))
    mx = hat_masses(-dx, s, hh)
    my = hat_masses(-dy, s, hh)
    return _outer9(mx, my, torch.exp(-(dz * dz) / (2 * v)))


def _narrow_hat(dx, dy, dz, hh, sx, sy, v: float) -> torch.Tensor:
    """The ``"narrow"`` rule: the terms of ``narrow_tilted_cell_mass`` with hat masses for its
    interval masses, times ``min(term, cap) / term`` (its cap on the sum): ``(9, M)``."""
    s = math.sqrt(v)
    cx, cy = 1 + sx * sx, 1 + sy * sy
    bx, by = dx + sx * dz, dy + sy * dz  # Δ · t_x, Δ · t_y
    resid = (dx * dx + dy * dy + dz * dz - bx * bx / cx - by * by / cy).clamp_min(0)
    mx = hat_masses(-bx / cx, s / torch.sqrt(cx), hh)
    my = hat_masses(-by / cy, s / torch.sqrt(cy), hh)
    lead = torch.exp(-resid / (2 * v))
    term = lead * sum(mx) * sum(my)
    near2 = (dx.abs() - hh).clamp_min(0) ** 2 + (dy.abs() - hh).clamp_min(0) ** 2
    area = 4 * hh * hh * torch.sqrt(1 + sx * sx + sy * sy)
    cap = area * torch.exp(-near2 / (2 * v)) / (2 * math.pi * v)
    scale = torch.where(term > cap, cap / torch.where(term > 0, term, 1.0), 1.0)
    return _outer9(mx, my, lead * scale)


def _quadrant_nodes(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes ``ξ ∈ [−1, 1]`` (``s = h ξ``) of an ``n``-point rule on each half axis, their
    weights, and the hat weights ``(3, 2n)`` of the offsets −1, 0, 1 at them."""
    x, w = _gauss_legendre(n)
    u = (x + 1) / 2  # [0, 1]
    xi = np.concatenate([-u[::-1], u])
    wt = np.concatenate([w[::-1], w]) / 2
    hat = np.stack([np.maximum(0, -xi) / 2, 1 - np.abs(xi) / 2, np.maximum(0, xi) / 2])
    return xi, wt, hat


def quadrant_order(n: int) -> int:
    """Points per half axis for a cell the box rule integrates with ``n`` points: a half is
    half as wide against σ, so about half the points (one more for the hat's linear
    factor), at least 2."""
    return max(2, n // 2 + 1)


def _quadrant_gauss_legendre(dx, dy, dz, hh, sx, sy, v, n, weights) -> torch.Tensor:
    """``Σ_g weights_g W_ab`` by ``n_g`` Gauss–Legendre points per half axis and quadrant,
    several Gaussians at once: ``(3, 9, M)``.

    As ``_sog_gauss_legendre`` of the reference: the squared distance of a node is a fixed
    polynomial of the node, ``|Δ|² + 2hξ_a Δ·t_x + 2hξ_b Δ·t_y + h²ξ_a²|t_x|² + h²ξ_b²|t_y|²
    + 2h²ξ_aξ_b t_x·t_y``, so the exponents are one matrix product of a (nodes, 6) table with
    six per-cell features, and the sums (quadrature × hat × channel weights) a second one.
    """
    phi, red = [], []
    for vg, nc, wg in zip(v, n, weights.tolist(), strict=True):
        ng = quadrant_order(nc)
        xi, wt, hat = _quadrant_nodes(ng)
        xa, xb = np.repeat(xi, 2 * ng), np.tile(xi, 2 * ng)
        phi.append(np.stack([np.ones_like(xa), xa, xb, xa**2, xb**2, xa * xb], 1) * (-0.5 / vg))
        q = np.outer(wt, wt).ravel() / (2 * math.pi * vg)  # (nodes,)
        hab = np.stack([np.outer(hat[a + 1], hat[b + 1]).ravel() for a, b in HAT_OFFSETS])
        red.append(np.asarray(wg)[:, None, None] * (hab * q)[None])  # (3, 9, nodes)
    a_mat = torch.from_numpy(np.concatenate(phi)).to(dx)
    r_mat = torch.from_numpy(np.concatenate(red, 2).reshape(27, -1)).to(dx)
    return node_sums(a_mat, r_mat, dx, dy, dz, sx, sy, hh).view(3, 9, dx.shape[0])


def _cell_features(
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
    hh: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The six features of each cell the quadrature's exponents are linear in, ``(6, M)``,
    and the cell's area element ``(M,)`` (inputs ``(M,)``, mm; the cell ``p + s t_x + t t_y``
    with ``t_x = (1, 0, sx)``, ``t_y = (0, 1, sy)``, ``|s|, |t| ≤ h``)."""
    two_h, h2 = 2 * hh, hh * hh
    sx2, sy2 = sx * sx, sy * sy
    feats = torch.stack(
        [
            torch.addcmul(torch.addcmul(dx * dx, dy, dy), dz, dz),  # |Δ|²
            two_h * torch.addcmul(dx, sx, dz),  # 2h Δ·t_x
            two_h * torch.addcmul(dy, sy, dz),  # 2h Δ·t_y
            torch.addcmul(h2, h2, sx2),  # h² |t_x|²
            torch.addcmul(h2, h2, sy2),  # h² |t_y|²
            (two_h * hh) * sx * sy,  # 2h² t_x·t_y
        ]
    )
    area = torch.sqrt(1 + sx2 + sy2) * h2  # dA = sqrt(1 + |∇z|²) dx dy
    return feats, area


def node_sums(
    a_mat: torch.Tensor,
    r_mat: torch.Tensor,
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
    hh: torch.Tensor,
) -> torch.Tensor:
    """``r_mat @ exp(a_mat @ features) · area`` per source: the quadrature of Gaussians over
    tilted cells shared by the box rule (:mod:`sssbench.ops.reference`) and the hat-weighted
    one here, the exponent being linear in six features of each cell (offset ``Δ = (dx, dy,
    dz)`` mm, slopes ``sx, sy``, half-size ``hh`` mm, all ``(M,)``).

    ``a_mat`` ``(rows, 6)`` holds each node's coefficients of the features, ``r_mat``
    ``(R, rows)`` the weights that reduce nodes to outputs; returns ``(R, M)``. Sources are
    taken in blocks so that ``rows × block`` stays near :data:`_NODE_ELEMS` elements."""
    feats, area = _cell_features(dx, dy, dz, sx, sy, hh)
    block = max(1, _NODE_ELEMS // a_mat.shape[0])
    m = dx.shape[0]
    parts = [r_mat @ torch.exp(a_mat @ feats[:, i : i + block]) for i in range(0, m, block)]
    return torch.cat(parts, 1) * area


def hat_cell_weights(
    profile: SumOfGaussians,
    rule: tuple[int | str | None, ...],
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    hh: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
) -> torch.Tensor:
    """The nine hat-weighted cell integrals of ``profile`` (channels first), ``(3, 9, M)``,
    for flat cell tensors ``(M,)`` (offset ``Δ`` from the target, mm; half-size; slopes) with
    the per-Gaussian ``rule`` of :func:`~sssbench.profiles.sum_of_gaussians.cell_rules`; an
    int rule ``n`` takes ``n`` points per half axis and quadrant. Summed over the nine, the
    box reference's cell weight (same rule; to rounding for ``"flat"`` and ``"narrow"``)."""
    v = profile.variances.to(torch.float64).tolist()
    w = profile.weights.to(dx)
    out = dx.new_zeros(3, 9, dx.shape[0])
    quad = [i for i, r in enumerate(rule) if isinstance(r, int)]
    if quad:
        order = [int(rule[i]) for i in quad]  # type: ignore[arg-type]
        out += _quadrant_gauss_legendre(
            dx, dy, dz, hh, sx, sy, [v[i] for i in quad], order, w[quad]
        )
    for i, r in enumerate(rule):
        if r == "flat":
            term = _flat_hat(dx, dy, dz, hh, v[i])
        elif r == "narrow":
            term = _narrow_hat(dx, dy, dz, hh, sx, sy, v[i])
        else:
            continue
        out += w[i][:, None, None] * term[None]
    return out


#: cells per block of :func:`hat_cell_sums` (a block's nine weights and gathered neighbours
#: stay in cache)
_CELL_BLOCK = 1 << 14


def _quadrant_tables(
    v: list[float], n: list[int], dtype: torch.dtype
) -> tuple[torch.Tensor, list[tuple[int, int, torch.Tensor, torch.Tensor]]]:
    """The exponent table of :func:`_quadrant_gauss_legendre` with the nodes ``t``-major
    (``(rows, 6)``) and per Gaussian its rows ``[start, stop)``, the ``t`` reduction ``(3,
    2n)`` (hat of offsets b = −1, 0, 1 × quadrature weight × ``1/2πv``) and the ``s`` one
    ``(3, 2n)`` (hat of a × quadrature weight): the hat weights factorise over the two axes,
    so the nine sums are two small matrix products instead of one (9, nodes) product."""
    phi, per, start = [], [], 0
    for vg, nc in zip(v, n, strict=True):
        ng = quadrant_order(nc)
        xi, wt, hat = _quadrant_nodes(ng)
        xb, xa = np.repeat(xi, 2 * ng), np.tile(xi, 2 * ng)  # t-major: row = t node, s node
        phi.append(np.stack([np.ones_like(xa), xa, xb, xa**2, xb**2, xa * xb], 1) * (-0.5 / vg))
        red_t = torch.from_numpy(hat * wt / (2 * math.pi * vg)).to(dtype)
        red_s = torch.from_numpy(hat * wt).to(dtype)
        per.append((start, start + xa.size, red_t, red_s))
        start += xa.size
    return torch.from_numpy(np.concatenate(phi)).to(dtype), per


def hat_cell_sums(
    profile: SumOfGaussians,
    rule: tuple[int | str | None, ...],
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    hh: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
    values: torch.Tensor,
    cells: torch.Tensor,
    hat: torch.Tensor,
    native: bool | None = None,
) -> torch.Tensor:
    """The bilinear near field's contribution of each cell, ``(6, M)``: rows 0–2
    ``Σ_ab W_ab q_{n+(a,b)}`` (numerator, per channel) and rows 3–5 ``Σ_ab W_ab s_{n+(a,b)}``
    (denominator) with the nine weights ``W`` of :func:`hat_cell_weights` (same rules, same
    nodes and closed forms) and the neighbours' stencil ``s`` and irradiance · stencil ``q``.

    ``values`` ``(N, 4)``: stencil and irradiance · stencil of every cell of the padded
    surface (one row per cell); ``cells`` ``(M,)``: each cell's flat index there; ``hat``
    ``(9,)``: the flat shifts of the nine neighbours in the order of :data:`HAT_OFFSETS`; the
    other arguments (``(M,)``, mm) as :func:`hat_cell_weights`.

    Equal to contracting :func:`hat_cell_weights` with the gathered neighbours, computed block
    by block of :data:`_CELL_BLOCK` cells so that the nine weights and the 36 gathered
    neighbour values stay in cache, and with the Gauss–Legendre hat sums factorised over the
    two axes (:func:`_quadrant_tables`): per Gaussian 3 products per node (the ``t`` sums)
    and 9 per ``s`` node and ``t`` hat (the ``s`` sums) instead of 27 per node. The same
    terms summed in another order: equal to rounding (tested to 1e-13 relative; measured
    2.5e-15 on the reference of the 128² face at 0.3 mm/px, float64).

    ``native``: ``None`` (default) computes each block's Gauss–Legendre sums and its
    contraction in the native quadrature (:func:`~sssbench.ops._reference_quad.native_cell_sums`,
    node values in registers: the same terms in another order, equal to rounding, tested)
    when its library is available and the tensors are float64, else with torch as above;
    ``False`` always with torch; ``True`` requires the native quadrature.
    """
    m = dx.shape[0]
    out = dx.new_empty(6, m)
    v = profile.variances.to(torch.float64).tolist()
    w = profile.weights.to(dx)  # (G, 3)
    quad = [i for i, r in enumerate(rule) if isinstance(r, int)]
    closed = [(i, r) for i, r in enumerate(rule) if r in ("flat", "narrow")]
    fused = native is not False and dx.dtype == torch.float64 and _quad.available()
    if native and not fused:
        raise RuntimeError("native=True: the native quadrature needs float64 and its library")
    if quad:
        order = [int(rule[i]) for i in quad]  # type: ignore[arg-type]
        if fused:
            tables = _native_tables([v[i] for i in quad], order)
            w_quad_g = w[quad].contiguous()  # (Gq, 3)
        else:
            a_mat, per = _quadrant_tables([v[i] for i in quad], order, dx.dtype)
            w_quad = w[quad].t().contiguous()  # (3, Gq)
    elif fused:
        tables = _native_tables([], [])
        w_quad_g = w.new_zeros(0, 3)
    for lo in range(0, m, _CELL_BLOCK):
        blk = slice(lo, min(m, lo + _CELL_BLOCK))
        bdx, bdy, bdz, bh, bsx, bsy = dx[blk], dy[blk], dz[blk], hh[blk], sx[blk], sy[blk]
        nb = bdx.shape[0]
        geo = (bdx, bdy, bdz, bh, bsx, bsy)
        if fused:
            extra = _add_closed(closed, v, w, bdx.new_zeros(3, 9, nb), *geo) if closed else None
            geom = torch.stack(geo)
            out[:, blk] = native_cell_sums(
                geom, extra, values, cells[blk].contiguous(), hat, tables, w_quad_g, 3
            )
            continue
        if quad:
            sums = _quadrant_sums(a_mat, per, bdx, bdy, bdz, bsx, bsy, bh)  # (Gq, 9·nb)
            wgt = (w_quad @ sums).view(3, 9, nb)
        else:
            wgt = bdx.new_zeros(3, 9, nb)
        _add_closed(closed, v, w, wgt, *geo)
        # the nine neighbours' rows (stencil, q): one row gather, then one fused
        # multiply-add per neighbour into the block's six sums (all in cache)
        qn = values.index_select(0, (hat[:, None] + cells[blk][None, :]).view(-1))
        qn = qn.view(9, nb, 4)
        res = out[:, blk]
        res.zero_()
        for j in range(9):
            q = qn[j].t()
            res[:3].addcmul_(wgt[:, j], q[1:])
            res[3:].addcmul_(wgt[:, j], q[0].expand(3, -1))
    return out


def _add_closed(closed, v, w, into, dx, dy, dz, hh, sx, sy) -> torch.Tensor:
    """``into`` ``(3, 9, M)`` += the channel-weighted nine weights of the closed-form rules
    ``closed`` (``(index, "flat" | "narrow")`` per Gaussian); returns ``into``."""
    for i, r in closed:
        if r == "flat":
            term = _flat_hat(dx, dy, dz, hh, v[i])
        else:
            term = _narrow_hat(dx, dy, dz, hh, sx, sy, v[i])
        into.addcmul_(w[i][:, None, None], term[None])
    return into


def _native_tables(
    v: list[float], n: list[int]
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """:func:`_quadrant_tables` in the layout of the native quadrature
    (:func:`~sssbench.ops._reference_quad.quad_tables`): per Gaussian its ``2n`` nodes per
    axis (n = :func:`quadrant_order`), the ``t`` (row) reduction ``hat_b × weight × 1/2πv``
    and the ``s`` (column) one ``hat_a × weight``, each ``(3, 2n)``."""
    parts = []
    for vg, nc in zip(v, n, strict=True):
        xi, wt, hat = _quadrant_nodes(quadrant_order(nc))
        parts.append((xi, hat * wt / (2 * math.pi * vg), hat * wt, vg))
    return quad_tables(parts)


def _quadrant_sums(
    a_mat: torch.Tensor,
    per: list[tuple[int, int, torch.Tensor, torch.Tensor]],
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
    hh: torch.Tensor,
) -> torch.Tensor:
    """Per Gauss–Legendre Gaussian the nine hat-weighted sums ``(G, 9·M)`` (order of
    :data:`HAT_OFFSETS`) over the nodes of :func:`_quadrant_tables`, times the area element:
    the exponents as :func:`node_sums` (one product with the six cell features, one exp, in
    blocks of about :data:`_NODE_ELEMS` node values), then the ``t`` reduction (one product
    over the node rows of each ``s`` node) and the ``s`` reduction."""
    feats, area = _cell_features(dx, dy, dz, sx, sy, hh)
    m = dx.shape[0]
    out = dx.new_empty(len(per), 3, 3, m)
    # node values in sub-blocks of about _NODE_ELEMS elements (they stay in cache)
    sub = max(1, _NODE_ELEMS // a_mat.shape[0])
    for lo in range(0, m, sub):
        hi = min(m, lo + sub)
        vals = torch.exp(a_mat @ feats[:, lo:hi])  # (rows, hi − lo)
        for g, (start, stop, red_t, red_s) in enumerate(per):
            n2 = red_t.shape[1]
            # Σ_t: (3_b, 2n_t) @ (2n_t, 2n_s · M) -> (3_b, 2n_s, M); Σ_s: (3_a, 2n_s) batched
            part = (red_t @ vals[start:stop].view(n2, n2 * (hi - lo))).view(3, n2, hi - lo)
            out[g, :, :, lo:hi] = torch.matmul(red_s, part)  # (3_b, 3_a, M)
    out.view(len(per), 9, m).mul_(area)
    return out.view(len(per), 9 * m)


def box_cell_sums(
    profile: SumOfGaussians,
    rule: tuple[int | str | None, ...],
    geom: torch.Tensor,
    values: torch.Tensor,
    cells: torch.Tensor,
) -> torch.Tensor:
    """The box reconstruction's near field per cell through the native quadrature, ``(6, M)``:
    rows 0–2 ``Σ_c-weights W q`` and rows 3–5 ``W`` with ``W`` the cell integral of
    :meth:`SumOfGaussians.cell_integral` (the reference's ``_sog_cell_weights``: the same
    n×n Gauss–Legendre rule over the whole cell and the same closed forms, summed in another
    order: equal to rounding, tested).

    ``geom`` ``(6, M)`` float64: offset from the target, half-size, slopes (mm); ``values``
    ``(N, 4)``: 1, then irradiance · stencil per cell (a zero-size cell has weight exactly 0,
    so the denominator needs no stencil); ``cells`` ``(M,)`` int64 rows of ``values``.
    """
    dx, dy, dz, hh, sx, sy = geom
    v = profile.variances.to(geom)
    w = profile.weights.to(geom)
    extra = None
    for i, r in enumerate(rule):
        if r == "flat":
            term = flat_cell_mass(dx, dy, dz, hh, hh, v[i])
        elif r == "narrow":
            term = narrow_tilted_cell_mass(dx, dy, dz, hh, hh, sx, sy, v[i])
        else:
            continue
        term = w[i][:, None] * term[None]
        extra = term if extra is None else extra.add_(term)
    quad = [i for i, r in enumerate(rule) if isinstance(r, int)]
    parts = []
    for i in quad:
        x, wt = _gauss_legendre(int(rule[i]))  # type: ignore[arg-type]
        vg = float(v[i])
        parts.append((x, (wt / (2 * math.pi * vg))[None], wt[None], vg))
    tables = quad_tables(parts)
    hat = torch.zeros(1, dtype=torch.int64)
    extra = None if extra is None else extra.view(3, 1, -1).contiguous()
    wq = w[quad].contiguous() if quad else w.new_zeros(0, 3)
    return native_cell_sums(geom, extra, values, cells, hat, tables, wq, 1)
