"""The ground station under test in the simulator (issue 38, item 2; the gcs role's far end,
:mod:`sim.gcs_role`): the reference GCS itself (``reference_impl.mavlink_gcs.ReferenceGcs``,
the program ``mcp-node --protocol mavlink gcs`` runs) or one of its faults
(:data:`sim.gcs_faults.FAULTS`), its code run unchanged on the run's
:class:`harness.clock.VirtualClock`: only its seams are the simulator's --

- its pymavlink connection (:class:`SimMavConn`, for ``mavutil.mavlink_connection``'s): the
  dialect's ``MAVLink`` encoder writing to the simulated link, and ``recv_match`` on the
  virtual clock; as pymavlink's ``mavfile`` it starts in MAVLink 1 unless ``MAVLINK20`` is set
  (``ReferenceGcs.mavlink2_first``) and switches to a fresh MAVLink 2 encoder, its sequence
  numbers from 0 again, when the first bytes it reads start a MAVLink 2 frame
  (``mavfile.auto_mavlink_version``); as pymavlink's ``udpin`` it sends nothing until it has
  heard a peer (``mavudp.write``);
- its clock: ``recv``'s timeout and ``command``'s wait after MAV_RESULT_IN_PROGRESS read
  ``ReferenceGcs.now``, the clock's here (:class:`SimGcsSeam`);
- its threads (the heartbeat's) and its ``main``: :class:`GcsProcess` runs ``main``'s steps
  in order with ``build_parser``'s defaults, in a clock thread, and reads as the session's
  spawned process (``alive``, ``returncode``, ``stop``); a stop is SIGTERM: the model's next
  call on its connection ends it.
"""

from __future__ import annotations

import traceback
from collections import deque
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.reference_impl.mavlink_gcs import ReferenceGcs, build_parser, mav
from mcp_conform.sim.gcs_faults import FAULTS
from mcp_conform.traceio.mavlink import MARKERS, version_of

__all__ = ["GcsProcess", "Killed", "SimGcsSeam", "SimMavConn", "gcs_class"]

#: the source IDs ``ReferenceGcs`` opens its connection with
SOURCE = (255, int(mav.MAV_COMP_ID_MISSIONPLANNER))


class Killed(BaseException):  # noqa: N818 - a signal, not an error
    """The ground station's process was stopped (SIGTERM): raised in its threads at their next
    call on the connection."""


class SimMavConn:
    """The ground station's pymavlink connection on the simulated link (module docstring):
    ``send_bytes(data)`` carries what it writes to the runner; :meth:`arrive` (a clock callback)
    is what the runner sent; ``listens``: pymavlink's ``udpin``, silent until it heard a peer."""

    def __init__(self, clock: VirtualClock, send_bytes: Callable[[bytes], None], *, mavlink2_first: bool = True,
                 listens: bool = False, on_close: Callable[[], None] | None = None) -> None:
        self.clock, self.send_bytes, self.listens, self.on_close = clock, send_bytes, listens, on_close
        # mavfile's own MAVLink object, not traceio's robust_parser: the encoder and parser at once
        # (written to this connection, with the GCS's source IDs), of MAVLink 1's or 2's dialect
        self.mav = (mavlink2 if mavlink2_first else mavlink1).MAVLink(self, srcSystem=SOURCE[0], srcComponent=SOURCE[1])
        self.mav.robust_parsing = True
        self.version = 2 if mavlink2_first else 1
        self.first_byte = True
        self.heard = False
        self.killed = self.closed = False
        self._cond = clock.condition()
        self._chunks: deque[bytes] = deque()
        self._msgs: deque[Any] = deque()

    # -- the link's side ------------------------------------------------------------------
    def arrive(self, data: bytes) -> None:
        with self._cond:
            if not self.closed:
                self._chunks.append(data)
                self._cond.notify_all()

    def kill(self) -> None:
        """SIGTERM: every thread of the ground station ends at its next call here."""
        with self._cond:
            self.killed = True
            self._cond.notify_all()

    # -- pymavlink's mavfile, as ReferenceGcs uses it ----------------------------------------
    def write(self, buf: bytes) -> None:
        if self.killed:
            raise Killed
        if self.closed or (self.listens and not self.heard):
            return  # mavudp.write: a udpin port has no peer to send to yet
        self.send_bytes(bytes(buf))

    def _parse(self) -> None:
        """The chunks read so far parsed, as ``mavfile.recv_msg`` does (held: the condition)."""
        while self._chunks:
            data = self._chunks.popleft()
            self.heard = True
            if self.first_byte and data[:1] and data[0] in MARKERS:
                self.first_byte = False
                if version_of(data) == 2 and self.version != 2:  # auto_mavlink_version: a fresh encoder
                    self.version = 2
                    self.mav = mavlink2.MAVLink(self, srcSystem=SOURCE[0], srcComponent=SOURCE[1])
                    self.mav.robust_parsing = True
            self._msgs.extend(self.mav.parse_buffer(data) or [])

    def recv_match(self, condition: Any = None, type: Any = None, blocking: bool = False,  # noqa: A002 - pymavlink's
                   timeout: float | None = None) -> Any | None:
        """The next message of ``type`` (a name or a list), waiting up to ``timeout`` s on the
        clock when ``blocking``; None when none came."""
        types = [type] if isinstance(type, str) else type
        end = None if timeout is None else self.clock.monotonic() + timeout
        with self._cond:
            while True:
                if self.killed:
                    raise Killed
                self._parse()
                while self._msgs:
                    msg = self._msgs.popleft()
                    if types is None or msg.get_type() in types:
                        return msg
                if not blocking or self.closed:
                    return None
                left = None if end is None else end - self.clock.monotonic()
                if left is not None and left <= 0:
                    return None
                self._cond.wait(0.05 if left is None else left)

    def close(self) -> None:
        with self._cond:
            if self.closed:
                return
            self.closed = True
            self._cond.notify_all()
        if self.on_close is not None:
            self.on_close()


