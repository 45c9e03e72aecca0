"""Compose operators, decide what a scene needs, time each pass (DESIGN §5).

The pipeline is the SSS stage of a deferred renderer:

    translucency -> texturing (before) -> blur method -> texturing (after) -> specular add
                                   ^ curvature width, halo weights

- translucency (004 §3.2): transmitted back light added to the irradiance before the blur, so
  it scatters with its neighbours;
- texturing (001 §5.3): ``pre`` / ``post`` / ``sqrt``, split around the blur (the method never
  sees the mode, so every method gets every mode);
- curvature modulation (004 §3.3.3): a per-pixel width multiplier passed to the method as
  ``width=``; halo reduction (004 §3.3.1 / §3.3.2): ``guide=`` and ``sample_weight=`` for the
  method's gather passes;
- specular (001 §5.4): added after scattering.

``Pipeline.plan(gbuffer)`` decides per stage whether it runs and records why not;
``Pipeline.run(gbuffer)`` executes the plan and returns the image with one
:class:`~sssbench.ops.timing.PassRecord` per executed pass.

Stencil: every per-pixel stage (translucency, texturing, the gather passes, specular) computes
only where ``mask > 0`` and records that pixel count; pixels outside the mask keep
``gbuffer.diffuse`` (they are not the SSS stage's business). The curvature map and the halo
guide are image filters whose values the gather also reads at neighbours outside the mask, so
they are computed (and recorded) over the full frame.
"""

from __future__ import annotations

import copy
import inspect
from dataclasses import dataclass, field

import torch
from torch import nn

from sssbench._checks import check_choice
from sssbench.gbuffer import GBuffer
from sssbench.ops._stencil import active_pixels, apply_on_active
from sssbench.ops.curvature import CurvatureModulation
from sssbench.ops.halo import HALO_KINDS, halo_weight
from sssbench.ops.texturing import TEXTURING_MODES, Texturing
from sssbench.ops.timing import PassRecord, record_passes, timed_pass
from sssbench.ops.translucency import Translucency, back_light

__all__ = ["Pipeline", "PipelineResult", "PlanEntry", "PassRecord", "STAGES"]

#: stages in execution order
STAGES = ("translucency", "texturing", "curvature", "halo", "sss", "specular")

#: automatic plan (``auto=True``, DESIGN §5): translucency is left out when the transmittance
#: at the thinnest back-lit pixel is below this (the stage could add at most this fraction of
#: the back light)
AUTO_TRANSMITTANCE = 1e-3
#: ... curvature modulation when no pixel's kernel width changes by more than this fraction
AUTO_WIDTH_CHANGE = 0.02
#: ... halo reduction when no depth step between neighbouring stencil pixels exceeds this many
#: pixel footprints (a surface steeper than atan(8) ≈ 83° to the view: a silhouette)
AUTO_SILHOUETTE_STEP = 8.0

_ZERO_MASK = "mask is zero everywhere (stencil)"


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


def _accepts(method: nn.Module, names: tuple[str, ...]) -> bool:
    params = inspect.signature(method.forward).parameters
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return True
    return all(n in params for n in names)


def _largest_depth_step_px(g: GBuffer) -> float:
    """The largest depth step (in pixel footprints) between neighbouring pixels of which at
    least one is in the stencil (DESIGN §2: footprint = 2 z tan(fov_y/2) / H)."""
    from sssbench.gbuffer import pixel_size_mm

    z = g.depth.double()
    foot = pixel_size_mm(z, g.fov_y, g.shape[1])
    inside = g.mask_or_ones() > 0
    worst = 0.0
    for dim in (2, 3):
        if z.shape[dim] < 2:
            continue
        dz = (z.narrow(dim, 1, z.shape[dim] - 1) - z.narrow(dim, 0, z.shape[dim] - 1)).abs()
        f = torch.minimum(
            foot.narrow(dim, 1, z.shape[dim] - 1), foot.narrow(dim, 0, z.shape[dim] - 1)
        )
        near = inside.narrow(dim, 1, z.shape[dim] - 1) | inside.narrow(dim, 0, z.shape[dim] - 1)
        if bool(near.any()):
            worst = max(worst, float((dz / f)[near].max()))
    return worst


