"""The mission-protocol messages of ``VehicleModel``: each handled by ``vehicle.mission``
and recorded as a request with the vehicle's answer (``records.REQUESTS``: mission_upload,
mission_item, guided_item, mission_download, mission_read, mission_clear,
mission_set_current). A mixin: it uses the model's ``missions``, ``_auto``, ``_request``,
``record`` and position targets."""

from __future__ import annotations

from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage
from .mission import ACCEPTED, Answer, check_item, convert_float_item, result_name
from .records import GUIDED

if TYPE_CHECKING:
    from .flight import AutoMission
    from .mission import MissionProtocol
    from .records import Event

class MissionMessages:
    """The handlers ``VehicleModel`` dispatches mission messages to (``_on_<type>``)."""

    missions: MissionProtocol
    _auto: AutoMission
    _target_pos: tuple[float, float] | None
    _target_alt: float | None
    _conn: int
    armed: bool
    custom_mode: int

    if TYPE_CHECKING:
        @property
        def mode(self) -> str: ...

        def record(self, now: float, kind: str, **detail: Any) -> Event: ...

        def _request(self, now: float, msg: MAVLinkMessage, request: str, accepted: bool,
                     reason: str | None, answer: str, *, command: int | None = None,
                     mav_result: int | None = None, **extra: Any) -> Event: ...

    @property
    def mission(self) -> list[dict[str, Any]]:
        """The stored mission (MISSION_ITEM_INT fields; item 0 as uploaded, home in downloads)."""
        return self.missions.items

    def _mission(self, msg: MAVLinkMessage, now: float, request: str, ans: Answer,
                 command: int | None = None, **detail: Any) -> list[MAVLinkMessage]:
        """Record a mission-protocol request with its answer; return the replies."""
        if ans.result is not None:
            answer = "MISSION_ACK " + result_name(ans.result)
        else:
            answer = ", ".join(_describe(m) for m in ans.replies if m.get_type() != "STATUSTEXT")
        self._request(now, msg, request, ans.result in (None, ACCEPTED), ans.why, answer,
                      command=command, mav_result=ans.result, **detail)
        return ans.replies

    def _src(self, msg: MAVLinkMessage) -> tuple[int, int]:
        return msg.get_srcSystem(), msg.get_srcComponent()

    def _on_mission_count(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        ans = self.missions.count(f, self._src(msg), self._conn, now)
        if ans.result == ACCEPTED:
            self.record(now, "mission", count=len(self.missions.items))
        return self._mission(msg, now, "mission_upload", ans, count=int(f["count"]))

    def _on_mission_item_int(self, msg: MAVLinkMessage, f: dict[str, Any],
                             now: float) -> Iterable:
        detail = {"command": int(f["command"]), "seq": int(f["seq"]), "frame": int(f["frame"]),
                  "current": int(f["current"]), "x": f["x"], "y": f["y"], "z": f["z"]}
        if int(f.get("current", 0)) in (2, 3) and int(f.get("mission_type", 0) or 0) == 0:
            return self._mission(msg, now, "guided_item", self._guided_item(msg, f), **detail)
        ans = self.missions.item(msg.get_type(), f, self._src(msg), now)
        if ans.result == ACCEPTED and self.missions.upload is None:
            self.record(now, "mission", count=len(self.missions.items))
        return self._mission(msg, now, "mission_item", ans, **detail)

    _on_mission_item = _on_mission_item_int

    def _guided_item(self, msg: MAVLinkMessage, f: dict[str, Any]) -> Answer:
        """A MISSION_ITEM with current=2 (fly here in GUIDED) or 3 (change altitude)."""
        item = dict(f)
        result, why = (convert_float_item(item) if msg.get_type() == "MISSION_ITEM"
                       else (ACCEPTED, ""))
        if result == ACCEPTED:
            result, why = check_item(item)
        if result == ACCEPTED and int(f["current"]) == 2 and self.custom_mode != GUIDED:
            result, why = mav.MAV_MISSION_ERROR, f"guided waypoint while in {self.mode}"
        if result == ACCEPTED:
            if int(f["current"]) == 2:
                self._target_pos = (int(item["x"]) * 1e-7, int(item["y"]) * 1e-7)
            self._target_alt = max(float(item["z"]), 0.0) if self.armed else None
            why = "guided target set"
        src = self._src(msg)
        return Answer([mav.MAVLink_mission_ack_message(src[0], src[1], result, 0)], result, why)

    def _on_mission_request_list(self, msg: MAVLinkMessage, f: dict[str, Any],
                                 now: float) -> Iterable:
        return self._mission(msg, now, "mission_download",
                             self.missions.request_list(f, self._src(msg)))

    def _on_mission_request_int(self, msg: MAVLinkMessage, f: dict[str, Any],
                                now: float) -> Iterable:
        ans = self.missions.request_item(msg.get_type(), f, self._src(msg))
        return self._mission(msg, now, "mission_read", ans, seq=int(f["seq"]))

    _on_mission_request = _on_mission_request_int

    def _on_mission_clear_all(self, msg: MAVLinkMessage, f: dict[str, Any],
                              now: float) -> Iterable:
        ans = self.missions.clear_all(f, self._src(msg))
        if ans.result == ACCEPTED and int(f.get("mission_type", 0) or 0) == 0:
            self._auto.started = False
            self.record(now, "mission", count=0)
        return self._mission(msg, now, "mission_clear", ans)

    def _on_mission_set_current(self, msg: MAVLinkMessage, f: dict[str, Any],
                                now: float) -> Iterable:
        seq = int(f["seq"])
        ok = 0 < seq < len(self.missions.items) or (seq == 0 and len(self.missions.items) > 1)
        if ok:
            self._auto.index = max(seq, 1)
            self._auto.started, self._auto.complete = True, False
            self.missions.current = self._auto.index
        self._request(now, msg, "mission_set_current", ok, f"no item {seq}",
                      "MISSION_CURRENT" if ok else "ignored", seq=seq)
        return [self.missions.current_message()] if ok else []



def _describe(msg: MAVLinkMessage) -> str:
    """``MISSION_REQUEST seq=3``-style summary of a reply."""
    seq = getattr(msg, "seq", None)
    if msg.get_type() == "MISSION_COUNT":
        return f"MISSION_COUNT count={msg.count}"
    return msg.get_type() if seq is None else f"{msg.get_type()} seq={seq}"
