"""``report._without_unneeded``'s fallback: where dropping every unneeded effect at once
loses another named effect (``probes.lost_with``), the first that goes alone, with all its
stands, without the loss goes; where none can, nothing is dropped and the stands are marked
``others_need_it``. ``_settle`` (the refit and everything after it) is replaced by a rule
saying which effects stay named after a drop, so only the decision is tested."""

from __future__ import annotations

import dataclasses

import pytest

from bench.diagnosis import report
from bench.diagnosis.select import Selection


class _Selector:
    def fit(self, effects, start):
        return start


def _got(effects: list[str], stands: list[dict]) -> report._Settled:
    sel = Selection(effects=list(effects), fit=None, baseline=None)
    return report._Settled(sel=sel, final=None, params={}, errs={}, undet={}, intervals={},
                           fitted=None, fit_fw=None,
                           leftover={"effects_in_question": stands})


def _stand(effect: str, probe: str = "friction") -> dict:
    return {"effect": effect, "probe": probe, "delta_bic": -3.0, "needed_beyond_bic": 2.0,
            "probe_finding": True}


def _run(monkeypatch, effects, stands, keeps):
    """``keeps(left_out) -> the effects still named`` after a settle without ``left_out``."""
    calls: list[list[str]] = []

    def settle(rm, selector, sel, candidates, fit_idx, left_out, rec, changes, pool, say):
        calls.append(list(left_out))
        named = [e for e in keeps(set(left_out)) if e not in left_out]
        return _got(named, [])

    monkeypatch.setattr(report, "_settle", settle)
    got = _got(effects, stands)
    left_out: list[str] = []
    out, dropped = report._without_unneeded(None, _Selector(), got, stands, [], None, left_out,
                                            None, [], None, lambda s: None)
    return out, dropped, left_out, calls


def test_of_two_the_one_that_goes_alone_without_a_loss_goes(monkeypatch):
    # C stays named unless both A and B go; A has two stands (two probes)
    stands = [_stand("A"), _stand("A", "backlash"), _stand("B")]

    def keeps(gone):
        return ["B", "C"] if gone == {"A"} else ["A", "C"] if gone == {"B"} else ["D"]

    out, dropped, left_out, calls = _run(monkeypatch, ["A", "B", "C"], stands, keeps)
    assert out.sel.effects == ["B", "C"]
    assert [q["effect"] for q in dropped] == ["A", "A"]  # both of A's stands
    assert left_out == ["A"]
    assert calls == [["A", "B"], ["A"]]  # both at once, then A alone (once, not per stand)


def test_when_none_goes_alone_nothing_is_dropped_and_the_stands_are_marked(monkeypatch):
    stands = [_stand("A"), _stand("B")]

    def keeps(gone):
        return ["D"] if gone else ["A", "B", "C"]  # C goes with either

    out, dropped, left_out, calls = _run(monkeypatch, ["A", "B", "C"], stands, keeps)
    assert out.sel.effects == ["A", "B", "C"] and dropped == [] and left_out == []
    marked = out.leftover["effects_in_question"]
    assert all(q.get("others_need_it") == ["C"] for q in marked)
    assert calls == [["A", "B"], ["A"], ["B"]]


@pytest.mark.parametrize("lost", [False, True])
def test_one_effect_alone_is_dropped_or_kept(monkeypatch, lost):
    stands = [_stand("A")]

    def keeps(gone):
        return ["B"] if lost else ["B", "C"]

    out, dropped, left_out, calls = _run(monkeypatch, ["A", "B", "C"], stands, keeps)
    assert calls == [["A"]]
    if lost:
        assert out.sel.effects == ["A", "B", "C"] and not dropped and not left_out
    else:
        assert out.sel.effects == ["B", "C"] and dropped == stands and left_out == ["A"]
    assert dataclasses.is_dataclass(out)
