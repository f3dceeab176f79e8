"""The use-case section of the demo report (cnctwin.validation.usecases_section), quick mode.

The section simulates a 120-hole wear run with the wear curve compressed, a loose tap at a hidden
hole and drilling faults at hidden times, and shows the analysis beside the hidden truth. The
figures are checked by count; the numbers by the same tolerances as
tests/usecases/test_wear_validation.py and test_trials.py (looser where 120 holes give less
data: wear RMS < 15 µm).
"""

from __future__ import annotations

import re
from typing import Any

import pytest

from cnctwin.report import Report
from cnctwin.validation.usecases_section import use_cases_section


class _Ctx:
    seed = 0
    quick = True

    def __init__(self) -> None:
        self.report = Report("test")
        self.timings: dict[str, float] = {}
        self.messages: list[str] = []

    def progress(self, message: str) -> None:
        self.messages.append(message)


@pytest.mark.slow
def test_use_cases_section_quick() -> None:
    ctx: Any = _Ctx()
    use_cases_section(ctx)
    html = ctx.report.to_html()
    text = re.sub(r"\s+", " ", re.sub("<[^>]+>", " ", re.sub(r'src="data:[^"]+"', "", html)))
    assert "failed" not in text and "not shown" not in text, text[:2000]
    # Fig 5.3, wear estimate, Fig 5.5, Figs 5.6-5.9 (4), Fig 5.10, detector score
    assert html.count("data:image/png;base64,") == 9
    for key in ("Fig. 5.3 analogue", "Fig. 5.5 analogue", "Fig. 5.6 analogue",
                "Fig. 5.9 analogue", "Fig. 5.10 analogue", "Per-hole record",
                "Within-set pattern", "Backtest over simulated faults"):
        assert key in text, key
    rms = re.search(r"wear RMS error \[µm\] ([\d.]+)", text)
    assert rms and float(rms.group(1)) < 15.0
    delay = re.search(r"detected ([\d.]+) s after the onset", text)
    assert delay and float(delay.group(1)) < 0.3
    assert any("use cases" in m for m in ctx.messages)
    assert "use cases: wear run simulation" in ctx.timings
