"""A fuzz campaign's parameters (docs/design.md "mcp-fuzz"), checked once by the command line.

The target options mean what they mean to ``mcp-conform`` (the runner's ``RunConfig`` is
built from them, so placeholders, listen semantics and the embedded default are the
runner's own); the rest belong to the campaign.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

from mcp_conform.harness.config import DEFAULT_SEED, RunConfig
from mcp_conform.spec.profiles import DEFAULT_PROTOCOL, pick

ENGINES = ("stateless", "stateful", "both")
#: The engine mix when ``--engine`` is not given, for a drone (MCP): the stateless engine's
#: batches, then the stateful engine's programs, the budget split between them
#: (``fuzz.campaign``). The faults that need a sequence — a message then its copy (MCP-ACK-1,
#: MCP-DUP-1), a seq walked to the wrap (MCP-SEQ-3) — are the stateful engine's; pipelined,
#: it runs about as fast as the stateless one (issue 36 item 4; bench/bench_fuzz.py).
DEFAULT_ENGINE = "both"
DEFAULT_DURATION = 60.0  # s, when neither --duration nor --max-cases is given
EXIT_INTERRUPTED = 130  # SIGINT: the campaign ended early, summary.json holds the counts so far


def target_class(protocol: str | None, role: str | None) -> Any:
    """The fuzz target class the role profile names (``spec.profiles``, ``fuzz_target``);
    None: the protocol is fuzzed by its own campaign."""
    from mcp_conform.spec.profiles import resolve

    path = pick(protocol, role)[1].fuzz_target
    return None if path is None else resolve(path)


def engines(protocol: str | None = None, role: str | None = None) -> tuple[str, ...]:
    """The engines that fuzz the node of ``protocol`` and ``role`` (the target's ``ENGINES``;
    a protocol fuzzed by its own campaign runs all of :data:`ENGINES`)."""
    cls = target_class(protocol, role)
    return ENGINES if cls is None else tuple(cls.ENGINES)


def default_engine(role: str | None = None, protocol: str | None = None) -> str:
    """``--engine``'s default (the one source the command line reads): :data:`DEFAULT_ENGINE`
    for a drone and for an Nsqd backend (its stateful engine's programs pipelined, judged at
    their end: 300-900 cases/s against the C backend, bench/bench_fuzz.py --protocol nsqd;
    the faults of a second client and of a cut frame are its); a target that cannot take it
    (a manager: the stateful engine's programs are a manager's moves) its first engine."""
    allowed = engines(protocol, role)
    return DEFAULT_ENGINE if DEFAULT_ENGINE in allowed else allowed[0]


@dataclass
class FuzzConfig:
    """Everything one campaign (or one of its ``--jobs`` workers) needs."""

    target: tuple[str, int] | None = None
    spawn: str | None = None
    listen: tuple[str, int] | None = None
    target_id: int | None = None
    mavlink: bool = False
    seed: int = DEFAULT_SEED
    max_cases: int | None = None
    duration: float | None = None
    engine: str = DEFAULT_ENGINE
    jobs: int = 1
    db: str | None = None  # a directory, or redis://HOST:PORT/N
    seeds_dir: str | None = None
    out: str | None = None
    rto: float | None = None  # None: the runner's default (the embedded default's short one)
    ack_window: float | None = None
    broadcast_id: int | None = None
    worker: int = 0  # which of the --jobs workers this is
    #: the protocol and role of the node under fuzz (``spec.profiles.pick``; manager: the
    #: fuzzer plays drones)
    protocol: str = DEFAULT_PROTOCOL
    role: str = pick()[1].name
    #: ``--impair SPEC``: the fuzzer's own socket edge is a bad link (a ``harness.impair.ImpairSpec``);
    #: an exchange it touched is not judged (``fuzz.oracles.judge_exchange``)
    impair: Any = None
    extra: dict[str, Any] = field(default_factory=dict)

    @property
    def embedded(self) -> bool:
        return self.target is None and self.spawn is None

    @property
    def duration_limit(self) -> float | None:
        """The campaign's ``--duration``: given, else ``DEFAULT_DURATION`` unless ``--max-cases`` bounds it."""
        return self.duration if self.duration is not None else (None if self.max_cases is not None else DEFAULT_DURATION)

    @property
    def mode(self) -> str:
        return "embedded" if self.embedded else ("spawn" if self.spawn else "attach")

    def target_summary(self) -> dict[str, Any]:
        """How the campaign reached its target, as summary.json's ``target`` says (every
        protocol's): ``mode`` (embedded, spawn, attach), the ``--target`` address, the ``--spawn`` template."""
        return {"mode": self.mode, "target": f"{self.target[0]}:{self.target[1]}" if self.target else None,
                "spawn": self.spawn}

    def for_worker(self, worker: int) -> FuzzConfig:
        """The configuration of worker ``worker``: its own seed stream and its own ports."""
        cfg = replace(self, worker=worker, jobs=1, extra=dict(self.extra))
        if worker:
            cfg.listen = None if self.listen is None else (self.listen[0], 0)
        return cfg

    def run_config(self) -> RunConfig:
        """The runner's configuration of the same target (its session drives the node)."""
        from mcp_conform.harness import drone_session as session_module

        cfg = RunConfig(protocol=self.protocol, role=self.role, target=self.target, listen=self.listen,
                        target_id=self.target_id, spawn=self.spawn, mavlink=self.mavlink,
                        seed=self.seed)
        cfg.impair = self.impair
        if self.embedded:
            # the reference drone, with or without the simulated vehicle as asked
            cfg.spawn = embedded_command(self.mavlink)
            cfg.rto = float(session_module.EMBEDDED_RTO)
            cfg.ack_window = float(session_module.EMBEDDED_ACK_WINDOW)
        if self.rto is not None:
            cfg.rto = self.rto
        if self.ack_window is not None:
            cfg.ack_window = self.ack_window
        if self.broadcast_id is not None:
            cfg.broadcast_id = self.broadcast_id
        return cfg

    def replay_args(self) -> list[str]:
        """The target options a finding's replay command repeats (its replay.txt)."""
        out: list[str] = []
        if self.target:
            out += ["--target", f"{self.target[0]}:{self.target[1]}"]
        if self.spawn:
            out += ["--spawn", self.spawn]
        if self.mavlink:
            out.append("--mavlink")
        if self.protocol != DEFAULT_PROTOCOL:
            out += ["--protocol", self.protocol]
        if self.role != pick(self.protocol)[1].name:
            out += ["--role", self.role]
        for opt, v in (("--target-id", self.target_id), ("--rto", self.rto), ("--ack-window", self.ack_window),
                       ("--broadcast-id", self.broadcast_id)):
            if v is not None:
                out += [opt, str(v)]
        if self.impair is not None:  # replayed as it was confirmed: through the same link
            out += ["--impair", self.impair.text()]
        return out


def embedded_command(mavlink: bool) -> str:
    """The reference drone as the fuzzer spawns it: the runner's embedded command, quiet
    (its per-datagram log lines would cost more than the fuzzing itself), and without the
    runner's vehicle unless ``--mavlink`` (the drone then flies its built-in one)."""
    from mcp_conform.harness.drone_session import embedded_command as runner_command

    cmd = runner_command()
    if not mavlink:
        cmd = cmd.replace(" --mavlink {mavlink}", "")
    return cmd + " --quiet"



def exit_code(findings: Sequence[Any], *, strict: bool = False) -> int:
    """1 when a finding counts: a MUST, or a SHOULD under ``--strict`` (the one convention of
    mcp-conform, mcp-capture check and mcp-fuzz); else 0."""
    counted = {"MUST", "SHOULD"} if strict else {"MUST"}
    return 1 if any(str(f.level).upper() in counted for f in findings) else 0

