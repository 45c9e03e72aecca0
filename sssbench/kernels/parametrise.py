"""Parametrisations of a method's kernel for the fit of :mod:`sssbench.tune.optimise`.

A parametrisation holds unconstrained parameters (an ``nn.Module``) whose every value is a
valid kernel for its method, and knows which attributes of the method the kernel lives in.
The one optimiser loop (:func:`sssbench.tune.optimise.fit_taps`) writes
:meth:`Parametrisation.value` into the method, runs the method's own passes and steps the
parameters; the best parameters become a :class:`Fitted` (detached), which is what is cached
and what :meth:`Parametrisation.install` puts into a method built with
``sampling="optimised"``.

- :class:`SymmetricTaps`: one symmetric two-pass kernel (the pre-integrated kernel, 000 eq. 5):
  its ``K`` offsets and ``K × 3`` weights.
- :class:`PerGaussianTaps`: the sum of Gaussians' tap sets (003 §7.3.3): one
  :class:`SymmetricTaps` per Gaussian that is blurred (each normalised on its own, as each
  incremental Gaussian is a normalised blur); the variances and blend weights stay.
- :class:`Jimenez2012Parameters`: the 2012 kernel's continuous parameters (002 eq. 1): per
  channel strength ``t`` and falloff ``f``, and the width; the taps stay where the 2012
  kernel builder puts them (power placement, 002 appendix), their weights follow ``t, f``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import torch
from torch import nn

from sssbench.kernels.artist import _per_channel
from sssbench.kernels.jimenez2012 import jimenez2012
from sssbench.kernels.kernel1d import Kernel1D

__all__ = [
    "Fitted",
    "Parametrisation",
    "SymmetricTaps",
    "PerGaussianTaps",
    "Jimenez2012Parameters",
]

_TINY = torch.finfo(torch.float64).tiny


@dataclass(frozen=True)
class Fitted:
    """A fitted kernel as data (what the cache stores and a method installs).

    Attributes:
        kernels: the method's 1D kernels (float64, detached): one for a two-pass method, one
            per Gaussian step for the sum of Gaussians (``None`` for a step without a pass).
        params: continuous parameters as plain numbers (the 2012 kernel's ``strength`` and
            ``falloff`` (3 each) and ``width`` mm), empty for tap parametrisations.
    """

    kernels: tuple[Kernel1D | None, ...]
    params: dict[str, Any] = field(default_factory=dict)

    @property
    def kernel(self) -> Kernel1D:
        """The only kernel of a two-pass method."""
        if len(self.kernels) != 1 or self.kernels[0] is None:
            raise ValueError(f"this fit holds {len(self.kernels)} kernels, not one: use .kernels")
        return self.kernels[0]

    def as_dict(self) -> dict[str, Any]:
        return {
            "kernels": [None if k is None else k.as_dict() for k in self.kernels],
            "params": self.params,
        }

    @classmethod
    def from_dict(cls, entry: Mapping[str, Any]) -> Fitted:
        def kernel(d: Mapping[str, Any] | None) -> Kernel1D | None:
            if d is None:
                return None
            return Kernel1D(
                torch.tensor(d["offsets"], dtype=torch.float64),
                torch.tensor(d["weights"], dtype=torch.float64),
            )

        return cls(tuple(kernel(d) for d in entry["kernels"]), dict(entry["params"]))


def _detached(kernel: Kernel1D) -> Kernel1D:
    return Kernel1D(kernel.offsets.detach(), kernel.weights.detach())


class Parametrisation(nn.Module):
    """Unconstrained parameters -> a method's kernel state (module doc)."""

    def value(self) -> dict[str, Any]:
        """The method attributes of the current parameters (differentiable), e.g.
        ``{"kernel": Kernel1D}``."""
        raise NotImplementedError

    def fitted(self) -> Fitted:
        """The current parameters as a :class:`Fitted` (detached)."""
        raise NotImplementedError

    @staticmethod
    def install(method: nn.Module, fitted: Fitted) -> None:
        """Put ``fitted`` into ``method`` (the attributes :meth:`value` sets)."""
        raise NotImplementedError


# ------------------------------------------------------------------- one symmetric kernel
def _softplus_inverse(y: torch.Tensor) -> torch.Tensor:
    """``log(exp(y) − 1)`` for ``y > 0``, stable for small and large ``y``."""
    return torch.where(y > 20.0, y, torch.log(torch.expm1(y.clamp_max(20.0))))


