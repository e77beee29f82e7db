"""PRM — the ground station's side of the parameter protocol
(https://mavlink.io/en/services/parameter.html): param_id's encoding, PARAM_SET naming a
parameter the vehicle has with the type the vehicle reported, and PARAM_SET resent when its
PARAM_VALUE does not come (the runner withholds the first one)."""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.conformance.mavlink_case import param_id
from mcp_conform.harness.mavlink_gcs_vehicle import Behaviour

WITHHOLD = Behaviour("withhold-param-value", withhold_param_value=True)


@rules("MAV-PRM-9")
def test_param_id_terminated(node):
    """MAV-PRM-9: param_id of PARAM_SET and PARAM_REQUEST_READ: at most 16 characters, nothing
    but NULs after the first NUL (the field as its bytes hold it)."""
    node.run()
    node.settle()
    frames = node.need(node.from_gcs("PARAM_SET", "PARAM_REQUEST_READ"), "PARAM_SET or PARAM_REQUEST_READ")

    def check(r):
        raw = node.raw_fields(r)["param_id"]
        text, nul, rest = raw.partition(b"\0")
        return f"param_id {raw!r}: bytes after its terminator" if nul and rest.strip(b"\0") else None
    node.expect_frames(frames, check, "MAV-PRM-9", "param_id NUL-terminated below 16 characters, nothing after")


@rules("MAV-PRM-17")
def test_param_set_names_a_parameter_with_its_type(node):
    """MAV-PRM-17: PARAM_SET names a parameter of the vehicle, with the MAV_PARAM_TYPE the
    vehicle reports for it."""
    node.run()
    node.settle()
    table = node.session.vehicle.model.params
    types = node.mav.enums["MAV_PARAM_TYPE"]

    def check(r):
        name = param_id(r.msg)
        if name not in table:
            return f"PARAM_SET {name!r}: no such parameter"
        want = table.type_of(name)
        return None if r.msg.param_type == want else (
            f"PARAM_SET {name} with param_type {r.msg.param_type}, the vehicle's is {types[want].name}")
    node.expect_frames(node.need(node.from_gcs("PARAM_SET"), "PARAM_SET"), check, "MAV-PRM-17",
                       "PARAM_SET of an existing parameter with its param_type")


@rules("MAV-PRM-16")
def test_param_set_resent(node):
    """MAV-PRM-16 (SHOULD, D-8): a PARAM_SET whose PARAM_VALUE does not come is resent within
    param_resend_window_s."""
    node.run(WITHHOLD)
    window = float(node.params["param_resend_window_s"])
    node.await_work(lambda: node.from_gcs("PARAM_SET"))
    first = node.need(node.from_gcs("PARAM_SET"), "PARAM_SET")[0]
    name = param_id(first.msg)
    node.wait(lambda: len([r for r in node.from_gcs("PARAM_SET") if param_id(r.msg) == name]) > 1, window)
    again = [r for r in node.from_gcs("PARAM_SET") if param_id(r.msg) == name][1:]
    node.expect_true(bool(again), "MAV-PRM-16", f"PARAM_SET {name} resent within {window:g} s without PARAM_VALUE",
                     "not resent")
