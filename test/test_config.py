"""config/sepfm.yaml, the parameter file shipped with the package, says it holds every default of
the node: it must list exactly the node's parameters, each with the default's value and type (a
ROS parameter's type is fixed by its first value: 1 and 1.0 are different parameters)."""

from __future__ import annotations

from pathlib import Path

from ruamel.yaml import YAML

from sepfm_ros.ros.session.parameters import COMPUTED_DEFAULTS, PARAMS

CONFIG = Path(__file__).resolve().parent.parent / "config" / "sepfm.yaml"


def _yaml_parameters() -> dict:
    doc = YAML(typ="safe").load(CONFIG.read_text())
    assert list(doc) == ["/**"], "the file applies to any node name"
    return doc["/**"]["ros__parameters"]


def test_yaml_lists_every_parameter_of_the_node():
    """Every parameter but those whose default follows other parameters (a value in the file
    would fix it whatever the mode): those are named in a comment with their rule."""
    values = _yaml_parameters()
    listed = set(PARAMS) - set(COMPUTED_DEFAULTS)
    assert sorted(values) == sorted(listed), (
        f"missing in the yaml: {sorted(listed - set(values))}; "
        f"unknown to the node: {sorted(set(values) - listed)}"
    )
    text = CONFIG.read_text()
    for name in COMPUTED_DEFAULTS:
        assert f"# {name}:" in text, f"{name}: its rule is not given in a comment"


def test_yaml_values_are_the_node_defaults_with_their_types():
    values = _yaml_parameters()
    for name, spec in PARAMS.items():
        if name in COMPUTED_DEFAULTS:
            continue
        assert values[name] == spec.default, f"{name}: yaml {values[name]!r}, node {spec.default!r}"
        assert type(values[name]) is type(spec.default), (
            f"{name}: yaml {type(values[name]).__name__}, node {type(spec.default).__name__}"
        )
