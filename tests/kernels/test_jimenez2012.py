"""jimenez2012(): 002 eq. 1 against a literal transcription of the 2012 shader's kernel builder."""

from __future__ import annotations

import math

import pytest
import torch

from sssbench.kernels import JIMENEZ2012_PRESETS, jimenez2012, jimenez2012_preset
from sssbench.profiles import SumOfGaussians

# d'Eon skin red channel without the 0.0064 Gaussian, written out independently (002 §3.1)
_RED = [(0.100, 0.0484), (0.118, 0.187), (0.113, 0.567), (0.358, 1.99), (0.078, 7.41)]


def _shader_kernel(n: int, strength: list[float], falloff: list[float]) -> list[list[float]]:
    """Plain-Python transcription of the 2012 SSSS kernel builder: rows (r, g, b, offset)."""
    rng = 3.0 if n > 20 else 2.0
    step = 2.0 * rng / (n - 1)
    offs = []
    for i in range(n):
        o = -rng + i * step
        sign = -1.0 if o < 0 else 1.0
        offs.append(rng * sign * abs(o**2) / rng**2)

    def profile(r: float) -> list[float]:
        out = []
        for c in range(3):
            rr = r / (0.001 + falloff[c])
            out.append(sum(w * math.exp(-rr * rr / (2 * v)) / (2 * math.pi * v) for w, v in _RED))
        return out

    kern = []
    for i in range(n):
        w0 = abs(offs[i] - offs[i - 1]) if i > 0 else 0.0
        w1 = abs(offs[i] - offs[i + 1]) if i < n - 1 else 0.0
        area = (w0 + w1) / 2
        kern.append([area * p for p in profile(offs[i])] + [offs[i]])
    t = kern[n // 2]
    for i in range(n // 2, 0, -1):
        kern[i] = kern[i - 1]
    kern[0] = t
    sums = [sum(k[c] for k in kern) for c in range(3)]
    for k in kern:
        for c in range(3):
            k[c] /= sums[c]
    for c in range(3):
        kern[0][c] = (1 - strength[c]) + strength[c] * kern[0][c]
        for i in range(1, n):
            kern[i][c] *= strength[c]
    return kern


@pytest.mark.parametrize("n", [5, 9, 17, 21, 33])
@pytest.mark.parametrize("name", sorted(JIMENEZ2012_PRESETS))
def test_matches_shader_kernel_builder(name: str, n: int) -> None:
    p = JIMENEZ2012_PRESETS[name]
    ref = sorted(_shader_kernel(n, list(p["strength"]), list(p["falloff"])), key=lambda r: r[3])
    k = jimenez2012_preset(name, n)
    ref_t = torch.tensor(ref, dtype=torch.float64)
    torch.testing.assert_close(k.offsets, ref_t[:, 3] * 2 / 3, rtol=0, atol=1e-12)
    torch.testing.assert_close(k.weights, ref_t[:, :3], rtol=1e-10, atol=1e-14)
    assert k.extent == pytest.approx((3.0 if n > 20 else 2.0) * 2 / 3)


def test_presets_are_table_1_and_shader_defaults() -> None:
    assert JIMENEZ2012_PRESETS["table1"]["strength"] == (0.78, 0.70, 0.75)  # 002 Table 1
    assert JIMENEZ2012_PRESETS["table1"]["falloff"] == (0.57, 0.13, 0.08)
    assert JIMENEZ2012_PRESETS["table1"]["width"] == 0.014
    assert JIMENEZ2012_PRESETS["shader_default"]["strength"] == (0.48, 0.41, 0.28)
    assert JIMENEZ2012_PRESETS["shader_default"]["falloff"] == (1.0, 0.37, 0.3)


def test_integrated_quadrature_closed_form() -> None:
    strength, falloff = (0.78, 0.70, 0.75), (0.57, 0.13, 0.08)
    k = jimenez2012(strength, falloff, 11, quadrature="integrated")
    offs = [2.0 * math.copysign(t * t, t) for t in [-1 + 0.2 * i for i in range(11)]]
    edges = (
        [-math.inf] + [(a + b) / 2 for a, b in zip(offs[:-1], offs[1:], strict=True)] + [math.inf]
    )

    def phi(x: float) -> float:
        return 0.5 * math.erfc(-x / math.sqrt(2))

    for c in range(3):
        f = 0.001 + falloff[c]
        w = []
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            tot = 0.0
            for wi, v in _RED:
                s = f * math.sqrt(v)
                tot += wi * f / math.sqrt(2 * math.pi * v) * (phi(b / s) - phi(a / s))
            w.append(tot)
        ref = [strength[c] * x / sum(w) for x in w]
        ref[5] += 1 - strength[c]
        torch.testing.assert_close(k.weights[:, c], torch.tensor(ref, dtype=torch.float64))


@pytest.mark.parametrize("quadrature", ["shader", "integrated"])
@pytest.mark.parametrize("n", [1, 2, 8, 9, 25])
def test_normalised_and_symmetric(n: int, quadrature: str) -> None:
    k = jimenez2012((0.3, 0.6, 1.0), (0.0, 0.5, 2.0), n, quadrature=quadrature)
    assert len(k) == (n if n % 2 else n + 1)
    torch.testing.assert_close(k.sum(), torch.ones(3, dtype=torch.float64), rtol=0, atol=1e-12)
    torch.testing.assert_close(k.offsets, -k.offsets.flip(0), rtol=0, atol=1e-12)
    torch.testing.assert_close(k.weights, k.weights.flip(0), rtol=0, atol=1e-12)
    assert bool(torch.isfinite(k.weights).all())
    # the delta carries at least 1 - strength at offset 0
    centre = k.weights[k.offsets == 0][0]
    assert bool((centre >= torch.tensor([0.7, 0.4, 0.0], dtype=torch.float64) - 1e-12).all())


def test_strength_zero_is_identity_and_falloff_widens() -> None:
    k = jimenez2012(0.0, 0.5, 9)
    torch.testing.assert_close(k.weights[4], torch.ones(3, dtype=torch.float64))
    wide = jimenez2012(1.0, (1.0, 0.5, 0.1), 17, quadrature="integrated")
    var = (wide.weights * wide.offsets[:, None] ** 2).sum(0)
    assert float(var[0]) > float(var[1]) > float(var[2])


def test_profile_argument() -> None:
    k1 = jimenez2012(0.5, 0.5, 9, profile="skin_deon6")
    k2 = jimenez2012(0.5, 0.5, 9, profile=SumOfGaussians.from_table("skin_deon6"))
    torch.testing.assert_close(k1.weights, k2.weights)


def test_bad_inputs_name_argument() -> None:
    with pytest.raises(ValueError, match="strength"):
        jimenez2012(1.1, 0.5, 9)
    with pytest.raises(ValueError, match="strength"):
        jimenez2012((0.5, -0.1, 0.5), 0.5, 9)
    with pytest.raises(ValueError, match="falloff"):
        jimenez2012(0.5, -0.01, 9)
    with pytest.raises(ValueError, match="falloff"):
        jimenez2012(0.5, (0.1, 0.2), 9)
    with pytest.raises(ValueError, match="falloff"):
        jimenez2012(0.5, float("inf"), 9)
    with pytest.raises(ValueError, match="samples"):
        jimenez2012(0.5, 0.5, 0)
    with pytest.raises(TypeError, match="samples"):
        jimenez2012(0.5, 0.5, 9.0)
    with pytest.raises(ValueError, match="quadrature"):
        jimenez2012(0.5, 0.5, 9, quadrature="simpson")
    with pytest.raises(ValueError, match="profile"):
        jimenez2012(0.5, 0.5, 9, profile="nope")
    with pytest.raises(TypeError, match="profile"):
        jimenez2012(0.5, 0.5, 9, profile=3)
    with pytest.raises(ValueError, match="name"):
        jimenez2012_preset("nope", 9)
