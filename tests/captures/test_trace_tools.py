"""``captures.trace_tools``: the capture tools' frame a protocol's plug-in declares itself into
(``captures.mavlink``, ``captures.nsqd``): check's verdict, reports and exit code, diff's,
the case and time windows of show, --select/--exclude, the sender-by-sender alignment."""

from __future__ import annotations

import io
import json
from argparse import Namespace
from collections import Counter
from types import SimpleNamespace
from typing import NamedTuple

import pytest

from mcp_conform.captures import trace_tools as core
from mcp_conform.captures.trace_tools import Checked, Compared, RuleBlock
from mcp_conform.judge import verdicts
from mcp_conform.traceio.files import UsageError
from mcp_conform.traceio.reader import CaseMark, Truncated


class _Plugin(core.CapturePlugin):
    name, a_capture, html_instead = "toy", "a toy trace", "use --json"
    spec = SimpleNamespace(rule=lambda r: SimpleNamespace(level="MUST", text=f"the text of {r}"))

    def __init__(self, checked: Checked | None = None, compared: Compared | None = None) -> None:
        self.checked, self.compared = checked, compared

    def check(self, ns):
        return self.checked

    def compare(self, golden, candidate):
        return self.compared


def _verdicts(rules: dict[str, str], failing: int, truncated: str | None = None) -> verdicts.Verdicts:
    return verdicts.Verdicts("toy", rules, [], Counter(MUST=failing), failing, truncated)


def _check(checked: Checked, tmp_path, **kw) -> tuple[int, str, dict]:
    out, path = io.StringIO(), tmp_path / "c.json"
    rc = core.run_check(_Plugin(checked), Namespace(json=str(path), **kw), out)
    return rc, out.getvalue(), json.loads(path.read_text())


@pytest.mark.parametrize(("failed", "truncated", "verdict", "rc"), [
    (True, "cut", "FAILED", 1), (False, "cut", "INCOMPLETE", 0), (False, None, "OK", 0), (True, None, "FAILED", 1)])
def test_check_says_its_verdict_in_the_report_the_json_and_the_exit_code(tmp_path, failed, truncated, verdict, rc):
    blocks = [RuleBlock("R-1", [("at +1s: expected a", ("#3", "#4")), ("at +2s: expected b", ())], 5, " link(s)")]
    v = _verdicts({"R-1": "failed" if failed else "passed"}, 6 if failed else 0, truncated)
    got, text, doc = _check(Checked(["head line"], blocks if failed else [], v, {"file": "f", "verdict": v.verdict},
                                    ["tail line"]), tmp_path)
    assert got == rc and doc == {"file": "f", "verdict": verdict}
    expected = ["head line", *(["R-1 MUST: the text of R-1", "  at +1s: expected a", "    #3", "    #4",
                                "  at +2s: expected b", "  ... and 5 more link(s)"] if failed else []),
                f"rules: R-1 {'failed' if failed else 'passed'}", "tail line", f"verdict: {verdict}"]
    assert text.splitlines() == expected


def test_check_says_no_more_when_every_example_is_shown(tmp_path):
    _, text, _ = _check(Checked([], [RuleBlock("R-1", [("x", ())], 0)], _verdicts({"R-1": "failed"}, 1), {}), tmp_path)
    assert "more" not in text


def _compared(divergences: list) -> Compared:
    return Compared(divergences, [f"  {d}" for d in divergences], "3 step(s) alike", " over 3 step(s)",
                    [("g", None), ("c", "cut at 9")], ["only some compared"], {"steps": 3})


@pytest.mark.parametrize("json_when_same", [True, False])
@pytest.mark.parametrize("divergences", [[], ["step 2 differs"]])
def test_diff_says_same_or_each_divergence(tmp_path, divergences, json_when_same):
    plugin, out, path = _Plugin(compared=_compared(divergences)), io.StringIO(), tmp_path / "d.json"
    plugin.json_when_same = json_when_same
    rc = core.run_diff(plugin, Namespace(golden="g", candidate="c", json=str(path)), out)
    head = ["note: only some compared", "note: c is TRUNCATED: cut at 9"]
    if divergences:
        assert (rc, out.getvalue().splitlines()) == (1, [*head, "different: 1 divergence(s) over 3 step(s)",
                                                         "  step 2 differs"])
    else:
        assert (rc, out.getvalue().splitlines()) == (0, [*head, "same: 3 step(s) alike"])
    if divergences or json_when_same:
        assert json.loads(path.read_text()) == {"protocol": "toy", "same": not divergences, "steps": 3,
                                                "divergences": divergences}
    else:
        assert not path.exists()


@pytest.mark.parametrize(("rule", "chosen", "left_out", "picked"), [
    ("MAV-CMD-1", (), (), True), ("MAV-CMD-1", ("CMD",), (), True), ("MAV-CMD-1", ("MAV-CMD",), (), True),
    ("MAV-CMD-1", ("MIS",), (), False), ("MAV-CMD-1", (), ("CMD-1",), False), ("MAV-CMD-2", (), ("CMD-1",), True),
    ("MAV-CMD-1", ("CMD",), ("MAV-CMD-1",), False)])
