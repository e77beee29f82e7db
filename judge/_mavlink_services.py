"""The MAVLink trace monitor's parameter and mission rules (``judge.mavlink_monitor``).

:class:`ParamService`, the parameter protocol (https://mavlink.io/en/services/parameter.html):
a list (PARAM_REQUEST_LIST) answered within param_reply_max_s (MAV-PRM-1; to component 0,
MAV-PRM-13) and, once param_list_gap_max_s passes with no PARAM_VALUE (the runner's
``param_list`` waits as long), one param_count throughout and every index 0..count-1 with
one name (MAV-PRM-2, D-5: an index of param_count or more, ArduPilot's 65535 (E-8), is no
list entry); an index named otherwise later, or param_count changed (MAV-PRM-6); a read by
name (MAV-PRM-4) or index (MAV-PRM-5) and a PARAM_SET (MAV-PRM-7) of a parameter the trace
has seen answered within param_reply_max_s; a name a whole list did not have never named by
a PARAM_VALUE after it was asked for (MAV-PRM-11); param_id's bytes (MAV-PRM-9) and
param_type (MAV-PRM-10: a MAV_PARAM_TYPE, one per name); the ground station's PARAM_SET of
a listed parameter with its listed type (MAV-PRM-17).

:class:`MissionService`, the mission protocol (https://mavlink.io/en/services/mission.html):
the upload handshake of MAV-MIS-1 (MISSION_COUNT answered by a request for seq 0, each item
by the request for the next, the last by MISSION_ACK MAV_MISSION_ACCEPTED with the upload's
mission_type; either request, E-9), in order (MAV-MIS-2), an item that did not come
requested again within mission_rerequest_max_s (MAV-MIS-3), count 0 answered at once
(MAV-MIS-14); the download (MAV-MIS-8: MISSION_COUNT, then each requested item, an error
MISSION_ACK past the end) and its round trip against the last accepted upload (MAV-MIS-9,
from seq 1 on an ArduPilot: E-3); MISSION_CLEAR_ALL answered (MAV-MIS-13); mission_type
values (MAV-MIS-17); the ground station's items only as requested (MAV-MIS-20) with seq
0..count-1 and its count's mission_type (MAV-MIS-21).
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.judge._mavlink_link import Evidence, Node, Service, name_of
from mcp_conform.spec import MAVLINK
from mcp_conform.traceio.mavlink import MavFrame

DIALECT: Any = MAVLINK.dialect
PARAM_TYPES = {int(v): e.name for v, e in DIALECT.enums["MAV_PARAM_TYPE"].items() if not e.name.endswith("_ENUM_END")}
MISSION_TYPES = {int(v): e.name for v, e in DIALECT.enums["MAV_MISSION_TYPE"].items()
                 if not e.name.endswith("_ENUM_END")}
MISSION_RESULTS = {int(v): e.name for v, e in DIALECT.enums["MAV_MISSION_RESULT"].items()
                   if not e.name.endswith("_ENUM_END")}
ACCEPTED = int(DIALECT.MAV_MISSION_ACCEPTED)
#: E-1: "A MISSION_ACK returning an error value (NACK) does not terminate the upload" when it is
#: ArduPilot's answer to an item out of sequence (it then re-requests the expected item)
INVALID_SEQUENCE = int(DIALECT.MAV_MISSION_INVALID_SEQUENCE)
TYPE_ALL = int(DIALECT.MAV_MISSION_TYPE_ALL)
REQUESTS = ("MISSION_REQUEST_INT", "MISSION_REQUEST")
ITEMS = ("MISSION_ITEM_INT", "MISSION_ITEM")
#: what a round trip compares of an item (as the runner's case does: MAV-MIS-9)
ITEM_KEYS = ("command", "frame", "x", "y", "z", "param1", "param2", "param3", "param4")


def param_id(msg: Any) -> str:
    raw = msg.param_id
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\0", 1)[0]


def raw_fields(f: MavFrame) -> dict[str, Any]:
    """A frame's fields as its bytes hold them (char arrays before pymavlink cuts them)."""
    cls = type(f.msg)
    start = 10 if f.version == 2 else 6
    payload = f.raw[start:start + f.raw[1]]
    payload = payload + bytes(max(0, cls.unpacker.size - len(payload)))
    return dict(zip(cls.ordered_fieldnames, cls.unpacker.unpack(payload[:cls.unpacker.size]), strict=True))


