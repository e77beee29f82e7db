"""``mcp-fuzz``: fuzz campaigns judged by the spec (docs/design.md "mcp-fuzz", issue 11).

    mcp-fuzz [--target HOST:PORT | --spawn CMD] [--listen HOST:PORT] [--target-id N] [--role drone|manager]
             [--mavlink] [--seed N] [--max-cases N] [--duration S]
             [--engine stateless|stateful|both] [--jobs N] [--db DIR|redis://HOST:PORT/N]
             [--seeds DIR] [--out DIR] [--rto S] [--ack-window S] [--broadcast-id N] [--strict]
             [--live [HOST:]PORT] [--status-every S]
    mcp-fuzz --replay finding-N [--target HOST:PORT | --spawn CMD] [--mavlink]

Without --target and --spawn it fuzzes the reference drone (embedded default); with
``--role manager`` the reference manager, the fuzzer playing drones (fuzz.manager_target). Exit 0:
no MUST finding (SHOULD findings are reported, and count under ``--strict``, as for
mcp-conform and mcp-capture check); 1: findings (for --replay: the finding reproduced); 2:
usage or setup error, with a one-line reason, or the node lost in attach mode (the campaign
ends there, its findings so far written); 130: interrupted (SIGINT), summary.json written
with the counts and findings so far and ``"interrupted": true``. Live progress (rich) on a terminal; otherwise a plain status line every 10 s
(``--status-every S``), then the summary line.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import NoReturn

from mcp_conform.fuzz.config import (
    ENGINES,
    EXIT_INTERRUPTED,
    FuzzConfig,
    default_engine,
    engines,
    exit_code,
)
from mcp_conform.fuzz.plugin import FuzzCampaign
from mcp_conform.harness.config import DEFAULT_SEED, parse_hostport
from mcp_conform.harness.errors import SetupError
from mcp_conform.spec.profiles import (
    DEFAULT_PROTOCOL,
    ProfileError,
    add_protocol_option,
    having,
    pick,
)
from mcp_conform.traceio.grammar import add_verbosity, add_version, epilog

__all__ = ["build_parser", "exit_code", "main"]

PROG = "mcp-fuzz"


class UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        raise UsageError(message)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Fuzz an MCP node; every exchange judged by the spec's rules.",
                epilog=epilog("No --target and no --spawn: fuzz the embedded reference drone. 1: a MUST finding\n"
                              "(a SHOULD one too under --strict); 2 also when the node is lost in attach mode;\n"
                              "130: summary.json keeps the counts so far."),
                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version(p, PROG)
    add_verbosity(p, "also each finding's expected and actual, and the hits counted but not triaged",
                  "no progress display; the findings and the last two lines only")
    t = p.add_mutually_exclusive_group()
    t.add_argument("--target", metavar="HOST:PORT", help="the node's unicast address (attach mode)")
    t.add_argument("--spawn", metavar="CMD", help="start the node: CMD with {target_host} {target_port} "
                   "{listen_host} {listen_port} {broadcast} {id} {mavlink}")
    p.add_argument("--listen", metavar="HOST:PORT", help="where the fuzzer receives and sends from")
    p.add_argument("--role", metavar="|".join(pick()[0].role_names), default=None,
                   help="the role of the node under fuzz (default: the protocol's first; manager: the "
                        "fuzzer plays drones; stateless engine)")
    p.add_argument("--target-id", metavar="N", help="the node's MCP ID (default: from its Mission_Ready, else 1)")
    p.add_argument("--mavlink", action="store_true", help="start the simulated vehicle and pass {mavlink}")
    p.add_argument("--seed", metavar="N", help=f"campaign seed (default {DEFAULT_SEED})")
    p.add_argument("--max-cases", metavar="N", help="stop after N cases")
    p.add_argument("--duration", metavar="S", help="stop after S seconds (default 60 unless --max-cases)")
    p.add_argument("--engine", metavar="|".join(ENGINES), default=None,
                   help="engine(s) to run (default: both for a drone, stateless for a manager "
                        "and for --protocol nsqd)")
    p.add_argument("--jobs", metavar="N", default="1", help="parallel workers, each with its own spawned node")
    p.add_argument("--db", metavar="DIR|redis://HOST:PORT/N", help="hypothesis example database shared by workers")
    p.add_argument("--seeds", metavar="DIR", help="MCAP captures whose datagrams seed the mutations")
    p.add_argument("--out", metavar="DIR", help="write summary.json and finding-N/ here")
    p.add_argument("--json", metavar="FILE|-", help="write the summary (summary.json's document) to FILE, or to "
                   "stdout with - (the campaign's own lines then go to stderr)")
    p.add_argument("--rto", metavar="S", help="the node's retransmission timeout as assumed (default 5; 0.2 embedded)")
    p.add_argument("--ack-window", metavar="S", help="how long 'no reply' is watched (default 2; 0.25 embedded)")
    p.add_argument("--broadcast-id", metavar="N", help="the broadcast MCP ID (default 65535)")
    p.add_argument("--strict", action="store_true", help="a SHOULD finding counts against the exit code "
                   "(as for mcp-conform and mcp-capture check)")
    p.add_argument("--impair", metavar="SPEC", help="fuzz through a bad link, reproducible by seed: "
                   "loss=0.1,dup=0.05,reorder=0.1,delay=0-50ms,corrupt=0.01,seed=7 (an exchange the "
                   "impairment touched is not judged: a dropped ACK is never a finding)")
    p.add_argument("--live", metavar="[HOST:]PORT", help="serve the campaign live over the Foxglove WebSocket "
                   "protocol: its traffic and its findings (loopback unless HOST is given; port 0: a free one)")
    p.add_argument("--replay", metavar="FINDING", help="replay a finding-N directory (or its finding.json) and exit")
    p.add_argument("--status-every", metavar="S", help="off a terminal, a plain status line every S seconds "
                                                       "(default 10)")
    add_protocol_option(p, f"{DEFAULT_PROTOCOL} (default) or nsqd: fuzz a TCP backend of the Nsqd drone protocol "
                           "(--spawn CMD with {target_host} {target_port}, or --target HOST:PORT); one of "
                           f"{', '.join(having('fuzz_campaign'))}, the protocols with a fuzz campaign",
                        default=DEFAULT_PROTOCOL, needs="fuzz_campaign")
    return p


def _int(v: str | None, name: str, lo: int, hi: int) -> int | None:
    if v is None:
        return None
    try:
        n = int(v, 0)
    except ValueError:
        raise UsageError(f"{name}: {v!r} is not an integer") from None
    if not lo <= n <= hi:
        raise UsageError(f"{name}: {n} is out of range {lo}-{hi}")
    return n


def _float(v: str | None, name: str) -> float | None:
    if v is None:
        return None
    try:
        x = float(v)
    except ValueError:
        raise UsageError(f"{name}: {v!r} is not a number") from None
    if not x > 0 or x != x or x == float("inf"):
        raise UsageError(f"{name}: must be a positive number, not {v!r}")
    return x


def _check_writable_dir(path: Path, option: str) -> None:
    """Before the campaign, not when its results are written: a directory we can write in."""
    import tempfile

    try:
        with tempfile.TemporaryFile(dir=path):
            pass
    except OSError as exc:
        raise UsageError(f"{option}: cannot write in {str(path)!r}: {exc.strerror}") from None


def _check_reachable(db: str) -> None:
    """The example database answers before the campaign starts (both engines): a Redis
    server that answers PING within 2 s, or a directory we can write in. The Redis URL is
    redis-py's (``Redis.from_url``: ``redis://[[user]:password@]host[:port][/db]``,
    ``rediss://`` for TLS, ``unix://path``); a password is never echoed in an error."""
    if db.startswith(("redis://", "rediss://", "unix://")):
        from urllib.parse import urlsplit

        import redis

        parts = urlsplit(db)
        shown = db if parts.password is None else parts._replace(
            netloc=f"{parts.username or ''}:***@{parts.netloc.rpartition('@')[2]}").geturl()
        try:
            client = redis.Redis.from_url(db, socket_connect_timeout=2, socket_timeout=2)
        except ValueError as exc:
            raise UsageError(f"--db: {shown!r} is not a Redis URL: {str(exc).splitlines()[0]}") from None
        try:
            client.ping()
        except redis.RedisError as exc:
            raise UsageError(f"--db: cannot reach {shown}: {str(exc).splitlines()[0]}") from None
        finally:
            client.close()
        return
    path = Path(db)
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"--db: cannot create {db!r}: {exc.strerror}") from None
    _check_writable_dir(path, "--db")


