"""Act on the machine: make the user's program as fast as the machine, tool and material allow.

Layer: beside :mod:`cnctwin.calibration` (it uses the simulator, the engagement model, the
calibrated spindle law and the materials). :func:`optimize_program` is the orchestrator;
:mod:`cnctwin.optimizer.constraints` holds the limits, :mod:`cnctwin.optimizer.engagement_pass`
the engagement of the programmed run, :mod:`cnctwin.optimizer.program_edit` the rewriting and
:mod:`cnctwin.optimizer.verify` the check on the twin.
"""

from cnctwin.optimizer.constraints import CONSTRAINTS, Limits, feed_limits, limits_from_machine
from cnctwin.optimizer.core import LinePlan, OptimizeResult, optimize_program, plan_feeds
from cnctwin.optimizer.verify import VerifyRun, load_violations, verify_run

__all__ = [
    "CONSTRAINTS",
    "Limits",
    "LinePlan",
    "OptimizeResult",
    "VerifyRun",
    "feed_limits",
    "limits_from_machine",
    "load_violations",
    "optimize_program",
    "plan_feeds",
    "verify_run",
]
