"""The runner's transport in the simulator (issue 38, item 2): ``harness.driver.TargetDriver``'s
far end is a node model (:mod:`sim.models`: the reference drone over ``reference_impl.endpoint``,
or a fault of :mod:`sim.faults`) on a :class:`harness.clock.VirtualClock`, through the runner's
own seeded link per direction (``harness.impair``, as :mod:`sim.link` carries it for
:class:`sim.world.World`).

What the runner sends to the node's address (or to the broadcast address on its port) goes down
the link and is read by the model when due (``model.receive``); what the model sends goes up
the link to the address it names -- the runner's socket, or a side socket of a case
(:meth:`SimTransport.side_socket`, MCP-TRN-2) -- and is read by the driver's receiver thread as
it falls due. The model's own timer (its retransmissions, its GPS fix, its linger) is a
callback on the clock. A model that closes (its mission's end, a give-up) is a process that
exited: :class:`SimNode` says so as ``SpawnedNode`` would (exit code 0 after End_Mission, 1 for a
give-up).

With the runner's vehicle (``vehicle_net``, :mod:`sim.vehicle`) a model's autopilot client
(:mod:`sim.autopilot`) is attached to the vehicle's net at its own address while the model runs:
its frames go to the vehicle, the vehicle's to it, on the same clock.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.impair import DelayQueue, Impairment, ImpairSpec
from mcp_conform.harness.transport import Transport
from mcp_conform.sim.link import Link, check_spec
from mcp_conform.sim.models import DroneModel

__all__ = ["RUNNER_ADDR", "SimNode", "SimTransport"]

Address = tuple[str, int]
RUNNER_ADDR: Address = ("127.0.0.1", 7889)


class _Inbox:
    """Datagrams due at one of the runner's addresses, read on the virtual clock."""

    def __init__(self, clock: VirtualClock, addr: Address) -> None:
        self.clock, self.addr = clock, addr
        self.cond = clock.condition()
        self.queue: deque[tuple[bytes, Address, int]] = deque()
        self.closed = False

    def put(self, data: bytes, src: Address) -> None:
        """A datagram due here, stamped now: the kernel's receive time, which a receiver thread
        stalled before it reads it does not change (``harness.stamps``)."""
        with self.cond:
            self.queue.append((data, src, self.clock.time_ns()))
            self.cond.notify_all()


def _put(box: _Inbox, src: Address, data: bytes) -> None:
    box.put(data, src)


class SimSideSocket:
    """A case's second socket (another source port, MCP-TRN-2; the flood of MCP-ROB-7), on the
    simulated link: ``sendto``, ``recvfrom`` (non-blocking: ``BlockingIOError``), ``close``."""

    def __init__(self, transport: SimTransport, inbox: _Inbox) -> None:
        self._t, self._inbox = transport, inbox

    def sendto(self, data: bytes, addr: Address) -> int:
        self._t.deliver_down(data, addr, self._inbox.addr)
        return len(data)

    def sendto_many(self, datagrams: list[bytes], count: int, addr: Address) -> int:
        """``count`` datagrams cycling through ``datagrams`` to ``addr`` at this virtual instant:
        ``harness.driver.flood``'s loop of ``sendto`` (MCP-ROB-7), each datagram as
        :meth:`sendto` carries it; how many left (all: the simulated socket never refuses)."""
        return self._t.deliver_down_many(datagrams, count, addr, self._inbox.addr)

    def recvfrom(self, _n: int) -> tuple[bytes, Address]:
        with self._inbox.cond:
            if not self._inbox.queue:
                raise BlockingIOError("nothing due")
            data, src, _ = self._inbox.queue.popleft()
            return data, src

    def getsockname(self) -> Address:
        return self._inbox.addr

    def settimeout(self, _t: float | None) -> None:
        pass

    def close(self) -> None:
        self._t.inboxes.pop(self._inbox.addr, None)


class SimNode:
    """The model as the session's spawned process (``harness.session_base.SpawnedNode``'s
    reading: ``alive``, ``returncode``, ``evidence``, ``stop``)."""

    def __init__(self, model: DroneModel, name: str, transport: SimTransport) -> None:
        self.model, self.name, self._t = model, name, transport
        self.argv = [f"sim:{name}"]
        self.before_stop: Callable[[], None] | None = None
        self.proc = self  # ``proc.wait`` / ``proc.pid`` as a process's
        self.pid = None

    def alive(self) -> bool:
        return not self.model.closed

    @property
    def returncode(self) -> int | None:
        if not self.model.closed:
            return None
        outcome = self.model.outcome
        if outcome.startswith("exit:"):  # a mutant's own exit code (sim.mutants)
            return int(outcome[5:])
        return 0 if outcome in ("end_mission", "stopped") else 1

    def wait(self, timeout: float | None = None) -> int | None:
        return self.returncode

    @property
    def process(self) -> SimNode:
        return self

    def output(self, lines: int = 12) -> tuple[list[str], list[str]]:
        return [], []

    def sanitizer_report(self) -> list[str]:
        return []

    def details(self, lines: int = 12) -> dict[str, Any]:
        rc = self.returncode
        return {"command": list(self.argv), "exit": None if rc is None else f"exited with code {rc}",
                "stdout": [], "stderr": []}

    def evidence(self) -> list[str]:
        rc = self.returncode
        ev = [f"node model: {self.name}"]
        if rc is not None:
            ev.append(f"node model closed ({self.model.outcome}): exit code {rc}")
        return ev

    def output_tail(self, lines: int = 12) -> str:
        return ""

    def stop(self, grace: float = 2.0) -> None:
        hook, self.before_stop = self.before_stop, None
        if hook is not None:
            hook()
        if not self.model.closed:
            self.model.close(self._t.clock.now, "stopped")
        self._t.detach(self.model)

    close = stop


