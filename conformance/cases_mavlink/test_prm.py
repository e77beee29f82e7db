"""PRM — the parameter protocol (https://mavlink.io/en/services/parameter.html): the whole
list with its count and indices, one parameter read by name and by index, a write echoed by
PARAM_VALUE and read back, a name and an index the vehicle does not have, and the list's
pacing. The write sets a parameter to the value it already has: the vehicle under test is
left as it was."""

from __future__ import annotations

import re

import pytest

from mcp_conform.conformance.cases_mavlink.mavlink_services import param_id
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive

#: no vehicle has a parameter of this name (16 characters, MAV-PRM-9's longest)
UNKNOWN_PARAM = "MCPCONF_NO_SUCH_"
#: the shortest list MAV-PRM-3 judges, and the pause it looks for
PACED_MIN = 20
PAUSE_S = 0.001
#: how many lists MAV-PRM-3 asks for before it says the vehicle does not pace them
LIST_TRIES = 5


@pytest.fixture(scope="module")
def table():
    """The list as the first PRM case read it: {index: PARAM_VALUE} and param_count."""
    return {}


def _listed(node, table, *, component=None):
    """PARAM_REQUEST_LIST sent; the PARAM_VALUEs that came (MAV-PRM-1)."""
    since = node.send("PARAM_REQUEST_LIST", target_system=node.sysid,
                      target_component=node.compid if component is None else component)
    node.expect_param_values(since, lambda m: True, "MAV-PRM-1", "after PARAM_REQUEST_LIST, PARAM_VALUEs")
    values = node.param_list(since)
    if not table:
        table["values"] = values
    return values


