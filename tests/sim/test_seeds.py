"""The regression seeds (``tests/sim/seeds/*.json``, issue 38 item 3): each one call -- seed and
parameters in, the same trace and verdicts out (its digest) -- and each a false verdict the
search found in the existing trace monitor, kept as the monitor's strict xfail with its
reason while it stands; those that blamed a correct node pass since judge.explain's veto
(``judge/veto.py``) and the MCP-FLOW-3 fix of a cut view. ``judge.explain`` holds on every one but the seed
that names its own miss (``explain_reason``), its strict xfail."""

from __future__ import annotations

from pathlib import Path

import pytest

from mcp_conform.sim.search import check, digest, load_seed, replay

SEEDS = sorted((Path(__file__).parent / "seeds").glob("*.json"))


def test_there_are_seeds():
    assert SEEDS


@pytest.mark.parametrize("path", SEEDS, ids=[p.stem for p in SEEDS])
def test_a_seed_replays_to_the_same_trace_and_verdicts(path):
    o, _ = replay(path)
    assert digest(o) == load_seed(path)["digest"]


def _seed_case(path: Path, why_key: str) -> object:
    """The seed as a test parameter, a strict xfail with its reason where the seed's
    ``why_key`` says the judge still gets it wrong (``explain_reason``, ``open``; the
    monitor's: ``reason`` when ``xfail``)."""
    doc = load_seed(path)
    why = (doc["reason"] if doc["xfail"] else None) if why_key == "reason" else doc.get(why_key)
    marks = [pytest.mark.xfail(strict=True, reason=why)] if why else []
    return pytest.param(path, id=path.stem, marks=marks)


@pytest.mark.parametrize("path", [_seed_case(p, "explain_reason") for p in SEEDS])
def test_explain_keeps_both_properties_on_the_seed(path):
    o, _ = replay(path)
    assert check(o, ("explain",)) == []


@pytest.mark.parametrize("path", [_seed_case(p, "reason") for p in SEEDS])
def test_the_monitor_keeps_both_properties_on_the_seed(path):
    o, _ = replay(path)
    problems = check(o, ("monitor",))
    assert problems == [], "\n".join(p.text() for p in problems)


@pytest.mark.parametrize("path", [_seed_case(p, "open") for p in SEEDS])
def test_the_monitor_fails_no_correct_party_on_the_seed(path):
    """A false verdict on a correct party (every party but the seed's faulty one) is gone:
    judge.explain's veto (``judge/veto.py``) on MCP-RTX-1/2, and MCP-FLOW-3 on a cut view.
    The faulty party's misses and wrong rules are the test above's strict xfails; a seed with
    ``open`` is a false verdict on a correct party the judge still gives (its strict xfail)."""
    o, _ = replay(path)
    faulty = o.schedule.faulty_party if o.schedule.faulty is not None else None
    problems = [p for p in check(o, ("monitor",)) if p.party != faulty]
    assert problems == [], "\n".join(p.text() for p in problems)


@pytest.mark.parametrize("path", SEEDS, ids=[p.stem for p in SEEDS])
def test_no_correct_party_is_warned_on_the_seed(path):
    """Nor a SHOULD rule (the sweep's property counts warnings, this holds the seeds to none):
    three seeds' correct parties, stalled before most copies of a message, were warned
    MCP-RTX-3 (the copies' median gap stretched by the stall, the one copy sent on time taken
    for a short gap) until judge.spacing held the gaps to the schedule the party kept while it
    could run."""
    o, _ = replay(path)
    assert o.judged is not None
    faulty = o.schedule.faulty_party if o.schedule.faulty is not None else None
    warned = {pid: o.judged.warned(pid) for pid in o.world.parties if pid != faulty and o.judged.warned(pid)}
    assert warned == {}, o.judged.summary()


@pytest.mark.parametrize("path", [p for p in SEEDS if "vetoed" in load_seed(p)], ids=lambda p: p.stem)
def test_the_old_judge_fails_the_seed_where_the_veto_drops_it(path):
    """The monitor without judge.explain's veto (the judge as it was) failed a correct party on
    the seed, or the faulty one by a rule not its fault's (monitor-rtx1-for-rtx2-after-a-stall):
    its replay has the failures the veto dropped, as the seed file names them."""
    o, _ = replay(path)
    assert o.judged is not None
    fault = o.schedule.faulty
    faulty = o.schedule.faulty_party if fault is not None else None
    got = [f"node {pid} {v.rule}: {v.actual}" for pid, vs in sorted(o.judged.vetoed.items()) for v in vs]
    assert got == load_seed(path)["vetoed"] and any(
        pid != faulty or (fault is not None and v.rule != fault.rule)
        for pid, vs in o.judged.vetoed.items() for v in vs)