class SimTransport(Transport):
    """The driver's far end in the simulator (see the module docstring)."""

    poll = None  # ``recv`` blocks on the virtual clock until a datagram is due or it closes

    def __init__(self, clock: VirtualClock, down: ImpairSpec | None = None, up: ImpairSpec | None = None,
                 *, link_seed: int = 0, listen: Address = RUNNER_ADDR, latency: float = 50e-6) -> None:
        from dataclasses import replace

        self.clock = clock
        self.listen = listen
        #: each way's least delay (a loopback's): a reply never arrives at its command's instant
        self.latency = latency
        self.inboxes: dict[Address, _Inbox] = {}
        self.model: DroneModel | None = None
        self._gen = 0
        self._armed: float | None = None  # the model's timer as armed on the clock
        self._due_at: set[float] = set()  # the times a delivery call is armed for
        self._held: DelayQueue[tuple[Any, ...]] = DelayQueue()  # (fn, *args): see _carry
        clean = ImpairSpec()
        self.down = Link("runner:down", Impairment(replace(check_spec(down or clean), seed=link_seed)), self._held)
        self.up = Link("runner:up", Impairment(replace(check_spec(up or clean), seed=link_seed + 1)), self._held)
        self.reply_to_source = False
        self._next_ports = 40000
        self._side_inboxes: list[_Inbox] = []
        self.vehicle_net: Any = None  # sim.vehicle.SimVehicleNet: the runner's vehicle

    # ------------------------------------------------------------------ the runner's side
    def bind(self, listen: Address) -> Address:
        self._inbox = self.inboxes[self.listen] = _Inbox(self.clock, self.listen)
        return (listen[0], self.listen[1])

    def sendto(self, data: bytes, addr: Address) -> int:
        self.deliver_down(data, addr, self.listen)
        return len(data)

    def recv(self) -> tuple[bytes, Any, int | None]:
        box = self._inbox
        with box.cond:
            while not box.queue and not box.closed:
                box.cond.wait()
            if box.closed:
                raise OSError("transport closed")
            data, src, arrived = box.queue.popleft()
        return data, src, arrived

    def getsockname(self) -> Address:
        return self.listen

    def close(self) -> None:
        with self._inbox.cond:
            self._inbox.closed = True
            self._inbox.cond.notify_all()

    def side_socket(self, host: str) -> SimSideSocket:
        self._next_ports += 1
        box = self.inboxes[(self.listen[0], self._next_ports)] = _Inbox(self.clock, (self.listen[0], self._next_ports))
        return SimSideSocket(self, box)

    # ------------------------------------------------------------------ the link
    def _carry(self, link: Link, data: bytes, held: Callable[[bytes], tuple[Any, ...]]) -> None:
        """``data`` into ``link``; each copy held as ``held(copy's bytes)``: a tuple ``(fn,
        *args)``, ``fn(*args)`` called when it falls due. One object a copy while it is held
        (a closure is three or four: the collector walked them all, ~30% of the simulated
        MCP-ROB-7 flood's 10,000 held at one instant)."""
        link.send(data, self.clock.now + self.latency, held)
        self._arm_due()

    def _arm_due(self) -> None:
        """One call on the clock at the earliest copy's due time (none twice for one time)."""
        due = self._held.next_due()
        if due is not None and due not in self._due_at:
            self._due_at.add(due)
            self.clock.call_at(due, lambda: self._due(due))

    def _due(self, t: float) -> None:
        self._due_at.discard(t)
        for item in self._held.pop_due(self.clock.now):
            item[0](*item[1:])
        self._arm_due()  # the next copy held: its own call (a later push need not come)

    def deliver_down(self, data: bytes, addr: Address, src: Address) -> None:
        """A datagram from one of the runner's addresses to ``addr``: to the model when it
        listens there (its address, or the broadcast address on its port)."""
        model = self.model
        if model is None or model.closed or addr[1] != model.addr[1]:
            return
        if addr[0] not in (model.addr[0], "255.255.255.255", "<broadcast>"):
            return
        gen = self._gen
        self._carry(self.down, data, lambda body: (SimTransport._to_model, self, src, gen, body))

    def deliver_down_many(self, datagrams: list[bytes], count: int, addr: Address, src: Address) -> int:
        """:meth:`deliver_down` of ``datagrams[i % len(datagrams)]`` for i < ``count``, in
        order, at this instant: the same copies, decisions, records and delivery calls (each
        one's ``_arm_due``), without a call and a closure per datagram. The model's state, and
        so whether it takes them, cannot change before the first one is due (the latency)."""
        n = len(datagrams)
        if not n or count <= 0:
            return 0
        model = self.model
        if model is None or model.closed or addr[1] != model.addr[1]:
            return count
        if addr[0] not in (model.addr[0], "255.255.255.255", "<broadcast>"):
            return count
        gen = self._gen

        def held(body: bytes) -> tuple[Any, ...]:
            return (SimTransport._to_model, self, src, gen, body)

        send, arm, t = self.down.send, self._arm_due, self.clock.now + self.latency
        for i in range(count):
            send(datagrams[i % n], t, held)
            arm()
        return count

    def _to_model(self, src: Address, gen: int, data: bytes) -> None:
        model = self.model
        if model is None or gen != self._gen or model.closed:
            return
        now = self.clock.now
        model.receive(data, src, now)
        self._after(model, now)

    # ------------------------------------------------------------------ the model
    def attach(self, model: DroneModel) -> None:
        """A fresh node (a spawn): its socket is open from now; its timers on the clock."""
        self.detach(self.model)
        self.model = model
        self._gen += 1
        self._armed = None
        if hasattr(model, "send_to"):
            model.send_to = self.listen  # where the node was told to send (source-port-filter)
        ap = getattr(model, "autopilot", None)  # a manager model has no autopilot
        if ap is not None and self.vehicle_net is not None:
            gen = self._gen
            self.vehicle_net.attach(ap.addr, lambda data: self._to_autopilot(model, gen, data))
        model.start(self.clock.now)
        self._after(model, self.clock.now)

    def detach(self, model: DroneModel | None) -> None:
        if model is not None and model is self.model:
            self._gen += 1
            self.model = None
            ap = getattr(model, "autopilot", None)
            if ap is not None and self.vehicle_net is not None:
                self.vehicle_net.detach(ap.addr)

    def _to_autopilot(self, model: DroneModel, gen: int, data: bytes) -> None:
        if gen != self._gen or model is not self.model or model.closed:
            return
        now = self.clock.now
        model.receive_autopilot(data, now)
        self._after(model, now)

    def _after(self, model: DroneModel, now: float) -> None:
        """The model's datagrams up the link, and its next timer armed."""
        drain = getattr(model, "drain", None)  # a mutant's wire (sim.mutants): (bytes, addr, delay)
        items = drain(now) if drain is not None else [(d, a, 0.0) for d, a in model.ep.datagrams_to_send(now)]
        for data, dst, delay in items:
            if delay > 0:
                self.clock.call_later(delay, lambda data=data, dst=dst: self._up(model, data, dst))  # type: ignore[misc]  # mypy: a default argument
            else:
                self._up(model, data, dst)
        ap = getattr(model, "autopilot", None)
        if ap is not None and self.vehicle_net is not None:
            for frame in ap.take_output():
                self.vehicle_net.from_node(frame, ap.addr)
            if model.closed:  # the process ended: its autopilot connection with it
                self.vehicle_net.detach(ap.addr)
        if model.closed:
            return
        t = model.timer()
        if t is not None and t != math.inf and t != self._armed:
            self._armed = t
            gen = self._gen
            self.clock.call_at(t, lambda: self._fire(model, gen, t))

    def _fire(self, model: DroneModel, gen: int, t: float) -> None:
        if gen != self._gen or model is not self.model or model.closed or self._armed != t:
            return  # re-armed since, replaced, or closed
        self._armed = None
        model.on_timer(self.clock.now)
        self._after(model, self.clock.now)

    def _up(self, model: DroneModel, data: bytes, dst: Any) -> None:
        if model is not self.model:
            return  # a datagram a stopped node held back (a mutant's late ACK) never leaves
        # the reference drone sends everything to its --target, ACKs included (its transport's
        # reply_to_source off); ``reply_to_source``: an ACK to the datagram's source instead
        addr = (str(dst[0]), int(dst[1])) if dst is not None and self.reply_to_source else self.listen
        box = self.inboxes.get(addr)
        if box is None and addr[1] == self.listen[1]:
            box = self._inbox  # the runner's port on any of its hosts
        if box is None:
            return  # nobody listens there
        src = model.addr
        self._carry(self.up, data, lambda body: (_put, box, src, body))