def _entry(node, table):
    """A parameter of the list (index, PARAM_VALUE); Inconclusive when the list is empty."""
    values = table.get("values") or _listed(node, table)
    count = values[0].param_count if values else 0
    entries = sorted((v.param_index, v) for v in values if v.param_index < count)
    if not entries:
        raise Inconclusive("MAV-PRM-1's list gave no parameter to read")
    return entries[len(entries) // 2]


@rules("MAV-PRM-1", "MAV-PRM-2")
def test_request_list_gives_every_parameter(node, table):
    """MAV-PRM-1: PARAM_REQUEST_LIST answered with PARAM_VALUEs; MAV-PRM-2 (D-5): one
    param_count throughout, every index 0..param_count-1 with one name."""
    values = _listed(node, table)
    counts = sorted({v.param_count for v in values})
    node.expect_true(len(counts) == 1, "MAV-PRM-2", "one param_count in every PARAM_VALUE of the list",
                     f"param_count {counts}")
    count = counts[0]
    names: dict[int, set[str]] = {}
    for v in values:
        if v.param_index < count:
            names.setdefault(v.param_index, set()).add(param_id(v))
    missing = [i for i in range(count) if i not in names]
    twice = {i: sorted(n) for i, n in names.items() if len(n) > 1}
    node.expect_true(not missing and not twice, "MAV-PRM-2",
                     f"indices 0..{count - 1} each with one name", f"{len(missing)} missing "
                     f"{missing[:8]}, {len(twice)} with two names {dict(list(twice.items())[:3])}")


@rules("MAV-PRM-4")
def test_read_by_name(node, table):
    """MAV-PRM-4: PARAM_REQUEST_READ with param_index -1 answered with that param_id."""
    _, entry = _entry(node, table)
    name = param_id(entry)
    since = node.send("PARAM_REQUEST_READ", target_system=node.sysid, target_component=node.compid,
                      param_id=name.encode(), param_index=-1)
    node.expect_param_values(since, lambda m: param_id(m) == name, "MAV-PRM-4",
                             f"after PARAM_REQUEST_READ of {name!r}, its PARAM_VALUE within {node.reply_max:g} s")


@rules("MAV-PRM-5", "MAV-PRM-6")
def test_read_by_index(node, table):
    """MAV-PRM-5: PARAM_REQUEST_READ by index answered with that param_index (param_id
    ignored: the runner sends a name no vehicle has); MAV-PRM-6: the name the list gave it."""
    index, entry = _entry(node, table)
    since = node.send("PARAM_REQUEST_READ", target_system=node.sysid, target_component=node.compid,
                      param_id=UNKNOWN_PARAM.encode(), param_index=index)
    got = node.expect_param_values(since, lambda m: m.param_index == index, "MAV-PRM-5",
                                   f"after PARAM_REQUEST_READ of index {index}, the PARAM_VALUE of index {index}")
    node.expect_true(param_id(got[0].msg) == param_id(entry), "MAV-PRM-6",
                     f"index {index} named {param_id(entry)!r}, as the list gave it", repr(param_id(got[0].msg)))


@rules("MAV-PRM-9", "MAV-PRM-10")
def test_names_and_types_of_the_list(node, table):
    """MAV-PRM-9: each param_id (read from the frame's bytes by the dialect's layout) is
    printable ASCII up to its NUL, at most 16 characters; MAV-PRM-10: param_type a
    MAV_PARAM_TYPE value, one per name in every PARAM_VALUE of the run, and an integer type's
    value an integer in its range when the vehicle says it casts (AUTOPILOT_VERSION's
    MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST; bytewise values are not judged)."""
    if not table.get("values"):
        _listed(node, table)
    values = node.from_vehicle(0.0, "PARAM_VALUE")

    def name_problem(r):
        raw = node.raw_fields(r)["param_id"]
        name = raw.split(b"\0", 1)[0]
        if not name or not all(0x20 < b < 0x7F for b in name):
            return f"param_id {raw!r}"
        return None
    node.expect_frames(values, name_problem, "MAV-PRM-9", "param_id printable ASCII up to its NUL, 1..16 characters")
    types = {v: e.name for v, e in node.mav.enums["MAV_PARAM_TYPE"].items() if not e.name.endswith("_ENUM_END")}
    caps = node.capabilities()
    cast = caps is not None and bool(caps & node.mav.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)
    seen: dict[str, int] = {}

    def type_problem(r):
        m = r.msg
        t, name = m.param_type, param_id(m)
        if t not in types:
            return f"{name}: param_type {t} is no MAV_PARAM_TYPE"
        if seen.setdefault(name, t) != t:
            return f"{name}: param_type {types[t]}, earlier {types[seen[name]]}"
        bits = re.fullmatch(r"MAV_PARAM_TYPE_(U?)INT(\d+)", types[t])
        if cast and bits:
            lo, hi = (0, 2 ** int(bits[2]) - 1) if bits[1] else (-(2 ** (int(bits[2]) - 1)), 2 ** (int(bits[2]) - 1) - 1)
            if m.param_value != int(m.param_value) or not lo <= m.param_value <= hi:
                return f"{name}: {types[t]} value {m.param_value!r}"
        return None
    node.expect_frames(values, type_problem, "MAV-PRM-10",
                       "param_type a MAV_PARAM_TYPE, one per parameter, an integer type's value an integer in range")
    if not cast:
        node.info("MAV-PRM-10: the vehicle does not say it casts integers to floats: their values are not judged")


@rules("MAV-PRM-7", "MAV-PRM-8")
def test_set_is_echoed_and_read_back(node, table):
    """MAV-PRM-7: PARAM_SET (the value the parameter has) answered with its PARAM_VALUE;
    MAV-PRM-8: a read after it gives the value that PARAM_VALUE gave."""
    _, entry = _entry(node, table)
    name = param_id(entry)
    since = node.send("PARAM_SET", target_system=node.sysid, target_component=node.compid, param_id=name.encode(),
                      param_value=entry.param_value, param_type=entry.param_type)
    echo = node.expect_param_values(since, lambda m: param_id(m) == name, "MAV-PRM-7",
                                    f"after PARAM_SET of {name!r}, its PARAM_VALUE within {node.reply_max:g} s")[0]
    since = node.send("PARAM_REQUEST_READ", target_system=node.sysid, target_component=node.compid,
                      param_id=name.encode(), param_index=-1)
    read = node.expect_param_values(since, lambda m: param_id(m) == name, "MAV-PRM-8",
                                    f"after PARAM_REQUEST_READ of {name!r}, its PARAM_VALUE")[0]
    node.expect_true(read.msg.param_value == echo.msg.param_value, "MAV-PRM-8",
                     f"{name} read back as the set's PARAM_VALUE gave it ({echo.msg.param_value:g})",
                     f"{read.msg.param_value:g}")


@rules("MAV-PRM-11")
def test_unknown_name_creates_nothing(node, table):
    """MAV-PRM-11: PARAM_SET and PARAM_REQUEST_READ of a name the vehicle has not: no
    PARAM_VALUE names it, and a list afterwards has the count it had; a read of the index
    param_count (one past the last) gets no PARAM_VALUE of that index."""
    values = table.get("values") or _listed(node, table)
    since = node.send("PARAM_SET", target_system=node.sysid, target_component=node.compid,
                      param_id=UNKNOWN_PARAM.encode(), param_value=1.0, param_type=node.mav.MAV_PARAM_TYPE_REAL32)
    node.send("PARAM_REQUEST_READ", target_system=node.sysid, target_component=node.compid,
              param_id=UNKNOWN_PARAM.encode(), param_index=-1)
    node.watch(node.reply_max)
    named = [r for r in node.from_vehicle(since, "PARAM_VALUE") if param_id(r.msg) == UNKNOWN_PARAM]
    node.expect_true(not named, "MAV-PRM-11", f"no PARAM_VALUE names {UNKNOWN_PARAM!r}",
                     f"{len(named)} PARAM_VALUE(s) do", [named[0].describe()] if named else [])
    after = _listed(node, table)
    before_count, after_count = values[0].param_count, after[0].param_count if after else None
    node.expect_true(after_count == before_count, "MAV-PRM-11", f"param_count {before_count} after it",
                     f"param_count {after_count}")
    since = node.send("PARAM_REQUEST_READ", target_system=node.sysid, target_component=node.compid,
                      param_id=b"", param_index=before_count)
    node.watch(node.reply_max)
    past = [r for r in node.from_vehicle(since, "PARAM_VALUE") if r.msg.param_index == before_count]
    node.expect_true(not past, "MAV-PRM-11", f"no PARAM_VALUE for index {before_count} (past param_count)",
                     f"{len(past)} PARAM_VALUE(s): {past[0].describe()}" if past else "")


@rules("MAV-PRM-12")
def test_unknown_name_is_said(node, table):
    """MAV-PRM-12 (SHOULD): PARAM_REQUEST_READ of a name the vehicle has not answered with a
    STATUSTEXT (ArduPilot says nothing: GCS_Param.cpp's param_io_timer, "vp =
    AP_Param::find(req.param_name, &reply.p_type); if (vp == nullptr) { return; }")."""
    since = node.send("PARAM_REQUEST_READ", target_system=node.sysid, target_component=node.compid,
                      param_id=UNKNOWN_PARAM.encode(), param_index=-1)
    node.link.wait_for(lambda: bool(node.from_vehicle(since, "STATUSTEXT")), node.reply_max)
    said = node.from_vehicle(since, "STATUSTEXT")
    node.expect_true(bool(said), "MAV-PRM-12", f"a STATUSTEXT after PARAM_REQUEST_READ of {UNKNOWN_PARAM!r}",
                     "no STATUSTEXT")
    node.info(f"MAV-PRM-12: {said[0].msg.text!r}")


@rules("MAV-PRM-3")
def test_list_is_paced(node, table):
    """MAV-PRM-3 (SHOULD): a list of at least PACED_MIN parameters does not come in one
    burst: somewhere between two of its PARAM_VALUEs the vehicle pauses PAUSE_S or more
    (ArduPilot sends at most 30 % of the link's bandwidth, 5 at a time without flow
    control: GCS_Param.cpp queued_param_send). On loopback the bandwidth is not the
    link's, so only a list sent whole at once is judged. A paced list read late comes in one
    read as a burst does -- the runner's reader stalled on a loaded host, or a TCP segment
    sent again holding the rest of the list behind it (the simulator's lossy TCP link,
    sim.vehicle_role) -- so a list seen in one burst is asked for again, up to LIST_TRIES
    lists: the vehicle is warned only when every one came in a burst."""
    seen = []
    for _ in range(LIST_TRIES):
        since = node.send("PARAM_REQUEST_LIST", target_system=node.sysid, target_component=node.compid)
        node.expect_param_values(since, lambda m: True, "MAV-PRM-1", "after PARAM_REQUEST_LIST, PARAM_VALUEs")
        node.param_list(since)
        frames = node.from_vehicle(since, "PARAM_VALUE")
        count = frames[0].msg.param_count
        listed = [r for r in frames if r.msg.param_index < count]
        if len(listed) < PACED_MIN:
            raise Inconclusive(f"MAV-PRM-3: a list of {len(listed)} parameters is too short to judge its pacing")
        gaps = [b.t - a.t for a, b in zip(listed, listed[1:], strict=False)]
        if max(gaps) >= PAUSE_S:
            return
        seen.append(f"all {len(listed)} PARAM_VALUEs within {(listed[-1].t - listed[0].t) * 1e3:.1f} ms, "
                    f"longest pause {max(gaps) * 1e3:.2f} ms")
    raise node.fail("MAV-PRM-3", f"a pause of {PAUSE_S * 1e3:g} ms or more somewhere in a list of {PACED_MIN} "
                    f"or more, in one of {LIST_TRIES} lists", seen[0], [f"list {i + 1}: {s}" for i, s in enumerate(seen)])


@rules("MAV-PRM-13")
def test_list_for_every_component_is_answered(node, table):
    """MAV-PRM-13: PARAM_REQUEST_LIST addressed to MAV_COMP_ID_ALL (0) is answered."""
    _listed(node, table, component=node.mav.MAV_COMP_ID_ALL)
