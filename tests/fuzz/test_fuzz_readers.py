"""Fuzzed recording files (issue 14, point 6): the real Capture4Analysis file and the real
servo trace (tests/data/real, PROVENANCE.md), and a CSV export, mutated by hypothesis
(truncation, byte flips, a removed bracket or tag character, NaN/huge numbers written into
the text). Each read ends in a recording (what was lost in ``meta.issues``/``partial``) or in
a :class:`cnctwin.exceptions.CnctwinError` that names the file; never a raw exception from
inside a reader, never a hang. The budget is small for CI (the files are 2 MB)."""

from __future__ import annotations

from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import cnctwin
from cnctwin.exceptions import CnctwinError
from cnctwin.iotools import read_dynamometer_csv, read_thermal_camera_csv
from tests.conftest import C4A_FILE, TRACE_FILE

SETTINGS = settings(max_examples=25, deadline=None, derandomize=True,
                    suppress_health_check=[HealthCheck.too_slow,
                                           HealthCheck.function_scoped_fixture])


def _csv_text() -> bytes:
    rows = ["time,CYCLE,CURRENT|SP1,CMD_SPEED|SP1"]
    rows += [f"2024-05-06T08:00:{k * 0.002:06.3f}Z,{1000 + k},{3.0 + 0.01 * k},2400"
             for k in range(500)]
    return ("\n".join(rows) + "\n").encode()


def _dynamometer_text() -> bytes:
    rows = ["Time [s];Fx [N];Fy [N];Fz [N];Mz [Nm]"]
    rows += [f"{k / 1000:.3f};{10 + k % 7},5;{-3 - k % 5},25;{200 + k % 11},0;{1 + k % 3},5"
             for k in range(300)]
    return ("\n".join(rows) + "\n").encode()


def _thermal_text() -> bytes:
    rows = ["time_s,hole,temperature_c,frame"]
    rows += [f"{2.5 * k:.1f},{k},{25 + 0.1 * k:.2f},f{k}" for k in range(200)]
    return ("\n".join(rows) + "\n").encode()


def _mutate(raw: bytes, kind: int, pos: int, value: int) -> bytes:
    pos %= max(len(raw), 1)
    if kind == 0:
        return raw[:pos]  # truncated
    if kind == 1:
        return raw[:pos] + bytes([value]) + raw[pos + 1:]  # one byte flipped
    if kind == 2:  # a bracket / tag / quote removed
        idx = [i for i in range(pos, min(pos + 5000, len(raw))) if raw[i] in b"[]{}<>\""]
        return raw[:idx[0]] + raw[idx[0] + 1:] if idx else raw[:pos]
    token = [b"NaN", b"Infinity", b"1e999", b"-", b"\xff\xfe", b"null"][value % 6]
    return raw[:pos] + token + raw[pos + 3:]  # a number replaced


@pytest.mark.parametrize("name", ["c4a", "trace", "csv", "dynamometer", "thermal"])
@SETTINGS
@given(kind=st.integers(0, 3), pos=st.integers(0, 10**7), value=st.integers(0, 255))
def test_reader_survives_mutation(name: str, kind: int, pos: int, value: int,
                                  tmp_path_factory: pytest.TempPathFactory) -> None:
    src = {"c4a": C4A_FILE, "trace": TRACE_FILE}.get(name)
    text = {"dynamometer": _dynamometer_text, "thermal": _thermal_text}.get(name, _csv_text)
    raw = src.read_bytes() if src is not None else text()
    suffix = src.suffix if src is not None else ".csv"
    path: Path = tmp_path_factory.mktemp("fuzz") / f"mutated{suffix}"
    path.write_bytes(_mutate(raw, kind, pos, value))
    try:
        if name in ("dynamometer", "thermal"):
            read = read_dynamometer_csv if name == "dynamometer" else read_thermal_camera_csv
            channel = read(path)
            assert len(channel.data) >= 0
            return
        rec = cnctwin.read_recording(path)
    except CnctwinError as exc:
        assert path.name in str(exc), f"the error does not name the file: {exc}"
        return
    except Exception as exc:
        pytest.fail(f"{type(exc).__name__} from inside the reader: {exc}")
    assert rec.n_cycles >= 0
