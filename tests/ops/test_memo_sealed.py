"""Sealed G-buffers (:func:`sssbench._memo.sealed`, :meth:`GBuffer.sealed`): memo lookups on
sealed tensors are O(1) — no bitwise compare, no snapshot — and every write the unsealed memo
catches by comparing is still caught, now as :class:`SealBroken`: at the next lookup when
torch counted the write (a version bump), else at the next verification point (``verify()``
or the block's end, which always verifies). Never a stale value passed on silently.

The stale-write cases are those of ``tests/reliability/test_gather_safety.py`` (a mask written
through ``.data``, a NumPy view, under ``inference_mode``) and
``tests/ops/test_gather_backends.py`` (the memo's probe), on a sealed G-buffer.
"""

import pytest
import torch

import sssbench._memo as memo
from sssbench._memo import SealBroken, memoised, seal_of, sealed
from sssbench.gbuffer import GBuffer
from sssbench.ops import backend, native, separable_pass

from ..reliability.test_gather_safety import fresh, kernel, scene

NATIVE = pytest.mark.skipif(native.library() is None, reason="no C compiler")
BACKENDS = [pytest.param("native", marks=NATIVE), "torch"]


def _write(t: torch.Tensor, how: str, new: torch.Tensor) -> None:
    if how == "data":
        t.data.copy_(new)
    elif how == "numpy":
        t.numpy()[...] = new.numpy()
    elif how == "inference":  # an inference tensor has no version counter
        with torch.inference_mode():
            t.copy_(new)
    else:  # an in-place torch op: a version bump
        t.copy_(new)


@pytest.fixture
def compares(monkeypatch):
    """Counts the memo's bitwise compares and digests."""
    calls = {"same_bits": 0, "digest": 0}
    for name in calls:
        real = getattr(memo, name)

        def counted(*a, _real=real, _name=name):
            calls[_name] += 1
            return _real(*a)

        monkeypatch.setattr(memo, name, counted)
    return calls


def test_sealed_lookups_compare_nothing(compares):
    """Unsealed, every lookup on a new scope compares the key tensor with its snapshot; sealed,
    a lookup compares nothing and digests nothing (the digest is taken once, at the seal)."""
    mask = torch.rand(1, 1, 16, 16)
    memoised((mask,), "probe-seal", lambda: 1)
    before = compares["same_bits"]
    for _ in range(3):
        assert memoised((mask,), "probe-seal", lambda: 2) == 1
    assert compares["same_bits"] == before + 3  # one compare per unsealed lookup
    with sealed({"mask": mask}):
        assert compares["digest"] == 1
        first = memoised((mask,), "probe-seal", lambda: 3)
        compares["same_bits"] = compares["digest"] = 0
        for _ in range(5):
            assert memoised((mask,), "probe-seal", lambda: 4) == first
        assert compares == {"same_bits": 0, "digest": 0}
    assert seal_of(mask) is None  # the seal ended with the block


@pytest.mark.parametrize("name", BACKENDS)
@pytest.mark.parametrize("how", ["data", "numpy", "inference"])
def test_a_write_without_a_version_bump_is_an_error_at_the_seal_end(name, how):
    """The unsealed memo recomputes after such a write (test_gather_safety.py); sealed, the
    second call may be served the first call's stencil, so the block's end raises, naming the
    field, and the same pass on a fresh G-buffer (what a re-run does) is exact."""
    g0 = scene()
    if how == "inference":
        with torch.inference_mode():
            g = GBuffer(
                g0.diffuse.clone(), g0.depth.clone(), g0.fov_y, mask=torch.zeros_like(g0.mask)
            )
    else:
        g = GBuffer(g0.diffuse, g0.depth, g0.fov_y, mask=torch.zeros_like(g0.mask))
    with backend(name), pytest.raises(SealBroken, match=r"changed while sealed \(mask\)"):
        with g.sealed():
            assert torch.equal(separable_pass(g.diffuse, kernel(), "x", g), g.diffuse)
            _write(g.mask, how, g0.mask)
            separable_pass(g.diffuse, kernel(), "x", g)
    assert seal_of(g.mask) is None
    with backend(name):  # after the seal: compared bit for bit again, never stale
        again = separable_pass(g.diffuse, kernel(), "x", g)
        ref = separable_pass(g0.diffuse.clone(), kernel(), "x", fresh(g0))
    torch.testing.assert_close(again, ref, rtol=0, atol=1e-6)


