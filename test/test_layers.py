"""Imports point down the layers and form no cycle (docs/design.md, "Layout").

Read from the source with ``ast`` (nothing is imported): every ``import`` / ``from ... import`` of
a ``sepfm_ros`` module, at module level or inside a function, is an edge. The rules:

- ``sepfm_ros.geometry`` imports no other part of ``sepfm_ros``; ``sepfm_ros.pipeline`` imports
  only the geometry and itself (not ``ros``, ``stream``, ``evaluation``, the CLI).
- inside the geometry, each folder imports only the folders below it (:data:`GEOMETRY_ALLOWED`):
  ``robust/`` nothing specific to F, ``fundamental/`` no part of the separable method, ...
- no cycle between modules (a strongly connected component of more than one module).
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "sepfm_ros"
GEOMETRY = "sepfm_ros.geometry"

#: geometry part -> the geometry parts it may import (besides itself). ``base``: the modules
#: below everything (epipolar algebra, the result type, synthetic pairs); ``top``: the public
#: entry (``__init__``, ``estimator``, ``options``, the ``pose`` facade, the kernel warm-up).
GEOMETRY_ALLOWED: dict[str, set[str]] = {
    "base": set(),
    "solvers": {"base"},
    "robust": set(),
    "fundamental": {"base", "solvers", "robust"},
    "separable": {"base", "solvers", "robust", "fundamental"},
    "calibrated": {"base", "solvers"},
    "top": {"base", "solvers", "robust", "fundamental", "separable", "calibrated"},
}
GEOMETRY_BASE = {"epipolar", "estimate", "synthetic"}
GEOMETRY_FOLDERS = {"solvers", "robust", "fundamental", "separable", "calibrated"}
#: layer of sepfm_ros -> the layers it may import (besides itself)
PACKAGE_ALLOWED: dict[str, set[str]] = {
    "geometry": set(),
    "pipeline": {"geometry"},
    "stream": set(),
    "synthetic": {"geometry"},
    "fleet": set(),
    "ros": {"geometry", "pipeline", "stream", "synthetic", "fleet"},
    "evaluation": {"geometry", "pipeline", "ros"},
}
ROS = "sepfm_ros.ros"
#: subpackage of sepfm_ros.ros -> the subpackages it may import (besides itself), by role:
#: message adapters, the session (a stream's set-up and answers), bag I/O and offline pairing,
#: offline paths (a bag through the session), the node runtime, and the commands on top
ROS_ALLOWED: dict[str, set[str]] = {
    "msgs": set(),
    "session": {"msgs"},
    "bags": {"msgs", "session"},
    "offline": {"msgs", "session", "bags"},
    "node": {"msgs", "session", "bags"},
    "commands": {"msgs", "session", "bags", "offline", "node"},
}
#: modules of ros/commands that are not commands (any command, and eval, may import them)
COMMAND_LIBRARIES = {f"{ROS}.commands.options"}
#: what the rest of sepfm_ros may import of sepfm_ros.ros (the eval and demo commands)
ROS_USERS_ALLOWED = {"msgs", "session", "bags", "node"}


def module_name(path: Path, root: Path) -> str:
    """Dotted module name of a source file under ``root`` (a package: its ``__init__``'s name)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def source_modules(package: Path = PACKAGE) -> dict[str, Path]:
    """Every module of the package: dotted name -> file."""
    return {module_name(p, package.parent): p for p in sorted(package.rglob("*.py"))}


def imported(path: Path, name: str, modules: set[str]) -> set[str]:
    """The modules of ``modules`` that the file ``path`` (module ``name``) imports.

    ``from a.b import c`` is an edge to ``a.b.c`` when that is a module, else to ``a.b``."""
    tree = ast.parse(path.read_text(), filename=str(path))
    is_package = path.name == "__init__.py"
    out: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(alias.name for alias in node.names if alias.name in modules)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:  # relative: resolve against this module's package
                anchor = name.split(".")
                anchor = anchor[: len(anchor) - node.level + (1 if is_package else 0)]
                base = ".".join([*anchor, base] if base else anchor)
            for alias in node.names:
                full = f"{base}.{alias.name}"
                if full in modules:
                    out.add(full)
                elif base in modules:
                    out.add(base)
    out.discard(name)
    return out


def import_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """module -> the package's modules it imports."""
    modules = source_modules(package)
    names = set(modules)
    return {name: imported(path, name, names) for name, path in modules.items()}


def layer(module: str) -> str | None:
    """The sepfm_ros layer of a module (``geometry``, ``pipeline``, ``ros``, ...), None for the
    package itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def geometry_part(module: str) -> str:
    """The geometry part (a key of GEOMETRY_ALLOWED) of a module of sepfm_ros.geometry."""
    first = module[len(GEOMETRY) :].lstrip(".").split(".")[0]
    if first in GEOMETRY_FOLDERS:
        return first
    return "base" if first in GEOMETRY_BASE else "top"


def upward_imports(graph: dict[str, set[str]]) -> list[str]:
    """Every import that breaks a layer rule, as 'importer -> imported (why)'."""
    bad = []
    for module, targets in sorted(graph.items()):
        for target in sorted(targets):
            a, b = layer(module), layer(target)
            if a in PACKAGE_ALLOWED and b is not None and b != a and b not in PACKAGE_ALLOWED[a]:
                bad.append(f"{module} -> {target} ({a} may import {sorted(PACKAGE_ALLOWED[a])})")
            if a == b == "geometry":
                pa, pb = geometry_part(module), geometry_part(target)
                if pb != pa and pb not in GEOMETRY_ALLOWED[pa]:
                    bad.append(
                        f"{module} -> {target} (geometry/{pa} may import "
                        f"{sorted(GEOMETRY_ALLOWED[pa])})"
                    )
    return bad


def ros_part(module: str) -> str | None:
    """The subpackage of sepfm_ros.ros a module is in (None: outside, or ros itself)."""
    if not module.startswith(ROS + "."):
        return None
    return module[len(ROS) + 1 :].split(".")[0]


def ros_imports(graph: dict[str, set[str]]) -> list[str]:
    """Every import that breaks a rule of sepfm_ros.ros's layout, as 'importer -> imported
    (why)': a subpackage importing one above it, a command importing another command, and
    a module outside ros importing a ros command or an offline path."""
    bad = []
    for module, targets in sorted(graph.items()):
        a = ros_part(module)
        for target in sorted(targets):
            b = ros_part(target)
            if b is None or target in COMMAND_LIBRARIES:
                continue
            if a is None and b not in ROS_USERS_ALLOWED:
                bad.append(f"{module} -> {target} (outside ros: {sorted(ROS_USERS_ALLOWED)})")
            elif a == b == "commands":
                bad.append(f"{module} -> {target} (a command imports another command)")
            elif a is not None and a != b and b not in ROS_ALLOWED.get(a, set()):
                bad.append(f"{module} -> {target} (ros/{a} may import {sorted(ROS_ALLOWED[a])})")
    return bad


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_points_up_a_layer():
    assert upward_imports(import_graph()) == []


def test_ros_subpackages_import_down_and_no_command_imports_another():
    assert ros_imports(import_graph()) == []


def test_every_ros_module_is_in_a_role_subpackage():
    """ros/ holds subpackages by role only (no flat modules beside them)."""
    ros = PACKAGE / "ros"
    flat = sorted(p.name for p in ros.glob("*.py") if p.name != "__init__.py")
    assert flat == [], flat
    assert {p.name for p in ros.iterdir() if (p / "__init__.py").is_file()} == set(ROS_ALLOWED)


def test_the_ros_rules_see_a_command_importing_a_command(tmp_path):
    """The rules fire on a tiny tree: a command importing another, the session importing the
    node, the evaluation importing a command; the shared options are allowed."""
    pkg = tmp_path / "sepfm_ros"
    files = {
        "__init__.py": "",
        "ros/__init__.py": "",
        "ros/commands/__init__.py": "",
        "ros/commands/options.py": "",
        "ros/commands/record.py": "from sepfm_ros.ros.commands import replay, options\n",
        "ros/commands/replay.py": "from sepfm_ros.ros.node.replayer import Replayer\n",
        "ros/node/__init__.py": "",
        "ros/node/replayer.py": "Replayer = 1\n",
        "ros/session/__init__.py": "",
        "ros/session/session.py": "from sepfm_ros.ros.node import replayer\n",
        "evaluation/__init__.py": "",
        "evaluation/cli.py": (
            "import sepfm_ros.ros.commands.record\nimport sepfm_ros.ros.commands.options\n"
        ),
    }
    for rel, text in files.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    bad = ros_imports(import_graph(pkg))
    assert bad == [
        "sepfm_ros.evaluation.cli -> sepfm_ros.ros.commands.record (outside ros: "
        "['bags', 'msgs', 'node', 'session'])",
        "sepfm_ros.ros.commands.record -> sepfm_ros.ros.commands.replay (a command imports "
        "another command)",
        "sepfm_ros.ros.session.session -> sepfm_ros.ros.node.replayer (ros/session may import "
        "['msgs'])",
    ], bad


def test_no_import_cycle_between_modules():
    assert cycles(import_graph()) == []


@pytest.mark.parametrize(
    "module, part",
    [
        ("sepfm_ros.geometry.robust.loop", "robust"),
        ("sepfm_ros.geometry.fundamental.problem", "fundamental"),
        ("sepfm_ros.geometry.separable.method", "separable"),
        ("sepfm_ros.geometry.solvers.seven_point", "solvers"),
        ("sepfm_ros.geometry.calibrated.pose", "calibrated"),
        ("sepfm_ros.geometry.epipolar", "base"),
        ("sepfm_ros.geometry.estimator", "top"),
        ("sepfm_ros.geometry.pose", "top"),
        ("sepfm_ros.geometry", "top"),
    ],
)
def test_modules_are_placed_in_their_part(module, part):
    assert geometry_part(module) == part


def test_the_checks_see_a_planted_upward_import_and_cycle(tmp_path):
    """The rules fire on a copy of a tiny tree with one upward import and one cycle."""
    pkg = tmp_path / "sepfm_ros"
    files = {
        "__init__.py": "",
        "geometry/__init__.py": "",
        "geometry/robust/__init__.py": "",
        "geometry/robust/loop.py": "from sepfm_ros.geometry.separable import method\n",
        "geometry/separable/__init__.py": "",
        "geometry/separable/method.py": "import sepfm_ros.geometry.robust.loop\n",
        "pipeline/__init__.py": "",
        "pipeline/pipeline.py": "def f():\n    from sepfm_ros.ros import node\n",
        "ros/__init__.py": "",
        "ros/node.py": "",
    }
    for rel, text in files.items():
        (pkg / rel).parent.mkdir(parents=True, exist_ok=True)
        (pkg / rel).write_text(text)
    graph = import_graph(pkg)
    bad = upward_imports(graph)
    assert any(b.startswith("sepfm_ros.geometry.robust.loop -> ") for b in bad), bad
    assert any(b.startswith("sepfm_ros.pipeline.pipeline -> sepfm_ros.ros") for b in bad), bad
    assert cycles(graph) == [
        ["sepfm_ros.geometry.robust.loop", "sepfm_ros.geometry.separable.method"]
    ]
