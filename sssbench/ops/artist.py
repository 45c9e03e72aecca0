"""The artist-friendly separable model (000 §5 eq. 6) rendered with the depth correction of
000 §7 eq. 7: two passes."""

from __future__ import annotations

import torch

from sssbench._checks import check_method_options
from sssbench.gbuffer import GBuffer
from sssbench.kernels.artist import ArtistParams
from sssbench.ops.functional import functional
from sssbench.ops.method import SeparableMethod
from sssbench.ops.preintegrated import two_pass

__all__ = ["ArtistSSS", "artist_sss"]


class ArtistSSS(SeparableMethod):
    """Artist-friendly two-Gaussian separable SSS (000 §5, §7).

    The kernel is ``a'_m(d_xy) = w N(σ_n) + (1 − w) N(σ_f)`` (000 eq. 6, normalised to one)
    with ``σ = σ' · s``, discretised over the screen plane only (importance-sampled,
    area-integrated taps, 000 §7; :meth:`~sssbench.kernels.ArtistParams.kernel`). The depth
    is resolved analytically per sample by the correction factor of 000 eq. 7,
    ``exp(−d_z² / 2σ_max²)``: ``follow_surface="gaussian"`` with ``surface_scale = σ_max``
    (:attr:`~sssbench.kernels.ArtistParams.sigma_max`, = σ_f, per channel — a choice: 000
    counts "a single exp" per sample; with a ``(3,)`` argument that is one exp per channel,
    and one shared σ_max = max over channels would leave green and blue, whose σ_f is 3–7×
    smaller in Table 2, almost uncorrected). The corrected weights are not renormalised
    (000 eq. 7 multiplies them), so a sample across a depth step loses its energy rather
    than passing it to the others.

    The app's default is the ``multi_layer_close_fit`` row of 000 Table 2 (its fit to the
    six-Gaussian skin of d'Eon, ``skin_deon6``) with the eq. 7 depth factor. Measured, that
    row does not match the profile it was fitted to at the stated ``s`` in mm: its red
    σ_f = 9.27 mm against the widest σ of skin_deon6, 2.72 mm, and on ``step_edge`` (128²)
    it scores rel RMS ~2× the unblurred input's (skill −0.93 against skin_deon6, −0.97
    against skin_jg10); the same σ' with ``s`` = 1–2 mm scores skill 0.62–0.72. The table's
    ``s`` is therefore probably not a σ scale in mm as printed (000 §5 does not say how the
    fit was made); we keep the table as printed and report the mismatch
    (``sssbench.score.budget``'s ``err_model`` shows it) rather than invent a scale.

    Args:
        near: σ'_n, scalar or ``(3,)`` in [0, 1].
        far: σ'_f, scalar or ``(3,)`` in [0, 1].
        weight: w in [0, 1] (scalar or per channel).
        scale: s in mm, > 0.
        samples: taps per pass (000 §7: 7).
        sampling: ``"importance"``, ``"uniform"`` or ``"power"``.
        follow_surface: ``"gaussian"`` (000 eq. 7, default), ``"lerp"`` (2012 shader, with
            the same scale) or ``None``.
        rotation: stochastic rotation radius fraction (000 §6), or ``None``.
        seed: rotation seed (one :class:`Rotation` for both passes).

    Shape:
        - forward(gbuffer): ``(B, 3, H, W)``.

    Example:
        >>> op = ArtistSSS.preset("production")
        >>> g = GBuffer(torch.ones(1, 3, 8, 8), torch.full((1, 1, 8, 8), 500.0), 0.4)
        >>> bool(torch.allclose(op(g), g.diffuse)), len(op.kernel)
        (True, 7)
    """

    scatters_in_place = True

    needs = ("mask",)

    def __init__(
        self,
        near: object,
        far: object,
        weight: object,
        scale: float,
        samples: int = 7,
        sampling: str = "importance",
        follow_surface: str | None = "gaussian",
        rotation: float | None = None,
        seed: int = 0,
    ) -> None:
        super().__init__()
        check_method_options(None, seed)
        self.params = ArtistParams.make(near, far, weight, scale)
        #: σ_max of 000 eq. 7 per channel (mm), floored so a zero σ' stays a valid scale
        self.set_options(
            follow_surface,
            None,
            rotation,
            seed,
            default_scale=self.params.sigma_max.clamp_min(1e-9),
        )
        self.kernel = self.params.kernel(samples, sampling)
        self.samples = samples
        self.sampling = sampling

    @classmethod
    def preset(
        cls,
        name: str,
        samples: int = 7,
        sampling: str = "importance",
        **options: object,
    ) -> ArtistSSS:
        """A row of 000 Table 2 (``"single_layer_close_fit"``, ``"multi_layer_close_fit"``,
        ``"production"``); ``options`` are the other keyword arguments."""
        p = ArtistParams.preset(name)
        return cls(p.near, p.far, p.weight, p.scale, samples, sampling, **options)

    def scatter(self, gbuffer: GBuffer, options: dict[str, object]) -> torch.Tensor:
        # follow_surface="gaussian" with surface_scale = σ_max: 000 eq. 7
        return two_pass(gbuffer.diffuse, self.kernel, gbuffer, name="artist", **options)


#: the functional twin: every argument of :class:`ArtistSSS`, kernels reused
artist_sss = functional(ArtistSSS, "artist_sss")
