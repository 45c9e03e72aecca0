"""The HTML report opens in a real browser (headless Chromium) with every image loaded, and
the plots keep sweep points apart (markers per sampling, labelled ticks)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys

import pytest

from tests.test_app import TINY, _sssbench

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("html")
    proc = _sssbench(
        tmp,
        *TINY,
        "method=preintegrated,sum_of_gaussians",
        "samples=3,5",
        "sampling=uniform,importance",
        multirun=True,
    )
    assert proc.returncode == 0, proc.stderr
    return tmp


def test_every_multirun_writes_the_html_report(sweep):
    page = sweep / "sweep" / "report" / "report.html"
    text = page.read_text()
    # self-contained: every image is a data URI, nothing is fetched
    srcs = re.findall(r"src='([^']*)'", text)
    assert srcs and all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "Error maps share one scale" in text and "config</summary>" in text


@pytest.mark.skipif(CHROMIUM is None, reason="needs Debian's chromium (installed by .ci/run)")
def test_html_report_loads_in_chromium(sweep):
    page = sweep / "sweep" / "report" / "report.html"
    dom = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000",
         "--dump-dom", page.as_uri()],
        capture_output=True, text=True, timeout=120,
    ).stdout  # fmt: skip
    loaded = re.search(r'data-images-loaded="(\d+)/(\d+)"', dom)
    assert loaded, dom[:500]
    ok, total = map(int, loaded.groups())
    # reference + 8 configurations × (result, error) + colour bar + plots
    assert total >= 1 + 8 * 2 + 1 and ok == total


def test_plots_tell_samplings_apart_and_label_ticks(sweep):
    import matplotlib

    matplotlib.use("Agg")
    from sssbench import report
    from sssbench.report import plots

    runs, _ = report.load_runs(sweep / "store.sqlite")
    table = report.summary_table(runs)
    captured = {}
    import matplotlib.pyplot as plt

    real_savefig = plt.Figure.savefig

    def keep(fig, *args, **kwargs):
        captured["fig"] = fig
        return real_savefig(fig, *args, **kwargs)

    plt.Figure.savefig = keep
    try:
        plots.plot_error_vs_time(table, sweep / "evt.png")
    finally:
        plt.Figure.savefig = real_savefig
    fig = captured["fig"]
    ax = fig.axes[0]
    markers = {
        tuple(c.get_paths()[0].vertices.round(3).ravel()[:6])
        for c in ax.collections
        if len(c.get_offsets()) == 1
    }
    assert len(markers) >= 2  # importance and uniform drawn with different markers
    fig.canvas.draw()
    labels = [t.get_text() for t in ax.get_xticklabels() if t.get_text()]
    assert labels, "the x axis has labelled ticks"
    annotations = [a.get_text() for a in ax.texts]
    assert {"3", "5"} <= set(annotations)  # samples written next to the points
    assert sys.modules["sssbench.report"] is report
