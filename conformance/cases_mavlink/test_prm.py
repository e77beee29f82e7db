"""PRM — the parameter protocol (https://mavlink.io/en/services/parameter.html): the whole
list with its count and indices, one parameter read by name and by index, a write echoed by
PARAM_VALUE and read back, and a name the vehicle does not have. The write sets a parameter
to the value it already has: the vehicle under test is left as it was."""

from __future__ import annotations

import pytest

from mcp_conform.conformance.marks import rules
from mcp_conform.conformance.mavlink_case import param_id
from mcp_conform.harness.errors import Inconclusive

#: no vehicle has a parameter of this name (16 characters, MAV-PRM-9's longest)
UNKNOWN_PARAM = "MCPCONF_NO_SUCH_"


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


@rules("MAV-PRM-5")
def test_read_by_index(node, table):
    """MAV-PRM-5: PARAM_REQUEST_READ by index answered with that param_index (param_id
    ignored: the runner sends a name no vehicle has)."""
    index, entry = _entry(node, table)
    since = node.send("PARAM_REQUEST_READ", target_system=node.sysid, target_component=node.compid,
                      param_id=UNKNOWN_PARAM.encode(), param_index=index)
    node.expect_param_values(since, lambda m: m.param_index == index and param_id(m) == param_id(entry),
                             "MAV-PRM-5", f"after PARAM_REQUEST_READ of index {index}, the PARAM_VALUE of "
                             f"index {index} ({param_id(entry)!r})")


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
    PARAM_VALUE names it, and a list afterwards has the count it had."""
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


@rules("MAV-PRM-13")
def test_list_for_every_component_is_answered(node, table):
    """MAV-PRM-13: PARAM_REQUEST_LIST addressed to MAV_COMP_ID_ALL (0) is answered."""
    _listed(node, table, component=node.mav.MAV_COMP_ID_ALL)
