"""A fork server for the tests' ``python -m mcp_conform.conformance`` runs (and ``captures``'s and
``fuzz``'s: ``SERVED``): one process per pytest process imports the runner once, then forks a
child for each run.

Why: the slow tests start the runner about 290 times. A fresh interpreter spends about
0.35 CPU s of each run importing pytest, the runner, the judge, the vehicle and pymavlink's
dialects before it sends a datagram (measured: 1.1 CPU s for a whole suite against the
sample node, 0.45 of it in imports), about 100 CPU s in all on CI's 2 cores. A forked child
starts with those modules loaded and runs the same entry point a user's ``mcp-conform``
runs (``conformance._entry.main``), in its own process: its own pid, working directory,
environment, standard streams (files the caller reads) and exit status (``os.waitpid`` in
the server, returned as it is, a signal as a negative number like ``subprocess``).

What a child does not share with a fresh interpreter: the modules below were imported
before its signal handlers were installed (the tests that signal the runner during its
imports start it themselves). What is read from the environment at import is the same: a
server is started with the caller's PYTHON* and MAVLINK* variables, one server for each
combination (``IMPORT_TIME``); the runner itself reads ``MCP_CONFORM_*`` when it configures.
The case modules are not imported here: pytest imports them in the child, with their
asserts rewritten, as in a user's run.

Set ``MCP_TEST_FORKSERVER=0`` to run each run in a fresh interpreter instead.

``MCP_TEST_RUNS=FILE`` (opt-in, for measuring CI): each run appends a line to FILE,
"cpu<TAB>wall<TAB>nodeid<TAB>argv" -- cpu: the run's user + system seconds with its waited-for
children's (the node it spawned), from ``os.wait4`` in the server or the fresh interpreter's
``RUSAGE_CHILDREN``; nodeid: the calling test (``PYTEST_CURRENT_TEST``). These runs are no
children of the pytest worker: ``MCP_TEST_CPU`` (tests/conftest.py) does not count them.

The server: ``python -m tests.forkserver SOCKET`` listens on a Unix socket. A request is one
JSON line (argv, cwd, env, the two output paths); the reply is a line with the child's pid,
then a line with its exit status and CPU seconds (with its children's) once the server has reaped it. One thread, a select loop.
"""

from __future__ import annotations

import json
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("spec", "vehicle", "traceio", "judge", "harness", "conformance")  # the runner and the floors below
#: What each served ``python -m NAME`` runs: the function its ``__main__`` exits with. The runner's
#: ends the process itself; the others return the exit status (``sys.exit(main())``).
SERVED = {"conformance": "mcp_conform.conformance._entry", "captures": "mcp_conform.captures.cli",
          "fuzz": "mcp_conform.fuzz.cli"}
THIRD_PARTY = ("pytest", "_pytest.pytester", "pymavlink.mavutil", "pymavlink.dialects.v10.ardupilotmega",
               "pymavlink.dialects.v20.ardupilotmega", "rich.console", "rich.table", "foxglove.messages", "mcap.writer",
               "mcap.reader", "orjson", "execnet", "xdist.plugin", "unittest", "xml.etree.ElementTree", "pdb")


def _preload() -> None:
    """Import what every run imports: the packages' modules but the cases and entry points."""
    import importlib
    import pkgutil

    for name in THIRD_PARTY:
        importlib.import_module(name)
    for package in PACKAGES:  # as the entry points import them (one namespace: never as a bare "spec")
        path = importlib.import_module("mcp_conform." + package).__path__
        for info in pkgutil.walk_packages(path, "mcp_conform." + package + "."):
            if ".cases" not in info.name and not info.name.endswith("__main__"):
                importlib.import_module(info.name)


def enabled() -> bool:
    return os.environ.get("MCP_TEST_FORKSERVER", "1") != "0" and hasattr(os, "fork")


#: What a fresh interpreter reads from the environment when it starts or imports: the
#: interpreter's own PYTHON* variables (PYTHONPATH: where modules come from) and pymavlink's
#: MAVLINK* (mavutil picks its dialect module at import; mavwp asks ``mavlink20()`` of the
#: environment when called). A request is served by a server started with the same values,
#: one server per combination (a test that sets MAVLINK20 gets its own).
IMPORT_TIME = ("PYTHON", "MAVLINK")


