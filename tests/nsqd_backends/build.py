"""Build the C Nsqd backend (nsqd_backend.c) with AddressSanitizer and UBSan, once per source.

``build()`` compiles ``nsqd_backend.c`` with gcc into a cache directory and returns the
executable's path.  The default directory is under ``tempfile.gettempdir()`` and named after
the sha256 of the source and of the gcc command, so repeated calls (and other processes, e.g.
pytest-xdist workers) reuse the binary; a changed source or command builds a new one.  The
compile writes a temporary name and ``os.replace``s it, so a concurrent caller never sees a
half-written executable.

``FAULTS`` maps each ``--fault NAME`` the program accepts to the rule ID it breaks; without
``--fault`` the backend follows the protocol.  ``available()`` returns a skip reason
(``GCC_MISSING_REASON``) when gcc is not installed, else None.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

SOURCE = Path(__file__).resolve().with_name("nsqd_backend.c")
EXE_NAME = "nsqd_backend"

#: The gcc command, without the output name and the source.
CFLAGS = (
    "-std=c99", "-D_POSIX_C_SOURCE=200809L", "-D_DEFAULT_SOURCE",
    "-fsanitize=address,undefined", "-fno-omit-frame-pointer", "-g", "-O1",
)

#: ``--fault NAME`` -> the rule ID that fault breaks (each breaks exactly one rule).
FAULTS: dict[str, str] = {
    "length-excludes-self": "NSQD-FRM-1",
    "no-reassembly": "NSQD-FRM-2",
    "first-frame-per-read": "NSQD-FRM-3",
    "no-close-on-bad-length": "NSQD-FRM-4",
    "small-frame-limit": "NSQD-FRM-5",
    "update-stops": "NSQD-MSG-1",
    "update-state-little-endian": "NSQD-MSG-2",
    "wrong-stop-test-state": "NSQD-MSG-3",
    "unknown-id-no-skip": "NSQD-MSG-4",
    "no-error-on-unknown-id": "NSQD-MSG-5",
    "unknown-id-hovers": "NSQD-MSG-6",
    "switch-fallthrough": "NSQD-MSG-3",
    "early-return-keeps-size": "NSQD-MSG-7",
    "crash-on-negative-string": "NSQD-ROB-1",
    "crash-on-bad-number": "NSQD-ROB-1",
    "gpx-stack-overflow": "NSQD-ROB-1",
    "overread-every-frame": "NSQD-ROB-1",
    "unbounded-gpx-alloc": "NSQD-ROB-1",
    "stale-partial-frame": "NSQD-ROB-3",
    "second-client-kicks-first": "NSQD-CON-2",
    "fd-leak": "NSQD-CON-3",
}

GCC_MISSING_REASON = "gcc is not installed (needed to build tests/nsqd_backends/nsqd_backend.c)"


def available() -> str | None:
    """None when the backend can be built here, else why not (a pytest skip reason)."""
    return None if shutil.which("gcc") else GCC_MISSING_REASON


def _command(out: Path) -> list[str]:
    return ["gcc", *CFLAGS, "-o", str(out), str(SOURCE), "-lm"]


def _key() -> str:
    digest = hashlib.sha256(SOURCE.read_bytes())
    digest.update(b"\0" + " ".join(CFLAGS).encode())
    return digest.hexdigest()


def build(out_dir: Path | None = None) -> Path:
    """The path of the built backend, compiling it only if this source has not been built.

    ``out_dir`` defaults to ``<tempdir>/nsqd_backend-<sha256 prefix>``.  A stamp file next to
    the executable records the key it was built from, so a given ``out_dir`` is reused too.
    Raises RuntimeError with gcc's output when the compile fails.
    """
    key = _key()
    if out_dir is None:
        out_dir = Path(tempfile.gettempdir()) / f"nsqd_backend-{key[:16]}"
    out_dir = Path(out_dir)
    exe, stamp = out_dir / EXE_NAME, out_dir / f"{EXE_NAME}.sha256"
    if exe.is_file() and stamp.is_file() and stamp.read_text().strip() == key:
        return exe
    out_dir.mkdir(parents=True, exist_ok=True)
    tmp = out_dir / f".{EXE_NAME}.{os.getpid()}.tmp"
    try:
        proc = subprocess.run(_command(tmp), capture_output=True, text=True, timeout=300)
        if proc.returncode != 0:
            raise RuntimeError(f"gcc failed ({proc.returncode}):\n{proc.stdout}{proc.stderr}")
        os.replace(tmp, exe)
    finally:
        tmp.unlink(missing_ok=True)
    tmp_stamp = out_dir / f".{EXE_NAME}.{os.getpid()}.sha256.tmp"
    tmp_stamp.write_text(key + "\n")
    os.replace(tmp_stamp, stamp)
    return exe


def built_or_skip() -> Path:
    """The binary for a test, or the test skipped with the reason gcc is missing."""
    import pytest

    why = available()
    if why:
        pytest.skip(why)
    return build()
