"""The report's plots (matplotlib, Agg): error against run time per ranking group with the
Pareto front, the baseline and the reference; median pass times per method; the error budget
as stacked bars. Each takes the summary table of :mod:`sssbench.report.tables`.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pandas as pd

from sssbench.report.tables import (
    BASELINE,
    MISSING,
    PLOT_METRIC,
    REFERENCE,
    SEARCH,
    group_keys,
    label,
    search_fronts,
)

__all__ = [
    "plot_error_vs_time",
    "error_vs_time_figure",
    "plot_pass_times",
    "plot_budget",
    "MARKERS",
    "BUDGET_PARTS",
    "PARETO_LABEL",
    "REFERENCE_LABEL",
    "WORSE_LABEL",
]

#: colour of the Optuna trials' Pareto front
SEARCH_COLOUR = "tab:red"
#: marker per sampling rule (the same in every plot)
MARKERS = {"importance": "o", "uniform": "s", "power": "^", None: "D"}


def _sampling_label(sampling: Any) -> str:
    return f"{sampling} sampling" if isinstance(sampling, str) else "no tap placement"


def _marker(sampling: Any) -> str:
    if isinstance(sampling, str):
        return MARKERS.get(sampling, "P")
    return MARKERS[None]


def _log_ticks(axis: Any, lo: float, hi: float) -> None:
    """Readable log ticks: 1-2-5 labels within two decades, one label per decade beyond,
    no minor labels (they overlap into unreadable runs)."""
    from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

    decades = math.log10(max(hi, 1e-300) / max(lo, 1e-300)) if lo > 0 and hi > 0 else 3
    subs = (1.0, 2.0, 5.0) if decades <= 2 else (1.0,)
    axis.set_major_locator(LogLocator(base=10, subs=subs, numticks=12))
    axis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    axis.set_minor_formatter(NullFormatter())


def _panels(n: int, width: float = 5.0, height: float = 4.0):
    import matplotlib.pyplot as plt

    ncols = min(3, max(n, 1))
    nrows = math.ceil(max(n, 1) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(width * ncols, height * nrows), squeeze=False)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    return fig, list(axes.flat)[:n]


def _title(info: dict[str, Any]) -> str:
    t = f"{info['scene']} · {info['scale']} · {info['resolution']}"
    return t + (f" · {info['stages']}" if info.get("stages", MISSING) != MISSING else "")


#: what each kind of mark of the error-versus-time plot means (its legend entry)
PARETO_LABEL = "Pareto front (ringed, stepped line)"
SEARCH_LABEL = "Optuna trials' front (red rings, dashed)"
BASELINE_LABEL = "doing nothing (identity, dashed line)"
REFERENCE_LABEL = "exact reference at its time (zero error drawn at the floor)"
WORSE_LABEL = "worse than doing nothing (red cross)"


def _legend_gid(*labels: str) -> str:
    """The ``gid`` of a drawn mark: the legend entries that explain it (checked by a test:
    every mark of the plot is explained by the legend)."""
    return "legend:" + "|".join(labels)


def plot_error_vs_time(table: pd.DataFrame, path: Path) -> Path | None:
    """Per ranking group: time against rel_rms, colour per method, marker per sampling,
    samples written next to each point, the Pareto front (rings and a stepped line), points
    worse than doing nothing crossed in red, the do-nothing baseline as a dashed line and the
    exact reference at its own time as the zero-error anchor (a star on the floor). Every kind
    of mark has a legend entry (each drawn mark carries the entries that explain it as its
    ``gid``)."""
    import matplotlib.pyplot as plt

    fig = error_vs_time_figure(table)
    if fig is None:
        return None
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def error_vs_time_figure(table: pd.DataFrame) -> Any:
    """The figure of :func:`plot_error_vs_time` (``None`` without a plottable run)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    ok = table[(table["status"] == "ok") & table["time_ms"].notna() & table[PLOT_METRIC].notna()]
    if ok.empty:
        return None
    methods = sorted(ok["method"].unique())
    colours = {m: plt.get_cmap("tab10")(i % 10) for i, m in enumerate(methods)}
    groups = list(ok.groupby(group_keys(ok), dropna=False, sort=True))
    fig, axes = _panels(len(groups))
    searched = False  # some panel has Optuna trials
    for ax, (key, sub) in zip(axes, groups, strict=True):
        info = dict(zip(group_keys(ok), key, strict=True))
        sub = sub.reset_index()
        err = sub[PLOT_METRIC].astype(float)
        time = sub["time_ms"].astype(float)
        positive = err[err > 0]
        floor = float(positive.min()) / 3 if len(positive) else 1e-6
        tpos = time[time > 0]
        tmin = float(tpos.min()) if len(tpos) else 1e-3
        for _, r in sub.iterrows():
            if r["method"] in (BASELINE, REFERENCE):
                continue
            e = max(float(r[PLOT_METRIC]), floor)
            t = max(float(r["time_ms"]), tmin / 3)
            sampling = r["sampling"] if isinstance(r["sampling"], str) else None
            ax.scatter(
                t,
                e,
                color=colours[r["method"]],
                marker=_marker(sampling),
                s=34,
                zorder=3,
                edgecolors="none",
                gid=_legend_gid(r["method"], _sampling_label(sampling)),
            )
            if r["worse_than_nothing"]:
                ax.scatter(
                    t, e, marker="x", s=60, color="tab:red", zorder=6, gid=_legend_gid(WORSE_LABEL)
                )
            if not pd.isna(r["samples"]):
                ax.annotate(
                    str(int(r["samples"])),
                    (t, e),
                    textcoords="offset points",
                    xytext=(4, 3),
                    fontsize=6,
                    color=colours[r["method"]],
                )
        base = sub[sub["method"] == BASELINE]
        if len(base):
            be = float(base[PLOT_METRIC].iloc[0])
            ax.axhline(
                max(be, floor),
                color="0.3",
                ls="--",
                lw=1,
                zorder=1,
                gid=_legend_gid(BASELINE_LABEL),
            )
            ax.annotate(
                "doing nothing (identity)",
                (0.02, max(be, floor)),
                xycoords=("axes fraction", "data"),
                textcoords="offset points",
                xytext=(0, 3),
                fontsize=7,
                color="0.3",
            )
        ref = sub[sub["method"] == REFERENCE]
        if len(ref):
            ax.scatter(
                max(float(ref["time_ms"].iloc[0]), tmin / 3),
                floor,
                marker="*",
                s=140,
                color="gold",
                edgecolors="k",
                zorder=5,
                gid=_legend_gid(REFERENCE_LABEL),
            )
            ax.annotate(
                "exact reference (zero error)",
                (float(ref["time_ms"].iloc[0]), floor),
                textcoords="offset points",
                xytext=(-10, 6),
                fontsize=6,
                ha="right",
            )
        for name, front in search_fronts(sub).items():  # the grid's and the search's
            searched |= name == SEARCH
            colour, ls = ("k", "-") if name == "grid" else (SEARCH_COLOUR, "--")
            gid = _legend_gid(PARETO_LABEL if name == "grid" else SEARCH_LABEL)
            ft = [max(float(t), tmin / 3) for t in front["time_ms"]]
            fe = [max(float(e), floor) for e in front[PLOT_METRIC]]
            ax.step(ft, fe, where="post", color=colour, ls=ls, lw=1, alpha=0.6, zorder=2, gid=gid)
            ax.scatter(ft, fe, s=120, facecolors="none", edgecolors=colour, zorder=4, gid=gid)
        ax.set_xscale("log")
        ax.set_yscale("log")
        lo_t, hi_t = ax.get_xlim()
        lo_e, hi_e = ax.get_ylim()
        _log_ticks(ax.xaxis, lo_t, hi_t)
        _log_ticks(ax.yaxis, lo_e, hi_e)
        hidden = " (SSS not visible)" if sub["visible"].eq(False).all() else ""
        ax.set_title(_title(info) + hidden, fontsize=9)
        ax.set_xlabel("time (ms, sum of pass medians)")
        ax.set_ylabel(f"{PLOT_METRIC} (zero drawn at the floor)")
        ax.grid(True, which="major", alpha=0.3)
    handles = [
        Line2D([], [], ls="", marker="o", color=colours[m], label=m)
        for m in methods
        if m not in (BASELINE, REFERENCE)
    ]
    samplings = sorted({s for s in ok["sampling"] if isinstance(s, str)})
    points = ok[~ok["method"].isin((BASELINE, REFERENCE))]
    drawn = {_sampling_label(s if isinstance(s, str) else None) for s in points["sampling"]}
    handles += [
        Line2D([], [], ls="", marker=_marker(s), color="0.4", label=_sampling_label(s))
        for s in [*samplings, None]
        if _sampling_label(s) in drawn
    ]
    ring = {"marker": "o", "ms": 11, "mfc": "none", "alpha": 0.6}
    handles.append(Line2D([], [], color="k", mec="k", label=PARETO_LABEL, **ring))
    if searched:
        handles.append(
            Line2D(
                [], [], color=SEARCH_COLOUR, mec=SEARCH_COLOUR, ls="--", label=SEARCH_LABEL, **ring
            )
        )
    if ok["method"].eq(BASELINE).any():
        handles.append(Line2D([], [], color="0.3", ls="--", label=BASELINE_LABEL))
    if ok["method"].eq(REFERENCE).any():
        handles.append(
            Line2D([], [], ls="", marker="*", ms=12, color="gold", mec="k", label=REFERENCE_LABEL)
        )
    if ok["worse_than_nothing"].fillna(False).astype(bool).any():
        handles.append(Line2D([], [], ls="", marker="x", color="tab:red", label=WORSE_LABEL))
    ncol = 3 * min(3, len(axes))
    legend_rows = math.ceil(len(handles) / ncol)
    fig.legend(
        handles=handles, loc="lower center", ncol=ncol, fontsize=7, bbox_to_anchor=(0.5, 0.0)
    )
    fig.tight_layout(rect=(0, min(0.4, 0.25 * legend_rows / fig.get_figheight()), 1, 1))
    return fig