def test_select_and_exclude_take_a_rule_with_or_without_its_prefix(rule, chosen, left_out, picked):
    assert verdicts.picked(rule, (*chosen, *("!" + x for x in left_out)), "MAV-") is picked


MARKS = [CaseMark(10, "CMD/a", "start", None, ()), CaseMark(20, "CMD/a", "end", "passed", ()),
         CaseMark(30, "CMD/ab", "start", None, ()), CaseMark(45, "CMD/ab", "end", "failed", ()),
         CaseMark(50, "MIS/x", "start", None, ()), CaseMark(60, "MIS/x", "end", "passed", ())]


def test_a_case_is_named_whole_or_by_the_one_it_starts():
    assert core.case_window(MARKS, "CMD/a", "f") == (10, 20)  # whole, though CMD/ab starts with it
    assert core.case_window(MARKS, "MIS", "f") == (50, 60)
    with pytest.raises(UsageError, match="matches several cases"):
        core.case_window(MARKS, "CMD", "f")
    with pytest.raises(UsageError, match="is not a case of it"):
        core.case_window(MARKS, "PRM", "f")
    with pytest.raises(UsageError, match="has no case marks"):
        core.case_window([], "CMD", "f")
    assert [core.case_at(MARKS, t) for t in (5, 15, 25, 45, 55)] == [None, "CMD/a", None, "CMD/ab", "MIS/x"]
    # a capture cut inside a case (its start mark, no end): the case runs to the capture's end
    cut = [*MARKS[:4], CaseMark(50, "MIS/x", "start", None, ())]
    lo, hi = core.case_window(cut, "MIS", "f")
    assert lo == 50 and hi > 10**18


def test_time_window():
    inside = core.window(Namespace(t_from="1", t_to="2.5"))
    assert [inside(t) for t in (0.5, 1.0, 2.5, 3.0)] == [False, True, True, False]
    assert core.window(Namespace())(1e9)


class _Rec(NamedTuple):
    t_ns: int
    text: str


def test_show_lists_the_records_in_the_windows_each_with_its_time_and_the_truncation_where_it_comes():
    """One show for every protocol's records (MAVLink's kept frames, Nsqd's as they are read):
    times since the first listed kind's record (a case mark before it counts for nothing)."""
    recs = [CaseMark(1, "CMD/a", "start", None, ()), _Rec(10, "a"), _Rec(15, "b"), _Rec(1_000_000_010, "c"),
            _Rec(2_500_000_011, "d"), Truncated("cut at byte 9")]

    def show(ns: Namespace, cases: list[CaseMark] | None = None) -> str:
        out = io.StringIO()
        assert core.show_frames(ns, out, "the header", recs, lambda r: r.text.upper(), path="f", cases=cases,
                                kinds=(_Rec,)) == 0
        return out.getvalue()
    assert show(Namespace()) == ("the header\n+0.000000s A\n+0.000000s B\n+1.000000s C\n+2.500000s D\n"
                                 "TRUNCATED: cut at byte 9\n")
    assert show(Namespace(t_from="0.5", t_to="2.5")) == "the header\n+1.000000s C\nTRUNCATED: cut at byte 9\n"
    assert show(Namespace(case="CMD/a"), MARKS) == "the header\n+0.000000s A\n+0.000000s B\nTRUNCATED: cut at byte 9\n"
    assert show(Namespace(case="CMD/a")).count("\n") == 6  # no case marks looked at (None): every record
    with pytest.raises(UsageError, match="matches several cases"):
        show(Namespace(case="CMD"), MARKS)


def test_steps_are_aligned_sender_by_sender():
    golden = {"gcs": [("A", "#1 A"), ("B", "#2 B"), ("C", "#3 C")], "vehicle": [("X", "#4 X")]}
    candidate = {"gcs": [("A", "#1 A"), ("C", "#2 C"), ("D", "#3 D")], "vehicle": [("X", "#9 X")]}
    diffs, lines = core.align(golden, candidate)
    assert [(d["kind"], d["role"], d["golden"], d["candidate"]) for d in diffs] == [
        ("missing", "gcs", ["#2 B"], []), ("extra", "gcs", [], ["#3 D"])]  # the vehicle's alike: keys compared
    assert lines == ["  missing (gcs's messages):", "    golden    #2 B", "  extra (gcs's messages):",
                     "    candidate #3 D"]
    def steps(side: str) -> dict[str, list[tuple[str, str]]]:  # 5 changed steps, each between alike ones
        return {"v": [s for i in range(5) for s in ((f"k{i}", f"k{i}"), (f"{side}{i}", f"{side}{i}"))]}

    diffs, lines = core.align(steps("g"), steps("c"), shown=2)
    assert [d["kind"] for d in diffs] == ["changed"] * 5
    assert lines[-1] == "  ... and 3 more" and sum(line.startswith("  changed") for line in lines) == 2
