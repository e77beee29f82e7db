"""``mcp-conform``: the black-box conformance runner's command line (docs/design.md,
"The runner's contract").

    mcp-conform [--target HOST:PORT] [--listen HOST:PORT] [--target-id N] [--role drone|manager]
                [--spawn CMD] [--mavlink [tcp|udp|udpin|udpout]] [--mavlink1] [--strict] [--select PREFIX ...] [--list]
                [--json FILE] [--junit FILE] [--capture FILE.mcap] [--live [HOST:]PORT] [--html FILE]
                [--rto S] [--ack-window S] [--broadcast-id N] [--timeout S] [--startup-timeout S] [--seed N]
                [--impair loss=P,dup=P,reorder=P,delay=LO-HI,corrupt=P,seed=N] [--serial] [--parallel N]

A thin front end over pytest and the ``conformance.plugin``: it checks the arguments (a bad
value is a one-line error naming the option, exit 2, with the JSON report still written),
then runs the installed cases (``--pyargs conformance.cases``) without pytest's cache,
random ordering, configuration files or terminal output (the plugin's rich report is the
output), and returns the contract's exit code: 0 no MUST failed (and no SHOULD under
``--strict``), 1 a case failed or errored, 2 a usage or setup error, 128 + the signal's
number when SIGINT (130) or SIGTERM (143) stopped the run (its reports written). The options
follow the tools' one grammar (``traceio.grammar``, docs/grammar.md): ``--json -`` writes the
report to stdout (the terminal report then goes to stderr); an ``MCP_CONFORM_*`` variable is
checked as its option is, a bad value a one-line error naming the variable.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import signal
import sys
import tempfile
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

from mcp_conform.conformance.baseline import BaselineError, load_baseline
from mcp_conform.conformance.option_names import _FLAGS, _KEYS, env_name
from mcp_conform.conformance.options import ConfigError, make_config, mavlink_value
from mcp_conform.conformance.report import RunRecord, write_json
from mcp_conform.harness.config import DEFAULT_ROLE, RunConfig
from mcp_conform.harness.interrupts import INTERRUPTS
from mcp_conform.spec import SPEC
from mcp_conform.spec.profiles import PROFILES, ROLE_NAMES, ProfileError, pick
from mcp_conform.traceio.grammar import STDIO, add_verbosity, epilog, version_text

__all__ = ["build_parser", "main", "pytest_args"]

PROG = "mcp-conform"
PLUGIN_MODULE = "mcp_conform.conformance.plugin"


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of printing usage and exiting."""

    def error(self, message: str) -> NoReturn:
        raise ConfigError(message)


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Black-box conformance runner for CentMesh MCP nodes.",
                epilog=epilog("No --target and no --spawn: test the embedded reference drone."),
                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--target", metavar="HOST:PORT", help="the node's unicast address (attach mode)")
    p.add_argument("--listen", metavar="HOST:PORT", help=(f"where the runner receives and sends from (default: all addresses, port "
                         f"{SPEC.protocol['ports']['manager']} for a drone under test; a free port when spawning)"))
    p.add_argument("--target-id", metavar="N", help="the node's MCP ID (default: from its Mission_Ready, else 1)")
    p.add_argument("--protocol", metavar="|".join(PROFILES), default=None,
                   help="the protocol the node speaks: mcp (default; UDP), nsqd (the Nsqd TCP drone protocol: the node is a backend)")
    p.add_argument("--role", metavar="|".join(ROLE_NAMES), default=None,
                   help="the role of the node under test (default: the protocol's first: drone; backend under --protocol nsqd)")
    p.add_argument("--spawn", metavar="CMD", help="start the node under test: CMD with {target_host} {target_port} {listen_host} {listen_port} {broadcast} {id} {mavlink}; "
                   "--role manager: {drones} {challenge} {waypoints} {obstacles} too")
    p.add_argument("--mavlink", nargs="?", const="tcp", default=None, metavar="tcp|udp|udpin|udpout",
                   help="start the simulated vehicle and pass {mavlink}: tcp:HOST:PORT (default), udp:/udpin:HOST:PORT "
                        "(the node listens; the vehicle sends there, as SITL's --out) or udpout:HOST:PORT (the vehicle listens); "
                        "in a role with no such link to start or choose (--role manager) a one-line error")
    p.add_argument("--mavlink1", action="store_true",
                   help="--protocol mavlink --role gcs: the runner's vehicle speaks MAVLink 1 on every link from the "
                        "start (as mcp-vehicle --mavlink1; ArduPilot's SERIALn_PROTOCOL 1), for a ground station "
                        "built on MAVLink 1 headers")
    p.add_argument("--strict", action="store_true", help="a failed SHOULD is a failure")
    p.add_argument("--select", metavar="PREFIX", nargs="+", action="extend", default=[], help="run only cases whose rule ID or case ID starts with PREFIX")
    p.add_argument("--exclude", metavar="PREFIX", nargs="+", action="extend", default=[], help="leave out cases whose rule ID or case ID starts with PREFIX")
    p.add_argument("--list", action="store_true", help="print the cases with their rule IDs and run nothing")
    p.add_argument("--json", metavar="FILE", help="write the JSON report (always, errors included; "
                   "'-': stdout, the terminal report then on stderr)")
    p.add_argument("--junit", metavar="FILE", help="write a JUnit XML report")
    p.add_argument("--junit-family", metavar="xunit2|xunit1", choices=("xunit2", "xunit1"), help="xunit2 (default): valid against the Jenkins junit-10 schema; xunit1: rule IDs also as properties in each testcase")
    p.add_argument("--baseline", metavar="FILE", help="expected failures (YAML or JSON, case or rule IDs with a reason): listed failures are xfailed (exit 0), listed cases that pass are xpassed (exit 1 under --strict)")
    p.add_argument("--write-baseline", metavar="FILE", help="write this run's failed and warned cases as a baseline")
    p.add_argument("--capture", metavar="FILE.mcap", help="record the run to an MCAP file")
    p.add_argument("--live", metavar="[HOST:]PORT", help="serve the run live over the Foxglove WebSocket protocol, "
                   "the capture's channels (loopback unless HOST is given; port 0: a free one; the ws:// URL is printed)")
    p.add_argument("--html", metavar="FILE", help="write a self-contained HTML report (failed cases with their sequence charts)")
    p.add_argument("--rto", metavar="S", help="the node's retransmission timeout as assumed (default 5)")
    p.add_argument("--ack-window", metavar="S", help="how long 'no reply' is watched (default 2)")
    p.add_argument("--broadcast-id", metavar="N", help="the broadcast MCP ID (default 65535)")
    p.add_argument("--timeout", metavar="S", help="deadline for the whole run (default 600)")
    p.add_argument("--startup-timeout", metavar="S",
                   help="how long to wait for the node's first datagram, and for a spawned node's "
                        "Mission_Ready (default 60; at most --timeout)")
    p.add_argument("--case-timeout", metavar="S", help="time limit of one case (default: from --rto and --ack-window)")
    p.add_argument("--seed", metavar="N", help="seed of the malformed corpus (default: fixed)")
    p.add_argument("--drones", metavar="1,2,3", help="--role manager: the drone IDs the runner plays (default 1,2,3)")
    p.add_argument("--challenge", metavar="1|2|3", help="--role manager: the challenge the manager runs (default 1)")
    p.add_argument("--waypoints", metavar="FILE", help="--role manager: the QGC WPL 110 file the manager is handed "
                                                       "(default: one the runner writes, {waypoints})")
    p.add_argument("--impair", metavar="SPEC", help="test through a bad link, reproducible by seed: "
                   "loss=0.1,dup=0.05,reorder=0.1,delay=0-50ms,corrupt=0.01,seed=7 (the runner's own socket "
                   "drops, duplicates, delays and reorders; a case the impairment spoiled is repeated, never failed); "
                   "the drone role")
    p.add_argument("--serial", action="store_true", help="run every case alone, one after another, as "
                   "listed (the default schedule overlaps what only waits; -v prints it)")
    p.add_argument("--parallel", metavar="N", default="1", help="spawn mode: share the cases out across up to N "
                   "node instances, each spawned on its own ports with its own startup phase (default 1; -v "
                   "prints which case runs on which); the drone role")
    p.add_argument("--shard", metavar="K/N", help=argparse.SUPPRESS)  # one instance of --parallel
    p.add_argument("--shard-events", metavar="FILE", help=argparse.SUPPRESS)
    add_verbosity(p, "print every datagram sent and received, live, to stderr",
                  "no terminal report: the exit code, errors and the files asked for only")
    p.add_argument("--version", action="store_true", help="print the version and exit")
    return p


