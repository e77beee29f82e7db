"""PRM — the ground station's side of the parameter protocol
(https://mavlink.io/en/services/parameter.html): param_id's encoding, PARAM_SET naming a
parameter the vehicle has with the type the vehicle reported, and PARAM_SET resent when its
PARAM_VALUE does not come (the runner withholds the first one)."""

from __future__ import annotations

from mcp_conform.conformance.cases_mavlink.mavlink_services import param_id
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.vehicle.behaviour import Behaviour

WITHHOLD = Behaviour("withhold-param-value", withhold_param_value=True)
#: How long a PARAM_VALUE may take to reach the ground station (a lossy link's TCP
#: retransmission, 0.2 s, and its delay; the ground station's reader): one the runner sent less
#: than this before the ground station's last request for the parameter came may have crossed
#: that request, and answered it in the ground station's eyes (MAV-PRM-16).
CROSSED_S = 0.5


def _asks(value):
    """Which of the ground station's frames ``value`` (a PARAM_VALUE) can answer: a list or a
    read by index (its index), a read by name or a PARAM_SET (index 65535)."""
    if value.param_index < value.param_count:
        return lambda r: r.name == "PARAM_REQUEST_LIST" or (r.name == "PARAM_REQUEST_READ" and r.msg.param_index >= 0)
    return lambda r: r.name == "PARAM_SET" or (r.name == "PARAM_REQUEST_READ" and r.msg.param_index < 0)


def _answered_late(node, sent_t: float, value) -> bool:
    """The runner's PARAM_VALUE ``value`` sent at ``sent_t`` answered a request it read late: a
    later frame of the ground station (one it sent after that request: a HEARTBEAT of its own
    clock, its next work) had come by then, both read from one backlog (the runner's reader kept
    off the CPU, a lossy link's segment sent again). The ground station may have stopped waiting
    for the answer before it went out -- a list given up on, a read by name sent meanwhile --
    and then take it as the answer to a later request of its own."""
    frames, asks = node.from_gcs(), _asks(value)
    asked = [i for i, r in enumerate(frames) if asks(r) and r.t <= sent_t]
    return bool(asked) and any(r.t <= sent_t for r in frames[asked[-1] + 1:])


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
    param_resend_window_s. The runner withholds the answer to the PARAM_SET, not every
    PARAM_VALUE of its parameter: one it sent after the PARAM_SET came (a read's answer, a list's
    entry, read late by the runner or held on a lossy link) may reach the ground station after
    it sent the PARAM_SET, and is that PARAM_SET's answer in its eyes (the protocol has no
    other) -- a ground station not resending then is SKIPPED, not judged."""
    node.run(WITHHOLD)
    window = float(node.params["param_resend_window_s"])
    node.await_work(lambda: node.from_gcs("PARAM_SET"))
    first = node.need(node.from_gcs("PARAM_SET"), "PARAM_SET")[0]
    name = param_id(first.msg)
    node.wait(lambda: len([r for r in node.from_gcs("PARAM_SET") if param_id(r.msg) == name]) > 1, window)
    again = [r for r in node.from_gcs("PARAM_SET") if param_id(r.msg) == name][1:]
    values = [(t, m) for t, m in node.runner_sent("PARAM_VALUE") if param_id(m) == name]
    strays = [m for t, m in values if t >= first.t]
    if not again and strays:
        raise Inconclusive(f"a PARAM_VALUE of {name} (index {strays[0].param_index}) went out after the PARAM_SET "
                           "came: its answer for the ground station")
    asks = [r.t for r in node.from_gcs("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ")
            if r.t < first.t and (r.name == "PARAM_REQUEST_LIST" or param_id(r.msg) == name or r.msg.param_index >= 0)]
    crossed = [m for t, m in values if asks and t < asks[-1] < t + CROSSED_S]
    if not again and crossed:
        raise Inconclusive(f"a PARAM_VALUE of {name} (index {crossed[0].param_index}) went out less than "
                           f"{CROSSED_S:g} s before the ground station's last request for it came: it may have crossed "
                           "that request and answered it, the request's own answer then the PARAM_SET's")
    late = [m for t, m in values if t < first.t and _answered_late(node, t, m)]
    if not again and late:
        raise Inconclusive(f"a PARAM_VALUE of {name} (index {late[0].param_index}) answered a request the runner read "
                           "late: the next one may have reached the ground station after its PARAM_SET, its answer "
                           "there")
    node.expect_true(bool(again), "MAV-PRM-16", f"PARAM_SET {name} resent within {window:g} s without PARAM_VALUE",
                     "not resent")


GAPS = Behaviour("param-list-gaps", list_gaps=(2, 7))
SHUFFLED = Behaviour("param-list-shuffled", list_shuffled=True)


def _list(node):
    """The ground station's first PARAM_REQUEST_LIST (SKIPPED when it asks for none) and the
    window in which it deals with the list's end: 3 x param_list_gap_max_s."""
    node.await_work(lambda: node.from_gcs("PARAM_REQUEST_LIST"))
    first = node.need(node.from_gcs("PARAM_REQUEST_LIST"), "PARAM_REQUEST_LIST")[0]
    return first, 3 * float(node.params["param_list_gap_max_s"])


