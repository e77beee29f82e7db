"""The simulated vehicle served to the MAVLink world's own client libraries, for their tests.

``served(transport)`` starts a ``SimVehicle`` the way a ground station finds ArduPilot SITL:

* ``tcp``: the vehicle listens (SITL's port 5760); the client connects out: dronekit
  ``tcp:127.0.0.1:PORT``, MAVSDK ``tcpout://127.0.0.1:PORT``, MAVProxy ``--master
  tcp:127.0.0.1:PORT``.
* ``udp``: the client listens on a free port and the vehicle sends its telemetry there, as
  SITL's ``--out udp:127.0.0.1:14550``, answering from the same socket (``vehicle.links``):
  dronekit ``udp:127.0.0.1:PORT`` (pymavlink's udp: listens), MAVSDK ``udpin://127.0.0.1:PORT``,
  MAVProxy ``--master udpin:127.0.0.1:PORT``.

Every client is closed by the helper that opened it (``mavsdk_system``, ``dronekit_vehicle``,
``MavproxyProcess``), and each checks that nothing it started outlives it: the process's
threads (Python's and native, ``/proc/self/task``) are back to what they were, the MAVProxy
process has exited. Every wait is bounded (``wait_until``). A library that is not installed
skips the test with the command that installs it (``require_*``).
"""

from __future__ import annotations

import contextlib
import os
import queue
import re
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import pytest
from pymavlink import mavutil

from mcp_conform.vehicle import SimVehicle
from mcp_conform.vehicle.links import start_for_node

MAV = mavutil.mavlink
TRANSPORTS = ("tcp", "udp")
#: Bound for anything the vehicle should do within a few telemetry ticks.
WAIT = 10.0
#: Bound for a client to connect and have what its ``wait_ready`` waits for.
CONNECT_WAIT = 20.0
#: pip lines that install each client (MAVProxy's own dependencies pull ~1 GB: OpenCV,
#: matplotlib, wxPython; headless it needs only pymavlink and pyserial).
INSTALL = {
    "dronekit": "pip install dronekit2",
    "mavsdk": "pip install 'mavsdk>=4.1' (the native binding, not mavsdk-grpc)",
    "mavproxy": "pip install --no-deps mavproxy==1.8.75 pyserial",
}


# ------------------------------------------------------------------ availability
def require_dronekit() -> Any:
    return pytest.importorskip("dronekit", reason=f"dronekit2 not installed: {INSTALL['dronekit']}")


def require_mavsdk() -> Any:
    mavsdk = pytest.importorskip("mavsdk", reason=f"mavsdk not installed: {INSTALL['mavsdk']}")
    if not hasattr(mavsdk, "Mavsdk"):
        pytest.skip(f"mavsdk is the gRPC wrapper (<4), not the native binding: {INSTALL['mavsdk']}")
    return mavsdk


def mavproxy_command() -> list[str]:
    """How to run MAVProxy with this interpreter (skips when it is not installed)."""
    pytest.importorskip("MAVProxy", reason=f"MAVProxy not installed: {INSTALL['mavproxy']}")
    pytest.importorskip("serial", reason=f"pyserial not installed: {INSTALL['mavproxy']}")
    return [sys.executable, "-m", "MAVProxy.mavproxy"]  # its mavproxy.py, this interpreter


# ------------------------------------------------------------------ the vehicle
@dataclass(frozen=True)
class Link:
    """Where a client reaches the vehicle: ``transport`` and the port the client uses."""

    transport: str
    port: int

    @property
    def pymavlink(self) -> str:
        """pymavlink/dronekit/MAVProxy URL (``udp:`` listens, as ``udpin:``)."""
        kind = "tcp" if self.transport == "tcp" else "udpin"
        return f"{kind}:127.0.0.1:{self.port}"

    @property
    def dronekit(self) -> str:
        return f"{'tcp' if self.transport == 'tcp' else 'udp'}:127.0.0.1:{self.port}"

    @property
    def mavsdk(self) -> str:
        kind = "tcpout" if self.transport == "tcp" else "udpin"
        return f"{kind}://127.0.0.1:{self.port}"


@contextlib.contextmanager
def served(transport: str, **settings: Any) -> Iterator[tuple[SimVehicle, Link]]:
    """A started ``SimVehicle(**settings)`` on ``transport`` and the ``Link`` to reach it."""
    vehicle, url = start_for_node(transport, **settings)
    try:
        yield vehicle, Link(transport, int(url.rsplit(":", 1)[1]))
    finally:
        vehicle.close()


