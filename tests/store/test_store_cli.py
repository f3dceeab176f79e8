"""``cnctwin ingest`` and ``cnctwin query`` through ``cnctwin.cli.main`` (both backends)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

import cnctwin.iotools
from cnctwin.cli import main
from cnctwin.recording import Recording

from .store_helpers import current_a, make_recording


@pytest.fixture
def fake_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> list[Path]:
    """Two files that ``read_recording`` (patched: wiring test) turns into known recordings."""
    recs = {
        "a.json": make_recording(machine="m1", start="2024-03-01T23:59:58", n=2000,
                                 gap=(100, 3)),
        "b.json": make_recording(machine="m2", start="2024-03-02T08:00:00", n=500),
    }
    files = []
    for name in recs:
        f = tmp_path / name
        f.write_text("{}")
        files.append(f)

    def fake_read(path: str | Path, *, salvage: bool = False) -> Recording:
        return recs[Path(path).name].copy()

    monkeypatch.setattr(cnctwin.iotools, "read_recording", fake_read)
    return files


def _ids(out: str) -> list[str]:
    return [line.split("\t")[0] for line in out.strip().splitlines()]


def test_ingest_and_query(
    store_url: str, fake_files: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["ingest", *map(str, fake_files), "--store", store_url]) == 0
    ids = _ids(capsys.readouterr().out)
    assert len(ids) == 2 and ids[0].startswith("m1-20240301T235958-1000-")
    # catalog listing
    assert main(["query", "--store", store_url]) == 0
    out = capsys.readouterr().out
    assert ids[0] in out and ids[1] in out and "n_cycles" in out
    # signals to parquet: 21 cycles of CURRENT|SP1 from 08:00:00.000 to .040 on m2
    dest = tmp_path / "cur.parquet"
    assert main(["query", "--store", store_url, "--signals", "CURRENT", "--machine", "m2",
                 "--start", "2024-03-02T08:00:00Z", "--end", "2024-03-02T08:00:00.040Z",
                 "--out", str(dest)]) == 0
    got = pd.read_parquet(dest)
    assert list(got.columns) == ["recording_id", "cycle", "time", "CURRENT|SP1"]
    assert len(got) == 21
    np.testing.assert_allclose(got["CURRENT|SP1"], current_a(got["cycle"].to_numpy()),
                               atol=1e-12, rtol=0)
    # SQL to csv
    dest_csv = tmp_path / "n.csv"
    assert main(["query", "--store", store_url, "--sql",
                 "SELECT machine, n_cycles FROM recordings ORDER BY machine",
                 "--out", str(dest_csv)]) == 0
    n = pd.read_csv(dest_csv)
    assert n.to_dict("list") == {"machine": ["m1", "m2"], "n_cycles": [2000, 500]}
    # printed head
    capsys.readouterr()
    assert main(["query", "--store", store_url, "--signals", "ENC_POS|X1",
                 "--recording", ids[1], "--head", "5"]) == 0
    out = capsys.readouterr().out
    assert "ENC_POS|X1" in out and "500 rows in all" in out


def test_ingest_machine_override(
    store_url: str, fake_files: list[Path], capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["ingest", str(fake_files[1]), "--store", store_url, "--machine", "DMU50"]) == 0
    capsys.readouterr()
    assert main(["query", "--store", store_url, "--machine", "DMU50"]) == 0
    assert "DMU50" in capsys.readouterr().out


def test_query_errors(
    store_url: str, fake_files: list[Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    main(["ingest", str(fake_files[0]), "--store", store_url])
    capsys.readouterr()
    assert main(["query", "--store", store_url, "--signals", "TORQUE"]) == 2
    assert "TORQUE" in capsys.readouterr().err
    assert main(["query", "--store", store_url, "--signals", "CURRENT",
                 "--out", str(tmp_path / "x.xlsx")]) == 2
    assert ".csv or .parquet" in capsys.readouterr().err


def test_query_missing_store(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["query", "--store", str(tmp_path / "nothing")]) == 2
    assert "no cnctwin store" in capsys.readouterr().err


def test_ingest_real_c4a_file(
    tmp_path: Path, c4a_file: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The real file through ``read_recording`` (format detection + the C4A reader)."""
    url = str(tmp_path / "store")
    assert main(["ingest", str(c4a_file), "--store", url]) == 0
    rid = _ids(capsys.readouterr().out)[0]
    assert rid.startswith("sinumerik_adapter_840Dsl-20231222T")
    assert main(["query", "--store", url, "--sql",
                 "SELECT count(DISTINCT cycle) AS n FROM hf"]) == 0
    # 3818 HF rows in Payload[*].HFData of the real file
    assert "3818" in capsys.readouterr().out