def _repairs(node, since):
    """After ``since``: the indices the ground station read by index, the names it read, and
    how many whole lists it asked for again."""
    reads = [r.msg for r in node.from_gcs("PARAM_REQUEST_READ") if r.t > since]
    return ({m.param_index for m in reads if m.param_index >= 0}, {param_id(m) for m in reads if m.param_index < 0},
            len([r for r in node.from_gcs("PARAM_REQUEST_LIST") if r.t > since]))


@rules("MAV-PRM-14")
def test_missing_parameters_read_one_by_one(node):
    """MAV-PRM-14 (SHOULD): a list with indices 2 and 7 missing: the ground station reads those
    two (by index or by name), not the whole list again."""
    node.run(GAPS)
    first, window = _list(node)
    names = node.session.vehicle.model.params.names()
    missing = {i: names[i] for i in GAPS.list_gaps}

    def asked():
        by_index, by_name, _ = _repairs(node, first.t)
        return {i for i, n in missing.items() if i in by_index or n in by_name}
    node.wait(lambda: asked() == set(missing), window)
    relists = _repairs(node, first.t)[2]
    listed = [(t, m) for t, m in node.runner_sent("PARAM_VALUE") if t >= first.t and m.param_index < m.param_count]
    if asked() != set(missing) and not relists and listed:
        work = [r.t for r in node.from_gcs() if r.t >= first.t and r.name not in ("HEARTBEAT", "PARAM_REQUEST_LIST")]
        end = max((t for t, _ in listed if not work or t <= work[0] + CROSSED_S), default=listed[0][0])
        if _answered_late(node, *listed[0]) or (work and work[0] < end + CROSSED_S):
            raise Inconclusive("the runner sent the list late (a later frame of the ground station had come by then, "
                               f"or its next work less than {CROSSED_S:g} s after the list's end): the ground station "
                               "may have given up on it before it came")
    node.expect_true(asked() == set(missing), "MAV-PRM-14", f"the missing {', '.join(missing.values())} read "
                     f"(by index {sorted(missing)} or by name)", f"read {sorted(asked()) or 'none'}, "
                     f"the whole list asked again {relists} time(s)")


@rules("MAV-PRM-15")
def test_list_in_any_order_with_duplicates(node):
    """MAV-PRM-15 (D-5): a complete list sent backwards with every third PARAM_VALUE twice: the
    ground station asks for nothing more (no read by index, no list again). A read by name is
    an application reading one parameter, not list repair."""
    node.run(SHUFFLED)
    first, window = _list(node)
    node.wait(lambda: any(_repairs(node, first.t)[0::2]), window)
    by_index, _, relists = _repairs(node, first.t)
    node.expect_true(not by_index and not relists, "MAV-PRM-15", "nothing asked for after a complete list",
                     f"indices {sorted(by_index)} read again, the whole list asked again {relists} time(s)")
