"""``--json`` means one JSON object on stdout whatever happens (bench/cli.py): usage errors
too. Interruptions and signals: tests/test_cli_signals.py."""

from __future__ import annotations

import json

import pytest

from bench.cli import json_requested, main


def _usage_error(capsys, argv: list[str]) -> tuple[str, str]:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert exc.value.code == 2
    cap = capsys.readouterr()
    return cap.out, cap.err


@pytest.mark.parametrize("argv, words, usage", [
    (["evaluate", "--json"], "--cases", "cdpr evaluate"),
    (["diagnose", "rec", "--json", "--bogus"], "--bogus", "cdpr"),
    (["nosuchcmd", "--json"], "nosuchcmd", "cdpr"),
    (["--json", "model", "check"], "robot", "cdpr model"),
    (["commission", "scan", "--json", "--bogus"], "--bogus", "cdpr"),
    (["evaluate", "--cases", "x", "--js"], "invalid int", "cdpr evaluate"),
])
def test_usage_errors_under_json_print_one_object(capsys, argv, words, usage):
    out, err = _usage_error(capsys, argv)
    obj = json.loads(out)  # exactly one object
    assert set(obj) == {"error", "usage"}
    assert words in obj["error"]
    assert obj["usage"].startswith(f"usage: {usage}")
    # the usual message still goes to stderr
    assert "usage:" in err and words in err and "error:" in err


def test_usage_errors_without_json_leave_stdout_empty(capsys):
    out, err = _usage_error(capsys, ["evaluate"])
    assert out == "" and "--cases" in err


def test_json_requested():
    assert json_requested(["diagnose", "r", "--json"])
    assert json_requested(["diagnose", "r", "--js"])
    assert not json_requested(["diagnose", "r", "--jobs", "2"])
    assert not json_requested(["diagnose", "--", "--json"])
