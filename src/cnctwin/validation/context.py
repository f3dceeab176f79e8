"""What a demo-report section builder gets: the campaign, the calibrated chains, the report.

The report sections (:mod:`cnctwin.validation.servo_section`,
:mod:`cnctwin.validation.usecases_section`) and ``cnctwin demo`` (:mod:`cnctwin.cli.demo`)
share this context; it lives in the validation layer so that no section imports the command
line.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from rich.console import Console

    from cnctwin.report import Report
    from cnctwin.sim.scenarios import ScenarioResult
    from cnctwin.twin import TwinChain

__all__ = ["DemoContext"]


@dataclass
class DemoContext:
    """What a report-section builder gets.

    Attributes
    ----------
    out_dir : Path
        Output directory (the report is ``out_dir / "report.html"``).
    seed : int
        Random seed of the campaign.
    quick : bool
        Quick mode (fewer speeds, shorter runs): builders should scale their work down.
    report : Report
        The report to add sections to.
    console : rich.console.Console
        Terminal output.
    sweep, warm_up, cold, warm : ScenarioResult
        Air-cut sweep, warm-up, drilling validation cold (calibration) and after the warm-up
        drift (validation).
    chains : dict of str to TwinChain
        Calibrated chains by name (``'thesis'``, ``'improved'``), already run on ``warm``.
    drift_k : float
        Temperature offset of the warm validation [K].
    timings : dict of str to float
        Wall time per step [s].
    extra : dict
        Free space for builders to share results.
    """

    out_dir: Path
    seed: int
    quick: bool
    report: Report
    console: Console
    sweep: ScenarioResult | None = None
    warm_up: ScenarioResult | None = None
    cold: ScenarioResult | None = None
    warm: ScenarioResult | None = None
    chains: dict[str, TwinChain] = field(default_factory=dict)
    drift_k: float = 15.0
    timings: dict[str, float] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)

    def progress(self, text: str) -> None:
        """Print a progress line."""
        self.console.log(text)
