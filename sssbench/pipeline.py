"""Compose operators, decide what a scene needs, time each pass (DESIGN §5).

``Pipeline.plan(gbuffer)`` decides per stage whether it runs and records why not;
``Pipeline.run(gbuffer)`` executes the plan and returns the image with one
:class:`~sssbench.ops.timing.PassRecord` per executed pass.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from sssbench.gbuffer import GBuffer
from sssbench.ops.timing import PassRecord, record_passes, timed_pass

__all__ = ["Pipeline", "PipelineResult", "PlanEntry", "PassRecord"]


@dataclass(frozen=True)
class PlanEntry:
    """One stage of a plan: whether it runs, and the reason when it does not."""

    stage: str
    runs: bool
    reason: str = ""


@dataclass
class PipelineResult:
    """Output of :meth:`Pipeline.run`.

    Attributes:
        image: ``(B, 3, H, W)`` final radiance.
        records: every executed pass, in order.
        plan: the plan that was executed (skipped stages carry their reason).
    """

    image: torch.Tensor
    records: list[PassRecord] = field(default_factory=list)
    plan: list[PlanEntry] = field(default_factory=list)

    @property
    def skipped(self) -> list[tuple[str, str]]:
        return [(e.stage, e.reason) for e in self.plan if not e.runs]


class Pipeline(nn.Module):
    """blur method -> specular add.

    Args:
        method: an SSS operator, ``forward(gbuffer) -> (B, 3, H, W)`` scattered diffuse.
        add_specular: add ``gbuffer.specular`` after scattering (DESIGN §5: only if present).

    Example:
        >>> from sssbench.ops import PreintegratedSSS
        >>> from sssbench.profiles import SumOfGaussians
        >>> pipe = Pipeline(PreintegratedSSS(SumOfGaussians.from_table("skin_jg10")))
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 300.0), 0.4)
        >>> [e.stage for e in pipe.plan(g) if e.runs]
        ['sss']
    """

    def __init__(self, method: nn.Module, *, add_specular: bool = True) -> None:
        super().__init__()
        if not isinstance(method, nn.Module):
            raise TypeError(f"method must be an nn.Module, got {type(method).__name__}")
        self.method = method
        self.add_specular = add_specular

    @property
    def needs(self) -> tuple[str, ...]:
        """Optional G-buffer fields the pipeline can use (scenes build only these)."""
        fields = set(getattr(self.method, "needs", ()))
        if self.add_specular:
            fields.add("specular")
        return tuple(sorted(fields))

    def plan(self, gbuffer: GBuffer) -> list[PlanEntry]:
        """Decide which stages run on ``gbuffer`` and why the others do not."""
        if not isinstance(gbuffer, GBuffer):
            raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
        entries = []
        if gbuffer.mask is not None and not bool((gbuffer.mask > 0).any()):
            entries.append(PlanEntry("sss", False, "mask is zero everywhere (stencil)"))
        else:
            entries.append(PlanEntry("sss", True))
        if not self.add_specular:
            entries.append(PlanEntry("specular", False, "disabled"))
        elif gbuffer.specular is None:
            entries.append(PlanEntry("specular", False, "no specular in the G-buffer"))
        else:
            entries.append(PlanEntry("specular", True))
        return entries

    def run(self, gbuffer: GBuffer) -> PipelineResult:
        """Execute the plan; every executed pass leaves a record."""
        plan = self.plan(gbuffer)
        runs = {e.stage for e in plan if e.runs}
        with record_passes() as records:
            image = self.method(gbuffer) if "sss" in runs else gbuffer.diffuse
            if "specular" in runs:
                b, h, w = gbuffer.shape
                with timed_pass("specular", 1, b * h * w):
                    image = image + gbuffer.specular
        return PipelineResult(image, list(records), plan)

    def forward(self, gbuffer: GBuffer) -> torch.Tensor:
        return self.run(gbuffer).image
