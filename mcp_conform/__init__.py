"""mcp-conform: a conformance and fuzz test harness for drone mission protocols.

One import namespace (docs/architecture.md): ``mcp_conform.spec``, ``mcp_conform.harness``, ...
The packages are the checkout's top-level folders; the wheel installs them under this one
package (setuptools' ``package-dir``), and in a checkout this folder holds a link to each, so
nothing of ours is ever importable as a bare ``spec`` or ``reports``.

The package imports nothing itself: pytest loads ``mcp_conform.conformance.plugin`` in every
run of an environment that has us, and such a run that does not ask for the runner costs
nothing (``mcp_conform.spec.about.__version__`` is the version).

An unpacked sdist has no links (an archive of the tree as git has it keeps none of them):
there the checkout's root is searched for the subpackages instead.
"""

import os as _os

_root = _os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))
if not _os.path.isdir(_os.path.join(__path__[0], "spec")) and _os.path.isfile(
        _os.path.join(_root, "spec", "__init__.py")) and _os.path.isfile(_os.path.join(_root, "pyproject.toml")):
    __path__.append(_root)
del _os, _root
