"""Each machine of a fleet store uses its own machine file (issue 24, pt 7).

Before, ``cnctwin web --machine FILE`` applied one file to every recording of a fleet store, so
every machine was "calibrated" with another machine's spindle. Now a file belongs to the machine
it names; a machine without one is labelled uncalibrated, its torque uses the library default,
and its twin comparison says which file is missing.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import pytest

from cnctwin.machine import MachineFile, ParameterRecord, Provenance, save_machine
from cnctwin.recording import Recording

pytest.importorskip("fastapi", reason="the web extra: pip install 'cnctwin[web]'")
from fastapi.testclient import TestClient

from cnctwin.web import create_app


def _machine_file(name: str, kt: float, path: Path) -> Path:
    mf = MachineFile()
    mf = dataclasses.replace(mf, machine=dataclasses.replace(mf.machine, name=name))
    prov = Provenance("test fixture")
    mf = mf.with_records({
        "spindle.kt_nm_per_a": ParameterRecord(kt, 0.01, prov),
        "spindle.viscous_friction_nm_per_rpm": ParameterRecord(8.3e-5, 1e-6, prov),
        "spindle.coulomb_friction_nm": ParameterRecord(0.34, 0.01, prov)})
    return save_machine(mf, path)


@pytest.fixture(scope="module")
def fleet_store(wear12_rec: Recording, tmp_path_factory: pytest.TempPathFactory) -> Path:
    from cnctwin.store import open as open_store

    root = tmp_path_factory.mktemp("fleet") / "st"
    with open_store(root) as st:
        for m in ("mill-1", "mill-2", "mill-3"):
            wear12_rec.meta.machine = m
            st.ingest(wear12_rec, recording_id=f"run-{m}")
    return root


def test_each_machine_its_own_file_and_the_rest_uncalibrated(fleet_store: Path,
                                                             tmp_path: Path) -> None:
    files = [_machine_file("mill-1", 1.01, tmp_path / "mill-1.toml"),
             _machine_file("mill-2", 1.20, tmp_path / "mill-2.toml")]
    with TestClient(create_app(store_url=str(fleet_store), machine=files)) as client:
        machines = {m["machine"]: m for m in client.get("/api/machines").json()}
        assert machines["mill-1"]["calibrated"] and machines["mill-2"]["calibrated"]
        assert machines["mill-1"]["machine_file"].endswith("mill-1.toml")
        assert machines["mill-2"]["machine_file"].endswith("mill-2.toml")
        assert not machines["mill-3"]["calibrated"] and machines["mill-3"]["machine_file"] is None
        page = client.get("/").text
        assert page.count(">uncalibrated<") == 1
        # each machine's torque from its own Kt: the same recording, scaled by 1.20 / 1.01
        h1 = client.get("/api/recordings/store:run-mill-1/holes").json()
        h2 = client.get("/api/recordings/store:run-mill-2/holes").json()
        h3 = client.get("/api/recordings/store:run-mill-3/holes").json()
        assert h1["calibrated"] and h2["calibrated"] and not h3["calibrated"]
        assert "mill-1.toml" in h1["model_source"] and "mill-2.toml" in h2["model_source"]
        k = h1["columns"].index("torque_mean_nm")
        t1 = [r[k] if isinstance(r, list) else r["torque_mean_nm"] for r in h1["rows"]]
        t2 = [r[k] if isinstance(r, list) else r["torque_mean_nm"] for r in h2["rows"]]
        assert t2[0] > t1[0] * 1.1  # mill-2's larger Kt gives it a larger torque
        assert client.get("/api/recordings/store:run-mill-1/compare").status_code == 200
        missing = client.get("/api/recordings/store:run-mill-3/compare")
        assert missing.status_code == 422
        assert "no machine file for machine 'mill-3'" in missing.json()["detail"]


def test_two_files_for_one_machine_are_refused(fleet_store: Path, tmp_path: Path) -> None:
    from cnctwin.exceptions import ConfigError

    files = [_machine_file("mill-1", 1.01, tmp_path / "a.toml"),
             _machine_file("mill-1", 1.02, tmp_path / "b.toml")]
    with pytest.raises(ConfigError, match="two machine files name machine 'mill-1'"):
        create_app(store_url=str(fleet_store), machine=files)


def test_one_file_naming_no_machine_is_everyones(fleet_store: Path, tmp_path: Any) -> None:
    """A one-machine user whose file has another name than the recordings' machine."""
    f = _machine_file("dmc60h", 1.01, tmp_path / "m.toml")
    with TestClient(create_app(store_url=str(fleet_store), machine=f)) as client:
        machines = client.get("/api/machines").json()
        assert all(m["calibrated"] for m in machines)
