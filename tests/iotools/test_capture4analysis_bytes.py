"""``parse_capture4analysis``: one Capture4Analysis document from bytes (file content, or a
Data Recorder MQTT message, which Siemens allows to be a zip archive).

Facts of the real file (``tests/data/real/capture4analysis``) counted by hand with
``orjson.loads`` on the raw JSON (see ``test_capture4analysis.py``): 3818 HF rows, first CYCLE
5558098, last 5565774, 78 HFBlockEvent and 49 HFCallEvent entries, 70 LF values.
"""

from __future__ import annotations

import io
import tempfile
import zipfile
from pathlib import Path

import pandas as pd
import pytest

from cnctwin.exceptions import ConfigError, FormatError, TruncatedFileError
from cnctwin.iotools import (
    parse_capture4analysis,
    read_capture4analysis,
    write_capture4analysis,
)
from cnctwin.iotools.mqtt import parse_data_recorder_message
from cnctwin.recording import Recording

TOPIC = "MACHINE_A/tapping/M8-40"


@pytest.fixture(scope="module")
def real(c4a_file: Path) -> Recording:
    return read_capture4analysis(c4a_file)


def _zipped(members: dict[str, bytes]) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def _assert_same_tables(a: Recording, b: Recording) -> None:
    pd.testing.assert_frame_equal(a.hf, b.hf)
    pd.testing.assert_frame_equal(a.events, b.events)
    pd.testing.assert_frame_equal(a.lf, b.lf)


def test_real_bytes_same_recording_as_path(real: Recording, c4a_file: Path) -> None:
    rec = parse_capture4analysis(c4a_file.read_bytes(), source=str(c4a_file))
    assert rec.n_cycles == 3818
    assert int(rec.cycles[0]) == 5558098 and int(rec.cycles[-1]) == 5565774
    assert (rec.events["kind"] == "block").sum() == 78
    assert (rec.events["kind"] == "call").sum() == 49
    assert len(rec.lf) == 70
    _assert_same_tables(rec, real)
    assert rec.meta == real.meta  # anchors, gaps, issues, attrs, source_files


def test_default_source_label(c4a_file: Path) -> None:
    rec = parse_capture4analysis(c4a_file.read_bytes())
    assert rec.meta.source_files == ["<bytes>"]
    assert rec.meta.source_format == "capture4analysis"


def test_zip_message_bytes(real: Recording, c4a_file: Path) -> None:
    payload = _zipped({"run.json": c4a_file.read_bytes()})
    assert payload[:4] == b"PK\x03\x04"
    rec = parse_capture4analysis(payload, source=TOPIC)
    _assert_same_tables(rec, real)
    assert rec.meta.source_files == [f"{TOPIC}:run.json"]
    assert rec.meta.time_anchors == real.meta.time_anchors
    assert rec.meta.gaps == real.meta.gaps
    assert not rec.meta.partial


def test_chained_zip_reads_one_document(real: Recording, tmp_path: Path) -> None:
    """A zip of a chained run: the chain start only, the Next member noted, not followed."""
    (path,) = write_capture4analysis(real, tmp_path / "run.zip", max_file_mb=0.8, zip=True)
    rec = parse_capture4analysis(path.read_bytes(), source=TOPIC)
    first = read_capture4analysis(path, follow_chain=False)
    assert 0 < rec.n_cycles == first.n_cycles < real.n_cycles
    _assert_same_tables(rec, first)
    assert rec.meta.source_files == [f"{TOPIC}:run.json"]
    assert any("run continues in 'run_2.json'; not read (one document parsed" in i
               for i in rec.meta.issues)


def test_errors_name_the_source(c4a_file: Path) -> None:
    data = c4a_file.read_bytes()
    with pytest.raises(TruncatedFileError) as info:
        parse_capture4analysis(data[:1_000_000], source=TOPIC)
    assert info.value.path == TOPIC
    assert info.value.position is not None and "byte 1000000" in info.value.position
    rec = parse_capture4analysis(data[:1_000_000], source=TOPIC, salvage=True)
    assert rec.meta.partial and 0 < rec.n_cycles < 3818
    broken = _zipped({"run.json": data})
    with pytest.raises(TruncatedFileError, match="broken zip") as info:
        parse_capture4analysis(broken[: len(broken) // 2], source=TOPIC)
    assert info.value.path == TOPIC
    salvaged = parse_capture4analysis(broken[: len(broken) // 2], source=TOPIC, salvage=True)
    assert salvaged.meta.partial and 0 < salvaged.n_cycles < 3818
    with pytest.raises(FormatError, match="empty"):
        parse_capture4analysis(b"", source=TOPIC)
    with pytest.raises(ConfigError, match="read_capture4analysis"):
        parse_capture4analysis(str(c4a_file))  # type: ignore[arg-type]


@pytest.mark.parametrize("zipped", [False, True])
def test_data_recorder_message_in_memory(
    real: Recording, c4a_file: Path, zipped: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    def no_temp_files(*args: object, **kwargs: object) -> None:
        raise AssertionError("a Data Recorder message must be parsed without a temp file")

    monkeypatch.setattr(tempfile, "mkstemp", no_temp_files)
    monkeypatch.setattr(tempfile, "NamedTemporaryFile", no_temp_files)
    data = c4a_file.read_bytes()
    rec = parse_data_recorder_message(_zipped({"job.json": data}) if zipped else data,
                                      topic=TOPIC)
    _assert_same_tables(rec, real)
    assert rec.meta.source_files == [TOPIC]
    with pytest.raises(FormatError) as info:
        parse_data_recorder_message(b'{"Payload": []}', topic=TOPIC)
    assert info.value.path == TOPIC