def make_config(ns: argparse.Namespace) -> FuzzConfig:
    cfg = FuzzConfig()
    try:
        if ns.target:
            cfg.target = parse_hostport(ns.target, "--target")
        if ns.listen:
            cfg.listen = parse_hostport(ns.listen, "--listen", default_host="")
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if ns.spawn is not None:
        if not ns.spawn.strip():
            raise UsageError("--spawn: the command is empty")
        cfg.spawn = ns.spawn
    cfg.target_id = _int(ns.target_id, "--target-id", 0, 0xFFFF)
    try:
        prof, role = pick(ns.protocol, ns.role)
    except ProfileError as exc:
        raise UsageError(f"--role: {exc}") from None
    if not role.fuzzed:
        fuzzed = ", ".join(r.name for r in prof.roles if r.fuzzed)
        raise UsageError(f"--role: a {role.name} ({prof.name}) is not fuzzed yet (roles fuzzed: {fuzzed})")
    cfg.protocol, cfg.role = prof.name, role.name
    cfg.mavlink = ns.mavlink
    seed = _int(ns.seed, "--seed", 0, 2**63 - 1)
    cfg.seed = DEFAULT_SEED if seed is None else seed
    cfg.max_cases = _int(ns.max_cases, "--max-cases", 1, 10**12)
    cfg.duration = _float(ns.duration, "--duration")
    if ns.status_every is not None:
        cfg.extra["status_every"] = _float(ns.status_every, "--status-every")
    engine = default_engine(cfg.role, cfg.protocol) if ns.engine is None else ns.engine
    if engine not in ENGINES:
        raise UsageError(f"--engine: {engine!r} is not one of {', '.join(ENGINES)}")
    cfg.engine = engine
    if engine not in engines(cfg.protocol, cfg.role):
        raise UsageError(f"--engine: a {cfg.role} is fuzzed by the {', '.join(engines(cfg.protocol, cfg.role))} "
                         "engine only (the stateful engine's programs are a manager's commands to a drone)")
    cfg.jobs = _int(ns.jobs, "--jobs", 1, 256) or 1
    if cfg.jobs > 1 and cfg.target is not None:
        raise UsageError("--jobs: each worker needs its own node; use --spawn (or the embedded default), not --target")
    cfg.db = ns.db
    if cfg.db is not None:
        from mcp_conform.fuzz.engine_stateful import check_database

        try:
            check_database(cfg.db)
        except ValueError as exc:
            raise UsageError(str(exc)) from None
        _check_reachable(cfg.db)
    cfg.seeds_dir = ns.seeds
    cfg.out = ns.out
    if cfg.out is not None:
        out = Path(cfg.out)
        if out.exists() and not out.is_dir():
            raise UsageError(f"--out: {cfg.out!r} is not a directory")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise UsageError(f"--out: cannot create {cfg.out!r}: {exc.strerror}") from None
        _check_writable_dir(out, "--out")
    cfg.rto = _float(ns.rto, "--rto")
    cfg.ack_window = _float(ns.ack_window, "--ack-window")
    cfg.broadcast_id = _int(ns.broadcast_id, "--broadcast-id", 0, 0xFFFF)
    from mcp_conform.harness.impair_link import ImpairmentError, impair_option

    try:
        cfg.impair = impair_option(ns.impair)
    except ImpairmentError as exc:
        raise UsageError(str(exc)) from None
    if cfg.impair is not None and not role.impairable:
        raise UsageError(f"--impair: a {cfg.role} ({cfg.protocol}) is not fuzzed through a bad link yet")
    if ns.live is not None:
        from mcp_conform.traceio.live import LiveError, parse_live

        try:
            cfg.extra["live"] = parse_live(ns.live)
        except LiveError as exc:
            raise UsageError(str(exc)) from None
        for given, why in ((cfg.jobs > 1, "one worker's run is served: use --jobs 1"),
                           (ns.replay, "not available with --replay")):
            if given:
                raise UsageError(f"--live: {why}")
    from mcp_conform.spec.profiles import resolve

    for opt in resolve(prof.fuzz_campaign).REFUSED:  # the options its campaign does not take
        if getattr(ns, opt[2:].replace("-", "_"), None):
            raise UsageError(f"{opt}: not available with --protocol {cfg.protocol}")
    return cfg


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        ns = build_parser().parse_args(argv)
        cfg = make_config(ns)
    except UsageError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    if ns.json is None:
        return _run(ns, cfg)
    with contextlib.redirect_stdout(sys.stderr) if ns.json == "-" else contextlib.nullcontext():
        rc = _run(ns, cfg)
    summary = getattr(ns, "summary", None)
    if summary is not None:
        text = json.dumps(summary, indent=2, default=str) + "\n"
        try:
            if ns.json == "-":
                sys.stdout.write(text)
                sys.stdout.flush()
            else:
                Path(ns.json).write_text(text, encoding="utf-8")
        except OSError as exc:
            print(f"{PROG}: error: --json: cannot write {ns.json!r}: {exc.strerror}", file=sys.stderr)
            return 2
    return rc


