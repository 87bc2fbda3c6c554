"""config/sepfm.yaml, the parameter file shipped with the package, says it holds every default of
the node: it must list exactly the node's parameters, each with the default's value and type (a
ROS parameter's type is fixed by its first value: 1 and 1.0 are different parameters)."""

from __future__ import annotations

from pathlib import Path

from ruamel.yaml import YAML

from sepfm_ros.ros.session.parameters import PARAMS

CONFIG = Path(__file__).resolve().parent.parent / "config" / "sepfm.yaml"


def _yaml_parameters() -> dict:
    doc = YAML(typ="safe").load(CONFIG.read_text())
    assert list(doc) == ["/**"], "the file applies to any node name"
    return doc["/**"]["ros__parameters"]


def test_yaml_lists_every_parameter_of_the_node():
    values = _yaml_parameters()
    assert sorted(values) == sorted(PARAMS), (
        f"missing in the yaml: {sorted(set(PARAMS) - set(values))}; "
        f"unknown to the node: {sorted(set(values) - set(PARAMS))}"
    )


def test_yaml_values_are_the_node_defaults_with_their_types():
    values = _yaml_parameters()
    for name, spec in PARAMS.items():
        assert values[name] == spec.default, f"{name}: yaml {values[name]!r}, node {spec.default!r}"
        assert type(values[name]) is type(spec.default), (
            f"{name}: yaml {type(values[name]).__name__}, node {type(spec.default).__name__}"
        )
