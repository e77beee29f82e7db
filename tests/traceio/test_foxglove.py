"""Captures for Foxglove (issue 24 item 1): /mavlink decoded beside its bytes, the vehicle as
foxglove.LocationFix and PoseInFrame, the cases and verdicts as foxglove.Log, every channel's
messages valid against the schema the file carries (those of foxglove-sdk for foxglove.*),
and the example layout."""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import pytest
from jsonschema import Draft202012Validator
from mcap.reader import make_reader

from mcp_conform.captures.scenarios import GOLDEN
from mcp_conform.traceio import fox
from mcp_conform.traceio.background import BackgroundRecorder
from mcp_conform.traceio.reader import open_capture
from mcp_conform.traceio.recorder import McapRecorder

ROOT = Path(__file__).resolve().parents[2]

with warnings.catch_warnings():
    warnings.simplefilter("ignore", DeprecationWarning)
    fm = pytest.importorskip("foxglove.messages", reason="foxglove-sdk is not installed")
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402


def _frames() -> dict[str, bytes]:
    mav = mavlink2.MAVLink(None, 1, 1)
    return {
        "position": mav.global_position_int_encode(5000, 357711030, -786746590, 103_500, 3_000, 1, -2, 0, 9000).pack(mav),
        "attitude": mav.attitude_encode(5000, 0.1, -0.2, 1.5, 0.0, 0.0, 0.0).pack(mav),
        "no_fix": mav.global_position_int_encode(10, 0, 0, 0, 0, 0, 0, 0, 0).pack(mav),
        "nan": mav.vfr_hud_encode(float("nan"), 0.0, 90, 50, 100.5, 0.0).pack(mav),
    }


def _validated(path: Path) -> dict[str, list[tuple[int, dict]]]:
    """Every message of every channel, each validated against its channel's schema."""
    out: dict[str, list[tuple[int, dict]]] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        validators: dict[int, Draft202012Validator] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json" and schema is not None
            assert schema.encoding == "jsonschema", channel.topic
            if schema.id not in validators:
                body = json.loads(schema.data)
                Draft202012Validator.check_schema(body)
                validators[schema.id] = Draft202012Validator(body)
            value = json.loads(message.data)  # strict JSON: NaN would fail Foxglove's parser
            errors = list(validators[schema.id].iter_errors(value))
            assert not errors, (channel.topic, errors[0].message, value)
            out.setdefault(channel.topic, []).append((message.log_time, value))
    return out


def test_schemas_are_the_sdks(tmp_path):
    """The JSON schemas name exactly the fields of foxglove-sdk's messages, and a body we
    write is accepted by the SDK's own message class."""
    for name in ("LocationFix", "PoseInFrame", "Log"):
        schema = fox.json_schema(name)
        assert schema["title"] == f"foxglove.{name}"
        assert fm.__dict__[name].get_schema().name == f"foxglove.{name}"
    body = fox.location_body(1_700_000_000_500_000_000, {"mavpackettype": "GLOBAL_POSITION_INT", "lat": 1,
                                                         "lon": 2, "alt": 3}, 1)
    assert body is not None
    stamp = body.pop("timestamp")
    kind = fm.LocationFixPositionCovarianceType
    body["position_covariance_type"] = next(getattr(kind, n) for n in dir(kind) if n[:1].isupper()
                                            and int(getattr(kind, n).value) == body["position_covariance_type"])
    fm.LocationFix(timestamp=fm.Timestamp(stamp["sec"], stamp["nsec"]), **body)  # the SDK takes every field
    assert set(body) | {"timestamp"} <= set(fox.json_schema("LocationFix")["properties"])
    log = fox.log_body(5, "error", "x", "case")
    assert log["level"] == int(fm.LogLevel.Error.value)
    stamp = log.pop("timestamp")
    fm.Log(timestamp=fm.Timestamp(stamp["sec"], stamp["nsec"]), level=fm.LogLevel.Error,
           **{k: v for k, v in log.items() if k != "level"})
    with pytest.raises(ValueError, match="log level"):
        fox.log_level("loud")


