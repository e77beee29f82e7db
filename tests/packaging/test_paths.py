"""The code points only at what the wheel ships (issue 40 item 3): every file the packages
find beside themselves (``Path(__file__)``, ``importlib.resources``) is accounted for here, and
no message or default names a folder of the repository that an installed wheel does not have
(``examples/``, ``docs/``, ``tests/``...). ``test_dist.py`` checks each such path is in the
built wheel."""

from __future__ import annotations

import ast
import json
import re

from tests.packaging.tree import ROOT, module_paths, resource_paths, sources, texts, top_packages

#: Modules that use ``__file__`` for something other than a file of their own shipped beside
#: them (those are module-level Path constants, found by ``module_paths``), and why that holds
#: in an installed wheel.
OTHER_FILE_USES = {
    "spec/docs.py": "docs/spec.md of the source tree, only when pyproject.toml is beside the "
    "package (a checkout); else the working directory's: a page it writes",
    "spec/docs_nsqd.py": "docs/nsqd.md, as spec/docs.py",
    "conformance/cli.py": "the folder of an imported case package (a package the wheel ships)",
    "captures/dissector_mavlink.py": "pymavlink's own dialect files",
    "vehicle/cli.py": "spec/about.py, the version's one source (a package the wheel ships): read, not imported",
}

#: String constants naming a folder of the repository, and why each is no pointer into it.
REPO_FOLDER_STRINGS = {
    (
        "spec/__main__.py",
        "docs/spec.md",
    ): "python -m mcp_conform.spec docs writes the page (a developer's command)",
    ("traceio/fox.py", "examples/foxglove-layout.json"): "LAYOUT_FILE: the repository's copy, "
    "which tests/traceio/test_foxglove.py regenerates; the banner names traceio.live.LAYOUT_PATH",
}
REPO_FOLDER = re.compile(r"(?<![\w./-])(examples|docs|bench|tests|captures/golden|\.ci)/[\w./-]*")


def _sources():
    return texts()  # the texts alone: no syntax tree parsed for this scan


def test_every_file_the_code_finds_beside_itself_is_accounted_for():
    constants = module_paths()
    owners = {"/".join(name.split(".")[:-1]) for name in constants}  # spec._load -> spec/_load
    unaccounted = []
    for rel, text in _sources():
        if "__file__" not in text:
            continue
        module = rel.removesuffix(".py").removesuffix("/__init__")
        if module not in owners and rel not in OTHER_FILE_USES:
            lines = [i for i, ln in enumerate(text.splitlines(), 1) if "__file__" in ln]
            unaccounted.append(f"{rel}:{lines}")
    assert not unaccounted, (
        "a module finds a file through __file__ that no module-level Path names: make it "
        "one (test_dist checks the wheel holds it) or say why in OTHER_FILE_USES: "
        + ", ".join(unaccounted)
    )
    # the ones known today, so that a path lost from the scan is noticed
    assert {"captures/golden", "traceio/foxglove-layout.json", "spec/mcp.yaml"} <= set(
        constants.values()
    ), constants
    assert {"captures/check.schema.json", "conformance/report.schema.json"} <= resource_paths()


def test_no_message_or_default_names_a_folder_the_wheel_does_not_have():
    named = []
    for rel, _, tree in sources():
        docstrings = {
            id(n.body[0].value)
            for n in ast.walk(tree)
            if isinstance(n, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef))
            and n.body
            and isinstance(n.body[0], ast.Expr)
            and isinstance(n.body[0].value, ast.Constant)
        }
        for node in ast.walk(tree):
            if (
                isinstance(node, ast.Constant)
                and isinstance(node.value, str)
                and id(node) not in docstrings
            ):
                for m in REPO_FOLDER.finditer(node.value):
                    if (rel, m.group(0)) not in REPO_FOLDER_STRINGS:
                        named.append(f"{rel}:{node.lineno}: {m.group(0)!r} in {node.value[:80]!r}")
    assert not named, "an installed wheel has no such folder:\n" + "\n".join(named)


def test_the_shipped_layout_is_the_examples_one():
    """The banner's layout (package data) and the README's (examples/) are the same file;
    tests/traceio/test_foxglove.py checks the latter is what traceio.fox.layout_json builds."""
    shipped = (ROOT / module_paths()["traceio.live.LAYOUT_PATH"]).read_text(encoding="utf-8")
    assert shipped == (ROOT / "examples" / "foxglove-layout.json").read_text(encoding="utf-8")
    assert json.loads(shipped)


def test_every_subpackage_on_disk_is_a_package_the_wheel_ships():
    """Each folder with an ``__init__.py`` below a shipped package is in pyproject.toml's
    explicit ``packages`` (a new case package left out installs without its cases: the
    wheel's ``--protocol mavlink`` found none until cases_mavlink was listed)."""
    from tests.packaging.tree import NAMESPACE, pyproject

    listed = set(pyproject()["tool"]["setuptools"]["packages"])
    on_disk = {f"{NAMESPACE}.{top}" + "".join(f".{part}" for part in init.parent.relative_to(ROOT / top).parts)
               for top in top_packages() for init in (ROOT / top).rglob("__init__.py")
               if "__pycache__" not in init.parts}
    assert on_disk - listed == set(), sorted(on_disk - listed)
