"""The radial diffusion profile interface (DESIGN §3) and numerical defaults.

A profile is a radially symmetric reflectance ``R(r)`` per RGB channel, ``r`` in mm,
``R`` in mm^-2 (so that ``total() = ∫ 2πr R(r) dr`` is dimensionless). Subclasses implement
:meth:`Profile.evaluate` and :meth:`Profile.length_scales`; everything else has a numerical
default here (Gauss–Legendre panels on a geometric grid in float64) that subclasses with a
closed form (e.g. :class:`~sssbench.profiles.SumOfGaussians`) override.
"""

from __future__ import annotations

import math
from functools import cache

import numpy as np
import torch

__all__ = ["Profile", "as_r"]

_GL_ORDER = 16


@cache
def _gauss_legendre(order: int) -> tuple[np.ndarray, np.ndarray]:
    nodes, weights = np.polynomial.legendre.leggauss(order)
    return nodes, weights


def _panel_nodes(edges: np.ndarray, order: int = _GL_ORDER) -> tuple[np.ndarray, np.ndarray]:
    """Gauss–Legendre nodes and weights over consecutive panels ``edges[k]..edges[k+1]``."""
    x, w = _gauss_legendre(order)
    a, b = edges[:-1, None], edges[1:, None]
    half = (b - a) / 2
    nodes = (a + b) / 2 + half * x[None, :]
    weights = half * w[None, :]
    return nodes.ravel(), weights.ravel()


def as_r(r: torch.Tensor | float | np.ndarray, *, allow_inf: bool = False) -> torch.Tensor:
    """Positions (mm) as a float64 tensor; rejects NaN (and ±inf unless ``allow_inf``)."""
    t = torch.as_tensor(r, dtype=torch.float64)
    bad = torch.isnan(t) if allow_inf else ~torch.isfinite(t)
    if bool(bad.any()):
        raise ValueError(
            f"r must be {'non-NaN' if allow_inf else 'finite'}, got {t[bad][:3].tolist()}"
        )
    return t


