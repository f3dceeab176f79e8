"""Tests of the HTML report builder (cnctwin.report)."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import pandas as pd

from cnctwin.report import Report


def test_report_is_self_contained(tmp_path: Path) -> None:
    rep = Report("cnctwin test", subtitle="unit test")
    sec = rep.section("Spindle <calibration>")
    sec.text("Kt & friction")
    sec.table(pd.DataFrame({"a": [1.0, 2.0]}), caption="values")
    fig, ax = plt.subplots()
    ax.plot([0, 1], [0, 1])
    sec.figure(fig, caption="a line")
    out = rep.write(tmp_path / "r" / "report.html")
    text = out.read_text()
    assert "data:image/png;base64," in text
    assert "Spindle &lt;calibration&gt;" in text  # titles are escaped
    assert 'href="#spindle--calibration' in text
    assert "<caption>values</caption>" in text
    assert "src=\"http" not in text  # nothing fetched from outside
