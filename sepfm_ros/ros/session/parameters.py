"""The node's parameters: names, defaults, ranges and descriptions, their validation, and the
:class:`~sepfm_ros.pipeline.pipeline.PipelineConfig` they make. Shared by the node and by
``process`` (offline processing takes the same ``-p NAME:=VALUE`` parameters).

``config/sepfm.yaml`` lists the same defaults (a test keeps them equal).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
)

from sepfm_ros.geometry.calibrated.correction_config import CorrectionConfig
from sepfm_ros.geometry.calibrated.monitor import MonitorConfig
from sepfm_ros.geometry.options import DEFAULT_METHOD, METHODS, EstimatorOptions
from sepfm_ros.pipeline.config import FEATURE_MAX_WIDTH, FEATURES, PipelineConfig

NODE_NAME = "sepfm"
MODES = ("stereo", "motion")
TRANSPORTS = ("raw", "compressed")
# Estimator option that the hough_width_px parameter sets (0 = leave the estimator's default).
HOUGH_WIDTH_OPTION = "hough_width"
# Estimator option that the max_samples parameter sets.
MAX_SAMPLES_OPTION = "max_samples"


_MONITOR = MonitorConfig()  # the calibration check's defaults
_CORRECTION = CorrectionConfig()  # the correction's defaults

# the period of the /diagnostics report, named as diagnostic_updater names it
DIAGNOSTIC_PERIOD = "diagnostic_updater.period"
# old name -> current name. An old name still sets its parameter (``-p``, params files, the
# node's overrides), with a warning that names the current one.
RENAMED_PARAMS = {"diagnostics_period_s": DIAGNOSTIC_PERIOD, "transport": "image_transport"}


def renamed_text(old: str) -> str:
    """The warning for the old parameter name ``old``."""
    return f"parameter {old} is renamed {RENAMED_PARAMS[old]}; set {RENAMED_PARAMS[old]} instead"


def renamed_help() -> str:
    """The renamed parameters, for --help."""
    return "renamed (the old name still works, with a warning):\n" + "\n".join(
        f"  {old} -> {new}" for old, new in RENAMED_PARAMS.items()
    )


def current_name(name: str, warn: bool = True) -> str:
    """``name``, or the current name of a renamed parameter (with a FutureWarning if ``warn``)."""
    if name not in RENAMED_PARAMS:
        return name
    if warn:
        warnings.warn(renamed_text(name), FutureWarning, stacklevel=3)
    return RENAMED_PARAMS[name]


def renamed_values(
    overrides: Mapping[str, Any], params: Mapping[str, ParamSpec] | None = None
) -> tuple[dict[str, Any], list[str]]:
    """A node's values given under an old name (``overrides``: rclpy's parameter overrides,
    name -> Parameter or value, from ``-p`` and params files): ({current name: value} for those
    of ``params`` (default :data:`PARAMS`) not given under their own name, the warnings to
    log, one per old name given)."""
    params = PARAMS if params is None else params
    values: dict[str, Any] = {}
    texts: list[str] = []
    for old, new in RENAMED_PARAMS.items():
        if old not in overrides or new not in params:
            continue
        if new in overrides:
            texts.append(f"{renamed_text(old)}; ignored, {new} is given")
        else:
            texts.append(renamed_text(old))
            values[new] = getattr(overrides[old], "value", overrides[old])
    return values, texts


@dataclass(frozen=True)
class ParamSpec:
    """One node parameter: default, description, and either a numeric range or choices."""

    default: Any
    description: str
    low: float | None = None
    high: float | None = None
    choices: tuple[str, ...] = ()
    read_only: bool = False


PARAMS: dict[str, ParamSpec] = {
    "mode": ParamSpec(
        "stereo",
        "stereo: pair left/image_raw with right/image_raw by stamp; motion: frame t-gap with t",
        choices=MODES,
        read_only=True,
    ),
    "image_transport": ParamSpec(
        "raw",
        "image_transport's TransportHints: raw = sensor_msgs/Image on <topic>; compressed ="
        " sensor_msgs/CompressedImage on <topic>/compressed (jpeg, png)",
        choices=TRANSPORTS,
        read_only=True,
    ),
    "input_reliability": ParamSpec(
        "auto",
        "QoS reliability of the image subscriptions: auto = what the publishers offer (reliable"
        " when all of them publish reliable; followed when they change, each switch counted in"
        " /diagnostics), reliable, or best_effort",
        choices=("auto", "reliable", "best_effort"),
        read_only=True,
    ),
    "sync_slop_s": ParamSpec(
        0.005,
        "stereo: largest stamp difference of a pair, s (0 = exact; up to half the frame period"
        " pairs each left frame with its nearest right one)",
        0.0,
        1.0,
    ),
    "sync_queue_size": ParamSpec(10, "stereo: unpaired messages kept per side", 1, 1000),
    "stamp_jump_reset_s": ParamSpec(
        1.0,
        "a frame stamped this much before the newest one (a looped bag, a restarted driver or"
        " simulator) restarts the pairing instead of being dropped as late, s",
        0.001,
        1e6,
    ),
    "frame_gap": ParamSpec(1, "motion: F between frame t - frame_gap and frame t", 1, 100),
    "features": ParamSpec(
        "orb",
        "feature detector/descriptor (akaze where this OpenCV has it: OpenCV 4, or OpenCV 5's "
        "contrib wheel)",
        choices=FEATURES,
    ),
    "max_features": ParamSpec(1000, "keypoints per image (orb, sift)", 8, 100000),
    "feature_max_width": ParamSpec(
        FEATURE_MAX_WIDTH,
        "features of an image wider than this are detected on a copy downscaled by the integer"
        " factor ceil(width / feature_max_width) (INTER_AREA), their keypoints mapped back to"
        " full-resolution pixels, so matches and F stay in the image's pixels; px (0 = always"
        " full size)",
        0,
        100000,
    ),
    "ratio": ParamSpec(0.8, "Lowe ratio-test bound for matches", 0.05, 1.0),
    "max_matches": ParamSpec(0, "keep at most this many best matches (0 = all)", 0, 100000),
    "method": ParamSpec(DEFAULT_METHOD, "estimator method", choices=METHODS),
    "threshold_px": ParamSpec(
        1.0, "inlier threshold, symmetric epipolar distance, px", 0.01, 100.0
    ),
    "confidence": ParamSpec(0.99, "RANSAC confidence", 0.5, 0.999999),
    "max_samples": ParamSpec(
        1000,
        "cap on the estimator's RANSAC samples per pair (bounds its time on a pair without"
        " consensus; ample for ORB matches of real pairs)",
        10,
        1_000_000,
    ),
    "hough_width_px": ParamSpec(
        0, "working width of the line-pair (Hough) search, px (0 = estimator default)", 0, 8192
    ),
    "seed": ParamSpec(
        0, "seed of the estimator's random choices (same for every pair)", 0, 2**31 - 1
    ),
    "publish_unreliable": ParamSpec(
        True,
        "also publish F when the estimator flags it unreliable (status not ok, e.g. a dominant"
        " plane); ~/estimate's status then says why",
    ),
    "debug_epipolar_lines": ParamSpec(8, "epipolar lines drawn on ~/debug_image", 0, 100),
    "use_camera_info": ParamSpec(
        True,
        "use camera_info (beside each image topic) when published: undistort the matched points"
        " (F in undistorted pixels of K), publish the pose (stereo: ~/relative_transform and"
        " ~/relative_pose; motion: ~/angular_velocity and ~/translation_direction) and, for a"
        " calibrated stereo rig, the calibration check",
        read_only=True,
    ),
    "images": ParamSpec(
        "auto",
        "what the images are, for camera_info: raw (pixels of K and D), rectified (pixels of P),"
        " or auto (rectified when every input image topic's name contains 'rect')",
        choices=("auto", "raw", "rectified"),
        read_only=True,
    ),
    "calibration_window": ParamSpec(
        _MONITOR.window, "calibration check: pairs in the sliding window", 1, 10000
    ),
    "calibration_min_pairs": ParamSpec(
        _MONITOR.min_pairs, "calibration check: usable pairs needed for a decision", 1, 10000
    ),
    "calibration_min_inliers": ParamSpec(
        _MONITOR.min_inliers, "calibration check: inliers a pair needs to count", 5, 100000
    ),
    "calibration_warn_epipolar_px": ParamSpec(
        _MONITOR.warn_epipolar_px,
        "calibration check: WARN above this window median of the epipolar error under the"
        " calibrated F, px",
        0.001,
        1000.0,
    ),
    "calibration_error_epipolar_px": ParamSpec(
        _MONITOR.error_epipolar_px, "calibration check: ERROR above this, px", 0.001, 1000.0
    ),
    "calibration_warn_rotation_deg": ParamSpec(
        _MONITOR.warn_rotation_deg,
        "calibration check: WARN above this window median of the rotation between the matches"
        " and the calibrated rig, deg",
        0.0001,
        180.0,
    ),
    "calibration_error_rotation_deg": ParamSpec(
        _MONITOR.error_rotation_deg, "calibration check: ERROR above this, deg", 0.0001, 180.0
    ),
    "correction_window": ParamSpec(
        _CORRECTION.window,
        "stereo correction: usable pairs whose matches the corrected rotation is fitted on"
        f" (estimated while the check is WARN or ERROR, from {_CORRECTION.min_pairs} pairs on)",
        _CORRECTION.min_pairs,
        10000,
    ),
    "publish_corrected": ParamSpec(
        False,
        "stereo correction: while a correction is active, publish each image again on"
        " ~/corrected/<side>/image_raw with the corrected ~/corrected/<side>/camera_info",
        read_only=True,
    ),
    "apply_correction": ParamSpec(
        False,
        "stereo correction: send the corrected camera_info to each driver's set_camera_info"
        " service, which stores it (as camera_calibration does)",
        read_only=True,
    ),
    DIAGNOSTIC_PERIOD: ParamSpec(
        1.0, "period of the /diagnostics health report, s", 0.1, 60.0, read_only=True
    ),
    "input_timeout_s": ParamSpec(
        0.5,
        "stereo: a camera silent this much longer than the other one turns /diagnostics to WARN"
        " (reported at once, and back to OK when it returns)",
        0.05,
        60.0,
    ),
    "always_on": ParamSpec(
        False,
        "process the input even without subscribers to ~/estimate, ~/matches, the pose outputs"
        " and ~/debug_image (monitoring); false: hold no image subscription without them",
    ),
    "autostart": ParamSpec(
        True,
        "configure and activate the lifecycle node at start; false: wait for a lifecycle manager",
        read_only=True,
    ),
}

# parameters whose default follows other parameters (config/sepfm.yaml leaves them out): the rule
COMPUTED_DEFAULTS = {
    "always_on": "(true in stereo mode with use_camera_info: calibrated stereo; else false)"
}


def always_on_default(values: Mapping[str, Any]) -> bool:
    """``always_on``'s default: true for calibrated stereo (mode stereo, use_camera_info), where
    the calibration check is the point of running; false otherwise."""
    return values["mode"] == "stereo" and bool(values["use_camera_info"])


PIPELINE_PARAMS = {
    "features": "features",
    "max_features": "max_features",
    "feature_max_width": "feature_max_width",
    "ratio": "ratio",
    "max_matches": "max_matches",
    "method": "method",
    "threshold_px": "threshold_px",
    "confidence": "confidence",
    "seed": "seed",
}


def descriptor(name: str, spec: ParamSpec) -> ParameterDescriptor:
    extra = f" (one of: {', '.join(spec.choices)})" if spec.choices else ""
    desc = ParameterDescriptor(
        name=name, description=spec.description + extra, read_only=spec.read_only
    )
    if isinstance(spec.default, bool):
        desc.type = ParameterType.PARAMETER_BOOL
    elif isinstance(spec.default, str):
        desc.type = ParameterType.PARAMETER_STRING
    elif isinstance(spec.default, int):
        desc.type = ParameterType.PARAMETER_INTEGER
        desc.integer_range = [
            IntegerRange(from_value=int(spec.low), to_value=int(spec.high), step=1)
        ]
    else:
        desc.type = ParameterType.PARAMETER_DOUBLE
        desc.floating_point_range = [
            FloatingPointRange(from_value=float(spec.low), to_value=float(spec.high), step=0.0)
        ]
    if spec.choices:
        desc.additional_constraints = "one of: " + ", ".join(spec.choices)
    return desc


def parameter_error(name: str, value: Any, params: Mapping[str, ParamSpec] = PARAMS) -> str | None:
    """Why ``value`` is not acceptable for parameter ``name`` of ``params`` (None when it is)."""
    spec = params.get(name)
    if spec is None:
        return None  # not ours (e.g. use_sim_time, qos overrides)
    if spec.choices:
        if value not in spec.choices:
            return f"{name} must be one of {', '.join(spec.choices)}; got {value!r}"
        return None
    if isinstance(spec.default, bool):
        return None if isinstance(value, bool) else f"{name} must be true or false; got {value!r}"
    if isinstance(value, bool) or not isinstance(value, int | float):
        return f"{name} must be a number; got {value!r}"
    if not spec.low <= value <= spec.high:
        return f"{name} must be in [{spec.low}, {spec.high}]; got {value}"
    return None


def pipeline_config(values: dict[str, Any]) -> PipelineConfig:
    """Node parameter values -> PipelineConfig (ValueError when invalid)."""
    options = {MAX_SAMPLES_OPTION: int(values.get("max_samples", PARAMS["max_samples"].default))}
    if int(values.get("hough_width_px", 0)) > 0:
        options[HOUGH_WIDTH_OPTION] = int(values["hough_width_px"])
    kwargs = {field: values[param] for param, field in PIPELINE_PARAMS.items() if param in values}
    return PipelineConfig(**kwargs, estimator_options=EstimatorOptions(**options))


def parameters_help(params: Mapping[str, ParamSpec] = PARAMS) -> str:
    """One line per parameter of ``params``: name, default, range or choices, description."""
    lines = []
    for name, spec in params.items():
        if spec.choices:
            rng = f" one of {'/'.join(spec.choices)}"
        elif isinstance(spec.default, bool):
            rng = " true/false"
        else:
            rng = f" [{spec.low}, {spec.high}]"
        ro = " (read-only)" if spec.read_only else ""
        default = COMPUTED_DEFAULTS.get(name, repr(spec.default)) if params is PARAMS else None
        lines.append(f"  {name} = {default or repr(spec.default)}{rng}{ro}: {spec.description}")
    return "\n".join(lines)


def monitor_config(values: dict[str, Any]) -> MonitorConfig:
    """Node parameter values -> the calibration check's config (ValueError when invalid)."""
    return MonitorConfig(
        window=int(values["calibration_window"]),
        min_pairs=int(values["calibration_min_pairs"]),
        min_inliers=int(values["calibration_min_inliers"]),
        warn_epipolar_px=float(values["calibration_warn_epipolar_px"]),
        error_epipolar_px=float(values["calibration_error_epipolar_px"]),
        warn_rotation_deg=float(values["calibration_warn_rotation_deg"]),
        error_rotation_deg=float(values["calibration_error_rotation_deg"]),
    )


