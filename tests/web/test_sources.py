"""Which files of a directory the dashboard takes as recordings."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.iotools import read_recording
from cnctwin.sim.scenarios import tool_wear_run
from cnctwin.web.sources import expand_recording_paths


def test_scenario_output_directory_gives_its_recording(tmp_path: Path) -> None:
    # a scenario's output: the chunk directory is the recording; truth.json,
    # truth_per_cycle.parquet, holes.csv and the dynamometer CSVs are not
    out = tmp_path / "wear"
    tool_wear_run(out, seed=1, n_holes=2)
    assert (out / "truth.json").is_file() and (out / "truth_per_cycle.parquet").is_file()
    found = expand_recording_paths([out])
    assert found == [out / "tool_wear_run"]
    assert len(read_recording(found[0]).hf) > 1000
    # the chunk directory given itself is one recording, not one per chunk file
    assert expand_recording_paths([out / "tool_wear_run"]) == [out / "tool_wear_run"]


def test_missing_path_names_it(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="nothing_here"):
        expand_recording_paths([tmp_path / "nothing_here"])
