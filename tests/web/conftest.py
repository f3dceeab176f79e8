"""Fixtures of the dashboard tests: a simulated 12-hole wear run (Capture4Analysis file), the
real Capture4Analysis recording, a calibrated-looking spindle model file, a DuckDB store holding
the wear run, and the CI rule for the headless browser."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import cnctwin
from cnctwin.recording import Recording
from cnctwin.spindle import SpindleModel

pytest.importorskip("fastapi", reason="the dashboard needs the web extra: "
                    "pip install 'cnctwin[web]'")


@pytest.fixture(scope="session")
def wear12(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """Simulated tool-wear run of thesis §5.1: 12 holes in 2 sets of 6 (CYCLE81, 2400 rpm,
    400 mm/min, 20 mm deep), written as one Capture4Analysis file (~50 s of cycles)."""
    from cnctwin.sim import scenarios as sc

    out = tmp_path_factory.mktemp("wear12")
    res = sc.tool_wear_run(out, n_holes=12, holes_per_set=6, dynamometer=False, fmt="c4a",
                           seed=11)
    path = next(Path(p) for p in res.recording_paths if str(p).endswith(".json"))
    return {"path": path, "truth": res.truth, "dir": out}


@pytest.fixture(scope="session")
def wear12_rec(wear12: dict[str, Any]) -> Recording:
    return cnctwin.read_recording(wear12["path"])


@pytest.fixture(scope="session")
def real_rec(c4a_file: Path) -> Recording:
    return cnctwin.read_recording(c4a_file)


@pytest.fixture(scope="session")
def model_file(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A spindle model file as `cnctwin edge` gets it (the edge tests' fixture values)."""
    from cnctwin.edge import save_spindle_model

    m = SpindleModel(kt_nm_per_a=1.01, b_nm_per_rpm=8.3e-5, tau_f_nm=0.34, j_kgm2=0.0045)
    return save_spindle_model(m, tmp_path_factory.mktemp("model") / "spindle.json",
                              source="test fixture")


@pytest.fixture(scope="session")
def store_dir(tmp_path_factory: pytest.TempPathFactory, wear12_rec: Recording,
              real_rec: Recording) -> Path:
    """A DuckDB + Parquet store holding the wear run and the real recording."""
    from cnctwin.store import open as open_store

    root = tmp_path_factory.mktemp("store") / "st"
    with open_store(root) as st:
        st.ingest(wear12_rec, recording_id="wear12")
        st.ingest(real_rec, recording_id="real")
    return root


@pytest.fixture(scope="session")
def client(wear12: dict[str, Any], c4a_file: Path) -> Iterator[Any]:
    """TestClient over the files: file:0 = the wear run, file:1 = the real recording."""
    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    app = create_app(recordings=[wear12["path"], c4a_file])
    with TestClient(app) as c:
        yield c


@pytest.fixture(scope="session")
def model_client(wear12: dict[str, Any], model_file: Path) -> Iterator[Any]:
    """TestClient over the wear run with a calibrated spindle model."""
    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    app = create_app(recordings=[wear12["path"]], model=model_file)
    with TestClient(app) as c:
        yield c


@pytest.fixture(scope="session")
def live_dir(wear12: dict[str, Any], model_file: Path,
             tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The state directory of a finished `cnctwin edge run --tools` replay of the wear run."""
    from cnctwin.cli import main

    live = tmp_path_factory.mktemp("live")
    tools = live.parent / "live-tools.toml"  # T1 of the wear program, planned for 40 holes
    tools.write_text('[tools.1]\nkind = "drill"\ndiameter_mm = 20\nname = "D20 HSS"\n'
                     "life_holes = 40\n")
    assert main(["edge", "run", "--source", str(wear12["path"]), "--model", str(model_file),
                 "--out", str(live), "--quiet", "--learn-s", "2", "--tools", str(tools)]) == 0
    return live
