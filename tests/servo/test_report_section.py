"""The position-loop section of the demo report (cnctwin.validation.servo_section).

Hidden loop parameters are drawn by the simulator (scenarios.random_loop_overrides); the section
identifies X1/Y1 from the recording and prints the comparison. Issue #5 tolerances: Kv within
5 %, jerk-filter time within 10 %, ENC_POS prediction residual below 10 % of the following error.
"""

from __future__ import annotations

import re

import pytest

from cnctwin.report import Report
from cnctwin.validation.servo_section import position_loop_section


class _Ctx:
    seed = 1

    def __init__(self) -> None:
        self.report = Report("test")

    def progress(self, message: str) -> None:
        pass


@pytest.mark.slow
def test_position_loop_section_reports_identified_against_hidden_truth() -> None:
    ctx = _Ctx()
    position_loop_section(ctx)  # type: ignore[arg-type]
    html = ctx.report.to_html()
    assert html.count("data:image/png;base64,") == 3  # tool path + X1/Y1 error signals
    text = re.sub(r"\s+", " ", re.sub("<[^>]+>", " ", re.sub(r'src="data:[^"]+"', "", html)))
    for axis in ("X1", "Y1"):
        kv = re.search(rf"{axis} kv_m_min_mm \S+ \S+ \S+ (-?[\d.e+-]+)", text)
        jerk = re.search(rf"{axis} jerk_time_s \S+ \S+ \S+ (-?[\d.e+-]+)", text)
        pred = re.search(rf"{axis} ENC_POS prediction RMS / following-error RMS (\S+)", text)
        assert kv and jerk and pred, text[-1500:]
        assert abs(float(kv.group(1))) < 5.0
        assert abs(float(jerk.group(1))) < 10.0
        assert float(pred.group(1)) < 0.10