def _key(env: dict[str, str]) -> tuple[tuple[str, str], ...]:
    """The variables that decide what an import gives, as an import sees them: PYTHONPATH's
    entries but the repository's (which every run has first, as its working directory or
    through the editable install) and mavutil's default dialect as if unset."""
    out = []
    for k, v in sorted(env.items()):
        if k == "PYTHONPATH":
            v = os.pathsep.join(dict.fromkeys(p for p in v.split(os.pathsep) if p and Path(p).resolve() != ROOT))
        if k.startswith(IMPORT_TIME) and v and not (k == "MAVLINK_DIALECT" and v == "ardupilotmega"):
            out.append((k, v))
    return tuple(out)


class _Server:
    def __init__(self, env: dict[str, str]) -> None:
        self.path = os.path.join(tempfile.mkdtemp(prefix="mcp-forkserver-"), "s")
        self.proc = subprocess.Popen([sys.executable, "-m", "tests.forkserver", self.path], cwd=ROOT, env=env,
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE)  # its stdin's end: ours
        assert self.proc.stdout is not None
        if self.proc.stdout.readline().strip() != b"ready":
            raise RuntimeError("the test fork server did not start")


class _Client:
    """The calling process's servers, each started on first use, ended with the process."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._servers: dict[tuple[tuple[str, str], ...], _Server] = {}

    def _server(self, env: dict[str, str]) -> str:
        with self._lock:
            server = self._servers.get(_key(env))
            if server is None or server.proc.poll() is not None:
                server = self._servers[_key(env)] = _Server(env)
            return server.path

    def run(self, argv: list[str], *, cwd: Path, env: dict[str, str], timeout: float, module: str = "conformance",
            limit_as: int | None = None) -> subprocess.CompletedProcess[str]:
        path = self._server(env)
        start = time.monotonic()
        with tempfile.TemporaryDirectory() as tmp:
            out, err = os.path.join(tmp, "stdout"), os.path.join(tmp, "stderr")
            request = {"argv": argv, "cwd": str(cwd), "env": env, "stdout": out, "stderr": err,
                       "module": _served(module), "limit_as": limit_as}
            with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as s:
                s.connect(path)
                s.sendall(json.dumps(request).encode() + b"\n")
                s.settimeout(timeout)
                reader = s.makefile("rb")
                pid = int(reader.readline())
                try:
                    line = reader.readline()
                except TimeoutError:
                    os.kill(pid, signal.SIGKILL)
                    raise subprocess.TimeoutExpired(argv, timeout) from None
                if not line:
                    raise RuntimeError(f"the test fork server died while running {argv}")
                rc, cpu = line.split()
            _record(float(cpu), time.monotonic() - start, argv)
            return subprocess.CompletedProcess(argv, int(rc), Path(out).read_text(errors="replace"),
                                               Path(err).read_text(errors="replace"))


_CLIENT = _Client()


def _record(cpu: float, wall: float, argv: list[str]) -> None:
    """``MCP_TEST_RUNS=FILE``: one line for this run (see the module's docstring)."""
    path = os.environ.get("MCP_TEST_RUNS")
    if path:
        test = os.environ.get("PYTEST_CURRENT_TEST", "-").rsplit(" ", 1)[0]
        with open(path, "a", encoding="utf-8") as f:
            f.write(f"{cpu:.3f}\t{wall:.3f}\t{test}\t{' '.join(argv)[:300]}\n")


def _children_cpu() -> float:
    import resource

    c = resource.getrusage(resource.RUSAGE_CHILDREN)
    return c.ru_utime + c.ru_stime


def _served(module: str) -> str:
    """``SERVED``'s key for ``python -m MODULE`` (the bare name or under ``mcp_conform.``)."""
    name = module.removeprefix("mcp_conform.")
    if name not in SERVED:
        raise ValueError(f"the fork server runs only {', '.join(SERVED)}, not {module}")
    return name


def run_module(module: str, args: list[str], *, cwd: Path | str | None = None, env: dict[str, str] | None = None,
               timeout: float = 300.0, limit_as: int | None = None) -> subprocess.CompletedProcess[str]:
    """``python -m MODULE ARGS`` (``SERVED``'s are served), as ``subprocess.run`` with
    ``capture_output=True, text=True``: in a child of the fork server when it is enabled. The
    working directory and the environment default to the caller's, as subprocess's do.

    ``limit_as``: bytes of address space (``RLIMIT_AS``, soft and hard, as ``prlimit --as``):
    set by the forked child on itself before it runs the module; for a fresh interpreter
    util-linux's prlimit(1) execs it (no ``preexec_fn`` in a process that may run threads)."""
    served = module.removeprefix("mcp_conform.") in SERVED
    if not served or not enabled():
        prefix: list[str] = []
        if limit_as is not None:
            prlimit = shutil.which("prlimit")
            if prlimit is None:
                raise RuntimeError("no prlimit(1): the address-space limit cannot be set")
            prefix = [prlimit, f"--as={limit_as}:{limit_as}", "--"]
        before, start = _children_cpu(), time.monotonic()  # a test's other threads' children: counted too
        proc = subprocess.run([*prefix, sys.executable, "-m", module, *args], cwd=cwd, env=env, capture_output=True,
                              text=True, timeout=timeout)
        if served:
            _record(_children_cpu() - before, time.monotonic() - start, [module, *args])
        return proc
    return _CLIENT.run(list(args), cwd=Path(cwd or os.getcwd()), env=dict(os.environ if env is None else env),
                       timeout=timeout, module=module, limit_as=limit_as)


# ---- the server --------------------------------------------------------------------------


def _child(request: dict, closing: list[int]) -> None:
    """In the forked child: become ``python -m mcp_conform.MODULE ARGS`` and never return."""
    import atexit
    import importlib

    code = 1
    module = request.get("module", "conformance")
    atexit._clear()  # the server's (its imports'): a fresh interpreter has none of them
    try:
        if request.get("limit_as") is not None:
            import resource

            resource.setrlimit(resource.RLIMIT_AS, (request["limit_as"], request["limit_as"]))
        for fd in closing:
            os.close(fd)
        signal.signal(signal.SIGCHLD, signal.SIG_DFL)
        null = os.open(os.devnull, os.O_RDONLY)
        os.dup2(null, 0)
        os.close(null)
        for fd, name in ((1, "stdout"), (2, "stderr")):
            f = os.open(request[name], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            os.dup2(f, fd)
            os.close(f)
        os.chdir(request["cwd"])
        extra = [p for p in request["env"].get("PYTHONPATH", "").split(os.pathsep) if p]
        sys.path[:] = [request["cwd"], *extra, *(p for p in sys.path[1:] if p not in extra)]  # as python -m has it
        os.environ.clear()
        os.environ.update(request["env"])
        sys.argv = [str(ROOT / module / "__main__.py"), *request["argv"]]
        main = importlib.import_module(SERVED[module]).main
        # the runner's ends the process itself (os._exit), its streams flushed; the others return
        raise SystemExit(main(request["argv"]))  # as ``sys.exit(main())``
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        if not isinstance(exc.code, int | None):  # the interpreter prints any other value
            print(exc.code, file=sys.stderr)
    except BaseException:
        import traceback

        traceback.print_exc()
    finally:
        try:
            atexit._run_exitfuncs()  # those the run registered, as the interpreter's exit runs them
        except BaseException:
            pass
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except Exception:
                pass
        os._exit(code)


def serve(path: str) -> None:
    _preload()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    listener.bind(path)
    listener.listen(64)
    os.write(1, b"ready\n")
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)  # the caller's pipe: closed here, so the caller never waits on it
    os.close(null)
    waiting: dict[int, socket.socket] = {}  # child pid -> its caller's connection
    pending: dict[socket.socket, bytes] = {}
    while True:
        ready, _, _ = select.select([0, listener, *pending], [], [], 0.02 if waiting else None)
        if 0 in ready and not os.read(0, 4096):
            break  # the calling process has ended
        if listener in ready:
            conn, _ = listener.accept()
            pending[conn] = b""
        for conn in [c for c in ready if c in pending]:
            data = conn.recv(1 << 16)
            if not data:
                pending.pop(conn).close()
                continue
            pending[conn] += data
            if not pending[conn].endswith(b"\n"):
                continue
            request = json.loads(pending.pop(conn))
            closing = [listener.fileno(), conn.fileno(), *(c.fileno() for c in pending),
                       *(c.fileno() for c in waiting.values())]
            pid = os.fork()
            if pid == 0:
                _child(request, closing)
            conn.sendall(b"%d\n" % pid)
            waiting[pid] = conn
        while waiting:
            pid, status, usage = os.wait4(-1, os.WNOHANG)
            if pid == 0:
                break
            conn = waiting.pop(pid, None)
            if conn is not None:
                rc = os.waitstatus_to_exitcode(status)
                try:
                    conn.sendall(b"%d %.3f\n" % (rc, usage.ru_utime + usage.ru_stime))
                except OSError:
                    pass
                conn.close()

    listener.close()
    os.unlink(path)
    os.rmdir(os.path.dirname(path))  # the caller's mkdtemp


if __name__ == "__main__":
    serve(sys.argv[1])
