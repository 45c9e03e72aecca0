"""Every scene of the benchmark presets is visible (or not) where docs/error_budget.md says it
is: the table between ``<!-- visibility-table -->`` markers is recomputed row by row (the
unblurred input against the exact reference, sssbench.score.verdict), and a retired scene name
is refused with its successors' names."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

import data_synth
from data_synth import make_scene
from sssbench import ops
from sssbench.profiles import SumOfGaussians
from sssbench.score.verdict import is_visible, visibility_stats

ROOT = Path(__file__).resolve().parents[1]
DOC = ROOT / "docs" / "error_budget.md"


def _rows() -> list[dict]:
    text = DOC.read_text()
    block = text.split("<!-- visibility-table -->")[1].split("<!-- /visibility-table -->")[0]
    lines = [ln for ln in block.strip().splitlines() if ln.startswith("|")][2:]
    rows = []
    for ln in lines:
        scene, px, prof, res, mean, local, vis = [c.strip() for c in ln.strip("|").split("|")]
        rows.append(
            dict(
                scene=scene,
                px=float(px),
                profile=prof,
                res=int(res),
                mean=float(mean),
                local=float(local),
                visible=vis == "yes",
            )  # fmt: skip
        )
    return rows


ROWS = _rows()


@pytest.mark.parametrize(
    "row", ROWS, ids=[f"{r['scene']}@{r['px']}-{r['profile']}-{r['res']}" for r in ROWS]
)
def test_documented_visibility(row):
    g = make_scene(row["scene"], (row["res"], row["res"]), fields=["mask"], pixel_mm=row["px"])
    ref = ops.ReferenceSSS(SumOfGaussians.from_table(row["profile"]))(g)
    mean, local = visibility_stats(ref, g.diffuse, g.mask)
    assert is_visible(mean, local) == row["visible"], (row, mean, local)
    assert mean == pytest.approx(row["mean"], rel=0.15, abs=2e-4)
    assert local == pytest.approx(row["local"], rel=0.15, abs=2e-4)


def test_every_preset_scene_and_scale_is_in_the_table():
    """The paper benchmark presets' scenes at their scales, and the default benchmark's
    scenes at their own, each have a row."""
    have = {(r["scene"], r["px"]) for r in ROWS}
    conf = ROOT / "sssbench" / "conf"
    for path in sorted((conf / "experiment").glob("*benchmark*.yaml")):
        params = yaml.safe_load(path.read_text())["hydra"]["sweeper"]["params"]
        scenes = params["scene"].split(",")
        scales = str(params.get("++scene.params.pixel_mm", "")).split(",")
        for scene in scenes:
            entry = yaml.safe_load((conf / "scene" / f"{scene}.yaml").read_text())
            name = entry["name"]
            if scales != [""]:
                wanted = [float(s) for s in scales]
            else:
                default = (entry.get("params") or {}).get("pixel_mm")
                wanted = [default if default is not None else data_synth.SCENES[name].pixel_mm]
            for px in wanted:
                if path.stem == "paper_benchmark_1080p" and px < 0.1:
                    continue  # the 1080p extreme close-up: not a small-resolution question
                assert (name, px) in have, f"{path.name}: {name} at {px} mm/px has no row"


def test_a_retired_name_is_refused_with_its_successors():
    assert "head_close" not in data_synth.SCENES
    with pytest.raises(ValueError, match=r"head_closeup.*head_cheek"):
        make_scene("head_close", (8, 8))
    from sssbench.run import registry

    with pytest.raises(ValueError, match="head_closeup"):
        registry.build_scene("head_close", (8, 8))
    # the successors: the close-up keeps the old name's meaning at 128² (0.6 mm/px, the cheek
    # on the axis), the cheek keeps its later one (0.3 mm/px)
    assert data_synth.SCENES["head_closeup"].defaults["pixel_mm"] == 0.6
    assert data_synth.SCENES["head_cheek"].defaults["pixel_mm"] == 0.3
    assert re.search(r"0d65624", data_synth.RETIRED_SCENES["head_close"])


def test_the_app_refuses_a_retired_scene_before_any_run(tmp_path):
    from sssbench.app import compose_spec

    with pytest.raises(ValueError, match=r"retired.*head_closeup.*head_cheek"):
        compose_spec("scene=head_close", store=tmp_path / "s.sqlite")
    assert compose_spec("scene=head_closeup", store=tmp_path / "s.sqlite").scene == "head_closeup"