def _run(ns: argparse.Namespace, cfg: FuzzConfig) -> int:
    """The campaign or the replay of the protocol's campaign (the profile's ``fuzz_campaign``,
    ``fuzz.config.FuzzCampaign``); its summary left in ``ns.summary`` (``--json``)."""
    from mcp_conform.fuzz.progress import LiveProgress
    from mcp_conform.spec.profiles import resolve

    kind: type[FuzzCampaign] = resolve(pick(cfg.protocol)[0].fuzz_campaign)
    if ns.replay:
        try:
            return kind.replay(ns.replay, cfg)
        except SetupError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return 2
    live = LiveProgress(cfg, every=cfg.extra.get("status_every"), quiet=ns.quiet, verbose=ns.verbose)
    campaign: FuzzCampaign | None = None
    try:
        campaign = kind.from_config(cfg, live.update)
        with live:
            summary = ns.summary = campaign.fuzz()
    except (SetupError, KeyboardInterrupt, Exception) as exc:  # noqa: BLE001 - our own bug: one line too
        if campaign is not None:  # summary.json of what it has
            campaign.abort()
        if isinstance(exc, KeyboardInterrupt):  # a second SIGINT while the campaign wound up
            print(f"{PROG}: interrupted", file=sys.stderr)
            return EXIT_INTERRUPTED
        print(f"{PROG}: error: {exc}" if isinstance(exc, SetupError) else
              f"{PROG}: error: internal error ({type(exc).__name__}: {exc}); "
              f"{len(campaign.store) if campaign else 0} finding(s) written so far", file=sys.stderr)
        return 2
    return campaign.final(summary, live, ns.strict)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