def correction_config(values: dict[str, Any]) -> CorrectionConfig:
    """Node parameter values -> the stereo correction's config (ValueError when invalid)."""
    return CorrectionConfig(window=int(values["correction_window"]))


def change_errors(values: dict[str, Any], changes: dict[str, Any]) -> list[str]:
    """Why the run-time parameter ``changes`` (name -> new value) cannot be applied to the
    current ``values`` (empty when they can): read-only, out of range, or an invalid config."""
    values = dict(values)
    reasons = []
    for name, value in changes.items():
        if name in PARAMS and PARAMS[name].read_only:
            reasons.append(f"{name} is read-only (set it at start-up)")
            continue
        error = parameter_error(name, value)
        if error:
            reasons.append(error)
        elif name in PARAMS:
            values[name] = value
    if not reasons:
        try:
            pipeline_config(values)
            monitor_config(values)
            correction_config(values)
        except ValueError as err:
            reasons.append(str(err))
    return reasons


class ParameterError(ValueError):
    """A parameter value, name or file that cannot be used (the message says why)."""


@dataclass(frozen=True)
class GivenParams:
    """Every parameter's value (defaults for the rest) and the names the user set."""

    values: dict[str, Any]
    given: frozenset[str]


def parse_value(name: str, text: str) -> Any:
    """The value of parameter ``name`` written as ``text`` (``-p name:=text``), validated."""
    name = current_name(name, warn=False)
    if name not in PARAMS:
        raise ParameterError(f"unknown parameter {name!r}; known: {', '.join(PARAMS)}")
    default = PARAMS[name].default
    try:
        if isinstance(default, bool):
            if text.lower() not in ("true", "false"):
                raise ValueError
            value: Any = text.lower() == "true"
        elif isinstance(default, int):
            value = int(text)
        elif isinstance(default, float):
            value = float(text)
        else:
            value = text
    except ValueError:
        raise ParameterError(f"parameter {name}: cannot read {text!r}") from None
    return checked(name, value)


