"""Errors at the command line: one readable message, a non-zero exit, no traceback (issue 16)."""

from __future__ import annotations

import socket
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from cnctwin.cli import main

ROOT = Path(__file__).resolve().parents[1]


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "cnctwin", *args], capture_output=True,
                          text=True, check=False, timeout=120)


def test_a_scenario_option_of_the_wrong_type(tmp_path: Path) -> None:
    r = _run("simulate", "tool_wear_run", "--out", str(tmp_path / "x"), "--option",
             "n_holes=abc")
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert "option n_holes must be an integer (default 2676), not 'abc'" in r.stderr
    assert not (tmp_path / "x").exists()


def test_web_on_an_impossible_or_busy_port(tmp_path: Path) -> None:
    pytest.importorskip("uvicorn", reason="the web extra: pip install 'cnctwin[web]'")
    rec = ROOT / "tests" / "data" / "real" / "sinumerik-trace"
    r = _run("web", "--recording", str(rec), "--port", "99999")
    assert r.returncode == 2 and "--port 99999 is not a TCP port" in r.stderr
    assert "Traceback" not in r.stderr
    with socket.socket() as busy:
        busy.bind(("127.0.0.1", 0))
        busy.listen()
        port = busy.getsockname()[1]
        r = _run("web", "--recording", str(rec), "--port", str(port))
    assert r.returncode == 2 and "choose another with --port" in r.stderr
    assert "serving on" not in r.stdout and "Traceback" not in r.stderr


def test_an_unexpected_error_is_one_line(monkeypatch: pytest.MonkeyPatch,
                                         capsys: pytest.CaptureFixture[str]) -> None:
    import cnctwin.cli.io as io_cli

    def boom(args: object) -> int:
        raise ValueError("something the code did not expect")

    monkeypatch.setattr(io_cli, "_cmd_info", boom)
    monkeypatch.delenv("CNCTWIN_DEBUG", raising=False)
    assert main(["info", "x"]) == 1
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "internal error: ValueError" in err
    assert "CNCTWIN_DEBUG=1" in err


def test_no_drilling_says_what_applies(capsys: pytest.CaptureFixture[str]) -> None:
    c4a = (ROOT / "tests" / "data" / "real" / "capture4analysis"
           / "example_data_ff429d74-6482-4d4f-80e1-31419d9bd56c.json")
    for cmd in ("holes", "wear"):
        assert main([cmd, str(c4a)]) == 2
        err = capsys.readouterr().err
        assert "no hole found" in err and "cnctwin servo FILE" in err


def test_license_matches_pyproject() -> None:
    meta = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert meta["project"]["license"] == "MIT"
    assert (ROOT / "LICENSE").read_text(encoding="utf-8").startswith("MIT License")
    first = (ROOT / "README.md").read_text(encoding="utf-8")[:2500]
    assert "make demo" in first and "make test" in first
    assert "Koç University" in first and "LICENSE" in first


def test_fleet_job_on_a_folder_that_is_no_store(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    """The hint names the command that makes a store, not the library's ``create=True``."""
    (tmp_path / "empty").mkdir()
    code = main(["fleet", "health", "--store", str(tmp_path / "empty"), "--out",
                 str(tmp_path / "res")])
    err = capsys.readouterr().err
    assert code == 2 and "cnctwin fleet ingest DIR --store" in err
    assert "create=True" not in err and "Traceback" not in err


def test_help_imports_only_the_command_line() -> None:
    """Issue 24, pt 8: ``cnctwin --help`` took 3.5 s (every subcommand imported pandas, scipy,
    the simulator and the edge runtime to register its options). The parser imports none of
    them now; a command imports what it uses when it runs."""
    import subprocess
    import sys

    code = ("import sys, cnctwin.cli as c; c.build_parser(); "
            "print(','.join(sorted(m for m in ('numpy', 'pandas', 'scipy', 'numba', "
            "'cnctwin.sim', 'cnctwin.edge', 'cnctwin.iotools', 'matplotlib') "
            "if m in sys.modules)))")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == ""


def test_the_simulate_choices_are_the_scenarios() -> None:
    from cnctwin.cli.sim import SCENARIO_NAMES
    from cnctwin.sim.scenarios import SCENARIOS

    assert tuple(sorted(SCENARIOS)) == SCENARIO_NAMES


@pytest.mark.parametrize(("content", "said"), [
    (b"", "the file is empty (0 bytes)"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR", "a PNG image"),
    (b"[1, 2, 3]", "a JSON array"),
    (b'{"machine": "m1", "values": []}', "a JSON object with the keys machine, values"),
    (b"time;current\n0;1\n", "text that is not JSON"),
])
def test_a_json_that_is_no_recording_says_what_it_is(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], content: bytes, said: str) -> None:
    """Issue 24, pt 8: an empty file or a PNG named .json got "JSON without Header/Payload"
    and a 600-character format list."""
    f = tmp_path / "run.json"
    f.write_bytes(content)
    assert main(["info", str(f)]) == 2
    err = capsys.readouterr().err
    assert str(f) in err and said in err and "Traceback" not in err
    assert len(err) - len(str(f)) < 420  # one readable message, not a format catalogue


def test_program_errors_name_the_file_and_point_to_the_subset_once(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Issue 24, pt 8: G-code errors pointed to the subset twice (a module and a document);
    the overspeed error named no file."""
    bad = tmp_path / "bad.mpf"
    bad.write_text("G1 X10 F100\nG5 X1\nM30\n")
    assert main(["simulate", "--program", str(bad), "--out", str(tmp_path / "o1")]) == 2
    err = capsys.readouterr().err
    assert f"{bad}: line 2: 'G5 X1': G5 is not supported" in err
    assert err.count("subset") == 1 and "docs/simulator.md" in err
    fast = tmp_path / "fast.mpf"
    fast.write_text("S30000 M3\nG1 X10 F100\nM30\n")
    assert main(["simulate", "--program", str(fast), "--out", str(tmp_path / "o2")]) == 2
    err = capsys.readouterr().err
    assert f"{fast}: line 1: 'S30000 M3': spindle speed 30000 rpm exceeds" in err
    assert "Traceback" not in err


@pytest.mark.parametrize("value", ["-1", "0"])
def test_reference_torque_must_be_positive(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                           value: str) -> None:
    """Issue 29, pt 5: ``--torque-nm`` took a negative or zero torque."""
    code = main(["calibrate", "spindle", "--air-cut", str(tmp_path / "a.json"), "--reference",
                 str(tmp_path / "r.json"), "--torque-nm", value, "--machine",
                 str(tmp_path / "m.toml")])
    err = capsys.readouterr().err
    assert code == 2 and f"--torque-nm {float(value):g}" in err and "positive" in err
    assert not (tmp_path / "m.toml").exists()
