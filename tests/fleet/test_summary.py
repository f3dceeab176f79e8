"""The fleet ranking keeps the sign of a drift (issue 24, pt 7: a Kv drop of 30 % was shown
as +30 %): a loop that lost gain and a friction that rose are different findings."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import pandas as pd
import pytest

from cnctwin.fleet.summary import fleet_summary


def _health() -> pd.DataFrame:
    rows = []
    for day, kv, fr in (("2026-01-01", 30.0, 0.40), ("2026-01-02", 25.0, 0.41),
                        ("2026-01-03", 21.0, 0.42)):
        rows += [{"machine": "m-kv", "day": day, "component": "X1", "parameter": "kv_1_s",
                  "value": kv},
                 {"machine": "m-kv", "day": day, "component": "SP1",
                  "parameter": "friction_current_a", "value": fr},
                 {"machine": "m-fr", "day": day, "component": "SP1",
                  "parameter": "friction_current_a", "value": {"2026-01-01": 0.4,
                                                               "2026-01-02": 0.44,
                                                               "2026-01-03": 0.5}[day]}]
    return pd.DataFrame(rows)


def test_drift_keeps_its_sign_and_names_the_parameter() -> None:
    out = fleet_summary({"health": _health()}, sort="drift").set_index("machine")
    assert out.at["m-kv", "max_drift"] == pytest.approx(21.0 / 30.0 - 1.0)  # -30 %
    assert out.at["m-kv", "drift_of"] == "X1 kv_1_s"
    assert out.at["m-fr", "max_drift"] == pytest.approx(0.25)  # friction +25 %
    assert out.at["m-fr", "drift_of"] == "SP1 friction_current_a"
    # ranked by the size of the drift, worst first
    ranked = fleet_summary({"health": _health()}, sort="drift")["machine"].tolist()
    assert ranked == ["m-kv", "m-fr"]


def test_fleet_page_shows_the_signed_drift(tmp_path: pytest.TempPathFactory) -> None:
    pytest.importorskip("fastapi", reason="the web extra: pip install 'cnctwin[web]'")
    from fastapi.testclient import TestClient

    from cnctwin.web import create_app

    res = tmp_path / "fleet"  # type: ignore[operator]
    res.mkdir()
    _health().to_parquet(res / "health.parquet")
    with TestClient(create_app(fleet=res)) as client:
        page = client.get("/fleet?sort=drift").text
    assert "-30.0 % X1 kv_1_s" in page and "+30.0" not in page
    assert "+25.0 % SP1 friction_current_a" in page


def _cli(*args: str) -> Any:
    import subprocess
    import sys

    return subprocess.run([sys.executable, "-m", "cnctwin", *args], capture_output=True,
                          text=True, timeout=300)


def test_fleet_ingest_says_plainly_what_it_could_not_store(tmp_path: Path,
                                                            c4a_file: Path) -> None:
    """Issue 24, pt 8: a folder of unreadable or empty ``.parquet`` files gave "0 recordings
    found ... 0 failed (of 0)" and exit 0, and "1 failed (of 3)" exited 0 too. Now an empty
    find is an error naming what was looked for, and a partial job exits 1 saying so."""
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "empty.parquet").write_bytes(b"")
    (bad / "noise.parquet").write_bytes(b"PAR1 not really")
    res = _cli("fleet", "ingest", str(bad), "--store", str(tmp_path / "st"), "--workers", "1")
    assert res.returncode == 1 and "Traceback" not in res.stderr
    assert "0 ingested" in res.stdout and "2 failed (of 2)" in res.stdout
    assert f"skipped {bad / 'empty.parquet'}" in res.stderr
    assert "2 of 2 recordings were not stored" in res.stderr
    nothing = tmp_path / "nothing"
    nothing.mkdir()
    (nothing / "notes.md").write_text("x")
    res = _cli("fleet", "ingest", str(nothing), "--store", str(tmp_path / "st"))
    assert res.returncode == 2 and "no recordings under" in res.stderr
    assert ".parquet" in res.stderr
    mixed = tmp_path / "mixed"
    mixed.mkdir()
    shutil.copy(c4a_file, mixed / "good.json")
    (mixed / "broken.json").write_text("{")
    res = _cli("fleet", "ingest", str(mixed), "--store", str(tmp_path / "st2"), "--workers",
               "1")
    assert res.returncode == 1
    assert "1 ingested" in res.stdout and "1 failed (of 2)" in res.stdout


def test_an_unreachable_scheduler_exits_1_as_documented(tmp_path: Path,
                                                        c4a_file: Path) -> None:
    from tests._services import free_port

    assert _cli("ingest", str(c4a_file), "--store", str(tmp_path / "st")).returncode == 0
    res = _cli("fleet", "health", "--store", str(tmp_path / "st"), "--out", str(tmp_path / "r"),
               "--scheduler", f"tcp://127.0.0.1:{free_port()}")
    assert res.returncode == 1, res.stderr  # docs/fleet.md: "an error (exit 1)"
    assert "Traceback" not in res.stderr