def plot_pass_times(table: pd.DataFrame, passes: pd.DataFrame, path: Path) -> Path | None:
    """Per scene: a stacked bar per method of its median pass times (mean over the method's
    points in that scene)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[table["status"] == "ok"]
    if ok.empty or passes.empty:
        return None
    merged = passes.merge(ok[["run_id", "method", "scene"]], on="run_id")
    merged = merged[merged["method"] != REFERENCE]
    if merged.empty:
        return None
    order = list(dict.fromkeys(merged.sort_values(["run_id", "idx"])["name"]))
    cmap = plt.get_cmap("tab20")
    colours = {n: cmap(i % 20) for i, n in enumerate(order)}
    scenes = sorted(merged["scene"].unique())
    fig, axes = _panels(len(scenes), width=5.5, height=0.9 + 0.35 * merged["method"].nunique())
    for ax, scene in zip(axes, scenes, strict=True):
        sub = merged[merged["scene"] == scene]
        per_run = sub.groupby(["method", "run_id", "name"], as_index=False)["ms_median"].sum()
        n_runs = per_run.groupby("method")["run_id"].nunique()
        total = per_run.groupby(["method", "name"])["ms_median"].sum()
        mean = total.div(n_runs, level="method").unstack("name").fillna(0.0)
        mean = mean[[c for c in order if c in mean.columns]]
        left = pd.Series(0.0, index=mean.index)
        for name in mean.columns:
            ax.barh(mean.index, mean[name], left=left, color=colours[name], label=name)
            left = left + mean[name]
        ax.set_title(scene, fontsize=9)
        ax.set_xlabel("mean time per run (ms)")
        ax.tick_params(labelsize=7)
    handles = [plt.Rectangle((0, 0), 1, 1, color=colours[n]) for n in order]
    fig.legend(handles, order, fontsize=6, loc="center left", bbox_to_anchor=(1.0, 0.5))
    fig.suptitle("where each method spends its time, per scene", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


#: the parts of the error budget, bottom to top (docs/error_budget.md)
BUDGET_PARTS = ("err_model", "err_taps", "err_screen")


def plot_budget(table: pd.DataFrame, path: Path) -> Path | None:
    """Per ranking group: the error budget of each configuration as stacked bars of the
    parts' signed contributions ``⟨part, error⟩ / (‖R‖ ‖error‖)``, which add up exactly to
    the configuration's rel RMS (the black mark): model, taps, screen space and the
    reconstruction convention (docs/error_budget.md) — so a user sees whether more taps, a
    better kernel or depth awareness would help. A negative part cancels some of the others."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = table[(table["status"] == "ok") & table["contribution_model"].notna()]
    ok = ok[~ok["method"].isin((BASELINE, REFERENCE))]
    if ok.empty:
        return None
    groups = list(ok.groupby(group_keys(ok), dropna=False, sort=True))
    fig, axes = _panels(len(groups), width=5.5, height=3.6)
    parts = ("model", "taps", "screen", "recon")
    colours = dict(zip(parts, ("tab:blue", "tab:orange", "tab:green", "tab:gray"), strict=True))
    for ax, (key, sub) in zip(axes, groups, strict=True):
        info = dict(zip(group_keys(ok), key, strict=True))
        sub = sub.sort_values(["method", "samples"]).head(14)
        labels = [label(r) for _, r in sub.iterrows()]
        up = [0.0] * len(sub)
        down = [0.0] * len(sub)
        for part in parts:
            vals = sub[f"contribution_{part}"].astype(float).fillna(0.0).tolist()
            base = [u if v >= 0 else d for u, d, v in zip(up, down, vals, strict=True)]
            ax.bar(labels, vals, bottom=base, color=colours[part], label=f"err_{part}")
            up = [u + max(v, 0.0) for u, v in zip(up, vals, strict=True)]
            down = [d + min(v, 0.0) for d, v in zip(down, vals, strict=True)]
        ax.scatter(
            labels,
            sub[PLOT_METRIC].astype(float),
            marker="_",
            s=200,
            color="k",
            zorder=3,
            label="rel_rms (total)",
        )
        ax.axhline(0.0, color="k", lw=0.5)
        ax.set_title(_title(info), fontsize=9)
        ax.tick_params(axis="x", labelrotation=60, labelsize=6)
        ax.set_ylabel("contribution to rel RMS")
    axes[0].legend(fontsize=6)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
