"""`cnctwin web`: argument errors say what to do next (the server itself is started by the
browser test)."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.cli import build_parser, main


def test_registered() -> None:
    args = build_parser().parse_args(["web", "--store", "st", "--recording", "a.json",
                                      "--recording", "b", "--port", "9001"])
    assert args.command == "web" and args.port == 9001 and args.host == "127.0.0.1"
    assert args.recording == [Path("a.json"), Path("b")]


def test_nothing_to_show(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["web"]) == 2
    err = capsys.readouterr().err
    assert "--store" in err and "--recording" in err and "--live" in err


def test_missing_store_path(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "nostore"
    assert main(["web", "--store", str(missing)]) == 2
    err = capsys.readouterr().err
    assert str(missing) in err and "cnctwin ingest" in err


def test_missing_recording(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["web", "--recording", str(tmp_path / "x.json"), "--port", "1"]) == 2
    assert "does not exist" in capsys.readouterr().err