# ------------------------------------------------------------------ waiting
def wait_until(predicate: Callable[[], Any], timeout: float, what: str,
               show: Callable[[], Any] | None = None, every: float = 0.05) -> Any:
    """Poll ``predicate`` until it is truthy (its value is returned) or ``timeout`` s pass:
    then AssertionError naming ``what`` and, if given, ``show()`` (the state seen last)."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value:
            return value
        if time.monotonic() >= deadline:
            seen = f"; last seen: {show()}" if show is not None else ""
            raise AssertionError(f"{what}: not within {timeout:g} s{seen}")
        time.sleep(every)


def tasks() -> int:
    """Threads of this process, Python's and native (MAVSDK's C++ core runs its own)."""
    try:
        return len(os.listdir("/proc/self/task"))
    except OSError:
        return threading.active_count()


@contextlib.contextmanager
def no_thread_outlives(what: str) -> Iterator[None]:
    """The block's threads are gone (within 3 s) when it ends, whether it failed or not."""
    before = tasks()
    python_before = set(threading.enumerate())
    failed = False
    try:
        yield
    except BaseException:
        failed = True
        raise
    finally:
        if not failed:
            wait_until(lambda: tasks() <= before, 3.0, f"threads left after {what}",
                       show=lambda: (tasks(), before, [t.name for t in threading.enumerate()
                                                       if t not in python_before]))


# ------------------------------------------------------------------ geometry
def north_east_m(lat0: float, lon0: float, lat1: float, lon1: float) -> tuple[float, float]:
    """Metres north and east from (lat0, lon0) to (lat1, lon1) (flat earth, ample here)."""
    import math

    north = (lat1 - lat0) * 111_320.0
    east = (lon1 - lon0) * 111_320.0 * math.cos(math.radians(lat0))
    return north, east


# ------------------------------------------------------------------ the record
#: The messages that carry a request to the autopilot (``vehicle.records.REQUESTS``: each one
#: is a request event, a line of ``--record``, with the answer and the reason).
REQUEST_MESSAGES = (
    "COMMAND_LONG", "COMMAND_INT", "SET_MODE", "REQUEST_DATA_STREAM",
    "SET_POSITION_TARGET_LOCAL_NED", "SET_POSITION_TARGET_GLOBAL_INT",
    "PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET", "FILE_TRANSFER_PROTOCOL",
    "MISSION_COUNT", "MISSION_ITEM", "MISSION_ITEM_INT", "MISSION_REQUEST_LIST",
    "MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT",
)


def unrecorded_requests(sim: SimVehicle, sysid: int = 1) -> list[str]:
    """What a client asked of this vehicle that has no request line of its own (issue 35:
    "--record holds a line for every request the peer made, with the answer and the reason"):
    per message type and sender, the frames addressed to the vehicle (or to every system)
    against the request events that came by that message; and request lines without their
    answer, or denied without a reason. Empty when the record is whole."""
    asked: dict[tuple[str, int, int], int] = {}
    for f in sim.frames():
        if f.msg_type in REQUEST_MESSAGES and f.fields.get("target_system") in (0, sysid):
            key = (f.msg_type, f.srcsys, f.srccomp)
            asked[key] = asked.get(key, 0) + 1
    recorded: dict[tuple[str, int, int], int] = {}
    problems = []
    for e in sim.events("request"):
        d = e.detail
        key = (str(d.get("via")), int(d.get("srcsys") or 0), int(d.get("srccomp") or 0))
        recorded[key] = recorded.get(key, 0) + 1
        if not d.get("answer") or (d.get("result") != "accepted" and not d.get("reason")):
            problems.append(f"request without its answer or reason: {d}")
    problems += [f"{n} {t} from {s}:{c}, {recorded.get((t, s, c), 0)} recorded"
                 for (t, s, c), n in sorted(asked.items()) if recorded.get((t, s, c), 0) < n]
    return problems


