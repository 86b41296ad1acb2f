"""A lab's own ``state`` words are kept and ignored (docs/formats/recording.md defines
``init``, ``move``, ``dwell``, ``hold``, ``quick_stop``, ``end``): words containing "stop"
("stopped", "nonstop", "estop_reset") are no supervisor's reaction, their rows are read from
the data as rows without a state column, and the words are listed in the samples' info."""

from __future__ import annotations

import pytest

from bench.chunked import read_conditioned
from bench.diagnosis.report import diagnose
from bench.diagnosis.samples import prepare
from tests.outsider.cases import make_case
from tests.outsider.logger import Habits

SMALL = {"targets": 3, "passes": 2, "dwell_s": 3.0, "seed": 41}


@pytest.fixture(scope="module")
def plain(tmp_path_factory) -> dict:
    rec, _, _ = read_conditioned(make_case(tmp_path_factory.mktemp("plain") / "rec", Habits(),
                                           **SMALL))
    return prepare(rec).info


@pytest.mark.parametrize("words", [("stopped", "nonstop"), ("estop_reset", "moving"),
                                   ("idle", "Stop_and_go")])
def test_a_labs_words_with_stop_are_read_from_the_data(tmp_path, plain, words):
    rec, _, _ = read_conditioned(make_case(tmp_path / "rec", Habits(state_words=words), **SMALL))
    info = prepare(rec).info
    assert info["rows_in_other_states"] == 0
    for k in ("dwell_samples", "path_samples", "dwells_available"):
        assert info[k] == plain[k], k
    assert set(info["states_unknown"]) == set(words)
    assert all(v > 0 for v in info["states_unknown"].values())


def test_the_diagnosis_says_which_words_it_read_from_the_data(tmp_path):
    path = make_case(tmp_path / "rec", Habits(state_words=("stopped", "nonstop")), **SMALL)
    said: list[str] = []
    rep = diagnose(path, progress=said.append).report
    assert rep["mismatch"]["samples"]["states_unknown"].keys() == {"stopped", "nonstop"}
    line = next(m for m in said if m.startswith("state words"))
    assert "stopped (" in line and "nonstop (" in line


def test_a_recording_without_a_state_column_lists_no_word(plain):
    assert plain["states_unknown"] == {} and plain["rows_in_other_states"] == 0


def test_the_formats_words_count_in_any_letter_case(tmp_path):
    """``Dwell`` / ``MOVE`` are the format's ``dwell`` / ``move`` (as ``HOLD`` is ``hold``):
    read as such, not left to the data and not listed as a lab's own."""
    infos = []
    for words in (("dwell", "move"), ("Dwell", "MOVE")):
        rec, _, _ = read_conditioned(make_case(tmp_path / words[0], Habits(state_words=words),
                                               **SMALL))
        infos.append(prepare(rec).info)
    for k in ("dwell_samples", "path_samples", "dwells_available", "states_unknown"):
        assert infos[1][k] == infos[0][k], k
