"""Out of memory reported by the system rather than the interpreter: under an address-space
limit (prlimit --as, ulimit -v) importlib listing a package's directory raises OSError ENOMEM,
not MemoryError. CI run 68 (a fresh clone, no bytecode cached: a subcommand's module compiled
under test_forkserver's 64 MiB limit) printed that traceback and exited 1; it is the same one
line and exit 2 as a MemoryError."""

from __future__ import annotations

import errno

import pytest

from mcp_conform.captures import cli


@pytest.mark.parametrize("exc", [MemoryError(), OSError(errno.ENOMEM, "Cannot allocate memory", "/x/reports")],
                         ids=["MemoryError", "ENOMEM"])
def test_out_of_memory_is_one_line_and_exit_2(monkeypatch, capsys, exc):
    def boom(argv):
        raise exc

    monkeypatch.setattr(cli, "_main", boom)
    assert cli.main(["check", "x.mcap"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "out of memory" in err and "Traceback" not in err, err


def test_another_os_error_is_not_taken_for_memory(monkeypatch):
    def boom(argv):
        raise OSError(errno.EIO, "I/O error")

    monkeypatch.setattr(cli, "_main", boom)
    with pytest.raises(OSError):
        cli.main(["check", "x.mcap"])
