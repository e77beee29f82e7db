"""``--db`` as a Redis URL is redis-py's (``Redis.from_url``): a password reaches the server,
a wrong or missing one is a one-line error that never echoes it, a malformed URL is one line
too (issue 40 item 4: the hand-written parser dropped passwords). A real redis-server on a
free loopback port; skipped where it is not installed."""

from __future__ import annotations

import shutil
import subprocess
import time
from collections.abc import Iterator

import pytest

from mcp_conform.fuzz.cli import UsageError, _check_reachable
from mcp_conform.vehicle.ports import free_port

SECRET = "s3cret-pw"


@pytest.fixture
def redis_with_password(tmp_path) -> Iterator[int]:
    exe = shutil.which("redis-server")
    if exe is None:
        pytest.skip("redis-server is not installed (Debian package redis-server, .ci/apt-tools)")
    import socket

    from redis import Redis

    port = free_port(kind=socket.SOCK_STREAM)
    proc = subprocess.Popen([exe, "--port", str(port), "--bind", "127.0.0.1", "--save", "", "--appendonly", "no",
                             "--requirepass", SECRET, "--dir", str(tmp_path)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 10
        while True:
            try:
                Redis(host="127.0.0.1", port=port, password=SECRET, socket_connect_timeout=0.5).ping()
                break
            except Exception:  # noqa: BLE001 - not up yet
                if time.monotonic() > deadline or proc.poll() is not None:
                    pytest.fail("redis-server did not answer")
                time.sleep(0.05)
        yield port
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_password_in_the_url_reaches_the_server(redis_with_password: int) -> None:
    _check_reachable(f"redis://:{SECRET}@127.0.0.1:{redis_with_password}/0")


@pytest.mark.parametrize("auth", ["", ":wrong-pw@"], ids=["none", "wrong"])
def test_a_missing_or_wrong_password_is_one_line_without_the_password(redis_with_password: int,
                                                                     auth: str) -> None:
    url = f"redis://{auth}127.0.0.1:{redis_with_password}/0"
    with pytest.raises(UsageError) as err:
        _check_reachable(url)
    msg = str(err.value)
    assert msg.startswith("--db: cannot reach redis://") and "\n" not in msg, msg
    assert "wrong-pw" not in msg and SECRET not in msg, msg


def test_a_malformed_url_is_one_line() -> None:
    with pytest.raises(UsageError) as err:
        _check_reachable(f"redis://:{SECRET}@127.0.0.1:not-a-port/0")
    msg = str(err.value)
    assert "is not a Redis URL" in msg and "\n" not in msg and SECRET not in msg, msg


def test_the_campaigns_database_keeps_the_password(redis_with_password: int) -> None:
    """The stateful engines' example database (``fuzz.engine_stateful.open_database``) is opened
    from the same URL by redis-py: what one worker saves, another reads (the hand-written parser
    kept host, port and db only, so a password-protected server refused every save)."""
    from mcp_conform.fuzz.engine_stateful import check_database, open_database

    url = f"redis://:{SECRET}@127.0.0.1:{redis_with_password}/0"
    check_database(url)
    db = open_database(url)
    assert db is not None
    db.save(b"program", b"moves")
    assert list(open_database(url).fetch(b"program")) == [b"moves"]
    with pytest.raises(ValueError, match="not a Redis URL"):
        check_database(f"redis://:{SECRET}@127.0.0.1:not-a-port/0")