def checked(name: str, value: Any) -> Any:
    """``value`` for parameter ``name`` as the node takes it (an integer where a float is
    expected becomes a float); ParameterError when it is not acceptable."""
    name = current_name(name, warn=False)
    if name not in PARAMS:
        raise ParameterError(f"unknown parameter {name!r}; known: {', '.join(PARAMS)}")
    default = PARAMS[name].default
    if isinstance(default, float) and isinstance(value, int) and not isinstance(value, bool):
        value = float(value)
    error = parameter_error(name, value)
    if error:
        raise ParameterError(error)
    if type(value) is not type(default):
        raise ParameterError(f"{name} must be of type {type(default).__name__}; got {value!r}")
    return value


# sections of a params file that apply to the sepfm node (rcl's wildcards and its name)
_SECTIONS = ("/**", NODE_NAME, "/" + NODE_NAME, "/**/" + NODE_NAME)
# parameters rclpy declares itself, or that configure rclpy (not the node's table)
_RCL_PARAMS = ("use_sim_time", "start_type_description_service")


def _flatten(section: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in section.items():
        name = f"{prefix}{key}"
        if isinstance(value, Mapping):
            out.update(_flatten(value, name + "."))
        else:
            out[name] = value
    return out


def read_params_file(path: str | Path) -> dict[str, Any]:
    """The sepfm node's values in a ROS 2 params file (``--params-file``; the YAML of
    ``config/sepfm.yaml``): the ``ros__parameters`` of its ``/**`` and ``sepfm`` sections,
    nested names joined with dots; rclpy's own (``use_sim_time``, ``qos_overrides.*``) are
    left out. ParameterError when the file cannot be read or holds an unknown name or value."""
    from ruamel.yaml import YAML  # only for a params file: not on the node's start-up path
    from ruamel.yaml.error import YAMLError

    try:
        data = YAML(typ="safe").load(Path(path).read_text())
    except (OSError, YAMLError) as err:
        raise ParameterError(f"params file {path}: {err}") from None
    if not isinstance(data, Mapping):
        raise ParameterError(f"params file {path}: not a mapping of node names")
    values: dict[str, Any] = {}
    for key, section in data.items():
        if str(key) not in _SECTIONS:
            continue
        if not isinstance(section, Mapping) or "ros__parameters" not in section:
            raise ParameterError(f"params file {path}: section {key!r} has no ros__parameters")
        for name, value in _flatten(section["ros__parameters"] or {}).items():
            if name in _RCL_PARAMS or name.startswith("qos_overrides."):
                continue
            try:
                name = current_name(name)
                values[name] = checked(name, value)
            except ParameterError as err:
                raise ParameterError(f"params file {path}: {err}") from None
    if not values:
        raise ParameterError(
            f"params file {path}: no ros__parameters for the sepfm node (sections: "
            f"{', '.join(map(str, data)) or 'none'}; expected one of {', '.join(_SECTIONS)})"
        )
    return values


def given_params(items: Sequence[str] = (), params_file: str | Path | None = None) -> GivenParams:
    """Parameter values from a params file and ``name:=value`` items (as in ``--ros-args
    --params-file FILE -p name:=value``: an item overrides the file), defaults for the rest."""
    values = {name: spec.default for name, spec in PARAMS.items()}
    given: set[str] = set()
    if params_file is not None:
        from_file = read_params_file(params_file)
        values.update(from_file)
        given.update(from_file)
    for item in items:
        if ":=" not in item:
            raise ParameterError(f"parameter {item!r} is not of the form name:=value")
        name, text = item.split(":=", 1)
        name = current_name(name)
        values[name] = parse_value(name, text)
        given.add(name)
    try:
        pipeline_config(values)
        monitor_config(values)
        correction_config(values)
    except ValueError as err:
        raise ParameterError(str(err)) from None
    return GivenParams(values, frozenset(given))


def parse_params(items: Sequence[str]) -> dict[str, Any]:
    """``name:=value`` strings -> node parameter values (defaults for the rest), validated."""
    return given_params(items).values
