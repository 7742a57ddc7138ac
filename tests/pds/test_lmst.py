"""Local mean solar time from the labels: the real Curiosity (PDS3, MSL:LOCAL_MEAN_SOLAR_TIME)
and Perseverance (PDS4, Time_Coordinates/local_mean_solar_time) labels against the values
their label text writes, and malformed times refused naming the field."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from mars_pairs.errors import LabelError
from mars_pairs.pds import read_observation
from mars_pairs.pds.common import Fields

# the time of day in the label's text, found by a regex independent of the readers
_PDS3 = re.compile(r'LOCAL_MEAN_SOLAR_TIME\s*=\s*"Sol-0*(\d+)M([0-9:.]+)"')
_PDS4 = re.compile(r"<local_mean_solar_time>([0-9:.]+)</local_mean_solar_time>")


def test_real_labels_give_their_lmst(samples_dir: Path) -> None:
    labels = sorted(samples_dir.glob("*/*.LBL")) + sorted(samples_dir.glob("*/*.xml"))
    assert labels
    for path in labels:
        text = path.read_text(errors="replace")
        obs = read_observation(path)
        m3, m4 = _PDS3.search(text), _PDS4.search(text)
        if m3 is not None:
            assert int(m3[1]) == obs.sol, path
            assert obs.lmst == m3[2], path
        elif m4 is not None:
            assert obs.lmst == m4[1], path
        else:
            assert obs.lmst is None, path


@pytest.mark.parametrize(
    ("value", "expected"),
    [("Sol-02663M11:20:51.901", "11:20:51.901"), ("13:13:05.890", "13:13:05.890"),
     ("Sol-00052M09:05:00", "09:05:00")],
)  # fmt: skip
def test_local_time_forms(value: str, expected: str) -> None:
    sol = 2663 if value.startswith("Sol-02663") else 52
    assert Fields(Path("x.LBL")).local_time(value, "LOCAL_MEAN_SOLAR_TIME", sol) == expected


@pytest.mark.parametrize(
    "value", ["noon", "25:00:00", "11:61:00", "Sol-00052M", "Sol-00053M11:00:00"]
)
def test_malformed_local_time_names_the_field(value: str) -> None:
    with pytest.raises(LabelError, match="LOCAL_MEAN_SOLAR_TIME"):
        Fields(Path("x.LBL")).local_time(value, "LOCAL_MEAN_SOLAR_TIME", 52)
