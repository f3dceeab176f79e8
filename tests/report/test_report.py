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


def test_tables_have_units_one_format_per_column_and_fit_the_page() -> None:
    """Issue 16, point 3: units in headers, the same decimals down a column, deviations in
    µm, and a wide table scrolls inside the page instead of widening it."""
    rep = Report("t")
    df = pd.DataFrame({"hole": [0, 1], "torque_mean_nm": [3.74561, 12.5],
                       "dev_z_rms_mm": [0.0021, 0.0153], "note": ["a", None]})
    rep.section("s").table(df)
    text = rep.to_html()
    assert "<th>torque mean [Nm]</th>" in text and "<th>dev z rms [µm]</th>" in text
    assert "<td>3.75</td>" in text and "<td>12.50</td>" in text  # 4 digits of the largest
    assert "<td>2.10</td>" in text and "<td>15.30</td>" in text  # mm -> µm
    assert "<td>0</td>" in text  # integers stay integers
    assert '<div class="table-wrap">' in text and "overflow-x:auto" in text
