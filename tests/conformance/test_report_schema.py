"""The report's and the capture check's JSON Schemas are read from the installed package: they
were read from top-level ``conformance`` and ``captures`` packages, which only a checkout's
working directory has (an installed wheel has ``mcp_conform.conformance`` and
``mcp_conform.captures``): ``validate_json`` raised "No module named 'conformance'" anywhere else."""

from __future__ import annotations

import os
import subprocess
import sys


def test_the_schema_is_read_from_the_installed_package(tmp_path):
    """From a directory where no top-level ``conformance`` or ``captures`` package is
    importable, as with an installed wheel: both schemas load."""
    code = ("from mcp_conform.conformance.report import load_schema as a\n"
            "from mcp_conform.captures.check import load_schema as b\n"
            "print(a()['title'] and 'ok', b() and 'ok')")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert out.returncode == 0 and out.stdout.split() == ["ok", "ok"], out.stdout + out.stderr
