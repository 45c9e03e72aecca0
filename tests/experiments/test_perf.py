"""The perf benchmark's quick variant produces its report section (no timing is asserted)."""

from experiments.common import Context, execute
from experiments.perf import run


def test_perf_quick_writes_its_section(tmp_path):
    path = execute("perf", run, Context("perf", quick=True, out=tmp_path, threads=1))
    text = path.read_text()
    assert text.startswith('<a id="perf"></a>')
    assert "× kornia 7×7" in text and "**Verdict:" in text
    assert "head_far" in text and "ReferenceSSS" in text