def _width_change(width: torch.Tensor, g: GBuffer) -> float:
    """Largest |width − 1| over the stencil (the curvature stage's effect on kernel widths)."""
    inside = g.mask_or_ones() > 0
    return float((width - 1).abs()[inside].max()) if bool(inside.any()) else 0.0


def _widths_unchanged(width: torch.Tensor, g: GBuffer) -> str | None:
    """The automatic plan's reason to leave curvature modulation out (no width changes by more
    than :data:`AUTO_WIDTH_CHANGE`), or ``None`` when it changes some width enough."""
    change = _width_change(width, g)
    if change > AUTO_WIDTH_CHANGE:
        return None
    return (
        f"auto: widths change by at most {change:.2g} <= {AUTO_WIDTH_CHANGE:g} "
        "(computed, not applied)"
    )


def _gate(stage: str, configured: bool, missing: str | None, covered: bool) -> PlanEntry:
    """A stage runs when configured, its G-buffer fields exist and some pixel is masked in
    (DESIGN §5); otherwise the entry carries the first reason it does not."""
    if not configured:
        return PlanEntry(stage, False, "disabled")
    if missing is not None:
        return PlanEntry(stage, False, missing)
    if not covered:
        return PlanEntry(stage, False, _ZERO_MASK)
    return PlanEntry(stage, True)


