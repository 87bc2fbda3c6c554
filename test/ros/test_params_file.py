"""The node's parameters from a params file and ``-p`` items, for the offline commands
(``--params-file`` / ``-p``): the same names, defaults and ranges as the live node."""

from __future__ import annotations

import pytest
from ground_truth import REPO_ROOT

from sepfm_ros.ros.session.parameters import PARAMS, ParameterError, given_params


def test_the_shipped_params_file_holds_the_defaults():
    given = given_params(params_file=REPO_ROOT / "config" / "sepfm.yaml")
    assert given.values == {name: spec.default for name, spec in PARAMS.items()}
    assert "sync_slop_s" in given.given  # a value in the file counts as set by the user


def test_a_node_section_is_read_and_p_items_override_it(tmp_path):
    path = tmp_path / "params.yaml"
    path.write_text(
        "other_node:\n  ros__parameters:\n    features: akaze\n"
        "sepfm:\n  ros__parameters:\n    features: sift\n    max_features: 1500\n"
        "    threshold_px: 2\n    use_sim_time: false\n"
    )
    given = given_params(["max_features:=800"], path)
    assert given.values["features"] == "sift"  # the sepfm section, not other_node's
    assert given.values["max_features"] == 800  # -p wins over the file
    assert given.values["threshold_px"] == 2.0 and isinstance(given.values["threshold_px"], float)
    assert given.given == {"features", "max_features", "threshold_px"}


@pytest.mark.parametrize(
    ("text", "reason"),
    [
        ("/**:\n  ros__parameters:\n    featurez: sift\n", "unknown parameter 'featurez'"),
        ("/**:\n  ros__parameters:\n    threshold_px: 500.0\n", "threshold_px must be in"),
        ("/**:\n  ros__parameters:\n    max_features: many\n", "max_features must be a number"),
        ("camera:\n  ros__parameters:\n    fps: 30\n", "no ros__parameters for the sepfm node"),
        ("/**: [1, 2\n", "params file"),
    ],
)
def test_an_unusable_params_file_says_why(tmp_path, text, reason):
    path = tmp_path / "params.yaml"
    path.write_text(text)
    with pytest.raises(ParameterError, match=reason):
        given_params(params_file=path)


def test_p_items_are_checked_as_the_node_checks_them():
    with pytest.raises(ParameterError, match="one of"):
        given_params(["features:=surf"])
    with pytest.raises(ParameterError, match="name:=value"):
        given_params(["features=sift"])
