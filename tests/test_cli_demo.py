"""``cnctwin demo --quick``: the report exists, has the spindle sections and embedded figures.

The numbers inside are checked by tests/test_twin_sim.py (issue #4 item 7); here only the
wiring of the command (issue #4 item 9): sections, figures, the Table 4.1 rows, the hook.
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from cnctwin.cli import main
from cnctwin.cli.demo import DEMO_SECTIONS, DemoContext


@pytest.mark.slow
def test_demo_quick_writes_report(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                  capsys: pytest.CaptureFixture[str]) -> None:
    monkeypatch.chdir(Path(__file__).resolve().parents[1])  # the real C4A file is relative
    seen: list[DemoContext] = []

    def hook(ctx: DemoContext) -> None:
        seen.append(ctx)
        ctx.report.section("Hook section").text("added by a DEMO_SECTIONS builder")

    DEMO_SECTIONS.append(hook)
    try:
        assert main(["demo", "--quick", "--out", str(tmp_path), "--seed", "3"]) == 0
    finally:
        DEMO_SECTIONS.remove(hook)
    printed = capsys.readouterr().out
    assert "simulating the air-cut sweep" in printed
    # progress lines without the source location of the logging call (issue 16, point 2)
    assert not re.search(r"\b\w+\.py:\d+", printed), printed[:2000]
    report = tmp_path / "report.html"
    text = report.read_text(encoding="utf-8")
    for title in (
        "Campaign and validation (thesis Table 4.1)",
        "Thesis method vs improved method",
        "Edge signals and dynamometer during the cuts",
        "Air cut, linear region and friction",
        "Motor temperature and current (Fig. 4.4)",
        "Real recording: Capture4Analysis example",
        "Position loop: identification from a milling recording",
        "Hook section",
    ):
        assert title in text, title
    assert "failed" not in text
    # Figures 3.6, 3.7, 4.5, 3.8, 3.9, 4.1, 4.2, 4.3, 4.4 and the real-data plot
    assert len(re.findall(r'src="data:image/png;base64,', text)) >= 10
    # the four validation rows of Table 4.1 + the calibration cut, for both methods
    assert text.count("Cast iron 3200 rpm 0.4 mm/rev") >= 2
    assert "cnctwin info" in text and "sinumerik" in text.lower()
    assert len(seen) == 1 and seen[0].quick and set(seen[0].chains) == {"thesis", "improved"}