class SymmetricTaps(Parametrisation):
    """Symmetric, sorted, normalised taps as unconstrained parameters.

    - offsets symmetric and sorted: the positive half is ``s · cumsum(softplus(u))`` (strictly
      increasing, > 0; ``s`` the initial extent in mm, so ``u`` is O(1)), mirrored, with a
      centre tap fixed at 0 for an odd tap count;
    - weights per channel non-negative, normalised and symmetric: a softmax over the taps of
      mirrored logits (``w_{-i} = w_i``, ``Σ w = 1``, as the normalised kernel of 000 eq. 5).

    Args:
        init: the starting kernel, symmetric (``offsets[i] = −offsets[K−1−i]``, a centre tap
            at 0 when K is odd, no two offsets equal) with non-negative weights summing to 1
            per channel — e.g. the importance-sampled kernel (000 §7).
        grey: one weight per tap for all three channels (``init`` must have equal channels),
            e.g. one Gaussian's blur of the sum of Gaussians; ``False``: per channel.

    Attributes:
        u: ``(K // 2,)`` softplus pre-images of the gaps between successive positive offsets,
            in units of ``scale`` mm.
        logits: ``(K // 2 + K % 2, C)`` log-weights of the centre (odd K) and the positive
            taps, ``C = 1`` when ``grey``, else 3.
    """

    def __init__(self, init: Kernel1D, grey: bool = False) -> None:
        super().__init__()
        if not isinstance(init, Kernel1D):
            raise TypeError(f"init must be a Kernel1D, got {type(init).__name__}")
        off = init.offsets.detach().to(torch.float64)
        w = init.weights.detach().to(torch.float64)
        k = len(init)
        self.taps, self.has_centre = k, k % 2 == 1
        m = k // 2
        scale = max(float(off.abs().max()), 1e-6)
        if not torch.allclose(off, -off.flip(0), atol=1e-9 * scale, rtol=0):
            raise ValueError(f"init offsets must be symmetric about 0, got {off.tolist()}")
        if not torch.allclose(w, w.flip(0), atol=1e-9, rtol=1e-7):
            raise ValueError("init weights must be symmetric (w[i] = w[K-1-i])")
        if bool((w < 0).any()) or not torch.allclose(w.sum(0), torch.ones(3, dtype=w.dtype)):
            raise ValueError("init weights must be >= 0 and sum to 1 per channel")
        if grey:
            if not torch.allclose(w, w[:, :1].expand_as(w), atol=1e-12, rtol=0):
                raise ValueError("init weights must be equal in every channel with grey=True")
            w = w[:, :1]
        pos = off[k - m :]
        gaps = torch.diff(torch.cat([pos.new_zeros(1), pos]))
        if bool((gaps <= 0).any()):
            raise ValueError(f"init offsets must be distinct (and the centre at 0), got {off}")
        self.scale = scale
        self.u = nn.Parameter(_softplus_inverse(gaps / scale))
        half = w[m:]  # the centre (odd K) and the positive taps
        self.logits = nn.Parameter(torch.log(half.clamp_min(_TINY)))

    def kernel(self) -> Kernel1D:
        """The current taps as a :class:`Kernel1D` (float64, differentiable)."""
        pos = self.scale * torch.cumsum(nn.functional.softplus(self.u), 0)
        mid = [pos.new_zeros(1)] if self.has_centre else []
        offsets = torch.cat([-pos.flip(0), *mid, pos])
        pairs = self.logits[1:] if self.has_centre else self.logits
        weights = torch.softmax(torch.cat([pairs.flip(0), self.logits]), dim=0)
        return Kernel1D(offsets, weights.expand(-1, 3))

    def value(self) -> dict[str, Any]:
        return {"kernel": self.kernel()}

    def fitted(self) -> Fitted:
        return Fitted((_detached(self.kernel()),))

    @staticmethod
    def install(method: nn.Module, fitted: Fitted) -> None:
        method.kernel = fitted.kernel


