"""``cnctwin info`` and ``cnctwin convert`` through the entry point."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.cli import main
from cnctwin.iotools import read_recording


def test_info_real_file(c4a_file: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["info", str(c4a_file)]) == 0
    out = capsys.readouterr().out
    for text in ("sinumerik_adapter_840Dsl", "3818", "500 Hz", "5558098 / 5565774",
                 "3859 after 5559591", "127 (78 block, 49 call)", "M17",
                 "/Channel/State/actTNumber", "SP1", "CURRENT [A]", "issues (4)"):
        assert text in out, text
    assert "2023-12-22" in out


def test_info_truncated_needs_salvage(c4a_file: Path, tmp_path: Path,
                                      capsys: pytest.CaptureFixture[str]) -> None:
    cut = tmp_path / "cut.json"
    cut.write_bytes(c4a_file.read_bytes()[:1_000_000])
    assert main(["info", str(cut)]) == 2
    err = capsys.readouterr().err
    assert "cnctwin info: error:" in err and "cut.json" in err and "salvage" in err
    assert main(["info", str(cut), "--salvage"]) == 0
    out = capsys.readouterr().out
    assert "PARTIAL" in out and "truncated at byte 1000000" in out


@pytest.mark.parametrize("to", ["parquet", "csv", "c4a"])
def test_convert(c4a_file: Path, tmp_path: Path, to: str,
                 capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / {"parquet": "r.parquet", "csv": "r", "c4a": "r.json"}[to]
    assert main(["convert", str(c4a_file), "--to", to, "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert f"3818 cycles, 60 signals, 127 events -> {to}" in printed
    target = {"parquet": out, "csv": tmp_path / "r_hfdata.csv", "c4a": out}[to]
    assert read_recording(target).n_cycles == 3818


def test_convert_c4a_zip_chain(c4a_file: Path, tmp_path: Path) -> None:
    out = tmp_path / "r.zip"
    assert main(["convert", str(c4a_file), "--to", "c4a", "--zip", "--max-file-mb", "1",
                 "--out", str(out)]) == 0
    rec = read_recording(out)
    assert rec.n_cycles == 3818 and len(rec.meta.source_files) == 3


def test_convert_unknown_format(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "x.txt"
    bad.write_text("hello")
    assert main(["convert", str(bad), "--to", "parquet"]) == 2
    assert "format not recognised" in capsys.readouterr().err