# ------------------------------------------------------------------ pymavlink
def pymavlink_params(link: Link, timeout: float = WAIT) -> dict[str, float]:
    """Every parameter by a plain PARAM_REQUEST_LIST (the reference a library is compared to)."""
    conn = mavutil.mavlink_connection(link.pymavlink, source_system=250)
    try:
        hb = None
        deadline = time.monotonic() + timeout
        while hb is None and time.monotonic() < deadline:
            conn.mav.heartbeat_send(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        assert hb is not None, f"no HEARTBEAT from the vehicle within {timeout:g} s"
        conn.mav.param_request_list_send(hb.get_srcSystem(), hb.get_srcComponent())
        got: dict[str, float] = {}
        count = None
        while time.monotonic() < deadline and (count is None or len(got) < count):
            m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if m is not None:
                got[m.param_id] = m.param_value
                count = m.param_count
        assert count is not None and len(got) == count, (
            f"PARAM_REQUEST_LIST: {len(got)} of {count} parameters within {timeout:g} s")
        return got
    finally:
        conn.close()


# ------------------------------------------------------------------ dronekit
@contextlib.contextmanager
def dronekit_vehicle(link: Link, **kwargs: Any) -> Iterator[Any]:
    """``dronekit.connect(link, **kwargs)`` (bounded), closed at the end; no thread outlives."""
    dronekit = require_dronekit()
    with no_thread_outlives("dronekit's close()"):
        kwargs.setdefault("timeout", CONNECT_WAIT)
        kwargs.setdefault("heartbeat_timeout", CONNECT_WAIT)
        vehicle = dronekit.connect(link.dronekit, **kwargs)
        try:
            yield vehicle
        finally:
            vehicle.close()


# ------------------------------------------------------------------ MAVSDK
class MavsdkLog:
    """MAVSDK's log lines, kept (not printed) for failure messages; installed once."""

    lines: list[str] = []
    _installed = False

    @classmethod
    def install(cls, mavsdk: Any) -> None:
        if cls._installed:
            return

        def keep(level: Any, message: str, _file: Any, _line: int) -> bool:
            cls.lines.append(f"{level.name} {message}")
            del cls.lines[:-200]
            return True  # not printed

        mavsdk.log_subscribe(keep)
        cls._installed = True

    @classmethod
    def tail(cls, n: int = 15) -> str:
        return "\n".join(cls.lines[-n:])


@contextlib.contextmanager
def mavsdk_system(link: Link) -> Iterator[Any]:
    """A MAVSDK ground station connected to the vehicle and its autopilot ``System``; every
    MAVSDK object destroyed at the end and its native threads gone."""
    mavsdk = require_mavsdk()
    MavsdkLog.install(mavsdk)
    with no_thread_outlives("Mavsdk.destroy()"):
        config = mavsdk.Configuration.create_with_component_type(
            mavsdk.ComponentType.GROUND_STATION)
        sdk = mavsdk.Mavsdk(config)
        try:
            result = sdk.add_any_connection(link.mavsdk)
            assert result == mavsdk.ConnectionResult.SUCCESS, f"{link.mavsdk}: {result!r}"
            system = sdk.first_autopilot(CONNECT_WAIT)
            assert system is not None, (
                f"MAVSDK found no autopilot on {link.mavsdk} within {CONNECT_WAIT:g} s\n"
                f"{MavsdkLog.tail()}")
            yield system
        finally:
            sdk.destroy()
            config.destroy()


# ------------------------------------------------------------------ MAVProxy
class MavproxyProcess:
    """MAVProxy as its own process, on the vehicle's link, without state files or GUI.

    ``console=False``: headless as a companion computer runs it (``--daemon
    --non-interactive``), commands only from ``--cmd``. ``console=True``: its console reads
    commands from a pipe (``send``), as ArduPilot's autotest drives it (over a pty there);
    --daemon and --non-interactive both stop MAVProxy reading its input, and ``--cmd`` runs
    before the first heartbeat, so a session of commands needs the console. Output lines are
    kept with the time they came (``expect``). ``close()`` ends it (SIGTERM, then SIGKILL).
    """

    def __init__(self, link: Link, workdir: str, *, console: bool = False,
                 extra: tuple[str, ...] = ()) -> None:
        args = mavproxy_command() + ["--master", link.pymavlink, "--no-state",
                                     "--state-basedir", workdir, *extra]
        if not console:
            args += ["--daemon", "--non-interactive"]
        self.lines: list[tuple[float, str]] = []
        self._new: queue.Queue[tuple[float, str]] = queue.Queue()
        self.started = time.monotonic()
        env = dict(os.environ, PYTHONUNBUFFERED="1", TERM="dumb")
        self.proc = subprocess.Popen(
            args, cwd=workdir, env=env, text=True, bufsize=1, errors="replace",
            stdin=subprocess.PIPE if console else subprocess.DEVNULL,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        self._reader = threading.Thread(target=self._read, name="mavproxy-out", daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            item = (time.monotonic() - self.started, line.rstrip("\n"))
            self.lines.append(item)
            self._new.put(item)

    def send(self, command: str) -> None:
        assert self.proc.stdin is not None, "MAVProxy was started without its console"
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def expect(self, pattern: str, timeout: float = WAIT) -> tuple[float, re.Match[str]]:
        """The first line from now on that matches ``pattern`` (its time since start)."""
        regex = re.compile(pattern)
        deadline = time.monotonic() + timeout
        while True:
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                raise AssertionError(
                    f"MAVProxy printed no line matching {pattern!r} within {timeout:g} s; "
                    f"its last lines:\n{self.tail()}")
            try:
                t, line = self._new.get(timeout=min(remaining, 0.2))
            except queue.Empty:
                ended = self.proc.poll() is not None and not self._reader.is_alive()
                if ended and self._new.empty():
                    raise AssertionError(f"MAVProxy exited ({self.proc.returncode}) before "
                                         f"{pattern!r}; its last lines:\n{self.tail()}") from None
                continue
            found = regex.search(line)
            if found:
                return t, found

    def printed(self, pattern: str) -> list[str]:
        """Every line so far that matches ``pattern``."""
        regex = re.compile(pattern)
        return [line for _, line in list(self.lines) if regex.search(line)]

    def tail(self, n: int = 25) -> str:
        return "\n".join(f"{t:7.3f} {line}" for t, line in list(self.lines)[-n:])

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5.0)
        if self.proc.stdin is not None:
            with contextlib.suppress(OSError):
                self.proc.stdin.close()
        self._reader.join(5.0)
        assert self.proc.returncode is not None and not self._reader.is_alive()

    def __enter__(self) -> MavproxyProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
