"""A browsable, self-contained HTML comparison report (``sssbench-report DIR --html``).

One static page (every image on it embedded as a data URI: no server, opens from disk) per sweep
or store. Images larger than :data:`THUMB_PX` are embedded as thumbnails (an integer-factor
reduction: area mean for images, the maximum for error maps, so no error is hidden) and written
at full resolution as PNG files beside the page (``report_files/``, linked from each caption):
the page of the paper benchmark stays a few MB instead of a hundred. Per ranking group (scene ·
scale · resolution · stages):

- the exact reference and each configuration's result and error map side by side at native
  resolution, with a zoom (1×–8×, nearest neighbour) and a flip (click a result, or hold
  the *flip* button) between the result and the reference;
- error maps ``|result − reference| / reference peak`` on **one colour scale per group**
  (the largest error of the group's configurations, written under the colour bar), so two
  methods' maps compare;
- each run's configuration one click away (``<details>``);

then the summary table (baseline, skill, flags), the recommendations and the report's plots.
Images are made from each run's ``result.exr`` / ``reference.exr`` (written by the runner);
runs without them (previews off) are listed without images.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pandas as pd
import torch

from sssbench import _json
from sssbench.report.tables import (
    BASELINE,
    MISSING,
    REFERENCE,
    _flags,
    _fmt,
    budget_verdicts,
    config_text,
    group_keys,
    label,
    recommendations,
)

__all__ = ["write_html", "THUMB_PX"]

#: largest side (pixels) of an image embedded in the page; larger ones are embedded reduced by
#: an integer factor and written at full resolution beside the page (``report_files/``)
THUMB_PX = 192

_CSS = """
body{font-family:system-ui,sans-serif;margin:1.5em;color:#222}
h1{font-size:1.4em} h2{font-size:1.15em;margin-top:2em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;font-size:.8em;margin:.5em 0}
td,th{border:1px solid #ddd;padding:2px 6px;text-align:right} th{background:#f4f4f4}
td:first-child,th:first-child{text-align:left}
.worse{background:#fde2e2} .best{background:#e2f5e2} .hidden{color:#999}
.strip{display:flex;flex-wrap:wrap;gap:12px;align-items:flex-start}
figure{margin:0;border:1px solid #ddd;padding:4px;background:#fafafa}
figcaption{font-size:.75em;max-width:320px}
img.px{image-rendering:pixelated;display:block}
.controls{position:sticky;top:0;background:#fff;padding:.4em 0;z-index:2}
"""

_JS = """
function setZoom(z){document.querySelectorAll('img.px').forEach(function(im){
  im.style.width=(im.naturalWidth*z)+'px';});}
function flip(im){var r=document.getElementById(im.getAttribute('data-ref'));if(!r)return;
  var own=im.getAttribute('data-own');
  if(own){im.setAttribute('src',own);im.removeAttribute('data-own');}
  else{im.setAttribute('data-own',im.getAttribute('src'));im.setAttribute('src',r.src);}
  var c=im.parentNode.querySelector('.which');
  if(c){c.textContent=c.textContent=='result'?'reference':'result';}}
function flipAll(){document.querySelectorAll('img[data-ref]').forEach(flip);}
window.addEventListener('load',function(){
  var imgs=document.querySelectorAll('img'),ok=0;
  imgs.forEach(function(im){if(im.complete&&im.naturalWidth>0)ok++;});
  document.body.setAttribute('data-images-loaded',ok+'/'+imgs.length);
  setZoom(parseInt(document.getElementById('zoom').value));});
"""


def _png(array: Any, **imsave: Any) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image

    buf = io.BytesIO()
    matplotlib.image.imsave(buf, array, format="png", **imsave)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _reduce(array: Any, reduce: str) -> Any:
    """``array`` (H, W[, C]) reduced by the smallest integer factor that brings its larger side
    to at most :data:`THUMB_PX`: area mean (``"mean"``) or maximum (``"max"``)."""
    import torch.nn.functional as F

    factor = math.ceil(max(array.shape[:2]) / THUMB_PX)
    if factor <= 1:
        return array
    t = torch.as_tensor(array, dtype=torch.float64)
    t = t[None, None] if t.ndim == 2 else t.permute(2, 0, 1)[None]
    pool = F.max_pool2d if reduce == "max" else F.avg_pool2d
    t = pool(t, factor, ceil_mode=True)
    return (t[0, 0] if array.ndim == 2 else t[0].permute(1, 2, 0)).numpy()


def _image(
    array: Any, files: Path, name: str, reduce: str = "mean", **imsave: Any
) -> tuple[str, str]:
    """``(data URI to embed, caption link)`` of an image: as it is when small, else a thumbnail
    and the full-resolution PNG written to ``files/name.png`` (linked)."""
    small = _reduce(array, reduce)
    if small is array:
        return _png(array, **imsave), ""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.image

    files.mkdir(parents=True, exist_ok=True)
    matplotlib.image.imsave(files / f"{name}.png", array, format="png", **imsave)
    href = html.escape(f"{files.name}/{name}.png")
    return _png(small, **imsave), f"<a href='{href}'>{html.escape(name.rsplit('_', 1)[-1])}</a>"


def _file_png(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode()


def _rgb(image: torch.Tensor) -> Any:
    from sssbench.score.metrics import tonemap

    return tonemap(image[:1].double().clamp(min=0)).squeeze(0).permute(1, 2, 0).clamp(0, 1).numpy()


def _colorbar(vmax: float) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(3.2, 0.55), dpi=100)
    fig.colorbar(
        plt.cm.ScalarMappable(plt.Normalize(0, vmax), "magma"), cax=ax, orientation="horizontal"
    )
    ax.set_xlabel("|error| / reference peak", fontsize=7)
    ax.tick_params(labelsize=7)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", bbox_inches="tight")
    plt.close(fig)
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode()


def _load(run_dir: Any) -> tuple[torch.Tensor, torch.Tensor] | None:
    from sssbench.io import read_image_exr

    if not isinstance(run_dir, str):
        return None
    d = Path(run_dir)
    if not ((d / "result.exr").is_file() and (d / "reference.exr").is_file()):
        return None
    return read_image_exr(d / "result.exr"), read_image_exr(d / "reference.exr")


def _config(run_dir: Any) -> str:
    """The run's stored configuration as ``key=value`` lines (nested keys dotted)."""
    if not isinstance(run_dir, str):
        return "{}"
    p = Path(run_dir) / "point.json"
    try:
        config = _json.loads(p.read_text()).get("config", {})
    except (OSError, json.JSONDecodeError):
        return "{}"
    return "\n".join(config_text(v, str(k)) for k, v in config.items())


def _table(df: pd.DataFrame, columns: list[str]) -> str:
    head = "".join(f"<th>{html.escape(c)}</th>" for c in columns)
    rows = []
    for _, r in df.iterrows():
        wrong = bool(r.get("worse_than_nothing")) or bool(r.get("visibly_wrong"))
        cls = "worse" if wrong else "best" if r.get("best") else ""
        cls = "hidden" if r.get("note") and not r.get("visibly_wrong") else cls
        cells = "".join(f"<td>{html.escape(_fmt(r.get(c)))}</td>" for c in columns)
        rows.append(f'<tr class="{cls}">{cells}</tr>')
    return f"<table><tr>{head}</tr>{''.join(rows)}</table>"


def write_html(
    table: pd.DataFrame,
    out_dir: Path,
    source: str,
    plots: list[Path],
    progress: Callable[[str], None] | None = None,
) -> Path:
    """Write ``report.html`` into ``out_dir`` and return its path (see the module docstring).

    Args:
        table: the report's summary table (:func:`sssbench.report.summary_table`).
        out_dir: output directory.
        source: the store or sweep the report covers (shown in the title).
        plots: PNG plots to embed.
        progress: called with a line per group of images (``report.html: k/n …``).
    """
    from sssbench.score.previews import relative_error

    parts = [
        "<!doctype html><html><head><meta charset='utf-8'>",
        f"<title>sssbench report — {html.escape(source)}</title><style>{_CSS}</style>",
        f"<script>{_JS}</script></head><body>",
        f"<h1>sssbench report</h1><p>Source: <code>{html.escape(source)}</code> — "
        f"{len(table)} points. Skill = 1 − rel_rms / rel_rms of doing nothing (the "
        "<code>identity</code> baseline); red rows are worse than doing nothing or visibly wrong "
        "(their own error passes the visibility bar, in any group), green the best skill, grey "
        "where SSS is not visible at the scale (not ranked).</p>",
        "<div class='controls'>zoom <select id='zoom' onchange='setZoom(parseInt(this.value))'>"
        + "".join(f"<option value='{z}'>{z}×</option>" for z in (1, 2, 4, 8))
        + "</select> <button onmousedown='flipAll()' onmouseup='flipAll()'>hold to flip all "
        "results with the reference</button> (or click an image to flip it)</div>",
    ]
    recs = recommendations(table)
    if len(recs):
        parts.append("<h2>Recommendations</h2>")
        parts.append(
            _table(recs, [*group_keys(table), "recommended", "best", "verdict"]).replace(
                'class="hidden"', ""
            )
        )
    budgets = budget_verdicts(table)
    if len(budgets):
        parts.append("<h2>Error budget</h2>")
        parts.append(
            "<p>Per scene, scale and method (its best configuration): each part's share of "
            "the error, the contributions that add up to its rel RMS (docs/error_budget.md).</p>"
        )
        parts.append(_table(budgets, [*group_keys(table), "sentence"]))
    shown = table.assign(flags=[_flags(r, markdown=False) for _, r in table.iterrows()])
    cols = ["scene", "scale", "resolution", "stages", "method", "sampling", "samples",
            "time_ms", "rel_rms", "skill", "flip", "err_model", "err_taps", "err_screen",
            "err_recon", "bias_rel_rms", "noise_rel_rms", "status", "flags"]  # fmt: skip
    parts += ["<h2>Summary</h2>", _table(shown, cols)]
    for path in plots:
        parts.append(f"<h2>{html.escape(path.stem.replace('_', ' '))}</h2>")
        parts.append(f"<img src='{_file_png(path)}' style='max-width:100%'>")

    ok = table[table["status"] == "ok"]
    files = Path(out_dir) / "report_files"
    groups_done: list[Any] = []
    grouped = list(ok.groupby(group_keys(ok), dropna=False, sort=True))
    for key, group in grouped:
        info = dict(zip(group_keys(ok), key, strict=True))
        title = " · ".join(str(info[k]) for k in group_keys(ok) if info[k] != MISSING)
        if progress is not None:
            progress(f"report.html: {len(groups_done) + 1}/{len(grouped)} {title}")
        parts.append(f"<h2>{html.escape(title)}</h2>")
        loaded = {i: _load(r["run_dir"]) for i, r in group.iterrows()}
        errors = {
            i: relative_error(*pair)
            for i, pair in loaded.items()
            if pair is not None and group.loc[i, "method"] != REFERENCE
        }
        vmax = max((float(e.max()) for e in errors.values()), default=0.0) or 1e-12
        ref_id = None
        figures = []
        for i, r in group.sort_values(["method", "samples"]).iterrows():
            pair = loaded.get(i)
            if pair is None:
                continue
            result, reference = pair
            name = f"{len(groups_done)}_{i}"
            if ref_id is None:
                ref_id = f"ref{len(groups_done)}"
                ref_uri, ref_link = _image(_rgb(reference), files, f"{name}_reference")
                full = f" (full resolution: {ref_link})" if ref_link else ""
                figures.insert(
                    0,
                    f"<figure><img class='px' id='{ref_id}' src='{ref_uri}'><figcaption><b>exact "
                    f"reference</b>{full}</figcaption></figure>",
                )
            if r["method"] == REFERENCE:
                continue
            res_uri, res_link = _image(_rgb(result), files, f"{name}_result")
            err_uri, err_link = _image(
                errors[i].numpy(), files, f"{name}_error", "max", cmap="magma", vmin=0.0, vmax=vmax
            )
            links = f"<br>full resolution: {res_link} · {err_link}" if res_link else ""
            skill = r["skill"]
            tag = " (baseline)" if r["method"] == BASELINE else ""
            caption = (
                f"<b>{html.escape(label(r))}</b>{tag} — <span class='which'>result</span><br>"
                f"rel_rms {r['rel_rms']:.3g}, skill "
                f"{'–' if pd.isna(skill) else f'{float(skill):+.2f}'}, "
                f"{float(r['time_ms']):.3g} ms {html.escape(_flags(r, markdown=False))}{links}"
                f"<details><summary>config</summary><pre>{html.escape(_config(r['run_dir']))}"
                "</pre></details>"
            )
            figures.append(
                f"<figure><img class='px' src='{res_uri}' data-ref='{ref_id}' "
                f"onclick='flip(this)' title='click: flip with the reference'>"
                f"<img class='px' src='{err_uri}' title='error, shared scale'>"
                f"<figcaption>{caption}</figcaption></figure>"
            )
        if figures:
            scale = f"{vmax:.3g}" if math.isfinite(vmax) else MISSING
            parts.append(
                f"<p>Error maps share one scale: 0 to {scale} of the reference peak. "
                f"<img src='{_colorbar(vmax)}'></p>"
            )
            parts.append("<div class='strip'>" + "".join(figures) + "</div>")
        else:
            parts.append("<p>No images stored for these runs (previews=false).</p>")
        groups_done.append(key)
    parts.append("</body></html>")
    path = Path(out_dir) / "report.html"
    path.write_text("\n".join(parts))
    return path
