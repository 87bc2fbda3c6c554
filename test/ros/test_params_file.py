"""The node's parameters from a params file and ``-p`` items, for the offline commands
(``--params-file`` / ``-p``): the same names, defaults and ranges as the live node."""

from __future__ import annotations

import pytest
from ground_truth import REPO_ROOT

from sepfm_ros.ros.session.parameters import (
    DIAGNOSTIC_PERIOD,
    PARAMS,
    ParameterError,
    given_params,
)


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


def test_the_diagnostics_period_is_diagnostic_updaters_and_the_old_name_warns(tmp_path):
    path = tmp_path / "params.yaml"
    # nested as diagnostic_updater's own params files write it
    path.write_text("/**:\n  ros__parameters:\n    diagnostic_updater:\n      period: 0.5\n")
    assert given_params(params_file=path).values[DIAGNOSTIC_PERIOD] == 0.5
    path.write_text("/**:\n  ros__parameters:\n    diagnostics_period_s: 0.25\n")
    with pytest.warns(FutureWarning, match="diagnostics_period_s is renamed"):
        given = given_params(params_file=path)
    assert given.values[DIAGNOSTIC_PERIOD] == 0.25 and "diagnostics_period_s" not in given.values
    with pytest.warns(FutureWarning, match="diagnostic_updater.period"):
        given = given_params(["diagnostics_period_s:=2.0"])
    assert given.values[DIAGNOSTIC_PERIOD] == 2.0 and given.given == {DIAGNOSTIC_PERIOD}
