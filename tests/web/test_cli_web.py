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


def test_plant_file_and_several_live_directories(tmp_path: Path, wear12: dict,  # type: ignore[type-arg]
                                                 model_file: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """`cnctwin web --plant plant.toml --live DIR`: every machine of the plant file is
    followed under its name, the extra directory under its folder name."""
    import uvicorn

    served = {}
    monkeypatch.setattr(uvicorn, "run", lambda app, **kw: served.update(app=app, **kw))
    plant = tmp_path / "plant.toml"
    plant.write_text(f'out = "state"\n[[machine]]\nname = "mill-1"\nsource = '
                     f'"{wear12["path"]}"\nmodel = "{model_file}"\n[[machine]]\nname = "mill-2"'
                     f'\nsource = "{wear12["path"]}"\nmodel = "{model_file}"\n',
                     encoding="utf-8")
    extra = tmp_path / "other" / "lathe"
    extra.mkdir(parents=True)
    assert main(["web", "--plant", str(plant), "--live", str(extra), "--port", "8999"]) == 0
    lives = served["app"].state.dashboard.lives
    assert list(lives) == ["lathe", "mill-1", "mill-2"]
    assert lives["mill-2"].directory == tmp_path / "state" / "mill-2"