class _ClockThread:
    """``threading.Thread``'s reading for ``ReferenceGcs._beater`` (``start``, ``is_alive``,
    ``join``), on the clock; a :class:`Killed` ends it."""

    def __init__(self, clock: VirtualClock, target: Callable[[], None], name: str) -> None:
        self.clock, self.target, self.name = clock, target, name
        self.handle: Any = None

    def _run(self) -> None:
        try:
            self.target()
        except Killed:
            pass

    def start(self) -> None:
        self.handle = self.clock.start_thread(self._run, self.name)

    def is_alive(self) -> bool:
        return self.handle is not None and self.handle.is_alive()

    def join(self, timeout: float | None = None) -> None:
        if self.handle is not None:
            self.handle.join(timeout)


class SimGcsSeam(ReferenceGcs):
    """``ReferenceGcs``'s seams on the simulator's (module docstring); first in the MRO of a
    ground station class (:func:`gcs_class`), so a fault's hooks stay its own."""

    def __init__(self, conn: SimMavConn, clock: VirtualClock, log: Callable[[str], None]) -> None:
        # ReferenceGcs.__init__ less the connection it opens and the environment it sets
        self.conn, self.clock, self.log = conn, clock, log
        self.target = (0, 0)
        self.position = (0, 0)
        self._lock = clock.condition()  # type: ignore[assignment]  # a mutex, held only while a frame is packed
        self._stop = clock.event()
        self._beater = _ClockThread(clock, self._beat, "gcs-heartbeat")  # type: ignore[assignment]

    def now(self) -> float:
        return self.clock.monotonic()


def gcs_class(fault: str | None) -> type[SimGcsSeam]:
    """The reference GCS (``fault`` None or ``none``) or the fault's, on the simulator's seams."""
    name = fault or "none"
    base = FAULTS.get(name)
    if base is None:
        raise ValueError(f"{name}: not a ground-station fault (known: {', '.join(sorted(FAULTS))})")
    if base is ReferenceGcs:
        return SimGcsSeam
    return type(f"Sim{base.__name__}", (SimGcsSeam, base), {})


class GcsProcess:
    """A ground station's run as the session's spawned process (``harness.session_base``'s
    reading of one: ``alive``, ``returncode``, ``details``, ``evidence``, ``stop``): the steps
    of ``reference_impl.mavlink_gcs.main`` with its defaults, on the clock, its exit code 0
    (its work done), 1 (no vehicle HEARTBEAT, or an exception: its traceback as stderr) or
    -15 (stopped)."""

    def __init__(self, clock: VirtualClock, conn: SimMavConn, url: str, fault: str | None, name: str) -> None:
        self.clock, self.conn, self.name = clock, conn, name
        self.argv = [f"sim:{name}", url]
        self.stderr: list[str] = []
        self.gcs = gcs_class(fault)(conn, clock, self.stderr.append)
        self.args = build_parser().parse_args(["gcs", url])
        self.code: int | None = None
        self.stopped = False
        self.before_stop: Callable[[], None] | None = None
        self.pid = None
        self.handle = clock.start_thread(self._main, "gcs-main")

    def _main(self) -> None:
        gcs, ns = self.gcs, self.args
        name, _, text = ns.param.partition("=")
        command = [float(v) for v in ns.command.split(",")]
        code = 1
        try:
            if gcs.connect():
                items = gcs.plan(ns.mission)
                gcs.upload(items)
                gcs.fetch_params()
                gcs.set_param(name, float(text))
                gcs.command(int(command[0]), command[1:])
                gcs.command_int()
                gcs.download()
                end = self.clock.monotonic() + max(0.0, ns.linger)
                while self.clock.monotonic() < end:  # the link read, the heartbeat going
                    self.conn.recv_match(blocking=True, timeout=0.2)
                code = 0
        except Killed:
            code = -15
        except Exception:  # noqa: BLE001 - a process's crash: exit 1, its traceback on stderr
            self.stderr += traceback.format_exc().splitlines()
        finally:
            try:
                gcs.close()
            except Killed:
                code = -15
            self.code = code

    # -- the process's reading --------------------------------------------------------------
    def alive(self) -> bool:
        return self.code is None and not self.stopped

    @property
    def returncode(self) -> int | None:
        return -15 if self.stopped and self.code is None else self.code

    def run_delay(self) -> int | None:
        return None

    def output_tail(self, lines: int = 12) -> str:
        return "\n".join(self.stderr[-lines:])

    def details(self, lines: int = 12) -> dict[str, Any]:
        rc = self.returncode
        return {"command": list(self.argv), "exit": None if rc is None else f"exited with code {rc}",
                "stdout": [], "stderr": self.stderr[-lines:]}

    def evidence(self) -> list[str]:
        return [f"ground-station model: {self.name}"]

    def stop(self, grace: float = 2.0) -> None:
        hook, self.before_stop = self.before_stop, None
        if hook is not None:
            hook()
        if self.code is None and not self.stopped:
            self.stopped = True
            self.conn.kill()
            self.gcs._stop.set()

    close = stop
