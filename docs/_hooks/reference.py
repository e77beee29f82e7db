"""MkDocs hook: the reference pages, generated at build time from the code itself.

- ``reference/cli.md``: the ``--help`` of every command, as a user's terminal prints it. The
  commands are the console scripts of ``pyproject.toml`` (``[project.scripts]``), plus
  ``mcp-vehicle`` and ``python -m mcp_conform.spec``; each is run in a subprocess with this checkout
  first on ``PYTHONPATH``. A command whose help fails fails the build.
- ``spec.md`` and ``nsqd.md``: rendered afresh from ``spec/mcp.yaml`` and ``spec/nsqd.yaml``
  by ``spec.docs`` and ``spec.docs_nsqd`` (the committed pages are the same text;
  ``python -m mcp_conform.spec docs --check`` and the spec tests keep them current).

Registered in ``mkdocs.yml`` under ``hooks:``; ``docs/_hooks/`` itself is excluded from the site.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
MARKER = "<!-- generated: the --help of every command -->"

#: the subcommands whose own --help is printed under their command's
SUBCOMMANDS: dict[str, tuple[str, ...]] = {
    "mcp-capture": ("check", "show", "diff", "replay", "export", "dissector"),
    "mcp-node": ("drone", "manager"),
    "mcp-node --protocol nsqd": ("backend", "client"),
    "python -m mcp_conform.spec": ("docs",),
}
#: commands that are not console scripts, and forms of one that take another protocol
EXTRA = ("mcp-node --protocol nsqd", "python -m mcp_conform.spec")


def _scripts() -> dict[str, str]:
    """``[project.scripts]`` of pyproject.toml: command name -> ``module:function``."""
    try:
        import tomllib
    except ImportError:  # Python 3.10: the installed distribution's entry points instead
        from importlib.metadata import entry_points

        return {ep.name: ep.value for ep in entry_points(group="console_scripts")
                if ep.value.split(".")[0] in {"conformance", "fuzz", "captures", "reference_impl",
                                              "harness", "soak", "vehicle"}}
    with open(ROOT / "pyproject.toml", "rb") as f:
        return dict(tomllib.load(f)["project"]["scripts"])


def _argv(command: str, scripts: dict[str, str]) -> list[str]:
    words = command.split()
    if words[0] == "python":
        return [sys.executable, *words[1:]]
    module, func = scripts[words[0]].split(":")
    code = (f"import sys; sys.argv[0] = {words[0]!r}; from {module} import {func}; "
            f"sys.exit({func}())")
    return [sys.executable, "-c", code, *words[1:]]


def _help(command: str, scripts: dict[str, str]) -> str:
    env = dict(os.environ, COLUMNS="100", NO_COLOR="1", TERM="dumb",
               PYTHONPATH=os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))
    proc = subprocess.run([*_argv(command, scripts), "--help"], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=60)
    if proc.returncode != 0:
        raise RuntimeError(f"`{command} --help` exited {proc.returncode}: {proc.stderr.strip()}")
    return proc.stdout.rstrip()


def cli_reference() -> str:
    scripts = _scripts()
    out: list[str] = []
    for command in [*scripts, *EXTRA]:
        out += [f"## `{command}`", "", "```text", _help(command, scripts), "```", ""]
        for sub in SUBCOMMANDS.get(command, ()):
            out += [f"### `{command} {sub}`", "", "```text",
                    _help(f"{command} {sub}", scripts), "```", ""]
    return "\n".join(out)


def spec_page(name: str) -> str:
    sys.path.insert(0, str(ROOT))
    from mcp_conform.spec import NSQD, SPEC, docs, docs_nsqd

    return docs.render(SPEC) if name == "spec.md" else docs_nsqd.render(NSQD)


def on_page_markdown(markdown: str, page, config, files) -> str:  # noqa: ANN001 (MkDocs' hook signature)
    uri = page.file.src_uri
    if uri in ("spec.md", "nsqd.md"):
        return spec_page(uri)
    if MARKER in markdown:
        return markdown.replace(MARKER, cli_reference())
    return markdown