def addressed(msg: Any, v: Node) -> bool:
    """A request to vehicle ``v``: its system, its component or every component (0)."""
    return int(msg.target_system) == v.sysid and int(msg.target_component) in (0, v.compid)


def _ev(f: MavFrame) -> tuple[Evidence, tuple[int, ...]]:
    return Evidence(f), (f.index,)


@dataclass
class ParamList:
    """One PARAM_REQUEST_LIST's PARAM_VALUEs, while they come."""

    start_ns: int
    index: int
    last_ns: int | None = None
    counts: set[int] = field(default_factory=set)
    names: dict[int, set[str]] = field(default_factory=dict)


class ParamService(Service):
    RULES = ("MAV-PRM-1", "MAV-PRM-2", "MAV-PRM-4", "MAV-PRM-5", "MAV-PRM-6", "MAV-PRM-7", "MAV-PRM-9",
             "MAV-PRM-10", "MAV-PRM-11", "MAV-PRM-13", "MAV-PRM-17")

    def __init__(self, mon: Any) -> None:
        super().__init__(mon)
        self.reply = float(self.p["param_reply_max_s"])
        self.gap_ns = int(float(self.p["param_list_gap_max_s"]) * 1e9)
        self.list_ns = int(float(self.p["param_list_max_s"]) * 1e9)
        #: (vehicle, name) -> until when a PARAM_VALUE naming it breaks MAV-PRM-11
        self.absent: dict[tuple[tuple[int, int], str], int] = {}

    def handlers(self) -> dict[str, Any]:
        return {"PARAM_REQUEST_LIST": self.request_list, "PARAM_REQUEST_READ": self.request_read,
                "PARAM_SET": self.set, "PARAM_VALUE": self.value}

    @staticmethod
    def state(v: Node) -> dict[str, Any]:
        return v.state.setdefault("prm", {"list": None, "count": None, "by_index": {}, "types": {}, "listed": None})

    def request_list(self, g: Node, f: MavFrame) -> None:
        for v in self.mon.vehicles():
            if not addressed(f.msg, v):
                continue
            st = self.state(v)
            if st["list"] is None:
                lst = st["list"] = ParamList(f.t_ns, f.index)
                for r in self.mon.recent_from(v, f.t_ns):  # answers stamped first (ORDER_SLACK_S)
                    if r.name == "PARAM_VALUE":
                        self._listed(lst, r)
            rule = "MAV-PRM-13" if int(f.msg.target_component) == 0 else "MAV-PRM-1"
            self.mon.expect(v, self.reply, rule, lambda r: r.name == "PARAM_VALUE",
                            f"after PARAM_REQUEST_LIST (#{f.index}), PARAM_VALUEs within {self.reply:g} s",
                            (f.index,), f.t_ns, lambda: "no PARAM_VALUE")

    def request_read(self, g: Node, f: MavFrame) -> None:
        m = f.msg
        index, name = int(m.param_index), param_id(m)
        for v in self.mon.vehicles():
            if not addressed(m, v):
                continue
            st = self.state(v)
            if index >= 0:
                if st["count"] is not None and index < st["count"]:
                    self.mon.expect(v, self.reply, "MAV-PRM-5", lambda r, i=index: r.name == "PARAM_VALUE"
                                    and int(r.msg.param_index) == i,
                                    f"after PARAM_REQUEST_READ of index {index} (#{f.index}), its PARAM_VALUE "
                                    f"within {self.reply:g} s", (f.index,), f.t_ns)
            else:
                self._named(v, name, "MAV-PRM-4", f, "PARAM_REQUEST_READ")

    def _named(self, v: Node, name: str, rule: str, f: MavFrame, what: str) -> None:
        st = self.state(v)
        if name in st["types"]:
            self.mon.expect(v, self.reply, rule, lambda r, n=name: r.name == "PARAM_VALUE" and param_id(r.msg) == n,
                            f"after {what} of {name!r} (#{f.index}), its PARAM_VALUE within {self.reply:g} s",
                            (f.index,), f.t_ns)
        elif st["listed"] is not None and name not in st["listed"]:
            self.absent[(v.key, name)] = f.t_ns + int(self.reply * 1e9)

    def set(self, g: Node, f: MavFrame) -> None:
        m = f.msg
        name = param_id(m)
        for v in self.mon.vehicles():
            if not addressed(m, v):
                continue
            self._named(v, name, "MAV-PRM-7", f, "PARAM_SET")
            st = self.state(v)
            if st["listed"] is not None:
                want = st["types"].get(name)
                self.mon.judge("MAV-PRM-17", g, want is not None and int(m.param_type) == want, f.t_ns,
                               "PARAM_SET of a listed parameter, with its listed param_type",
                               f"{name!r} " + ("is no parameter of the vehicle" if want is None else
                                               f"with {name_of(PARAM_TYPES, m.param_type)}, listed "
                                               f"{name_of(PARAM_TYPES, want)}"), *_ev(f))

    def value(self, v: Node, f: MavFrame) -> None:
        mon, m, t = self.mon, f.msg, f.t_ns
        st = self.state(v)
        name, index, count, ptype = param_id(m), int(m.param_index), int(m.param_count), int(m.param_type)
        ev = _ev(f)
        raw = raw_fields(f)["param_id"].split(b"\0", 1)[0]
        mon.judge("MAV-PRM-9", v, bool(raw) and all(0x20 < b < 0x7F for b in raw), t,
                  "param_id printable ASCII up to its NUL, 1..16 characters", f"param_id {raw!r}", *ev)
        seen = st["types"].setdefault(name, ptype)
        mon.judge("MAV-PRM-10", v, ptype in PARAM_TYPES and seen == ptype, t,
                  "param_type a MAV_PARAM_TYPE, the same in every PARAM_VALUE of the parameter",
                  f"{name}: param_type {name_of(PARAM_TYPES, ptype)}"
                  + ("" if seen == ptype else f", earlier {name_of(PARAM_TYPES, seen)}"), *ev)
        until = self.absent.get((v.key, name))
        if until is not None:
            mon.judge("MAV-PRM-11", v, False, t, f"no PARAM_VALUE naming {name!r}, which the list had not",
                      "a PARAM_VALUE names it", *ev)
            del self.absent[(v.key, name)]
        lst: ParamList | None = st["list"]
        if lst is not None:
            self._listed(lst, f)
            return
        if st["count"] is not None:
            mon.judge("MAV-PRM-6", v, count == st["count"], t, f"param_count {st['count']} while the link is up",
                      f"param_count {count}", *ev)
        known = st["by_index"].get(index)
        if index < count and known is not None:
            mon.judge("MAV-PRM-6", v, known == name, t, f"index {index} named {known!r}, as the list gave it",
                      repr(name), *ev)

    @staticmethod
    def _listed(lst: ParamList, f: MavFrame) -> None:
        index, count = int(f.msg.param_index), int(f.msg.param_count)
        lst.last_ns = f.t_ns
        lst.counts.add(count)
        if index < count:
            lst.names.setdefault(index, set()).add(param_id(f.msg))

    def advance(self, t_ns: int) -> None:
        for key, until in list(self.absent.items()):
            if until < t_ns:
                del self.absent[key]
                v = self.mon.nodes.get(key[0])
                if v is not None:
                    self.mon.judge("MAV-PRM-11", v, True, until)
        for v in self.mon.vehicles():
            lst = v.state.get("prm", {}).get("list")
            if lst is None:
                continue
            quiet = lst.last_ns is not None and t_ns - lst.last_ns > self.gap_ns
            never = lst.last_ns is None and t_ns - lst.start_ns > int(self.reply * 1e9)
            if quiet or never or t_ns - lst.start_ns > self.list_ns:
                self._close(v, lst, t_ns)

    def finish(self, end_ns: int) -> None:
        for v in self.mon.vehicles():
            lst = v.state.get("prm", {}).get("list")
            if lst is not None and lst.last_ns is not None and end_ns - lst.last_ns >= self.gap_ns:
                self._close(v, lst, end_ns)

    def _close(self, v: Node, lst: ParamList, t_ns: int) -> None:
        """A list ended: MAV-PRM-2 on all it had (MAV-PRM-6 against the lists before it)."""
        st = self.state(v)
        st["list"] = None
        if lst.last_ns is None:
            return  # no answer: MAV-PRM-1's (its expectation)
        mon = self.mon
        counts = sorted(lst.counts)
        ev = (f"#{lst.index} PARAM_REQUEST_LIST",), (lst.index,)
        if len(counts) != 1:
            mon.judge("MAV-PRM-2", v, False, lst.last_ns, "one param_count in every PARAM_VALUE of the list",
                      f"param_count {counts}", *ev)
            return
        count = counts[0]
        missing = [i for i in range(count) if i not in lst.names]
        twice = {i: sorted(n) for i, n in lst.names.items() if len(n) > 1}
        mon.judge("MAV-PRM-2", v, not missing and not twice, lst.last_ns, f"indices 0..{count - 1} each with one name",
                  f"{len(missing)} missing {missing[:8]}, {len(twice)} with two names {dict(list(twice.items())[:3])}",
                  *ev)
        if st["count"] is not None:
            mon.judge("MAV-PRM-6", v, count == st["count"], lst.last_ns,
                      f"param_count {st['count']} while the link is up", f"param_count {count}", *ev)
        for i, names in lst.names.items():
            known = st["by_index"].get(i)
            if known is not None and len(names) == 1 and known not in names:
                mon.judge("MAV-PRM-6", v, False, lst.last_ns, f"index {i} named {known!r}, as the list gave it",
                          repr(sorted(names)[0]), *ev)
                break
            st["by_index"][i] = sorted(names)[0]
        st["count"] = count
        if not missing:
            st["listed"] = {n for names in lst.names.values() for n in names}