def test_a_mission_run_has_location_attitude_log_and_decoded_mavlink(tmp_path):
    path = tmp_path / "run.mcap"
    frames = _frames()
    with McapRecorder(path) as rec:
        rec.case_mark("MIS/test_wp_list", "start", 1_000, rules=("MCP-MIS-1",))
        rec.mavlink("tx", frames["no_fix"], 1_100, drone=1)
        rec.mavlink("tx", frames["position"], 1_200, drone=1)
        rec.mavlink("rx", frames["position"], 1_250, drone=1)  # the node's, not the vehicle's
        rec.mavlink("tx", frames["attitude"], 1_300, drone=1)
        rec.mavlink("tx", frames["nan"], 1_350, drone=1)
        rec.mavlink("tx", frames["position"][:-3], 1_360, drone=1)  # cut
        rec.case_mark("MIS/test_wp_list", "end", 1_400, outcome="failed", rules=("MCP-MIS-1",),
                      evidence="item 2 never uploaded to the autopilot")
        rec.log("finding MCP-ROB-3 confirmed 3 of 3", "warning", "mcp-fuzz", 1_500)
    msgs = _validated(path)
    mav = msgs["/mavlink"]
    assert [m["message"]["mavpackettype"] if m["message"] else None for _, m in mav] == [
        "GLOBAL_POSITION_INT", "GLOBAL_POSITION_INT", "GLOBAL_POSITION_INT", "ATTITUDE", "VFR_HUD", None]
    decoded = mavlink2.MAVLink(None).decode(bytearray(frames["position"])).to_dict()
    assert mav[1][1]["message"] == decoded and mav[1][1]["raw_base64"]
    assert mav[4][1]["message"]["airspeed"] is None  # NaN as null
    assert mav[5][1]["decode_error"]
    fixes = msgs["/vehicle/location"]
    assert len(fixes) == 1  # no fix yet (0, 0) and the node's frame are not the vehicle's position
    t, fix = fixes[0]
    assert t == 1_200 and fix["frame_id"] == "drone1"
    assert fix["latitude"] == pytest.approx(35.771103) and fix["longitude"] == pytest.approx(-78.674659)
    assert fix["altitude"] == pytest.approx(103.5)
    (_, pose), = msgs["/vehicle/attitude"]
    q = pose["pose"]["orientation"]
    assert sum(v * v for v in q.values()) == pytest.approx(1.0)
    assert q["z"] == pytest.approx(0.677, abs=0.01)  # yaw 1.5 rad dominates
    logs = [(m["level"], m["name"], m["message"]) for _, m in msgs["/log"]]
    assert logs == [
        (2, "case", "MIS/test_wp_list: started [MCP-MIS-1]"),
        (4, "case", "MIS/test_wp_list: failed [MCP-MIS-1]: item 2 never uploaded to the autopilot"),
        (3, "mcp-fuzz", "finding MCP-ROB-3 confirmed 3 of 3"),
    ]
    cap = open_capture(path)
    list(cap)
    assert cap.truncated is None and not any("not readable" in n for n in cap.notes)


def test_background_recorder_passes_log_and_evidence(tmp_path):
    path = tmp_path / "node.mcap"
    with BackgroundRecorder(path) as rec:
        rec.case_mark("c", "start", 10)
        rec.case_mark("c", "end", 20, outcome="passed", evidence=None)
        rec.log("node restarted", "warning", "mcp-node", 30)
        rec.mavlink("tx", _frames()["position"], 40, drone=2)
    rec.close()
    msgs = _validated(path)
    assert [m["message"] for _, m in msgs["/log"]] == ["c: started", "c: passed", "node restarted"]
    assert msgs["/vehicle/location"][0][1]["frame_id"] == "drone2"


@pytest.mark.parametrize("name", ["challenge1", "challenge2", "challenge3", "drone-suite"])
def test_golden_captures_validate(name):
    msgs = _validated(GOLDEN / f"{name}.mcap")
    assert msgs["/mcp/tx"] and msgs["/mcp/rx"]
    if name == "drone-suite":  # the runner against the drone and its simulated vehicle: a mission run
        assert msgs["/vehicle/location"] and msgs["/vehicle/attitude"]
        assert any(m["message"] for _, m in msgs["/mavlink"])
        levels = {m["level"] for _, m in msgs["/log"]}
        assert len(msgs["/log"]) == len(msgs["/conformance/case"]) and 2 in levels


def test_example_layout_is_the_generated_one_and_names_our_topics():
    text = (ROOT / fox.LAYOUT_FILE).read_text()
    assert text == fox.layout_json(), f"regenerate {fox.LAYOUT_FILE} (traceio.fox.layout_json)"
    layout = json.loads(text)
    panels: dict[str, dict] = {}

    def walk(node):
        if isinstance(node, dict):
            if node.get("type") == "panel":
                panels.setdefault(node["panelType"], node["config"])
            for v in node.values():
                walk(v)
        elif isinstance(node, list):
            for v in node:
                walk(v)

    walk(layout)
    assert panels["Map"]["followTopic"] == fox.LOCATION
    assert panels["Log"]["topicToRender"] == fox.LOG
    assert panels["Table"]["topicPath"] in ("/mcp/rx", "/mcp/tx")
    assert {"Map", "Log", "Table", "Plot", "RawMessages"} <= set(panels)


@pytest.mark.slow
def test_a_failed_case_logs_its_rule_and_evidence(tmp_path):
    """The runner's verdicts in /log: a manager that starts the mission before every drone is
    ready fails MCP-BLK-2; its end line is an error naming the rule and the report's reason."""
    from tests.conformance.runner_helpers import FAST, run_conform, sample_manager_command

    cap = tmp_path / "run.mcap"
    res = run_conform("--role", "manager", "--spawn", sample_manager_command("--fault", "start-early"), *FAST,
                      "--capture", str(cap))
    assert res.rules["MCP-BLK-2"] == "failed", res.explain()
    msgs = _validated(cap)
    failed = [c for c in res.report["cases"] if c["outcome"] == "failed" and c["failed_rule"] == "MCP-BLK-2"]
    assert failed, res.explain()
    lines = {m["message"]: m["level"] for _, m in msgs["/log"]}
    for case in failed:
        line = next(t for t in lines if t.startswith(f"{case['id']}: failed ["))
        assert lines[line] == 4 and "MCP-BLK-2" in line and case["reason"] in line, line
    assert len(msgs["/log"]) == len(msgs["/conformance/case"])
