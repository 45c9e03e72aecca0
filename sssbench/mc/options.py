"""The options of the Monte Carlo scene reference (:func:`sssbench.mc.scene.scene_mc`): the
material each profile table is simulated as, the medium of a material, and the checks of the
options that need no scene — run by ``scene_mc`` on entry and by the app for every job before
its first run (:func:`sssbench.run.inputs.check_spec`), so the two never disagree."""

from __future__ import annotations

import torch

from sssbench._checks import check_int, check_seed
from sssbench.mc.transport import Medium
from sssbench.profiles.dipole import MATERIALS

__all__ = ["PROFILE_MATERIALS", "check_options", "medium_for"]

_F64 = torch.float64
#: measured material (JMLH01, :data:`sssbench.profiles.MATERIALS`) simulated for a profile
#: table: the skin tables are fits to skin, the marble table to marble
PROFILE_MATERIALS = {"skin_jg10": "skin1", "skin_deon6": "skin1", "marble_jg10": "marble"}


def medium_for(material: str | tuple) -> Medium:
    """The :class:`~sssbench.mc.transport.Medium` of a name of :data:`MATERIALS` (η = 1.3),
    of a profile table name (:data:`PROFILE_MATERIALS`) or of ``(σs′, σa[, η])`` (mm⁻¹)."""
    if isinstance(material, str):
        key = PROFILE_MATERIALS.get(material, material).lower()
        if key not in MATERIALS:
            raise ValueError(
                f"material must be one of {sorted(MATERIALS)} or a profile of "
                f"{sorted(PROFILE_MATERIALS)}, got {material!r}"
            )
        ss, sa = MATERIALS[key]
        return Medium(ss, sa, 1.3)
    if isinstance(material, (tuple, list)) and len(material) in (2, 3):
        ss, sa = (torch.as_tensor(v, dtype=_F64).expand(3).tolist() for v in material[:2])
        return Medium(tuple(ss), tuple(sa), float(material[2]) if len(material) == 3 else 1.3)
    raise TypeError(
        f"material must be a material or profile name or a (sigma_s_prime, sigma_a[, eta]) "
        f"tuple, got {type(material).__name__}"
    )


def check_options(
    material: str | tuple = "skin1",
    *,
    photons: int | None = None,
    batches: int = 8,
    seed: int = 0,
    workers: int | None = None,
) -> tuple[int, Medium, int]:
    """The checks of :func:`~sssbench.mc.scene.scene_mc`'s options that need no scene (it calls
    this on entry; the app calls it before the first run): ``(seed, medium, batches)``.

    Raises:
        ValueError, TypeError: naming the option (``material``, ``photons``, ``batches``,
            ``seed``, ``workers``) and what was expected.
    """
    seed = check_seed("seed", seed)
    medium = medium_for(material)
    _check_scatters(material, medium)
    if photons is not None:
        check_int("photons", photons, 6)
    batches = check_int("batches", batches, 2)
    if workers is not None:
        check_int("workers", workers, 1)
    return seed, medium, batches


def _check_scatters(material: object, medium: Medium) -> None:
    """Refuse a medium that scatters nothing back in some channel (σs′ = 0): its diffuse
    albedo ρ is exactly 0, and the normalised exitance ``M/ρ`` of
    :class:`~sssbench.mc.scene.SceneMC` (what every score divides by) is 0/0 — all-NaN images
    otherwise (docs/reliability.md, class 10)."""
    dead = [c for c, s in zip(("R", "G", "B"), medium.sigma_s_prime, strict=True) if s == 0]
    if dead:
        raise ValueError(
            f"material {material!r} has sigma_s_prime = 0 in channel(s) {', '.join(dead)}: no "
            "light scatters back (albedo rho = 0), so the normalised exitance M/rho is "
            "undefined; give sigma_s_prime > 0"
        )