@dataclass
class Upload:
    """One upload to a vehicle: what the ground station said it sends and what came."""

    gcs: tuple[int, int]
    count: int
    mtype: int
    index: int
    last_req: int | None = None
    req_ns: int = 0
    items: dict[int, Any] = field(default_factory=dict)
    rerequested: set[int] = field(default_factory=set)
    watched: set[int] = field(default_factory=set)
    ended: bool = False  # the vehicle's MISSION_ACK came
    accepted: bool = False  # ... and accepted it
    t_ns: int = 0  # its MISSION_COUNT's time
    #: the upload still in progress its MISSION_COUNT replaced: a request of that one may cross
    #: this one's count on the link (:meth:`MissionService.crossed`)
    before: Upload | None = None


@dataclass
class Download:
    gcs: tuple[int, int]
    mtype: int
    count: int | None = None
    items: dict[int, Any] = field(default_factory=dict)


def item_of(msg: Any) -> dict[str, Any]:
    return {k: getattr(msg, k) for k in ITEM_KEYS} | {"kind": msg.get_type()}


class MissionService(Service):
    RULES = ("MAV-MIS-1", "MAV-MIS-2", "MAV-MIS-3", "MAV-MIS-8", "MAV-MIS-9", "MAV-MIS-13", "MAV-MIS-14",
             "MAV-MIS-17", "MAV-MIS-20", "MAV-MIS-21")

    def __init__(self, mon: Any) -> None:
        super().__init__(mon)
        self.reply = float(self.p["mission_reply_max_s"])
        self.rerequest_ns = int(float(self.p["mission_rerequest_max_s"]) * 1e9)

    def handlers(self) -> dict[str, Any]:
        return {"*": self.mission_type, "MISSION_COUNT": self.count, "MISSION_REQUEST_INT": self.request,
                "MISSION_REQUEST": self.request, "MISSION_ITEM_INT": self.item, "MISSION_ITEM": self.item,
                "MISSION_ACK": self.ack, "MISSION_REQUEST_LIST": self.request_list,
                "MISSION_CLEAR_ALL": self.clear_all}

    @staticmethod
    def state(v: Node) -> dict[str, Any]:
        return v.state.setdefault("mis", {"upload": None, "download": None, "plans": {}, "clear": None,
                                          "used": deque(maxlen=256)})  # >= the monitor's recent frames

    def _targets(self, f: MavFrame) -> list[Node]:
        return [v for v in self.mon.vehicles() if addressed(f.msg, v)]

    def mission_type(self, n: Node, f: MavFrame) -> None:
        mt = getattr(f.msg, "mission_type", None)
        if mt is None or not f.name.startswith("MISSION_"):
            return
        ok = int(mt) in MISSION_TYPES and (int(mt) != TYPE_ALL or f.name == "MISSION_CLEAR_ALL")
        self.mon.judge("MAV-MIS-17", n, ok, f.t_ns, "mission_type a MAV_MISSION_TYPE, ALL only in MISSION_CLEAR_ALL",
                       f"{f.name} with mission_type {name_of(MISSION_TYPES, mt)}", *_ev(f))

    def count(self, n: Node, f: MavFrame) -> None:
        m, t = f.msg, f.t_ns
        if n.role == "vehicle":  # a download's answer
            dl = self.state(n)["download"]
            if dl is not None:
                dl.count = int(m.count)
                self._whole(n, f)
            return
        for v in self._targets(f):
            st = self.state(v)
            count, mtype = int(m.count), int(getattr(m, "mission_type", 0))
            prev: Upload | None = st["upload"]
            st["upload"] = (Upload(n.key, count, mtype, f.index, t_ns=t,
                                   before=prev if prev is not None and not prev.ended else None)
                            if count > 0 else None)
            if count > 0:
                for r in self.mon.recent_from(v, t):  # its first request stamped first (ORDER_SLACK_S)
                    if r.name in REQUESTS and r.index not in st["used"]:
                        self.request(v, r)
            if count == 0:
                self._clear(v, mtype, f)
                self.mon.expect(v, self.reply, "MAV-MIS-14", lambda r: r.name == "MISSION_ACK",
                                f"after MISSION_COUNT 0 (#{f.index}), MISSION_ACK at once", (f.index,), t)
            else:
                self.mon.expect(v, self.reply, "MAV-MIS-1", lambda r: (r.name in REQUESTS and r.msg.seq == 0)
                                or r.name == "MISSION_ACK", f"after MISSION_COUNT {count} (#{f.index}), a request "
                                f"for seq 0 within {self.reply:g} s", (f.index,), t)

    def crossed(self, up: Upload, seq: int, t: int) -> bool:
        """A request that is the replaced upload's, not ``up``'s: the first after ``up``'s
        MISSION_COUNT, sent before the vehicle could have read that count (within its answer
        time, ``reply``), and what the replaced upload in progress asked or asks next (its last
        request again, on a timeout, or the next). ArduPilot re-requests an unanswered item
        each second: one crossed a new upload's count and was judged as the new upload's first
        request out of order (MAV-MIS-2, "seq 3 after none", a fresh-clone CI run against our
        vehicle)."""
        old = up.before
        if up.last_req is not None or old is None or old.last_req is None or t - up.t_ns > self.reply * 1e9:
            return False
        if seq in (old.last_req, old.last_req + 1) and seq < old.count:
            old.last_req = seq
            return True
        return False

    def request(self, n: Node, f: MavFrame) -> None:
        m, t, mon = f.msg, f.t_ns, self.mon
        seq = int(m.seq)
        if n.role == "vehicle":
            up: Upload | None = self.state(n)["upload"]
            if up is None or up.ended:
                return  # a new upload's, whose MISSION_COUNT is stamped after it: taken up by count()
            self.state(n)["used"].append(f.index)
            if self.crossed(up, seq, t):
                return
            ok = seq < up.count and (seq == 0 if up.last_req is None else seq in (up.last_req, up.last_req + 1))
            mon.judge("MAV-MIS-2", n, ok, t, f"requests in order 0..{up.count - 1} (the last one again, or the next)",
                      f"{f.name} seq {seq} after "
                      + ("none" if up.last_req is None else f"seq {up.last_req}"), *_ev(f))
            mtype = int(getattr(m, "mission_type", 0))
            mon.judge("MAV-MIS-1", n, mtype == up.mtype, t, f"mission_type {name_of(MISSION_TYPES, up.mtype)}",
                      f"{f.name} with mission_type {name_of(MISSION_TYPES, mtype)}", *_ev(f))
            if up.last_req == seq and seq not in up.items and seq not in up.rerequested:
                up.rerequested.add(seq)
                mon.judge("MAV-MIS-3", n, True, t)
            up.last_req, up.req_ns = seq, t
            return
        for v in self._targets(f):
            dl: Download | None = self.state(v)["download"]
            if dl is None or dl.count is None:
                continue
            if seq < dl.count:
                self.mon.expect(v, self.reply, "MAV-MIS-8", lambda r, s=seq: r.name in ITEMS and r.msg.seq == s,
                                f"after {f.name} seq {seq} (#{f.index}), the item of seq {seq}", (f.index,), t)
            else:
                self.mon.expect(v, self.reply, "MAV-MIS-8", lambda r: r.name == "MISSION_ACK" and r.msg.type != ACCEPTED,
                                f"after {f.name} seq {seq} past the plan's {dl.count} (#{f.index}), an error MISSION_ACK",
                                (f.index,), t)

    def item(self, n: Node, f: MavFrame) -> None:
        m, t, mon = f.msg, f.t_ns, self.mon
        seq = int(m.seq)
        if n.role == "vehicle":
            st = self.state(n)
            dl = st["download"]
            if dl is not None:
                dl.items.setdefault(seq, item_of(m))
                self._whole(n, f)
            return
        for v in self._targets(f):
            up: Upload | None = self.state(v)["upload"]
            if up is None or up.gcs != n.key:
                continue
            mtype = int(getattr(m, "mission_type", 0))

            def asked(up: Upload = up, n: Node = n, f: MavFrame = f, seq: int = seq) -> None:
                mon.judge("MAV-MIS-20", n, up.last_req is not None and seq <= up.last_req, f.t_ns,
                          "an item only once it was requested", f"{f.name} seq {seq}, requested "
                          + ("none" if up.last_req is None else f"up to seq {up.last_req}"), *_ev(f))
            if up.last_req is not None and seq <= up.last_req:
                asked()
            else:  # its request may be stamped after it (mavlink_monitor.ORDER_SLACK_S)
                mon.later(t + mon.slack_ns, asked)
            mon.judge("MAV-MIS-21", n, seq < up.count and mtype == up.mtype, t,
                      f"seq 0..{up.count - 1}, mission_type {name_of(MISSION_TYPES, up.mtype)}",
                      f"seq {seq}, mission_type {name_of(MISSION_TYPES, mtype)}", *_ev(f))
            fresh = seq not in up.items
            up.items.setdefault(seq, item_of(m))
            if not fresh or seq != up.last_req:
                continue
            if seq == up.count - 1:
                mon.expect(v, self.reply, "MAV-MIS-1", lambda r: r.name == "MISSION_ACK",
                           f"after the last item (#{f.index}), MISSION_ACK within {self.reply:g} s", (f.index,), t)
            elif seq < up.count - 1:
                mon.expect(v, self.reply, "MAV-MIS-1", lambda r, s=seq + 1: (r.name in REQUESTS and r.msg.seq == s)
                           or r.name == "MISSION_ACK", f"after item {seq} (#{f.index}), the request for seq {seq + 1}",
                           (f.index,), t)

    def ack(self, n: Node, f: MavFrame) -> None:
        t, mon = f.t_ns, self.mon
        if n.role == "vehicle":
            st = self.state(n)
            up: Upload | None = st["upload"]
            if up is not None and not up.ended and int(f.msg.type) == INVALID_SEQUENCE:
                st["used"].append(f.index)
                return  # E-1: ArduPilot's answer to an item out of sequence; the upload goes on
            if up is not None and not up.ended:
                up.ended = True  # its last item may be stamped after this (mavlink_monitor.ORDER_SLACK_S)
                up.accepted = int(f.msg.type) == ACCEPTED
                st["used"].append(f.index)
                if int(f.msg.type) == ACCEPTED and all(s in up.items for s in range(up.count)):
                    st["plans"][up.mtype] = up.items  # now: a download may follow at once
                mon.later(t + mon.slack_ns, lambda up=up: self._uploaded(n, up, f))
            elif st["clear"] is not None:
                self._cleared(st, f)
            return
        for v in self._targets(f):
            st = self.state(v)
            up = st["upload"]
            if up is not None and up.gcs == n.key:
                st["upload"] = None  # the ground station ended (cancelled) it
                if v.ardupilot and up.items:  # part of it taken (E-2): the plan is not known
                    st["plans"].pop(up.mtype, None)
            dl: Download | None = st["download"]
            if dl is not None and dl.gcs == n.key:  # ended before it was whole: not compared
                st["download"] = None

    def _uploaded(self, v: Node, up: Upload, f: MavFrame) -> None:
        """The vehicle's MISSION_ACK ended ``up``: MAV-MIS-1 on what came before it."""
        st = self.state(v)
        current = st["upload"] is up  # not superseded meanwhile (a clear, another upload)
        if current:
            st["upload"] = None
        result, mtype = int(f.msg.type), int(getattr(f.msg, "mission_type", 0))
        whole = all(s in up.items for s in range(up.count))
        if result != ACCEPTED:
            # an error ends an upload as the protocol allows ("If an error is sent, both ends
            # ... reset themselves to the idle state"): not MAV-MIS-1's to judge but MAV-MIS-7's;
            # on an ArduPilot the plan is then what the items it took made of it (E-2: uploads
            # are not atomic), so no round trip is compared until the next accepted upload
            if v.ardupilot:
                st["plans"].pop(up.mtype, None)
            return
        if result == ACCEPTED:
            self.mon.judge("MAV-MIS-1", v, whole and result == ACCEPTED and mtype == up.mtype, f.t_ns,
                           f"MISSION_ACK MAV_MISSION_ACCEPTED, mission_type {name_of(MISSION_TYPES, up.mtype)}, "
                           f"after all {up.count} items", f"MISSION_ACK {name_of(MISSION_RESULTS, result)} "
                           f"(mission_type {name_of(MISSION_TYPES, mtype)}) after items {sorted(up.items)[:10]}",
                           *_ev(f))
        if whole and result == ACCEPTED and current:
            st["plans"][up.mtype] = up.items

    def _whole(self, v: Node, f: MavFrame) -> None:
        """A download with every item: its round trip judged now (a ground station need not
        send its MISSION_ACK: MAVProxy 1.8 sends none after ``wp list``)."""
        st = self.state(v)
        dl: Download | None = st["download"]
        if dl is not None and dl.count is not None and all(s in dl.items for s in range(dl.count)):
            st["download"] = None
            up: Upload | None = st["upload"]  # accepted, its last item stamped after the ACK?
            if up is not None and up.accepted and up.mtype == dl.mtype and all(s in up.items for s in range(up.count)):
                st["plans"][up.mtype] = up.items
            self._round_trip(v, dl, st["plans"].get(dl.mtype), f)

    def _round_trip(self, v: Node, dl: Download, plan: dict[int, Any] | None, f: MavFrame) -> None:
        """MAV-MIS-9: the plan downloaded is the last one accepted (E-3: from seq 1 on an ArduPilot)."""
        if plan is None or dl.count is None or any(s not in dl.items for s in range(dl.count)):
            return
        home = 1 if v.ardupilot else 0
        ev = _ev(f)
        if dl.count != len(plan) and not (not plan and dl.count <= home):
            self.mon.judge("MAV-MIS-9", v, False, f.t_ns, f"{len(plan)} items, as uploaded",
                           f"MISSION_COUNT {dl.count}", *ev)
            return
        bad = []
        for seq in range(home, dl.count):
            want, have = plan.get(seq), dl.items[seq]
            if want is None or want["kind"] != have["kind"]:
                continue  # items of the deprecated message against INT ones: not compared
            diff = [k for k in ITEM_KEYS if abs(float(want[k]) - float(have[k])) > 1e-3]
            if diff:
                bad.append(f"seq {seq}: {', '.join(f'{k} {want[k]} -> {have[k]}' for k in diff)}")
        self.mon.judge("MAV-MIS-9", v, not bad, f.t_ns, f"items {home}..{dl.count - 1} as uploaded", "; ".join(bad[:3]),
                       *ev)

    def request_list(self, g: Node, f: MavFrame) -> None:
        for v in self._targets(f):
            dl = self.state(v)["download"] = Download(g.key, int(getattr(f.msg, "mission_type", 0)))
            for r in self.mon.recent_from(v, f.t_ns):  # an answer stamped first (ORDER_SLACK_S)
                if r.name == "MISSION_COUNT":
                    dl.count = int(r.msg.count)
                    self._whole(v, r)
            self.mon.expect(v, self.reply, "MAV-MIS-8", lambda r: r.name == "MISSION_COUNT",
                            f"after MISSION_REQUEST_LIST (#{f.index}), MISSION_COUNT within {self.reply:g} s",
                            (f.index,), f.t_ns)

    def _clear(self, v: Node, mtype: int, f: MavFrame) -> None:
        """A clear of ``mtype`` asked of ``v`` (MISSION_CLEAR_ALL, MISSION_COUNT 0): its plan is
        empty once a MISSION_ACK accepts it."""
        st = self.state(v)
        st["clear"] = mtype
        for r in self.mon.recent_from(v, f.t_ns):  # its answer stamped first (ORDER_SLACK_S)
            if r.name == "MISSION_ACK" and r.index not in st["used"]:
                self._cleared(st, r)
                break

    @staticmethod
    def _cleared(st: dict[str, Any], ack: MavFrame) -> None:
        st["used"].append(ack.index)
        if int(ack.msg.type) == ACCEPTED:
            for k in (list(MISSION_TYPES) if st["clear"] == TYPE_ALL else [st["clear"]]):
                st["plans"][k] = {}
            if st["upload"] is not None and st["upload"].ended:
                st["upload"] = None  # the upload before it is over: its plan cleared
        st["clear"] = None

    def clear_all(self, g: Node, f: MavFrame) -> None:
        for v in self._targets(f):
            self._clear(v, int(getattr(f.msg, "mission_type", 0)), f)
            self.mon.expect(v, self.reply, "MAV-MIS-13", lambda r: r.name == "MISSION_ACK",
                            f"after MISSION_CLEAR_ALL (#{f.index}), MISSION_ACK within {self.reply:g} s",
                            (f.index,), f.t_ns)

    def advance(self, t_ns: int) -> None:
        """MAV-MIS-3: a request whose item did not come is sent again within its bound."""
        for v in self.mon.vehicles():
            up = v.state.get("mis", {}).get("upload")
            if up is None or up.last_req is None:
                continue
            seq = up.last_req
            if seq in up.items or seq in up.rerequested or seq in up.watched:
                continue
            if t_ns - up.req_ns > self.rerequest_ns:
                up.watched.add(seq)
                self.mon.judge("MAV-MIS-3", v, False, up.req_ns + self.rerequest_ns,
                               f"seq {seq} requested again within {self.rerequest_ns / 1e9:g} s (its item did not come)",
                               "no request again", (f"the upload's MISSION_COUNT #{up.index}",), (up.index,))
