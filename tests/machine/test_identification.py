"""The machine file's ``[identification]`` (issue 27, point 1): read, checked, written back."""

from __future__ import annotations

from pathlib import Path

import pytest

from cnctwin.exceptions import ConfigError
from cnctwin.machine import load_machine, save_machine


def test_identification_round_trip_and_bad_keys(tmp_path: Path) -> None:
    p = tmp_path / "m.toml"
    p.write_text('name = "m1"\n\n[identification]\nmanufacturer = "DMG MORI"\n'
                 'model = "DMC 60H"\nserial_number = "SN-4711"\nyear_of_construction = 2019\n')
    m = load_machine(p)
    assert dict(m.identification) == {"manufacturer": "DMG MORI", "model": "DMC 60H",
                                      "serial_number": "SN-4711", "year_of_construction": 2019}
    out = tmp_path / "again.toml"
    save_machine(m, out)
    assert dict(load_machine(out).identification) == dict(m.identification)
    for text, needle in (('[identification]\nmaker = "x"\n', "identification.maker is not a key"),
                         ('[identification]\nyear_of_construction = "2019"\n',
                          "identification.year_of_construction must be a whole number")):
        p.write_text('name = "m1"\n\n' + text)
        with pytest.raises(ConfigError, match=needle):
            load_machine(p)
