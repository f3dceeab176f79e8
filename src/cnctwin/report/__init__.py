"""Self-contained HTML reports: sections of text, tables and figures in one file.

Figures are embedded as base64 PNG, so the report opens anywhere without its folder.

Examples
--------
>>> import pandas as pd
>>> rep = Report("Demo")
>>> sec = rep.section("Validation")
>>> sec.text("Table 4.1 analogue.")
>>> sec.table(pd.DataFrame({"error_pct": [0.5]}), caption="errors")
>>> "<table" in rep.to_html()
True
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import io
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pandas as pd

if TYPE_CHECKING:
    from matplotlib.figure import Figure

__all__ = ["Report", "Section", "column_format", "unit_header"]

_CSS = """
body{font-family:system-ui,-apple-system,Segoe UI,Roboto,sans-serif;max-width:1100px;
margin:2em auto;
padding:0 1em;color:#1d2330;line-height:1.45}
h1{border-bottom:3px solid #2a6f97;padding-bottom:.3em}
h2{color:#2a6f97;margin-top:2em;border-bottom:1px solid #d0d7de}
h3{color:#374151}
table{border-collapse:collapse;margin:.8em 0;font-size:.9em}
th,td{border:1px solid #d0d7de;padding:.3em .6em;text-align:right}
th{background:#f1f5f9}
td:first-child,th:first-child{text-align:left}
figure{margin:1em 0}
figcaption,caption{font-size:.88em;color:#4b5563;caption-side:bottom;text-align:left}
img{max-width:100%}
.table-wrap{max-width:100%;overflow-x:auto}
.note{background:#fff8e1;border-left:4px solid #f0b429;padding:.5em 1em}
.ok{color:#137333}.bad{color:#b3261e}
nav ul{columns:2}
code{background:#f1f5f9;padding:0 .2em}
"""


# column-name suffix -> unit, longest first (a name ends in its unit, conventions.md)
_UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_nm_per_a", "Nm/A"), ("_nm_per_rpm", "Nm/rpm"), ("_mm_per_rev", "mm/rev"),
    ("_mm_per_min", "mm/min"), ("_mm_min", "mm/min"), ("_j_per_k", "J/K"),
    ("_per_k", "1/K"), ("_kgm2", "kg m²"), ("_rpm", "rpm"), ("_pct", "%"), ("_ms", "ms"),
    ("_um", "µm"), ("_mm", "mm"), ("_nm", "Nm"), ("_hz", "Hz"), ("_deg", "°"), ("_s", "s"),
    ("_a", "A"), ("_v", "V"), ("_w", "W"), ("_j", "J"), ("_n", "N"), ("_c", "°C"),
    ("_k", "K"),
)
# lengths in mm that are deviations from the ideal hole or path: shown in µm
_DEVIATION_WORDS = ("dev", "error", "runout", "straightness", "deviation", "offset")


def unit_header(name: str) -> tuple[str, float]:
    """A column header with its unit in brackets, and the factor to apply to the values.

    Parameters
    ----------
    name : str
        Column name with the unit as its suffix (``torque_mean_nm``, ``dev_z_rms_mm``).

    Returns
    -------
    header : str
        ``"torque mean [Nm]"``; the name unchanged when it ends in no known unit.
    factor : float
        1, or 1000 for a deviation in mm shown in µm.

    Examples
    --------
    >>> unit_header("torque_mean_nm")
    ('torque mean [Nm]', 1.0)
    >>> unit_header("dev_z_rms_mm")
    ('dev z rms [µm]', 1000.0)
    """
    low = name.lower()
    for suffix, unit in _UNIT_SUFFIXES:
        if low.endswith(suffix) and len(low) > len(suffix):
            base = name[: -len(suffix)].replace("_", " ").strip()
            if unit == "mm" and any(w in low for w in _DEVIATION_WORDS):
                return f"{base} [µm]", 1000.0
            return f"{base} [{unit}]", 1.0
    return name, 1.0


def column_format(values: pd.Series, *, digits: int = 4) -> str:
    """One number format for a whole column: the same decimals in every row.

    Parameters
    ----------
    values : pandas.Series
        The column.
    digits : int, default 4
        Significant digits of the largest value.

    Returns
    -------
    str
        A ``str.format`` pattern: ``"{:.0f}"`` for integers, fixed decimals chosen from the
        largest magnitude, or ``"{:.3e}"`` for very large or very small columns.

    Examples
    --------
    >>> column_format(pd.Series([3.7456, 12.5, 0.25]))
    '{:.2f}'
    """
    x = pd.to_numeric(values, errors="coerce").to_numpy(dtype=float)
    x = x[pd.notna(x) & (x != float("inf")) & (x != float("-inf"))]
    if x.size == 0:
        return "{}"
    if (x == x.round()).all() and abs(x).max() < 1e12:
        return "{:.0f}"
    top = float(abs(x).max())
    if top >= 1e7 or top < 1e-3:
        return "{:.3e}"
    decimals = min(max(digits - 1 - math.floor(math.log10(top)), 0), 6)
    return f"{{:.{decimals}f}}"


def _formatter(pattern: str) -> Callable[[Any], str]:
    def fmt(v: Any) -> str:
        return "–" if pd.isna(v) else pattern.format(v)

    return fmt


@dataclass
class Section:
    """A report section: an ordered list of HTML blocks."""

    title: str
    blocks: list[str] = field(default_factory=list)

    @property
    def anchor(self) -> str:
        """HTML id of the section."""
        return "".join(ch if ch.isalnum() else "-" for ch in self.title.lower()).strip("-")

    def text(self, paragraph: str, *, note: bool = False) -> None:
        """Add a paragraph (plain text, escaped)."""
        cls = ' class="note"' if note else ""
        self.blocks.append(f"<p{cls}>{html.escape(paragraph)}</p>")

    def html(self, fragment: str) -> None:
        """Add a trusted HTML fragment as is."""
        self.blocks.append(fragment)

    def heading(self, title: str) -> None:
        """Add a sub-heading."""
        self.blocks.append(f"<h3>{html.escape(title)}</h3>")

    def table(
        self, df: pd.DataFrame, *, caption: str = "", float_format: str | None = None,
        index: bool = False, units: bool = True,
    ) -> None:
        """Add a table from a DataFrame, scrolling sideways inside the page when wide.

        Parameters
        ----------
        df : pandas.DataFrame
            The table.
        caption : str, optional
            Caption under the table.
        float_format : str, optional
            One ``str.format`` pattern for every float; default per column
            (:func:`column_format`: the same decimals down a column).
        index : bool, default False
            Show the index.
        units : bool, default True
            Headers from the unit suffixes of the column names (:func:`unit_header`:
            ``torque_mean_nm`` -> ``torque mean [Nm]``, deviations in mm shown in µm).
        """
        out = df.copy()
        if units:
            names = {}
            for col in out.columns:
                header, factor = unit_header(str(col))
                if factor != 1.0 and pd.api.types.is_numeric_dtype(out[col]):
                    out[col] = out[col] * factor
                elif factor != 1.0:
                    header = str(col)
                names[col] = header
            out = out.rename(columns=names)
        formatters: dict[Any, Callable[[Any], str]] = {}
        for col in out.columns:
            if pd.api.types.is_float_dtype(out[col]):
                pattern = float_format or column_format(out[col])
                formatters[col] = _formatter(pattern)
        body = out.to_html(index=index, border=0, na_rep="–", formatters=formatters)
        if caption:
            body = body.replace(
                "</table>", f"<caption>{html.escape(caption)}</caption></table>", 1
            )
        self.blocks.append(f'<div class="table-wrap">{body}</div>')

    def figure(self, fig: Figure, *, caption: str = "", dpi: int = 110) -> None:
        """Add a matplotlib figure as an embedded PNG and close it."""
        import matplotlib.pyplot as plt

        buf = io.BytesIO()
        fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
        plt.close(fig)
        data = base64.b64encode(buf.getvalue()).decode("ascii")
        cap = f"<figcaption>{html.escape(caption)}</figcaption>" if caption else ""
        self.blocks.append(f'<figure><img alt="{html.escape(caption)}" '
                           f'src="data:image/png;base64,{data}"/>{cap}</figure>')


@dataclass
class Report:
    """An HTML report made of sections.

    Parameters
    ----------
    title : str
        Report title.
    subtitle : str, optional
        A line under the title (machine, data, date).
    """

    title: str
    subtitle: str = ""
    sections: list[Section] = field(default_factory=list)

    def section(self, title: str) -> Section:
        """Append and return a new section."""
        sec = Section(title)
        self.sections.append(sec)
        return sec

    def to_html(self) -> str:
        """The whole report as one HTML document."""
        stamp = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
        toc = "".join(
            f'<li><a href="#{s.anchor}">{html.escape(s.title)}</a></li>' for s in self.sections
        )
        body = "".join(
            f'<h2 id="{s.anchor}">{html.escape(s.title)}</h2>{"".join(s.blocks)}'
            for s in self.sections
        )
        sub = f"<p>{html.escape(self.subtitle)}</p>" if self.subtitle else ""
        return (
            "<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'>"
            f"<title>{html.escape(self.title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{html.escape(self.title)}</h1>{sub}<p><small>Generated by cnctwin, {stamp}"
            f"</small></p><nav><ul>{toc}</ul></nav>{body}</body></html>"
        )

    def write(self, path: str | Path) -> Path:
        """Write the report to ``path`` (parent folders are created)."""
        p = Path(path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(self.to_html(), encoding="utf-8")
        return p
