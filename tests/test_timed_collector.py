"""The timed repeats of a run (sssbench/run/settings.py, ``time_runs``) run with Python's
cyclic garbage collector paused, as ``timeit`` times: a collection that the calls' own
allocations trigger comes after them, not inside a timed pass."""

from __future__ import annotations

import gc
from types import SimpleNamespace

import pytest

from sssbench.run.settings import collector_paused, time_runs


class _Cycles:
    """A pipeline whose every run leaves cyclic garbage: enough to start collections."""

    def run(self, gbuffer):
        for _ in range(5000):
            a: list = []
            a.append(a)  # a reference cycle: only the cyclic collector frees it
        return SimpleNamespace(records=[], image=None)


@pytest.fixture
def collections():
    """The generations of the collections started while the fixture's flag is set."""
    seen: list[int] = []
    state = {"on": False}

    def callback(phase, info):
        if phase == "start" and state["on"]:
            seen.append(info["generation"])

    gc.callbacks.append(callback)
    yield seen, state
    gc.callbacks.remove(callback)


def test_collections_start_while_not_paused(collections):
    # the control: the same garbage outside the pause starts collections (gen0: every 700
    # allocations of tracked objects), so the test below can fail
    seen, state = collections
    assert gc.isenabled()
    state["on"] = True
    _Cycles().run(None)
    state["on"] = False
    assert len(seen) >= 5


def test_no_collection_inside_the_timed_repeats(collections, monkeypatch):
    seen, state = collections
    pipeline = _Cycles()
    inner = pipeline.run

    def run(gbuffer):
        state["on"] = True  # only while a repeat runs
        try:
            assert not gc.isenabled()
            return inner(gbuffer)
        finally:
            state["on"] = False

    monkeypatch.setattr(pipeline, "run", run)
    out, stats = time_runs(pipeline, None, 0, 3)
    assert seen == [] and stats == []
    assert gc.isenabled()  # restored
    gc.collect()  # and the garbage the repeats left is collectable


def test_the_pause_restores_the_state_before_it():
    gc.disable()
    try:
        with collector_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()  # it was off: stays off
    finally:
        gc.enable()
    with pytest.raises(RuntimeError):
        with collector_paused():
            raise RuntimeError("inside")
    assert gc.isenabled()  # on again after an error


def test_the_app_finalises_its_cycles_before_it_freezes_the_heap(monkeypatch, tmp_path):
    # main() freezes the heap around the sweep (gc.freeze: the exit's collections skip it);
    # a cycle the sweep left (an open file in one, say) is collected first, so its finalizer
    # runs — frozen, it never would
    import hydra

    from sssbench import app

    finalised: list[str] = []

    class _Holder:
        def __del__(self) -> None:
            finalised.append("flushed")

    def fake_main(**kwargs):
        def wrap(task):
            def run():
                assert gc.get_freeze_count() > 0  # the imports so far: frozen
                holder = _Holder()
                holder.self = holder  # a cycle: only the cyclic collector frees it

            return run

        return wrap

    monkeypatch.chdir(tmp_path)
    monkeypatch.setattr(hydra, "main", fake_main)
    monkeypatch.setattr("sys.argv", ["sssbench", "method=identity", "scene=step_edge"])
    try:
        app.main()
        assert finalised == ["flushed"]
        assert gc.isenabled()
    finally:
        gc.unfreeze()
