"""Camera calibration files in the YAML format of ROS's ``camera_calibration_parsers``: the
files ``camera_info_manager`` loads from a driver's ``camera_info_url`` (``file:///...yaml``)
and ``camera_calibration`` writes.

:func:`camera_yaml` writes a :class:`~sepfm_ros.geometry.calibrated.camera.CameraModel` as such
a file's text, with the keys in the order ``camera_calibration_parsers`` emits them::

    image_width: 1241
    image_height: 376
    camera_name: left_camera
    camera_matrix:
      rows: 3
      cols: 3
      data: [718.856, 0.0, 607.1928, ...]
    distortion_model: plumb_bob
    distortion_coefficients:
      rows: 1
      cols: 5
      data: [0.0, 0.0, 0.0, 0.0, 0.0]
    rectification_matrix:
      rows: 3
      cols: 3
      data: [...]
    projection_matrix:
      rows: 3
      cols: 4
      data: [...]

Matrices are row-major (K, R: 3x3; P: 3x4; D: 1xn, as ``sensor_msgs/CameraInfo`` holds them).
Every number is written with the 17 significant digits that read back to the same double, with a
decimal point in each mantissa (``1.0e-05``, not ``1e-05``), so YAML 1.1 readers (yaml-cpp,
PyYAML) and 1.2 readers all read floats. :func:`read_camera_yaml` reads such a file back into a
validated model (for tests and for users checking a file); no ROS is needed for either.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from ruamel.yaml import YAML
from ruamel.yaml.error import YAMLError

from sepfm_ros.geometry.calibrated.camera import CalibrationError, CameraModel, camera_model

#: the keys ``camera_calibration_parsers`` writes, in its order
KEYS = (
    "image_width",
    "image_height",
    "camera_name",
    "camera_matrix",
    "distortion_model",
    "distortion_coefficients",
    "rectification_matrix",
    "projection_matrix",
)


def camera_name(text: str) -> str:
    """A name ``camera_info_manager`` accepts (letters, digits and ``_``; it rejects others)
    from a frame id or topic: other characters become ``_``, leading/trailing ``_`` dropped;
    ``camera`` when nothing is left."""
    name = re.sub(r"[^A-Za-z0-9_]+", "_", text).strip("_")
    return name or "camera"


def _number(value: float) -> str:
    """A float as YAML text that reads back to the same double in YAML 1.1 and 1.2."""
    text = repr(float(value))
    if "e" in text:
        mantissa, exponent = text.split("e")
        if "." not in mantissa:
            mantissa += ".0"
        text = f"{mantissa}e{exponent}"
    return text


def _matrix(key: str, values: np.ndarray, rows: int, cols: int) -> list[str]:
    data = ", ".join(_number(v) for v in np.ravel(values))
    return [f"{key}:", f"  rows: {rows}", f"  cols: {cols}", f"  data: [{data}]"]


def camera_yaml(model: CameraModel, name: str) -> str:
    """The calibration file text of one camera.

    Args:
        model: the calibration (K 3x3 px, D (n,), distortion model, R 3x3, P 3x4 px, size).
        name: the camera's name (made valid with :func:`camera_name`); ``camera_info_manager``
            warns when it differs from the driver's ``camera_name`` but loads the file.
    Returns:
        YAML text, newline-terminated.
    """
    lines = [
        f"image_width: {int(model.width)}",
        f"image_height: {int(model.height)}",
        f"camera_name: {camera_name(name)}",
        *_matrix("camera_matrix", model.K, 3, 3),
        f"distortion_model: {model.distortion_model}",
        *_matrix("distortion_coefficients", model.D, 1, int(model.D.size)),
        *_matrix("rectification_matrix", model.R, 3, 3),
        *_matrix("projection_matrix", model.P, 3, 4),
    ]
    return "\n".join(lines) + "\n"


def write_camera_yaml(path: Path, model: CameraModel, name: str) -> None:
    """Write :func:`camera_yaml` of ``model`` to ``path`` (replaced when it exists)."""
    path.write_text(camera_yaml(model, name))


def _field(doc: dict[str, Any], key: str, source: str) -> Any:
    if key not in doc:
        raise CalibrationError(f"{source}: no {key!r} (a camera calibration YAML has {KEYS})")
    return doc[key]


def _read_matrix(doc: dict[str, Any], key: str, rows: int | None, source: str) -> list[float]:
    node = _field(doc, key, source)
    if not isinstance(node, dict) or not {"rows", "cols", "data"} <= set(node):
        raise CalibrationError(f"{source}: {key} is not a matrix of rows, cols and data")
    try:
        r, c, data = int(node["rows"]), int(node["cols"]), [float(v) for v in node["data"]]
    except (TypeError, ValueError):
        raise CalibrationError(f"{source}: {key} has non-numeric rows, cols or data") from None
    if (rows is not None and r != rows) or len(data) != r * c:
        raise CalibrationError(f"{source}: {key} is {r}x{c} with {len(data)} values")
    return data


def parse_camera_yaml(text: str, source: str = "camera YAML") -> tuple[str, CameraModel]:
    """(camera name, validated model) of a calibration file's text.

    Raises:
        CalibrationError: not YAML, a missing key, a matrix of the wrong size, or values
            :func:`~sepfm_ros.geometry.calibrated.camera.camera_model` rejects; ``source``
            names the file in the message.
    """
    try:
        doc = YAML(typ="safe", pure=True).load(text)
    except YAMLError as err:
        raise CalibrationError(f"{source} is not YAML: {err}") from None
    if not isinstance(doc, dict):
        raise CalibrationError(f"{source} is not a YAML mapping of calibration keys")
    name = str(doc.get("camera_name", "unknown"))
    K = _read_matrix(doc, "camera_matrix", 3, source)
    D = _read_matrix(doc, "distortion_coefficients", None, source)
    R = _read_matrix(doc, "rectification_matrix", 3, source)
    P = _read_matrix(doc, "projection_matrix", 3, source)
    model = str(doc.get("distortion_model", "plumb_bob"))
    width, height = _field(doc, "image_width", source), _field(doc, "image_height", source)
    try:
        return name, camera_model(K, D, model, R, P, width, height)
    except CalibrationError as err:
        raise CalibrationError(f"{source}: {err}") from None


def read_camera_yaml(path: Path) -> tuple[str, CameraModel]:
    """(camera name, model) of a calibration file (:func:`parse_camera_yaml`); CalibrationError
    when it cannot be read."""
    try:
        text = Path(path).read_text()
    except (OSError, UnicodeDecodeError) as err:
        raise CalibrationError(f"cannot read {path}: {err}") from None
    return parse_camera_yaml(text, str(path))
