"""The fleet ranking keeps the sign of a drift (issue 24, pt 7: a Kv drop of 30 % was shown
as +30 %): a loop that lost gain and a friction that rose are different findings."""

from __future__ import annotations

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