def _json_path(argv: Sequence[str]) -> str | None:
    """--json FILE from raw arguments, for reports of errors argparse itself refused."""
    path = None
    for i, a in enumerate(argv):
        if a == "--json" and i + 1 < len(argv):
            path = argv[i + 1]
        elif a.startswith("--json="):
            path = a.split("=", 1)[1]
    return path


def _values(ns: argparse.Namespace) -> dict[str, Any]:
    """The options' values: the command line's, else their ``MCP_CONFORM_*`` variable's (as
    the plugin reads them, ``conformance.options.option_values``), so a bad variable is the
    same one-line error as a bad option."""
    given = {"target": ns.target, "listen": ns.listen, "target_id": ns.target_id,
            "protocol": ns.protocol, "role": ns.role,
            "spawn": ns.spawn, "mavlink": ns.mavlink, "mavlink1": ns.mavlink1, "strict": ns.strict, "rto": ns.rto,
            "ack_window": ns.ack_window, "broadcast_id": ns.broadcast_id, "timeout": ns.timeout,
            "seed": ns.seed, "capture": ns.capture, "json": ns.json, "junit": ns.junit,
            "case_timeout": ns.case_timeout, "startup_timeout": ns.startup_timeout,
            "drones": ns.drones, "challenge": ns.challenge, "waypoints": ns.waypoints,
            "impair": ns.impair}
    for key in _KEYS:
        env = os.environ.get(env_name(key), "")
        if key not in _FLAGS and key != "mavlink" and given.get(key) is None and env != "":
            given[key] = env
        elif key == "mavlink1" and not given[key] and env != "":  # a flag checked as its option is
            given[key] = env
        elif key == "mavlink" and given[key] is None and env != "":  # as the plugin reads it
            given[key] = mavlink_value(env)
    return given