class Profile:
    """Base class of radial diffusion profiles ``R(r) -> (..., 3)`` in mm^-2.

    Subclasses implement :meth:`evaluate` (float64 in, float64 out) and :meth:`length_scales`.
    """

    #: short name used in logs and configs
    name: str = "profile"
    #: evaluations of ``evaluate`` per point of :meth:`preintegrated` (the numeric default is a
    #: quadrature over ~1600 nodes); closed forms set 1. Only sizes the chunks of
    #: :meth:`preintegrated_cdf`.
    _preintegrated_cost: int = 1600
    #: ``R`` has an integrable singularity at ``r = 0`` (``r R(r)`` bounded, e.g. Burley's
    #: ``1/r``): :meth:`cell_integral` then integrates the cells near the singular point in
    #: polar coordinates about it (:func:`_polar_patch_integral`), where a tensor-product rule
    #: misses the spike (an 8×8 Gauss–Legendre rule is 9–15% low on Burley's centre cell).
    singular_at_origin: bool = False

    # ----------------------------------------------------------------- required
    def evaluate(self, r: torch.Tensor) -> torch.Tensor:
        """``R(r)`` for float64 radii ``r`` (mm, any shape) -> ``(*r.shape, 3)``."""
        raise NotImplementedError

    def length_scales(self) -> tuple[float, float]:
        """(smallest, largest) characteristic length in mm, used to place quadrature panels."""
        raise NotImplementedError

    # ----------------------------------------------------------------- public API
    def __call__(self, r: torch.Tensor | float) -> torch.Tensor:
        """Evaluate ``R(r)``.

        Args:
            r: radius in mm, any shape, >= 0.

        Returns:
            ``(*r.shape, 3)`` float64, in mm^-2.
        """
        t = as_r(r)
        return self.evaluate(t.abs())

    def total(self) -> torch.Tensor:
        """Total diffuse reflectance ``∫ 2πr R(r) dr`` per channel, ``(3,)``."""
        r, w = self._radial_quadrature()
        vals = self.evaluate(torch.from_numpy(r))
        return (torch.from_numpy(2 * math.pi * r * w)[:, None] * vals).sum(0)

    def preintegrated(self, x: torch.Tensor | float) -> torch.Tensor:
        """The pre-integrated 1D kernel ``a_p(x) = ∫ R(√(x²+y²)) dy`` (000 eq. 4), ``(..., 3)``."""
        xt = as_r(x)
        y, w = self._radial_quadrature()
        yt = torch.from_numpy(y)
        rr = torch.sqrt(xt.reshape(-1, 1) ** 2 + yt.reshape(1, -1) ** 2)
        vals = self.evaluate(rr)  # (n, q, 3)
        out = 2.0 * (vals * torch.from_numpy(w)[None, :, None]).sum(1)
        return out.reshape(*xt.shape, 3)

    def preintegrated_cdf(self, x: torch.Tensor | float) -> torch.Tensor:
        """``∫_{-∞}^{x} a_p(t) dt`` per channel, ``(..., 3)``; tends to :meth:`total`.

        ``total/2 ± ∫_0^{|x|} a_p``, the integral by Gauss–Legendre panels on a geometric grid
        from ``lo/64`` to ``hi·64`` (``lo, hi`` = :meth:`length_scales`) clipped at ``|x|``,
        continued geometrically (ratio 2) beyond ``hi·64`` for far-out ``x``. The full panels
        are integrated once and accumulated; each ``x`` adds only its partial panel, all ``x``
        in one vectorised call (the same nodes as integrating every ``x`` separately).
        """
        xt = as_r(x, allow_inf=True)
        flat = xt.reshape(-1)
        half = 0.5 * self.total()
        a = flat.abs()
        finite = torch.isfinite(a) & (a > 0)
        out = half.expand(flat.shape[0], 3).clone()
        out[torch.isinf(flat) & (flat > 0)] = 2 * half
        out[torch.isinf(flat) & (flat < 0)] = 0.0
        if bool(finite.any()):
            af = a[finite].numpy()
            lo, hi = self.length_scales()
            base = np.geomspace(lo / 64, hi * 64, 48)
            amax = float(af.max())
            if amax > base[-1]:
                k = int(math.ceil(math.log2(amax / base[-1]))) + 1
                base = np.concatenate([base, base[-1] * 2.0 ** np.arange(1, k + 1)])
            edges = np.concatenate([[0.0], base])
            gx, gw = _gauss_legendre(_GL_ORDER)
            # full panels once: cum[k] = ∫_0^{edges[k]} a_p
            nodes, wts = _panel_nodes(edges)
            full = self._weighted_sum(nodes[None, :], wts[None, :])[0]  # (P*Q, 3) summed below
            per_panel = full.reshape(len(edges) - 1, _GL_ORDER, 3).sum(1)
            cum = torch.cat([torch.zeros(1, 3, dtype=torch.float64), per_panel.cumsum(0)])
            # partial panel [edges[k], |x|] of each x (same nodes as clipping the panels at |x|)
            k = np.searchsorted(edges, af, side="right") - 1
            lo_e = edges[k]
            half_w = (af - lo_e) / 2
            pnodes = ((af + lo_e) / 2)[:, None] + half_w[:, None] * gx
            pwts = half_w[:, None] * gw
            part = cum[torch.from_numpy(k)] + self._weighted_sum(pnodes, pwts).sum(1)
            sign = torch.sign(flat[finite])[:, None]
            out[finite] = half + sign * part
        return out.reshape(*xt.shape, 3)

    def _weighted_sum(self, nodes: np.ndarray, wts: np.ndarray) -> torch.Tensor:
        """``wts · a_p(nodes)`` for ``(n, m)`` arrays -> ``(n, m, 3)``, in memory-bounded chunks
        (a numeric :meth:`preintegrated` is itself a quadrature)."""
        chunk = max(1, 4_000_000 // (nodes.shape[1] * self._preintegrated_cost))
        parts = []
        for s in range(0, nodes.shape[0], chunk):
            nd = torch.from_numpy(np.ascontiguousarray(nodes[s : s + chunk]))
            vals = self.preintegrated(nd)
            parts.append(
                vals * torch.from_numpy(np.ascontiguousarray(wts[s : s + chunk]))[..., None]
            )
        return torch.cat(parts, 0)

    def preintegrated_interval(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """``∫_a^b a_p(x) dx`` per channel, ``(..., 3)``; ``a`` and ``b`` may be ±inf."""
        return self.preintegrated_cdf(b) - self.preintegrated_cdf(a)

    def cell_integral(
        self,
        dx: torch.Tensor,
        dy: torch.Tensor,
        dz: torch.Tensor,
        half_x: torch.Tensor,
        half_y: torch.Tensor,
        slope_x: torch.Tensor | None = None,
        slope_y: torch.Tensor | None = None,
    ) -> torch.Tensor:
        """∫∫ R(|p|) dA over the cell ``[dx±half_x] × [dy±half_y]`` (mm), ``(..., 3)``.

        Fronto-parallel cell (no slopes): ``p = (x, y, dz)``. Tilted cell: the planar patch
        ``p = (dx+s, dy+t, dz + slope_x s + slope_y t)`` with its area element
        ``√(1 + slope_x² + slope_y²)`` — the same surface :class:`SumOfGaussians` integrates
        in closed form. The exact reference weights each neighbour by this integral: a profile
        narrower than a pixel keeps its full weight instead of being point-sampled. The default
        uses an 8×8 Gauss–Legendre rule per cell; closed forms override it. A profile with
        :attr:`singular_at_origin` integrates the cells whose nearest point to the origin lies
        within the cell dilated by its half-size (and within that distance of the patch's
        plane) in polar coordinates about that point (:func:`_polar_patch_integral`, exact up
        to a smooth angular quadrature and :meth:`radial_mass`).
        """
        x, w = _gauss_legendre(8)
        xt = torch.from_numpy(x).to(dx)
        wt = torch.from_numpy(w).to(dx)
        s = half_x[..., None] * xt  # (..., 8) offsets along x within the cell
        t = half_y[..., None] * xt
        px = dx[..., None] + s
        py = dy[..., None] + t
        pz = dz[..., None, None].expand(*px.shape, 8).clone()
        area = torch.ones_like(dx)
        if slope_x is not None or slope_y is not None:
            sx = torch.zeros_like(dx) if slope_x is None else slope_x.to(dx)
            sy = torch.zeros_like(dx) if slope_y is None else slope_y.to(dx)
            pz = pz + sx[..., None, None] * s[..., :, None] + sy[..., None, None] * t[..., None, :]
            area = torch.sqrt(1.0 + sx * sx + sy * sy)
        rr = torch.sqrt(px[..., :, None] ** 2 + py[..., None, :] ** 2 + pz**2)
        vals = self.evaluate(rr.double()).to(dx)  # (..., 8, 8, 3)
        ww = (wt[:, None] * wt[None, :])[..., None]
        out = (vals * ww).sum((-3, -2)) * (half_x * half_y * area)[..., None]
        if not self.singular_at_origin:
            return out
        cells = (dx, dy, dz, half_x, half_y, slope_x, slope_y)
        args = torch.broadcast_tensors(
            *(torch.zeros_like(dx) if v is None else v.to(dx) for v in cells)
        )
        flat = [a.reshape(-1).double() for a in args]
        foot = _foot_point(*flat[:3], *flat[5:])
        near = _near_singularity(foot, flat[3], flat[4])
        if not bool(near.any()):
            return out
        polar = _polar_patch_integral(self, *(v[near] for v in (*foot, flat[3], flat[4])))
        res = out.reshape(-1, 3).clone()
        res[near] = polar.to(res)
        return res.reshape(out.shape)

    def radial_mass(self, a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
        """``∫_a^b R(r) r dr`` per channel for float64 radii ``0 <= a <= b`` (mm, same shape),
        ``(..., 3)`` (dimensionless / 2π: the energy of the annulus is ``2π`` times this).

        The default is a 16-point Gauss–Legendre rule over ``[a, b]`` (``r R(r)`` is bounded
        for an integrable ``1/r`` singularity); accurate while ``b − a`` is at most a few of the
        profile's smallest length scale, which holds for the cells :meth:`cell_integral`
        integrates with it. Closed forms override it.
        """
        x, w = _gauss_legendre(_GL_ORDER)
        xt, wt = torch.from_numpy(x), torch.from_numpy(w)
        half = ((b - a) / 2)[..., None]
        r = ((a + b) / 2)[..., None] + half * xt
        vals = self.evaluate(r) * r[..., None]  # (..., Q, 3)
        return (vals * (half * wt)[..., None]).sum(-2)

    def radius(self, tol: float = 1e-4) -> float:
        """Support radius (mm) beyond which the profile can be neglected.

        The largest of: the radius where ``R`` falls below ``tol`` of its peak (issue 2 item 8)
        and the radius outside which less than ``tol`` of each channel's total energy lies.
        The second criterion is added because the first alone truncates several per cent of the
        red energy of skin (the narrow Gaussians set the peak; the wide ones hold the energy).
        """
        r, w = self._radial_quadrature()
        rt = torch.from_numpy(r)
        vals = self.evaluate(rt)  # (q, 3)
        peak = self.evaluate(torch.zeros(1, dtype=torch.float64))[0]
        energy = torch.from_numpy(2 * math.pi * r * w)[:, None] * vals
        tail = energy.flip(0).cumsum(0).flip(0)  # energy beyond each node
        total = energy.sum(0).clamp_min(1e-300)
        ok_energy = (tail <= tol * total).all(1)
        ok_peak = (vals <= tol * peak.clamp_min(1e-300)).all(1)
        ok = ok_energy & ok_peak
        # first node after which everything is ok
        bad = torch.nonzero(~ok).flatten()
        if bad.numel() == 0:
            return float(r[0])
        last_bad = int(bad[-1])
        return float(r[min(last_bad + 1, len(r) - 1)])

    def second_moment(self) -> torch.Tensor:
        """``∫ x² a_p(x) dx / total`` per channel (mm²): the variance of the 1D kernel, ``(3,)``."""
        r, w = self._radial_quadrature()
        vals = self.evaluate(torch.from_numpy(r))
        mom = (torch.from_numpy(math.pi * r**3 * w)[:, None] * vals).sum(0)
        return mom / self.total().clamp_min(1e-300)

    def dominant_channel(self) -> int:
        """Index of the widest channel (largest second moment; 000 §7 samples all channels
        at the dominant channel's positions)."""
        return int(torch.argmax(self.second_moment()))

    # ----------------------------------------------------------------- helpers
    def _radial_quadrature(self) -> tuple[np.ndarray, np.ndarray]:
        """Nodes and weights on [0, ~60 × largest scale] with panels geometric in r."""
        lo, hi = self.length_scales()
        edges = np.concatenate([[0.0], np.geomspace(lo / 64, hi * 60, 96)])
        return _panel_nodes(edges)


#: Gauss–Legendre nodes per angular sub-range of :func:`_polar_patch_integral`
_POLAR_ORDER = 24


def _foot_point(
    dx: torch.Tensor,
    dy: torch.Tensor,
    dz: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The point of the patch's plane ``p(s, t) = (dx+s, dy+t, dz + sx s + sy t)`` nearest to
    the origin: its parameters ``(cs, ct)``, its distance ``h0`` (mm) and the slopes; all
    ``(M,)`` float64.

    Normal equations ``JᵀJ c = −Jᵀ p(0, 0)`` with ``J = [(1, 0, sx), (0, 1, sy)]ᵀ``,
    ``det JᵀJ = 1 + sx² + sy²``; ``h0 = |dz − sx dx − sy dy| / √det`` (the plane's normal
    ``(−sx, −sy, 1)``).
    """
    det = 1 + sx * sx + sy * sy
    bx, by = dx + sx * dz, dy + sy * dz
    cs = -((1 + sy * sy) * bx - sx * sy * by) / det
    ct = -((1 + sx * sx) * by - sx * sy * bx) / det
    h0 = (dz - sx * dx - sy * dy).abs() / torch.sqrt(det)
    return cs, ct, h0, sx, sy


def _near_singularity(
    foot: tuple[torch.Tensor, ...], hx: torch.Tensor, hy: torch.Tensor
) -> torch.Tensor:
    """Cells (``(M,)`` bool) whose nearest plane point lies in the cell dilated by its half-size
    and at most a cell size off the plane: the ones a tensor-product rule cannot integrate
    near a ``1/r`` singularity."""
    cs, ct, h0 = foot[:3]
    return (cs.abs() <= 2 * hx) & (ct.abs() <= 2 * hy) & (h0 <= 2 * torch.maximum(hx, hy))


def _polar_patch_integral(
    profile: Profile,
    cs: torch.Tensor,
    ct: torch.Tensor,
    h0: torch.Tensor,
    sx: torch.Tensor,
    sy: torch.Tensor,
    hx: torch.Tensor,
    hy: torch.Tensor,
) -> torch.Tensor:
    """∫∫ R(|p(s, t)|) √det ds dt over ``[−hx, hx] × [−hy, hy]`` in polar coordinates
    ``(ρ, ψ)`` of the patch's own plane about the foot point ``c = (cs, ct)`` at distance
    ``h0`` (:func:`_foot_point`); all inputs ``(M,)`` float64, output ``(M, 3)``.

    In-plane orthonormal coordinates are ``X = Q (q − c)`` with ``Q`` the Cholesky factor of
    ``JᵀJ`` (``QᵀQ = JᵀJ``: ``Q = [[a, sx sy / a], [0, √det / a]]``, ``a = √(1 + sx²)``), so
    the surface element is ``ρ dρ dψ`` and the 3D distance ``r² = h0² + ρ²`` (Pythagoras:
    ``p(c)`` is normal to the plane). A ray's share of the cell is then exactly
    ``radial_mass(r_in, r_out)``, with ``ρ_in, ρ_out`` where it enters and leaves the
    rectangle (slab test on the parameter direction ``Q⁻¹ (cos ψ, sin ψ)``); no sign
    cancellation. Working in the plane's own metric (not in ``(s, t)``) keeps the integrand
    free of the ``1 / (1 + (sx cos θ + sy sin θ)²)`` spike of steep slopes.

    Angular rule: the corners' angles split ψ into 4 sub-ranges around ``c`` inside the cell,
    3 across the angle the cell subtends from outside (or on its boundary). In each the ray
    leaves (inside) or enters (outside) through one edge, at ``ρ = L / cos(ψ − ψ0)`` with
    ``L`` that edge line's distance and ``ψ0`` its normal's angle, which varies on the angular
    scale ``L / ρ``: sharp when ``c`` is near an edge. The sinh transformation of nearly
    singular integrals, ``ψ − ψ0 = atan(sinh μ)`` (``dψ = dμ / cosh μ``), Gauss–Legendre in
    ``μ``, clusters the nodes there (measured: relative error < 1e-9 with 24 nodes per
    sub-range for ``c`` from the centre to 1e-4 of a half-size off an edge, slopes up to the
    reference's 85°).
    """
    a = torch.sqrt(1 + sx * sx)
    root = torch.sqrt(1 + sx * sx + sy * sy)
    q01, q11 = sx * sy / a, root / a  # Q = [[a, q01], [0, q11]]
    # corners relative to c, in the plane's coordinates, (M, 4)
    vs = torch.stack([-hx, hx, hx, -hx], 1) - cs[:, None]
    vt = torch.stack([-hy, -hy, hy, hy], 1) - ct[:, None]
    x1, x2 = a[:, None] * vs + q01[:, None] * vt, q11[:, None] * vt
    inside = (cs.abs() < hx) & (ct.abs() < hy)  # on the boundary: the outside branch
    # angles from the direction towards the cell centre (outside; the corners' cone spans
    # <= π about it, so no wrap-around) or from the first axis (inside)
    base = torch.where(inside, torch.zeros_like(cs), torch.atan2(-q11 * ct, -a * cs - q01 * ct))
    cb, sb = torch.cos(base)[:, None], torch.sin(base)[:, None]
    phi = torch.atan2(x2 * cb - x1 * sb, x1 * cb + x2 * sb).sort(1).values + base[:, None]
    last = torch.where(inside, phi[:, 0] + 2 * math.pi, phi[:, 3])
    bounds = torch.cat([phi, last[:, None]], 1)  # (M, 5): 4 sub-ranges (the 4th empty outside)
    lo, hi = bounds[:, :-1], bounds[:, 1:]  # (M, 4)
    e = lambda v: v[:, None]  # noqa: E731

    def direction(psi: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Parameter direction ``u = Q⁻¹ (cos ψ, sin ψ)`` (``(M, 4[, Q])``)."""
        ex = (lambda v: v[:, None, None]) if psi.dim() == 3 else e
        ut = torch.sin(psi) / ex(q11)
        us = (torch.cos(psi) - ex(q01) * ut) / ex(a)
        tiny = torch.finfo(torch.float64).tiny
        return torch.where(us == 0, tiny, us), torch.where(ut == 0, tiny, ut)

    # the critical edge of each sub-range, from its middle ray: the face the ray leaves by
    # (inside) or enters by (outside); ``side`` is its s or t value
    us, ut = direction((lo + hi) / 2)
    s_exit, t_exit = torch.sign(us) * e(hx), torch.sign(ut) * e(hy)
    far_s, far_t = (s_exit - e(cs)) / us, (t_exit - e(ct)) / ut
    near_s, near_t = (-s_exit - e(cs)) / us, (-t_exit - e(ct)) / ut
    on_s = torch.where(e(inside), far_s < far_t, near_s > near_t)
    side_s = torch.where(e(inside), s_exit, -s_exit)
    side_t = torch.where(e(inside), t_exit, -t_exit)
    # the edge line in X: n · X = k with n = (1, −q01/q11) (s face) or (0, 1) (t face)
    n1 = torch.where(on_s, torch.ones_like(lo), torch.zeros_like(lo))
    n2 = torch.where(on_s, -e(q01 / q11), torch.ones_like(lo))
    k = torch.where(on_s, e(a) * (side_s - e(cs)), e(q11) * (side_t - e(ct)))
    norm = torch.sqrt(n1 * n1 + n2 * n2)
    dist = k.abs() / norm
    psi0 = torch.atan2(torch.sign(k) * n2, torch.sign(k) * n1)
    wrap = lambda v: torch.atan2(torch.sin(v), torch.cos(v))  # noqa: E731
    mu1 = torch.asinh(torch.tan(wrap(lo - psi0)))[..., None]
    mu2 = torch.asinh(torch.tan(wrap(hi - psi0)))[..., None]
    x, w = _gauss_legendre(_POLAR_ORDER)
    xt, wt = torch.from_numpy(x), torch.from_numpy(w)
    mu = (mu1 + mu2) / 2 + (mu2 - mu1) / 2 * xt  # (M, 4, Q)
    psi = psi0[..., None] + torch.atan(torch.sinh(mu))
    wpsi = (mu2 - mu1) / 2 * wt / torch.cosh(mu)
    # a critical edge through c (c on the boundary) has no scale to cluster at: plain rule
    flat = (dist <= 1e-12 * torch.maximum(e(hx), e(hy)))[..., None]
    psi = torch.where(flat, (lo + hi)[..., None] / 2 + (hi - lo)[..., None] / 2 * xt, psi)
    wpsi = torch.where(flat, (hi - lo)[..., None] / 2 * wt, wpsi)
    us, ut = direction(psi)
    ee = lambda v: v[:, None, None]  # noqa: E731
    s1, s2 = (-ee(hx) - ee(cs)) / us, (ee(hx) - ee(cs)) / us
    t1, t2 = (-ee(hy) - ee(ct)) / ut, (ee(hy) - ee(ct)) / ut
    rho_in = torch.maximum(torch.minimum(s1, s2), torch.minimum(t1, t2)).clamp_min(0.0)
    rho_out = torch.maximum(torch.minimum(torch.maximum(s1, s2), torch.maximum(t1, t2)), rho_in)
    h2 = ee(h0) ** 2
    mass = profile.radial_mass(torch.sqrt(h2 + rho_in**2), torch.sqrt(h2 + rho_out**2))
    return (mass * wpsi[..., None]).sum((1, 2))
