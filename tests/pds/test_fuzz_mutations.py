"""The mutation fuzzer's first cases in the suite, and XML entity attacks made inert.

The full run (``python tests/pds/fuzz_labels.py --cases 10000``) is the same deterministic
sequence; these are its first cases, so a failure here replays there by case number.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from fuzz_labels import run

from mars_pairs.errors import LabelError
from mars_pairs.pds import read_observation
from support.label_seeds import PDS4_SEED


@pytest.mark.slow
def test_first_mutation_cases_keep_the_contract(tmp_path: Path) -> None:
    report = run(cases=800, seed=0, workdir=tmp_path, max_seconds=2.0)
    assert report.breaches == []
    assert report.cases == 800
    assert report.observations > 50 and report.errors > 400  # both outcomes are exercised


def _with_doctype(doctype: str, entity_use: str) -> str:
    head, rest = PDS4_SEED.split("\n", 1)
    rest = rest.replace(
        "<alternate_id>ZLF_0052_0671559321_081RAD_N0031950ZCAM05024_110085J01</alternate_id>",
        f"<alternate_id>{entity_use}</alternate_id>",
    )
    return f"{head}\n{doctype}\n{rest}"


def test_external_entity_pointing_at_a_local_file_is_inert(tmp_path: Path) -> None:
    secret = tmp_path / "secret.txt"
    secret.write_text("TOPSECRET_1234")
    doctype = f'<!DOCTYPE Product_Observational [<!ENTITY xxe SYSTEM "file://{secret}">]>'
    label = tmp_path / "xxe.xml"
    label.write_text(_with_doctype(doctype, "&xxe;"))
    with pytest.raises(LabelError, match=r"xxe\.xml: .*DOCTYPE") as err:
        read_observation(label)
    assert "TOPSECRET" not in str(err.value)


def test_billion_laughs_is_inert(tmp_path: Path) -> None:
    entities = ['<!ENTITY lol0 "lol">'] + [
        f'<!ENTITY lol{i} "{f"&lol{i - 1};" * 10}">' for i in range(1, 10)
    ]
    doctype = "<!DOCTYPE Product_Observational [" + "".join(entities) + "]>"
    label = tmp_path / "laughs.xml"
    label.write_text(_with_doctype(doctype, "&lol9;"))
    start = time.perf_counter()
    with pytest.raises(LabelError, match=r"laughs\.xml: "):  # libxml2 or our DOCTYPE check
        read_observation(label)
    assert time.perf_counter() - start < 1.0


def test_parameter_entity_fetching_a_dtd_is_inert(tmp_path: Path) -> None:
    dtd = tmp_path / "evil.dtd"
    dtd.write_text('<!ENTITY leak "LEAKED">')
    doctype = f'<!DOCTYPE Product_Observational [<!ENTITY % ext SYSTEM "file://{dtd}"> %ext;]>'
    label = tmp_path / "param.xml"
    label.write_text(_with_doctype(doctype, "&leak;"))
    with pytest.raises(LabelError) as err:
        read_observation(label)
    assert "LEAKED" not in str(err.value)
