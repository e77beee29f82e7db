"""The stream session spawns its backend through the runner's one spawn helper
(``harness.session_base``: ``fill_placeholders``, ``SpawnedNode``), so ``--spawn`` means the
same for every protocol: a placeholder the stream does not fill (``{id}``) is left as it is,
not a KeyError; a command that cannot be split is a one-line setup error; a program that
cannot be started is a setup error naming it, not an OSError."""

from __future__ import annotations

import shlex
import sys

import pytest

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.nsqd_session import StreamSession

#: listens on the port it is given and sends each connection 8 bytes at once (bytes the
#: runner cannot parse prove the backend live too: NSQD-FRM-1's to judge)
SERVE = ("import socket, sys, threading, time\n"
         "s = socket.socket(); s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)\n"
         "s.bind((sys.argv[1], int(sys.argv[2]))); s.listen(8)\n"
         "def serve(c):\n"
         "    c.sendall(b'\\xff' * 8); time.sleep(1); c.close()\n"
         "while True:\n"
         "    threading.Thread(target=serve, args=(s.accept()[0],), daemon=True).start()\n")


def test_a_placeholder_the_stream_does_not_fill_is_left_as_it_is():
    cmd = f"{shlex.quote(sys.executable)} -c {shlex.quote(SERVE)} {{target_host}} {{target_port}} --id {{id}}"
    s = StreamSession(RunConfig(spawn=cmd))
    try:
        s.start()  # str.format raised KeyError('id') here
        assert s.node is not None and s.node.argv[-2:] == ["--id", "{id}"]
        assert s.node.argv[-4:-2] == ["127.0.0.1", str(s.address[1])]
    finally:
        s.close()


def test_a_command_that_cannot_be_split_is_a_one_line_setup_error():
    s = StreamSession(RunConfig(spawn="backend --name 'unclosed {target_port}"))
    with pytest.raises(SetupError, match=r"^--spawn: cannot split command: No closing quotation$"):
        s.start()
    s.close()


def test_a_program_that_cannot_start_is_a_setup_error_naming_it():
    s = StreamSession(RunConfig(spawn="/nonexistent/nsqd-backend --port {target_port}"))
    with pytest.raises(SpawnFailure, match=r"^--spawn: cannot start '/nonexistent/nsqd-backend': "):
        s.start()  # an OSError escaped here
    s.close()