def _spelling(ns: argparse.Namespace) -> Any:
    """How make_config names an option in an error: ``--rto``, or ``MCP_CONFORM_RTO`` when
    only the variable gave it."""
    def opt(name: str) -> str:
        from_env = getattr(ns, name, None) in (None, False) and os.environ.get(env_name(name), "") != ""
        return env_name(name) if from_env else "--" + name.replace("_", "-")
    return opt


def _check_writable(path: str | None, option: str) -> None:
    if path is None:
        return
    if not path:
        raise ConfigError(f"{option}: empty file name")
    parent = Path(path).expanduser().resolve().parent
    if not parent.is_dir():
        raise ConfigError(f"{option}: directory {str(parent)!r} does not exist")
    if Path(path).is_dir():
        raise ConfigError(f"{option}: {path!r} is a directory")


def _check_live(value: str) -> None:
    """--live [HOST:]PORT, checked before anything runs (a one-line error, exit 2)."""
    from mcp_conform.traceio.live import LiveError, parse_live

    try:
        parse_live(value)
    except LiveError as exc:
        raise ConfigError(str(exc)) from None


def _parallel(ns: argparse.Namespace) -> int:
    """--parallel N, checked: N node instances of a spawned drone (1: the run of one)."""
    try:
        n = int(ns.parallel)
    except ValueError:
        n = 0
    if n < 1:
        raise ConfigError(f"--parallel: {ns.parallel!r} is not a positive whole number")
    if n == 1 or ns.list:
        return 1
    if ns.target is not None:
        raise ConfigError("--parallel: attach mode has one node under test; only spawned nodes "
                          "(--spawn, the embedded one) are shared out")
    if not pick(ns.protocol, ns.role)[1].shardable:
        raise ConfigError(f"--parallel: the {ns.role} role's cases are not shared out (the drone role's are)")
    if ns.live is not None:
        raise ConfigError("--parallel: --live follows one node instance; run it without --parallel")
    if ns.listen is not None and not ns.listen.endswith(":0"):
        raise ConfigError("--parallel: each node instance listens on a free port of its own; "
                          "give --listen HOST:0 or leave it out")
    if ns.shard is not None:
        raise ConfigError("--parallel: not within one of its own instances (--shard)")
    return n


def _fail(message: str, json_path: str | None, cfg: RunConfig | None = None) -> int:
    """Print the one-line error, write the JSON report if asked, return 2."""
    print(f"{PROG}: error: {message}", file=sys.stderr)
    if json_path:
        cfg = cfg or RunConfig()
        target = f"{cfg.target[0]}:{cfg.target[1]}" if cfg.target else None
        run = RunRecord(role=cfg.role if cfg.role in ROLE_NAMES else DEFAULT_ROLE, target=target,
                        parameters=cfg.parameters(), seed=cfg.seed, strict=cfg.strict, error=message)
        run.finished = run.started
        try:
            if json_path == STDIO:
                from mcp_conform.conformance.report import build_json

                print(json.dumps(build_json(run), indent=2), flush=True)
            else:
                write_json(json_path, run)
        except OSError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
    return 2


