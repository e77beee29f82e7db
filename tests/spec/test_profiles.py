"""spec.profiles: each protocol declared once; every name in the table resolves to a thing of
the kind the floor that uses it expects, and ``pick`` is the one place names turn into it."""

from __future__ import annotations

import pytest

from spec import ROLES
from spec.profiles import PROFILES, ROLE_NAMES, ProfileError, pick, profile_of_role, resolve


def test_every_name_in_the_table_resolves():
    from conformance._case_base import CaseBase
    from harness.node import NodeBase

    for prof in PROFILES.values():
        for path in (prof.codec, prof.monitor, prof.dissector, prof.capture_reader, prof.mutators,
                     prof.oracles, prof.reference_cli, prof.capture_detect, prof.capture_tools):
            if path is not None:
                assert resolve(path) is not None, path
        assert hasattr(resolve(prof.dissector), "generate") and resolve(prof.reference_cli).main
        for role in prof.roles:
            assert role.name in getattr(prof.spec, "roles", ROLES), (prof.name, role.name)
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
    with pytest.raises(ProfileError, match=r"^'xyz' is not one of mcp, nsqd$"):
        pick("xyz")
    assert profile_of_role("backend").framing == "stream" and set(ROLE_NAMES) == {"drone", "manager", "backend"}