def test_a_write_with_a_version_bump_is_an_error_at_the_next_lookup():
    mask = torch.ones(1, 1, 4, 4)
    with pytest.raises(SealBroken, match="written in place while sealed"):
        with sealed({"mask": mask}):
            assert memoised((mask,), "probe-bump", lambda: int((mask > 0).sum())) == 16
            mask[0, 0, 0] = 0
            memoised((mask,), "probe-bump", lambda: int((mask > 0).sum()))
    assert memoised((mask,), "probe-bump", lambda: int((mask > 0).sum())) == 12


@pytest.mark.parametrize("how", ["data", "numpy"])
def test_verify_is_a_verification_point(how):
    """``verify()`` inside the block raises as soon as the contents differ (the runner's check
    after the timed runs); the last byte of a float64 tensor counts."""
    t = torch.zeros(1000, dtype=torch.float64)
    with pytest.raises(SealBroken, match=r"\(t\)"), sealed({"t": t}) as seal:
        seal.verify()
        new = t.clone()
        new[-1] = 5e-324  # the smallest subnormal: only the last bytes differ
        _write(t, how, new)
        seal.verify()


def test_pristine_copy_verifies_by_compare_and_must_match():
    t = torch.rand(8, 8)
    with pytest.raises(ValueError, match="pristine copy of t"):
        with sealed({"t": t}, {"t": t + 1}):
            pass
    with pytest.raises(ValueError, match="pristine copy of t"):
        with sealed({"t": t}, {"t": t}):  # the tensor itself is no copy
            pass
    with pytest.raises(SealBroken), sealed({"t": t}, {"t": t.clone()}):
        t.numpy()[3, 3] += 1.0


def test_values_memoised_on_sealed_tensors_are_sealed_with_them():
    """A LOD mask memoised on a sealed depth and mask is read-only by the same contract: a
    write into it is caught at the block's end."""
    g = scene()
    with pytest.raises(SealBroken, match="a value memoised on depth"), g.sealed():
        lod = memoised((g.depth, g.mask), "probe-lod", lambda: (g.mask * 2).clamp(max=1))
        assert seal_of(lod) is not None
        lod.numpy()[...] = 0.0


def test_an_inner_block_leaves_the_outer_seals_alone():
    g = scene()
    with g.sealed() as outer:
        with g.replace(mask=g.mask.clone()).sealed() as inner:
            assert inner.names == ("mask",)  # diffuse and depth belong to the outer block
        assert seal_of(g.depth) is not None and seal_of(g.mask) is not None
        outer.verify()
    assert seal_of(g.depth) is None


def test_a_block_left_by_an_error_ends_its_seals_without_masking_the_error():
    t = torch.ones(3)
    with pytest.raises(KeyError), sealed({"t": t}):
        t.numpy()[0] = 2.0
        raise KeyError("first")
    assert seal_of(t) is None


@pytest.mark.parametrize("name", BACKENDS)
def test_a_renderer_seals_every_field_but_the_one_it_writes(name):
    """``g.sealed(writable=("diffuse",))``: an in-place operator call writes the lit diffuse
    and the block ends without ``SealBroken``; the stencil and depth stay sealed (a write to
    them is still caught), the diffuse is not; the result equals the call on an unsealed copy.
    A name that is not a field is an error naming the argument."""
    from sssbench.ops import PreintegratedSSS
    from sssbench.profiles import SumOfGaussians

    op = PreintegratedSSS(SumOfGaussians.from_table("skin_deon6"), 7)
    g = scene(seed=3, h=12, w=19)
    expected = op(fresh(g))
    with backend(name):
        with g.sealed(writable=("diffuse",)):
            assert seal_of(g.mask) is not None and seal_of(g.depth) is not None
            assert seal_of(g.diffuse) is None
            for _ in range(2):  # the second call on the first call's result
                op(g, inplace=True)
        again = fresh(scene(seed=3, h=12, w=19))
        op(again, inplace=True)
        op(again, inplace=True)
        assert torch.equal(g.diffuse, again.diffuse)
        assert torch.equal(op(fresh(scene(seed=3, h=12, w=19))), expected)
        with pytest.raises(SealBroken):
            with g.sealed(writable=("diffuse",)):
                g.mask.numpy()[0, 0, 0, 0] = 0.5
    with pytest.raises(SealBroken):  # sealed whole, the in-place write breaks the seal
        with g.sealed():
            op(g, inplace=True)
    with pytest.raises(ValueError, match="writable"):
        g.sealed(writable=("difuse",))
