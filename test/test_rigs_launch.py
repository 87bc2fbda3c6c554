"""launch/sepfm_rigs_launch.py: one stereo node per rig namespace (read without ROS's launch
packages, which are not on PyPI; where they are installed, the description is generated)."""

from __future__ import annotations

import ast
import importlib.util

import pytest
from ground_truth import REPO_ROOT

LAUNCH = REPO_ROOT / "launch" / "sepfm_rigs_launch.py"


def _rig_names():
    """The launch file's own ``rig_names`` function, compiled alone."""
    tree = ast.parse(LAUNCH.read_text())
    func = next(n for n in tree.body if isinstance(n, ast.FunctionDef) and n.name == "rig_names")
    namespace: dict = {}
    exec(compile(ast.Module([func], []), str(LAUNCH), "exec"), namespace)  # noqa: S102
    return namespace["rig_names"]


def test_rigs_argument_names_one_namespace_per_rig():
    rig_names = _rig_names()
    assert rig_names("front, /rear ,") == ["front", "rear"]
    with pytest.raises(ValueError, match="names no rig"):
        rig_names(" , ")
    with pytest.raises(ValueError, match="twice"):
        rig_names("front,front")


def test_each_rig_is_a_stereo_node_in_its_namespace():
    tree = ast.parse(LAUNCH.read_text())
    keys: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "args":
            keys |= {k.value for k in node.value.keys}
    assert keys == {"rigs", "image_transport", "params_file", "use_sim_time", "autostart"}
    calls = [
        n
        for n in ast.walk(tree)
        if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "LifecycleNode"
    ]
    assert not [
        n for n in ast.walk(tree) if isinstance(n, ast.Call) and getattr(n.func, "id", "") == "Node"
    ]
    assert len(calls) == 1
    kw = {k.arg: k.value for k in calls[0].keywords}
    assert getattr(kw["namespace"], "id", "") == "name"  # the rig's own namespace
    assert ast.literal_eval(kw["name"]) == "sepfm" and ast.literal_eval(kw["executable"]) == "node"
    assert "remappings" not in kw  # relative inputs resolve in the rig's namespace
    parameters = ast.unparse(kw["parameters"]).replace("'", '"')
    assert '"mode": "stereo"' in parameters and '"autostart": autostart' in parameters


def test_launch_description_generates():
    if importlib.util.find_spec("launch_ros") is None:
        pytest.skip("launch_ros is not installed here (it is not on PyPI; a ROS install has it)")
    spec = importlib.util.spec_from_file_location("sepfm_rigs_launch", LAUNCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    names = {getattr(e, "name", None) for e in module.generate_launch_description().entities}
    assert {"rigs", "image_transport", "params_file", "use_sim_time", "autostart"} <= names
