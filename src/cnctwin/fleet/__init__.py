"""Fleet scale: the single-machine analyses over many machines and days, on Dask distributed.

Layers: :mod:`~cnctwin.fleet.cluster` (the cluster: embedded LocalCluster or a scheduler
address), :mod:`~cnctwin.fleet.ingest` (parallel, idempotent, crash-consistent ingest),
:mod:`~cnctwin.fleet.jobs` (one task per (machine, day) partition of the store) and
:mod:`~cnctwin.fleet.drift` (alarms and trends from the per-day tables). ``cnctwin fleet ...``
is the command line; docs/fleet.md the guide.
"""

from __future__ import annotations

from cnctwin.fleet.cluster import SCHEDULER_ENV, fleet_client, map_tasks
from cnctwin.fleet.drift import DRIFT_RULES, DriftRule, drift_alarms, wear_trend
from cnctwin.fleet.ingest import (
    IngestOutcome,
    IngestReport,
    content_hash,
    find_recordings,
    ingest_recordings,
)
from cnctwin.fleet.jobs import (
    LONG_RECORDING_S,
    Partition,
    compare_partition,
    health_estimates,
    health_partition,
    health_table,
    holes_partition,
    machine_files_in,
    partitions,
    quality_partition,
    run_job,
    split_partitions,
)

__all__ = [
    "DRIFT_RULES",
    "LONG_RECORDING_S",
    "SCHEDULER_ENV",
    "DriftRule",
    "IngestOutcome",
    "IngestReport",
    "Partition",
    "compare_partition",
    "content_hash",
    "drift_alarms",
    "find_recordings",
    "fleet_client",
    "health_estimates",
    "health_partition",
    "health_table",
    "holes_partition",
    "ingest_recordings",
    "machine_files_in",
    "map_tasks",
    "partitions",
    "quality_partition",
    "run_job",
    "split_partitions",
    "wear_trend",
]