def run_pytest(args: list[str], plugins: Sequence[Any] = ()) -> int:
    """``pytest.main(args)`` (:func:`pytest_args`) with the runner's plugin and ``plugins``."""
    import importlib

    import pytest

    return int(pytest.main(args, plugins=[importlib.import_module(PLUGIN_MODULE), *plugins]))


def pytest_args(ns: argparse.Namespace) -> list[str]:
    """The pytest command line for these arguments."""
    import importlib

    package = pick(ns.protocol, ns.role)[1].cases
    cases_dir = str(Path(importlib.import_module(package).__file__ or "").parent)  # not resolved: mcp_conform/ names it
    # An isolated session: no plugin but ours, registered as an object (:func:`run_pytest`;
    # ``--disable-plugin-autoload``: pytest walks no installed distribution's entry points, as
    # ``-p NAME`` would to look the name up, and a user's pytest plugins take no part in a run),
    # and no ``conftest.py`` of the directory it runs in (the cases are named by package, so
    # pytest would load the working directory's ``test*/conftest.py``: a user's own test hooks
    # inside the run). The cases' packages have no conftest.
    args = ["-c", os.devnull, "--rootdir", cases_dir, "--noconftest", "--disable-plugin-autoload",
            "-p", "no:cacheprovider", "-p", "no:randomly",
            "-p", "no:terminal", "-p", "no:xdist", "-p", "no:timeout",
            "-p", "no:unraisableexception",  # its gc.collect() x 5 at the end: 60 ms a run, for nothing here
            "--capture=no",  # the runner's own live output (progress, -v traffic) reaches the terminal
            "-W", "ignore::pytest.PytestAssertRewriteWarning", "-W", "ignore::pytest.PytestConfigWarning"]
    args += ["--mcp-frontend", "--mcp-protocol", ns.protocol, "--mcp-role", ns.role]
    for name in ("target", "listen", "target_id", "spawn", "json", "junit", "capture", "live", "html", "rto",
                 "ack_window", "broadcast_id", "timeout", "seed", "baseline", "write_baseline",
                 "junit_family", "case_timeout", "startup_timeout", "drones", "challenge", "waypoints",
                 "impair"):
        value = getattr(ns, name)
        if value is not None:
            args.append(f"--mcp-{name.replace('_', '-')}={value}")
    if ns.mavlink:
        args.append(f"--mcp-mavlink={ns.mavlink}")
    if ns.shard is not None:
        args.append(f"--mcp-shard={ns.shard}")
    if ns.shard_events is not None:
        args.append(f"--mcp-shard-events={ns.shard_events}")
    for flag in ("strict", "mavlink1", "list", "serial"):
        if getattr(ns, flag):
            args.append(f"--mcp-{flag}")
    if ns.verbose:
        args.append("--mcp-verbose-traffic")
    for prefix in ns.select:
        args.append(f"--mcp-select={prefix}")
    for prefix in ns.exclude:
        args.append(f"--mcp-exclude={prefix}")
    args += ["--pyargs", package]
    return args


def main(argv: Sequence[str] | None = None) -> int:
    """Run the suite; return the contract's exit code (0, 1 or 2). SIGINT and SIGTERM are
    taken first (``harness.interrupts``): the first stops the run, the reports are
    written whatever follows."""
    argv = list(sys.argv[1:] if argv is None else argv)
    installed = INTERRUPTS.install()
    try:
        with _json_to_stdout(argv) as args:
            try:
                return _main(args)
            except KeyboardInterrupt:  # before pytest took over, or after it returned
                return interrupted(args)
    finally:
        if installed:
            INTERRUPTS.restore()


@contextlib.contextmanager
def _json_to_stdout(argv: list[str]) -> Any:
    """``--json -``: the report is written to a file of our own, the terminal report and
    anything else printed goes to stderr meanwhile, then the report goes to stdout."""
    i = next((i for i, a in enumerate(argv) if a == "--json=-" or (a == "--json" and argv[i + 1:i + 2] == ["-"])),
             None)
    if i is None or "--version" in argv or "-h" in argv or "--help" in argv:
        yield argv
        return
    fd, path = tempfile.mkstemp(prefix="mcp-conform-", suffix=".json")
    os.close(fd)
    os.unlink(path)
    args = [*argv[:i], f"--json={path}", *argv[i + (1 if argv[i] == "--json=-" else 2):]]
    sys.stdout.flush()
    saved = os.dup(1)
    os.dup2(2, 1)
    try:
        yield args
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)
        with contextlib.suppress(OSError):
            with open(path, encoding="utf-8") as f:
                sys.stdout.write(f.read())
            sys.stdout.flush()
            os.unlink(path)


