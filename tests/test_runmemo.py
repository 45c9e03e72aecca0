"""The in-process memo of a sweep's per-scene work (sssbench.run.runmemo): runs share the scene's
G-buffer and the baseline's scores, and no run can change what the next one gets."""

from __future__ import annotations

import json

import pytest
import torch
from specs import small_spec
from torch import nn

from sssbench.run import registry, runmemo, runner


class VandalSSS(nn.Module):
    """A broken method that writes into its G-buffer (diffuse ×3, depth +1 mm) in place."""

    needs = ("mask",)

    def __init__(self, profile) -> None:
        super().__init__()

    def forward(self, gbuffer):
        gbuffer.diffuse.mul_(3.0)
        gbuffer.depth.add_(1.0)
        return gbuffer.diffuse.clone()


@pytest.fixture
def vandal(monkeypatch):
    VandalSSS.__module__ = __name__
    entry = registry.MethodEntry(f"{__name__}:VandalSSS", samples_arg=None)
    monkeypatch.setitem(registry.METHODS, "vandal", entry)
    return "vandal"


@pytest.fixture(autouse=True)
def fresh_memo():
    runmemo.clear()
    yield
    runmemo.clear()


def _run(tmp_path, method: str, name: str, status: str = "ok") -> dict:
    spec = small_spec(tmp_path, scene="light_dot", method=method, store=tmp_path / f"{name}.sqlite")
    outcome = runner.execute(spec, tmp_path / name)
    assert outcome.status == status, outcome.message
    return {"message": outcome.message} | (
        json.loads((tmp_path / name / "metrics.json").read_text()) if status == "ok" else {}
    )


def test_a_run_that_writes_into_its_gbuffer_fails_and_does_not_reach_the_next(tmp_path, vandal):
    # the baseline's scores from a process that has kept nothing (no memo)
    fresh = _run(tmp_path, "identity", "fresh")
    runmemo.clear()
    # builds and keeps the scene, then vandalises its copy: the run fails, naming the fields
    broken = _run(tmp_path, vandal, "a", status="failed")
    assert "wrote into its G-buffer (diffuse, depth changed)" in broken["message"]
    after = _run(tmp_path, "identity", "b")  # served from the memo
    for key in ("rel_rms", "rel_rms_identity", "visibility", "visibility_window"):
        assert after[key] == fresh[key], key


def test_compute_once_per_key_and_copies_handed_out():
    calls = []

    def build():
        calls.append(1)
        return {"image": torch.ones(2, 2)}

    a = runmemo.remembered("x", {"k": 1}, build)
    a["image"].add_(5.0)  # the caller owns its copy
    b = runmemo.remembered("x", {"k": 1}, build)
    assert len(calls) == 1
    assert torch.equal(b["image"], torch.ones(2, 2))
    runmemo.remembered("x", {"k": 2}, build)
    runmemo.remembered("y", {"k": 1}, build)  # another namespace is another value
    assert len(calls) == 3


def test_bounded():
    calls = []
    for i in range(runmemo.MAX_ENTRIES + 1):
        runmemo.remembered("x", {"i": i}, lambda: calls.append(1))
    runmemo.remembered("x", {"i": 0}, lambda: calls.append(1))  # the oldest was dropped
    assert len(calls) == runmemo.MAX_ENTRIES + 2


def test_values_are_normal_tensors_whatever_the_callers_mode():
    """A value built under ``torch.inference_mode()`` (as ``runner.prepare`` builds scenes)
    is handed out later, outside it, as a normal tensor that can be written to."""
    with torch.inference_mode():
        inside = runmemo.remembered("x", {"k": 3}, lambda: torch.ones(3))
    later = runmemo.remembered("x", {"k": 3}, lambda: torch.zeros(3))
    assert inside.is_inference()  # the caller's own value, as computed
    assert not later.is_inference()
    later.add_(1.0)  # an inference tensor would raise here
    assert torch.equal(later, torch.full((3,), 2.0))
