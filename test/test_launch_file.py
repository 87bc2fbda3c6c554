"""launch/sepfm_launch.py: its arguments and remaps (read without ROS), and the launch
description it generates where the ROS launch packages are installed."""

from __future__ import annotations

import ast
import importlib.util

import pytest
from ground_truth import REPO_ROOT

LAUNCH = REPO_ROOT / "launch" / "sepfm_launch.py"
ARGUMENTS = {
    "mode",
    "image_transport",
    "params_file",
    "namespace",
    "use_sim_time",
    "left",
    "right",
    "autostart",
}


def _literal_dict_keys(tree: ast.AST) -> set[str]:
    keys: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "args":
            keys |= {k.value for k in node.value.keys}
    return keys


def test_launch_file_declares_namespace_sim_time_and_remaps_base_topics():
    tree = ast.parse(LAUNCH.read_text())
    assert ARGUMENTS | {"image"} <= _literal_dict_keys(tree)
    remapped = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.keyword) and node.arg == "remappings":
            remapped = {elt.elts[0].value for elt in node.value.elts}
    # base image topics only: the node adds /compressed after resolving them
    assert remapped == {"left/image_raw", "right/image_raw", "image_raw"}
    assert "compressed" not in {r.split("/")[-1] for r in remapped}


def test_the_node_is_a_lifecycle_node_with_autostart():
    """launch_ros's LifecycleNode (its lifecycle services for a manager); autostart passed on."""
    tree = ast.parse(LAUNCH.read_text())
    calls = [n for n in ast.walk(tree) if isinstance(n, ast.Call)]
    names = {getattr(c.func, "id", "") for c in calls}
    assert "LifecycleNode" in names and "Node" not in names
    imports = {
        (n.module, a.name) for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) for a in n.names
    }
    assert ("launch_ros.actions", "LifecycleNode") in imports
    node = next(c for c in calls if getattr(c.func, "id", "") == "LifecycleNode")
    kw = {k.arg: k.value for k in node.keywords}
    assert "autostart" in ast.unparse(kw["parameters"])


def test_launch_description_generates():
    if importlib.util.find_spec("launch_ros") is None:
        pytest.skip("launch_ros is not installed here (it is not on PyPI; a ROS install has it)")
    spec = importlib.util.spec_from_file_location("sepfm_launch", LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    names = {getattr(e, "name", None) for e in description.entities}
    assert ARGUMENTS <= names
