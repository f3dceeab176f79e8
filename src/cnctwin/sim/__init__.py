"""Physics simulator of a SINUMERIK 840D sl machining centre (issue #3).

Produces what the edge device records: one sample per 2 ms position-control cycle (500 Hz) of
spindle and feed-axis drive values, plus external sensors (dynamometer, thermal camera) and the
true parameters used (``truth``).
"""

from cnctwin.sim.spindle import SpindleMotor, SpindleState, SpindleTrace, simulate_spindle

__all__ = ["SpindleMotor", "SpindleState", "SpindleTrace", "simulate_spindle"]

from cnctwin.sim.gcode import Block, DrillCycle, Program, parse_program

__all__ += ["Block", "DrillCycle", "Program", "parse_program"]

from cnctwin.sim.interpolator import (  # noqa: E402
    AxisLimits,
    SpindleLimits,
    Trajectory,
    interpolate,
    interpolate_chunks,
)

__all__ += ["AxisLimits", "SpindleLimits", "Trajectory", "interpolate", "interpolate_chunks"]

from cnctwin.sim.machine import FeedAxis, Machine  # noqa: E402
from cnctwin.sim.recorder import (  # noqa: E402
    Capture4AnalysisSink,
    MemorySink,
    ParquetChunkSink,
    read_parquet_chunks,
)
from cnctwin.sim.servo import ServoState, ServoTrace, simulate_servo  # noqa: E402
from cnctwin.sim.simulation import (  # noqa: E402
    CuttingInput,
    CuttingOutput,
    SimulationResult,
    simulate,
)

__all__ += [
    "Capture4AnalysisSink",
    "CuttingInput",
    "CuttingOutput",
    "FeedAxis",
    "Machine",
    "MemorySink",
    "ParquetChunkSink",
    "ServoState",
    "ServoTrace",
    "SimulationResult",
    "read_parquet_chunks",
    "simulate",
    "simulate_servo",
]

from cnctwin.sim.cutting import (  # noqa: E402
    MATERIALS,
    CuttingLoad,
    DrillingModel,
    Material,
    drilling_load,
    milling_load,
    tapping_load,
)
from cnctwin.sim.faults import Chatter, HardnessChange, LooseTool, ToolBreakage  # noqa: E402
from cnctwin.sim.scenarios import SCENARIOS, ScenarioResult, run_scenario  # noqa: E402
from cnctwin.sim.sensors import Dynamometer, ThermalCamera  # noqa: E402
from cnctwin.sim.tool import Drill, EndMill, Tap, flank_wear_um, tool_temperature  # noqa: E402

__all__ += [
    "MATERIALS",
    "SCENARIOS",
    "Chatter",
    "CuttingLoad",
    "Drill",
    "DrillingModel",
    "Dynamometer",
    "EndMill",
    "HardnessChange",
    "LooseTool",
    "Material",
    "ScenarioResult",
    "Tap",
    "ThermalCamera",
    "ToolBreakage",
    "drilling_load",
    "flank_wear_um",
    "milling_load",
    "run_scenario",
    "tapping_load",
    "tool_temperature",
]

from cnctwin.sim import programs  # noqa: E402

__all__ += ["programs"]
