"""``cnctwin servo`` through the entry point (cnctwin.cli.main)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.cli import main

from ..conftest import C4A_FILE


def test_cli_servo_on_real_c4a(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["servo", str(C4A_FILE), "--axis", "Y1", "--axis", "X1", "--out",
                 str(tmp_path), "--bootstrap", "20"])
    assert code == 0
    out = capsys.readouterr().out
    # issue 16: a short summary first, one row per axis; the reasons behind --verbose
    assert "summary (details: --verbose)" in out
    assert "kv_m_min_mm = 1.70" in out  # Y1 1.7072, X1 1.6997 (m/min)/mm, docs/own-machine.md
    assert "CTRL_POS is not recorded" not in out and "signal relations" not in out
    assert len(out.splitlines()) < 60
    code = main(["servo", str(C4A_FILE), "--axis", "Y1", "--axis", "X1", "--bootstrap", "20",
                 "--verbose"])
    assert code == 0
    out = capsys.readouterr().out
    assert "kv_m_min_mm" in out and "signal relations" in out
    assert "not identified" in out and "CTRL_POS" in out
    assert "behaves as" not in out  # declared unit (catalog, mm/s) agrees with the data
    assert (tmp_path / "tool_path_Y1_X1.png").stat().st_size > 10_000
    assert (tmp_path / "errors_Y1.png").exists()


def test_cli_servo_unknown_axis(capsys: pytest.CaptureFixture[str]) -> None:
    code = main(["servo", str(C4A_FILE), "--axis", "Q9"])
    assert code == 2
    assert "Q9" in capsys.readouterr().err


def test_cli_servo_default_path_plane_is_linear(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    # issue 16: the real file lists C1 and B1 (deg) first; the default tool path is X1-Y1 (mm)
    code = main(["servo", str(C4A_FILE), "--out", str(tmp_path), "--bootstrap", "5"])
    assert code == 0
    assert (tmp_path / "tool_path_X1_Y1.png").stat().st_size > 10_000
    assert not list(tmp_path.glob("tool_path_C1*")) and not list(tmp_path.glob("tool_path_B1*"))