class Pipeline(nn.Module):
    """translucency -> texturing -> blur method -> texturing -> specular add (module docstring).

    Args:
        method: an SSS operator, ``forward(gbuffer) -> (B, 3, H, W)`` scattered diffuse. With
            ``curvature`` it must accept ``forward(gbuffer, width=(B, 1, H, W))`` (a multiplier
            of its kernel width), with ``halo`` ``forward(gbuffer, guide=..., sample_weight=...)``
            (forwarded to :func:`~sssbench.ops.separable_pass`).
        translucency: a :class:`~sssbench.ops.Translucency` (004 §3.2), or ``None``. The
            pipeline applies albedo in its texturing stage, so a translucency built with
            ``apply_albedo=True`` is copied with ``apply_albedo=False``.
        texturing: ``None`` (the blur scatters ``diffuse`` as given; default, which keeps the
            output comparable with earlier runs), ``"pre"``, ``"post"`` or ``"sqrt"`` (001 §5.3).
        curvature: a :class:`~sssbench.ops.CurvatureModulation` (004 §3.3.3), or ``None``.
        halo: ``None``, ``"bilateral"`` (004 §3.3.1) or ``"lab"`` (004 §3.3.2).
        halo_sigma: range σ of ``halo`` (``None``: :data:`~sssbench.ops.halo.DEFAULT_SIGMA`).
        add_specular: add ``gbuffer.specular`` after scattering (DESIGN §5: only if present).
        irradiance: extra stages on the irradiance before the blur (after translucency), in
            order: modules with a ``name`` (str), ``needs`` (G-buffer fields) and
            ``forward(gbuffer, image) -> image``; optionally ``skip(gbuffer) -> str | None``
            (a reason to leave the stage out on this scene). Each runs as one timed pass over
            the stencil and appears in the plan as ``irradiance.<name>`` (docs/extending.md).
        auto: leave out configured stages the scene does not need, decided from the scene
            itself and recorded in the plan: translucency where no back-lit pixel is thin
            enough to transmit (:data:`AUTO_TRANSMITTANCE`), halo reduction where the stencil
            has no silhouette (:data:`AUTO_SILHOUETTE_STEP`), curvature modulation where it
            changes no width by more than :data:`AUTO_WIDTH_CHANGE`. ``False`` runs every
            configured stage whose fields exist.

    Example:
        >>> from sssbench.ops import PreintegratedSSS
        >>> from sssbench.profiles import SumOfGaussians
        >>> pipe = Pipeline(PreintegratedSSS(SumOfGaussians.from_table("skin_jg10")))
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 300.0), 0.4)
        >>> [e.stage for e in pipe.plan(g) if e.runs]
        ['sss']
    """

    def __init__(
        self,
        method: nn.Module,
        *,
        translucency: Translucency | None = None,
        texturing: str | None = None,
        curvature: CurvatureModulation | None = None,
        halo: str | None = None,
        halo_sigma: float | None = None,
        add_specular: bool = True,
        irradiance: tuple[nn.Module, ...] | list[nn.Module] = (),
        auto: bool = True,
    ) -> None:
        super().__init__()
        if not isinstance(method, nn.Module):
            raise TypeError(f"method must be an nn.Module, got {type(method).__name__}")
        if translucency is not None and not isinstance(translucency, Translucency):
            raise TypeError(
                f"translucency must be a Translucency or None, got {type(translucency).__name__}"
            )
        check_choice("texturing", texturing, (None, *TEXTURING_MODES))
        if curvature is not None and not isinstance(curvature, CurvatureModulation):
            raise TypeError(
                f"curvature must be a CurvatureModulation or None, got {type(curvature).__name__}"
            )
        check_choice("halo", halo, (None, *HALO_KINDS))
        if curvature is not None and not _accepts(method, ("width",)):
            raise TypeError(
                f"curvature needs a method whose forward accepts width=; "
                f"{type(method).__name__}.forward does not"
            )
        if halo is not None and not _accepts(method, ("guide", "sample_weight")):
            raise TypeError(
                f"halo needs a method whose forward accepts guide= and sample_weight=; "
                f"{type(method).__name__}.forward does not"
            )
        self.method = method
        if translucency is not None and translucency.apply_albedo:
            translucency = Translucency(
                translucency.profile,
                translucency.translucency,
                translucency.width,
                form=translucency.form,
                intensity=translucency.intensity,
                apply_albedo=False,
            )
        self.translucency = translucency
        self.texturing = None if texturing is None else Texturing(texturing)
        self.curvature = curvature
        self.halo = halo
        self.halo_sigma = halo_sigma
        self.add_specular = add_specular
        self.auto = bool(auto)
        for stage in irradiance:
            if not isinstance(stage, nn.Module) or not isinstance(
                getattr(stage, "name", None), str
            ):
                raise TypeError(
                    "irradiance stages must be nn.Modules with a name attribute, got "
                    f"{type(stage).__name__}"
                )
        self.irradiance = nn.ModuleList(irradiance)

    @property
    def needs(self) -> tuple[str, ...]:
        """Optional G-buffer fields the configured pipeline uses (scenes build only these)."""
        fields = set(getattr(self.method, "needs", ()))
        for stage in (self.translucency, self.texturing, self.curvature, *self.irradiance):
            if stage is not None:
                fields |= set(getattr(stage, "needs", ()))
        if self.halo == "bilateral":
            fields.add("normal")
        elif self.halo == "lab":
            fields.add("albedo")
        if self.add_specular:
            fields.add("specular")
        return tuple(sorted(fields))

    # ------------------------------------------------------------------ plan
    def _plan_translucency(self, g: GBuffer, covered: bool) -> PlanEntry:
        if self.translucency is None:
            return PlanEntry("translucency", False, "disabled")
        for name in ("thickness", "normal", "light_dir"):
            if getattr(g, name) is None:
                return PlanEntry("translucency", False, f"no {name} in the G-buffer")
        if not covered:
            return PlanEntry("translucency", False, _ZERO_MASK)
        # the stage is non-zero where its cosine term is
        wrap = 0.3 if self.translucency.form == "jimenez2012" else 0.0
        lit = self._lit(g)
        if not bool(lit.any()):
            bound = "-0.3" if wrap else "0"
            return PlanEntry(
                "translucency",
                False,
                f"no back light: n·(-l) <= {bound} at every masked pixel (light in front)",
            )
        if self.auto:
            most, total, thinnest = self._most_transmitted(g, lit)
            if most / total < AUTO_TRANSMITTANCE:
                return PlanEntry(
                    "translucency",
                    False,
                    f"auto: too thick to transmit (T = {most / total:.2g} < {AUTO_TRANSMITTANCE:g}"
                    f" at the thinnest back-lit pixel, {thinnest:.3g} mm)",
                )
        return PlanEntry("translucency", True)

    def _lit(self, g: GBuffer) -> torch.Tensor:
        """Masked pixels where translucency's cosine term is non-zero: clamp(0.3 + n·(−l)) > 0
        (004 Fig. 3.11) or n·(−l) > 0 (deon)."""
        assert self.translucency is not None
        wrap = 0.3 if self.translucency.form == "jimenez2012" else 0.0
        return (back_light(g) + wrap > 0) & (g.mask_or_ones() > 0)

    def _most_transmitted(self, g: GBuffer, lit: torch.Tensor) -> tuple[float, float, float]:
        """``(T, total, thinnest)``: the largest transmittance over the back-lit pixels ``lit``
        (at the thinnest, in float64), the profile's total weight, and that thickness (mm)."""
        t = self.translucency
        assert t is not None
        thinnest = float(g.thickness[lit].min())
        s = thinnest  # 001 eq. 16: the distance through the material, mm
        if t.form == "jimenez2012":  # 004 Fig. 3.11: scale = 8.25 (1 − translucency) / width
            s = thinnest * 8.25 * (1.0 - t.translucency) / t.width
        from sssbench.ops.translucency import transmittance

        most = float(transmittance(torch.tensor([s], dtype=torch.float64), t.profile).max())
        total = float(t.profile.weights.sum(0).max()) if hasattr(t.profile, "weights") else 1.0
        return most, total, thinnest

    def inert(self, gbuffer: GBuffer) -> dict[str, str]:
        """The configured stages that can run on ``gbuffer`` but would leave its image exactly
        as it is, with the reason: translucency whose transmittance at the thinnest back-lit
        pixel is 0 in float64 (001 eq. 16 underflows: every pixel adds exactly 0, in any
        dtype). The app refuses such a stage when it is switched on (issue 28).

        Returns:
            stage -> reason; empty when every runnable stage can change the image.
        """
        own = {e.stage: e.runs for e in self.plan(gbuffer)}
        out: dict[str, str] = {}
        if own.get("translucency"):
            most, _, thinnest = self._most_transmitted(gbuffer, self._lit(gbuffer))
            if most == 0.0:
                out["translucency"] = (
                    f"too thick to transmit anything (T = 0 in float64 at the thinnest "
                    f"back-lit pixel, {thinnest:.3g} mm: it would add exactly nothing)"
                )
        return out

    def _plan_halo(self, g: GBuffer, covered: bool) -> PlanEntry:
        no_normals = None if g.normal is not None else "no normals in the G-buffer"
        entry = _gate(
            "halo", self.halo is not None, no_normals if self.halo == "bilateral" else None, covered
        )
        if not (entry.runs and self.auto):
            return entry
        step = _largest_depth_step_px(g)
        if step <= AUTO_SILHOUETTE_STEP:
            return PlanEntry(
                "halo",
                False,
                f"auto: no silhouette in the stencil (largest depth step {step:.3g} pixel "
                f"footprints <= {AUTO_SILHOUETTE_STEP:g})",
            )
        return entry

    def plan(self, gbuffer: GBuffer) -> list[PlanEntry]:
        """Decide which stages run on ``gbuffer`` and why the others do not (DESIGN §5).

        Returns:
            one :class:`PlanEntry` per stage of :data:`STAGES`, in execution order.
        """
        if not isinstance(gbuffer, GBuffer):
            raise TypeError(f"gbuffer must be a GBuffer, got {type(gbuffer).__name__}")
        g = gbuffer
        covered = g.mask is None or bool((g.mask > 0).any())
        entries = [self._plan_translucency(g, covered)]
        for stage in self.irradiance:
            missing = [f for f in getattr(stage, "needs", ()) if getattr(g, f, None) is None]
            entry = _gate(
                f"irradiance.{stage.name}",
                True,
                f"no {missing[0]} in the G-buffer" if missing else None,
                covered,
            )
            skip = getattr(stage, "skip", None)
            reason = skip(g) if entry.runs and self.auto and callable(skip) else None
            entries.append(PlanEntry(entry.stage, False, f"auto: {reason}") if reason else entry)

        no_normals = None if g.normal is not None else "no normals in the G-buffer"
        entries += [
            _gate(
                "texturing",
                self.texturing is not None,
                None if g.albedo is not None else "no albedo in the G-buffer",
                covered,
            ),
            _gate("curvature", self.curvature is not None, no_normals, covered),
            self._plan_halo(g, covered),
            _gate("sss", True, None, covered),
            _gate(
                "specular",
                self.add_specular,
                None if g.specular is not None else "no specular in the G-buffer",
                covered,
            ),
        ]
        return entries

    def negligible(self, gbuffer: GBuffer) -> dict[str, str]:
        """The configured stages that can run on ``gbuffer`` but that the automatic plan
        (``auto=True``) would leave out as negligible, with its reason — whether or not this
        pipeline plans automatically. The app tells a user who switched such a stage on
        (it still runs: ``sssbench.run.inputs.check_stages``).

        Returns:
            stage -> reason (``"auto: ..."``); empty when every runnable stage matters.
        """
        auto = copy.copy(self)  # shallow: the same stages, planned automatically
        auto.auto = True
        own = {e.stage: e.runs for e in self.plan(gbuffer)}
        out = {e.stage: e.reason for e in auto.plan(gbuffer) if own.get(e.stage) and not e.runs}
        if own.get("curvature") and self.curvature is not None:
            unchanged = _widths_unchanged(self.curvature(gbuffer), gbuffer)
            if unchanged:
                out["curvature"] = unchanged
        return out

    # ------------------------------------------------------------------ run
    def run(self, gbuffer: GBuffer) -> PipelineResult:
        """Execute the plan; every executed pass leaves a record.

        Returns:
            :class:`PipelineResult` with the ``(B, 3, H, W)`` image, the pass records and the
            plan.
        """
        plan = self.plan(gbuffer)
        runs = {e.stage for e in plan if e.runs}
        g = gbuffer
        b, h, w = g.shape
        with record_passes() as records:
            image = g.diffuse
            if "translucency" in runs:
                image = self.translucency(g, add_to=image)
            for stage in self.irradiance:
                if f"irradiance.{stage.name}" in runs:
                    active = active_pixels(g.mask, g.depth.numel())
                    with timed_pass(
                        f"irradiance.{stage.name}",
                        1,
                        b * h * w if active is None else active.numel(),
                    ):
                        image = stage(g, image)
            if "texturing" in runs:
                image = self.texturing.before(image, g)
            extras: dict[str, object] = {}
            if "curvature" in runs:
                width = self.curvature(g)
                unchanged = _widths_unchanged(width, g)
                if self.auto and unchanged:
                    plan = [
                        PlanEntry("curvature", False, unchanged) if e.stage == "curvature" else e
                        for e in plan
                    ]
                else:
                    extras["width"] = width
            if "halo" in runs:
                with timed_pass(f"halo.{self.halo}", 1, b * h * w):
                    extras["guide"], extras["sample_weight"] = halo_weight(
                        g, self.halo, self.halo_sigma
                    )
            if "sss" in runs:
                src = g if image is g.diffuse else g.replace(diffuse=image)
                image = self.method(src, **extras)
            if "texturing" in runs:
                image = self.texturing.after(image, g)
            if "specular" in runs:
                active = active_pixels(g.mask, g.depth.numel())
                n = b * h * w if active is None else active.numel()
                with timed_pass("specular", 1, n):
                    image = apply_on_active(lambda x, s: x + s, image, [image, g.specular], active)
        return PipelineResult(image, list(records), plan)

    def forward(self, gbuffer: GBuffer) -> torch.Tensor:
        return self.run(gbuffer).image