# ------------------------------------------------------------------- sum of Gaussians
class PerGaussianTaps(Parametrisation):
    """The sum of Gaussians' tap sets: one :class:`SymmetricTaps` per Gaussian step that runs
    passes (003 §7.3.3), each normalised on its own; the steps' variances and blend weights
    ``w'`` are kept (the profile's, not fitted: a choice, so that the method stays 003's
    schedule and only its discretisation changes).

    Each tap set is grey (one weight per tap for R, G and B), as each Gaussian's blur is in
    003 (the colour comes from the blend weights): a choice. Measured with the held-out
    scenes of ``experiments/optimised.py`` (7 and 9 taps, 0.3 and 1 mm per pixel), per-channel
    weights (3× the parameters) fit the training scenes better (loss 0.54–0.89 against
    0.60–0.91) but change the held-out gains by at most 2 points (e.g. the portrait head
    −8 % against −10 % at 7 taps).

    Args:
        steps: the method's :class:`~sssbench.ops.sum_of_gaussians.SoGStep` list; steps whose
            ``kernel`` is ``None`` (the unblurred first Gaussian) stay without passes.
    """

    def __init__(self, steps: Sequence[Any]) -> None:
        super().__init__()
        if not steps or not all(hasattr(s, "kernel") for s in steps):
            raise TypeError("steps must be a non-empty sequence of SoGStep")
        self.steps = list(steps)
        self.taps = nn.ModuleList(
            SymmetricTaps(s.kernel, grey=True) for s in steps if s.kernel is not None
        )

    def _kernels(self) -> list[Kernel1D | None]:
        fitted = iter(t.kernel() for t in self.taps)
        return [None if s.kernel is None else next(fitted) for s in self.steps]

    def value(self) -> dict[str, Any]:
        kernels = self._kernels()
        return {"steps": [replace(s, kernel=k) for s, k in zip(self.steps, kernels, strict=True)]}

    def fitted(self) -> Fitted:
        return Fitted(tuple(None if k is None else _detached(k) for k in self._kernels()))

    @staticmethod
    def install(method: nn.Module, fitted: Fitted) -> None:
        steps = method.schedule
        if len(fitted.kernels) != len(steps) or any(
            (k is None) != (s.kernel is None) for k, s in zip(fitted.kernels, steps, strict=True)
        ):
            raise ValueError("the fitted kernels do not match the method's Gaussian steps")
        method.steps = [replace(s, kernel=k) for s, k in zip(steps, fitted.kernels, strict=True)]


# ------------------------------------------------------------------- the 2012 kernel
class Jimenez2012Parameters(Parametrisation):
    """The 2012 kernel's strength, falloff and width (002 eq. 1) as unconstrained parameters.

    ``t = sigmoid(a)`` in (0, 1), ``f = exp(b)`` > 0 per channel, width ``w = w₀ · exp(c)``
    with ``w₀`` the method's width (mm). The taps are :func:`~sssbench.kernels.jimenez2012`'s
    (power placement and quadrature of the 2012 kernel builder, 002 appendix) for ``t, f``;
    during the fit the width ratio ``exp(c)`` scales their offsets, so the method keeps its
    width ``w₀`` and its surface scale (the follow-surface lerp's depth step, ``w₀`` by
    default) is the same in every iterate. :meth:`install` writes the fitted ``t, f`` and
    ``w = w₀ exp(c)`` into the method (offsets in widths again): the same passes, and
    parameters a 2012 shader can take as they are.

    Args:
        method: a :class:`~sssbench.ops.Jimenez2012SSS` (its ``strength``, ``falloff``,
            ``width``, ``samples``, ``base_profile`` and ``quadrature`` are the start). A
            strength of exactly 0 or 1 starts at 1e-6 from it (the logit is finite), a falloff
            of 0 at 1e-6.
    """

    def __init__(self, method: nn.Module) -> None:
        super().__init__()
        for name in ("strength", "falloff", "width", "samples", "base_profile", "quadrature"):
            if not hasattr(method, name):
                raise TypeError(f"method must be a Jimenez2012SSS (it has no {name!r})")
        t = _per_channel("strength", method.strength, 0.0, 1.0).detach().double()
        f = _per_channel("falloff", method.falloff, 0.0, None).detach().double()
        self.width0 = float(method.width)
        self.samples, self.profile = method.samples, method.base_profile
        self.quadrature = method.quadrature
        self.a = nn.Parameter(torch.logit(t.clamp(1e-6, 1 - 1e-6)))
        self.b = nn.Parameter(torch.log(f.clamp_min(1e-6)))
        self.c = nn.Parameter(torch.zeros((), dtype=torch.float64))

    def _taps(self) -> Kernel1D:
        """The 2012 kernel of the current ``t, f`` (offsets in widths)."""
        t, f = torch.sigmoid(self.a), torch.exp(self.b)
        return jimenez2012(t, f, self.samples, profile=self.profile, quadrature=self.quadrature)

    def value(self) -> dict[str, Any]:
        k = self._taps()
        return {"kernel": Kernel1D(k.offsets * torch.exp(self.c), k.weights)}

    def fitted(self) -> Fitted:
        with torch.no_grad():
            params = {
                "strength": torch.sigmoid(self.a).tolist(),
                "falloff": torch.exp(self.b).tolist(),
                "width": self.width0 * float(torch.exp(self.c)),
            }
            return Fitted((_detached(self._taps()),), params)

    @staticmethod
    def install(method: nn.Module, fitted: Fitted) -> None:
        method.kernel = fitted.kernel
        method.strength = tuple(fitted.params["strength"])
        method.falloff = tuple(fitted.params["falloff"])
        method.width = float(fitted.params["width"])