def _signal_code() -> int:
    """128 + the number of the first signal that stopped the run (130 SIGINT, 143 SIGTERM)."""
    name = INTERRUPTS.signals[0] if INTERRUPTS.signals else "SIGINT"
    return 128 + int(getattr(signal, name, signal.SIGINT))


def interrupted(argv: Sequence[str]) -> int:
    """A signal stopped the run outside pytest: the report says so (exit 128 + its number)."""
    INTERRUPTS.stop_raising()
    written = _json_path(argv)
    if written and written != STDIO and Path(written).exists():  # the run's own report: keep it
        print(f"{PROG}: error: {INTERRUPTS.reason()}", file=sys.stderr)
        return _signal_code()
    _fail(INTERRUPTS.reason(), written)
    return _signal_code()


@contextlib.contextmanager
def _quiet(quiet: bool) -> Any:
    """``-q``: stdout (the terminal report) to /dev/null for the run; errors stay on stderr."""
    if not quiet:
        yield
        return
    sys.stdout.flush()
    saved, devnull = os.dup(1), os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    os.close(devnull)
    try:
        yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def _main(argv: list[str]) -> int:
    json_path = _json_path(argv)
    parser = build_parser()
    try:
        ns = parser.parse_args(argv)
    except ConfigError as exc:
        return _fail(str(exc), json_path)
    try:  # the one pick (spec.profiles): each name checked, the defaults filled in
        prof, role = pick(ns.protocol, ns.role)
    except ProfileError as exc:
        option = "--protocol" if ns.protocol is not None and ns.protocol not in PROFILES else "--role"
        return _fail(f"{option}: {exc}", json_path)
    ns.protocol, ns.role = prof.name, role.name
    if ns.version:
        with contextlib.suppress(BrokenPipeError):
            print(version_text(PROG), flush=True)
        return 0
    try:
        cfg = make_config(_values(ns), _spelling(ns))
        _check_writable(ns.json, "--json")
        _check_writable(ns.junit, "--junit")
        _check_writable(ns.capture, "--capture")
        _check_writable(ns.html, "--html")
        _check_writable(ns.write_baseline, "--write-baseline")
        if ns.live is not None:
            _check_live(ns.live)
        if ns.baseline:
            load_baseline(ns.baseline)
    except (ConfigError, BaselineError) as exc:
        return _fail(str(exc), json_path, RunConfig(protocol=ns.protocol, role=ns.role))
    try:
        parallel = _parallel(ns)
    except ConfigError as exc:
        return _fail(str(exc), json_path, cfg)
    if parallel > 1:
        from mcp_conform.conformance.parallel import run_parallel

        return run_parallel(ns, cfg, parallel, _fail, main)
    if ns.list and (ns.capture or ns.html or ns.live):
        ns.capture = ns.html = ns.live = None  # nothing runs: no capture file, no HTML report, no server

    if ns.json:
        Path(ns.json).unlink(missing_ok=True)  # rewritten below; its absence shows a pytest failure
    INTERRUPTS.hold()  # until the plugin is configured (``_plugin_run.pytest_configure``)
    with _quiet(ns.quiet):
        rc = run_pytest(pytest_args(ns))
    INTERRUPTS.stop_raising()
    INTERRUPTS.release()  # pytest ended before it configured the plugin: nothing left to raise
    if INTERRUPTS.interrupted:
        if not ns.json or not Path(ns.json).exists():
            _fail(INTERRUPTS.reason(), ns.json, cfg)
        return _signal_code()
    if rc in (0, 1, 2) and (not ns.json or Path(ns.json).exists()):
        return rc
    why = {3: "internal error in the runner (see the traceback above)",
           4: "pytest refused the arguments (see above)",
           5: "no conformance cases were collected"}.get(rc, f"the run ended with pytest exit code {rc}")
    if ns.json and Path(ns.json).exists():
        print(f"{PROG}: error: {why}", file=sys.stderr)
        return 2
    return _fail(why, ns.json, cfg)


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
