"""spec.profiles: each protocol declared once; every name in the table resolves to a thing of
the kind the floor that uses it expects, and ``pick`` is the one place names turn into it."""

from __future__ import annotations

import pytest

from mcp_conform.spec import ROLES, SpecBase
from mcp_conform.spec.profiles import (
    PROFILES,
    ROLE_NAMES,
    ProfileError,
    pick,
    profile_of_role,
    resolve,
)


def test_every_name_in_the_table_resolves():
    from mcp_conform.conformance._case_base import CaseBase
    from mcp_conform.harness.node import NodeBase

    for prof in PROFILES.values():
        for path in (prof.monitor, prof.dissector, prof.mutators,
                     prof.oracles, prof.reference_cli, prof.capture_detect, prof.capture_tools, prof.loader):
            if path is not None:
                assert resolve(path) is not None, path
        assert prof.dissector is None or hasattr(resolve(prof.dissector), "generate")
        assert resolve(prof.reference_cli).main
        for role in prof.roles:
            assert role.name in prof.spec.roles and role.peer in prof.spec.roles, (prof.name, role.name)
            assert issubclass(resolve(role.session), NodeBase), role.session
            assert issubclass(resolve(role.context), CaseBase), role.context
            assert resolve(role.cases).__path__, role.cases
            if role.fuzz_target is not None:
                assert resolve(role.fuzz_target), role.fuzz_target


def test_pick_names_the_defaults_and_refuses_in_one_line():
    assert [(p.name, r.name) for p, r in (pick(), pick("nsqd"), pick(None, "manager"))] == [
        ("mcp", "drone"), ("nsqd", "backend"), ("mcp", "manager")]
    with pytest.raises(ProfileError, match=r"^'backend' is not a role of --protocol mcp \(drone, manager\)$"):
        pick("mcp", "backend")
    with pytest.raises(ProfileError, match=r"^'xyz' is not one of mcp, nsqd, mavlink$"):
        pick("xyz")
    assert profile_of_role("backend").framing == "stream" and set(ROLE_NAMES) == {"drone", "manager", "backend",
                                                                                  "vehicle", "gcs"}
    assert pick("mavlink")[1].name == "vehicle" and pick("mavlink")[1].peer == "gcs"
    with pytest.raises(ProfileError, match=r"^this protocol has no such piece yet"):
        resolve(None)  # a piece a protocol's profile does not name


def test_every_spec_answers_the_one_interface():
    """Both protocols' specs are read the same way (``SpecBase``): name, version, roles and
    their ports, messages by id and by name, rules by ID, their page (``spec.docs``)."""
    from mcp_conform.spec import docs

    assert PROFILES["mcp"].spec.roles == ROLES
    for prof in PROFILES.values():
        spec = prof.spec
        assert isinstance(spec, SpecBase) and spec.name and spec.short_name and spec.version
        assert type(resolve(prof.loader)(spec.path)) is type(spec)
        for m in spec.messages:
            assert spec.message(m.id) is m and spec.message(m.name) is m
        with pytest.raises(KeyError):
            spec.message("NO_SUCH_MESSAGE")
        assert all(spec.rule(r.id) is r for r in spec.rules)
        assert spec.port(prof.default_role.name) > 0
        assert docs.check(spec), f"{docs.default_output(spec)} is stale: run `python -m mcp_conform.spec docs`"
        assert docs.page(spec).summary(spec)


def test_a_node_id_names_its_role():
    mcp = PROFILES["mcp"]
    assert [mcp.role_of_id(i).name for i in (0, 1, 7)] == ["manager", "drone", "drone"]
    assert mcp.role(mcp.role("drone").peer).fixed_id == 0 and mcp.role("drone").fixed_id is None


@pytest.mark.parametrize(("argv", "says"), [
    (["check", "x.mcap", "--protocol", "nope"], "check: --protocol: 'nope' is not one of"),
    (["show", "x.mcap", "--protocol", "nope"], "show: --protocol: 'nope' is not one of"),
    (["dissector", "--protocol", "nope"], "dissector: --protocol: 'nope' is not one of"),
])
def test_a_tool_refuses_a_protocol_without_its_piece_in_one_line(argv, says, capsys, tmp_path, monkeypatch):
    """A protocol a tool does not know (or one without the tool's piece) is a usage error in
    one line naming the protocols that have it, not a traceback from ``resolve(None)``."""
    from mcp_conform.captures.cli import main

    monkeypatch.chdir(tmp_path)
    (tmp_path / "x.mcap").write_bytes(b"x")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and says in err[0] and "Traceback" not in err[0], err


def test_the_pieces_a_protocol_has_are_listed_and_picked(monkeypatch):
    import dataclasses

    from mcp_conform.spec import profiles
    from mcp_conform.spec.profiles import PIECES, ProfileError, having, pick_having

    for piece in PIECES:
        assert set(having(piece)) == {"mcp", "nsqd", "mavlink"}
    assert pick_having("mavlink", "dissector").name == "mavlink"
    # a protocol without a piece (MAVLink's capture tools before they were written)
    monkeypatch.setitem(profiles.PROFILES, "mavlink", dataclasses.replace(profiles.PROFILES["mavlink"],
                                                                          capture_tools=None))
    assert "mavlink" not in having("capture_tools")
    with pytest.raises(ProfileError, match="protocols with one: mcp, nsqd"):
        pick_having("mavlink", "capture_tools")
