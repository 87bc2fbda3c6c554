"""Pairs with ground truth for the evaluation: manifests in the format of ``pairs.json``.

A manifest is a JSON list of entries. An *image entry* (as in ``../shared/data/pairs.json``)::

    {"scene": "templeRing", "img_a": "templeRing/templeR0001.png", "img_b": "...",
     "size_a": [640, 480], "size_b": [640, 480], "F": [[...], [...], [...]],
     "kind": "calibrated_cameras", "baseline": "small"}

Image paths are relative to the manifest's folder (or ``root``); ``size_a``/``size_b`` (width,
height) are optional and then read from the images; ``kind``/``baseline``/``name`` are optional.
A *points entry* gives the putative matches directly instead of images (for synthetic data or
matches made elsewhere): ``"pts_a"``/``"pts_b"`` (N x 2 pixel lists) and ``size_a`` (required).

``F`` satisfies ``x_b^T F x_a = 0`` in pixels. Loading never stops at a bad entry: each bad entry
becomes a :class:`PairError` with a message naming the entry and the problem (missing image,
malformed F, ...), and the report lists it; only a file that is not a JSON list of objects raises
:class:`ManifestError`.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: An F whose smallest/largest singular value ratio exceeds this is not rank 2 (malformed GT).
RANK2_TOLERANCE = 1e-4


class ManifestError(ValueError):
    """The manifest as a whole cannot be read (not JSON, not a list of objects)."""


class PairDataError(ValueError):
    """A single pair cannot be evaluated; the message says why."""


@dataclass
class PairSpec:
    """One pair to evaluate.

    Attributes:
        pair_id: unique readable id (``name`` of the entry, or scene and image paths).
        scene: scene name (tables are grouped by it).
        F_gt: (3, 3) float64 ground truth, ``x_b^T F x_a = 0``, unit Frobenius norm.
        img_a, img_b: image files, or None for a points entry.
        pts_a, pts_b: (N, 2) float64 matches of a points entry, or None for an image entry.
        size_a, size_b: (width, height) in pixels, or None to read from the images.
        kind, baseline: free-form labels from the manifest ("" when absent).
    """

    pair_id: str
    scene: str
    F_gt: np.ndarray
    img_a: Path | None = None
    img_b: Path | None = None
    pts_a: np.ndarray | None = None
    pts_b: np.ndarray | None = None
    size_a: tuple[int, int] | None = None
    size_b: tuple[int, int] | None = None
    kind: str = ""
    baseline: str = ""


@dataclass(frozen=True)
class PairError:
    """A pair that could not be evaluated, and why."""

    pair_id: str
    scene: str
    message: str


def parse_fundamental(value: object) -> np.ndarray:
    """Validate a GT F (3x3 nested list) and return it with unit Frobenius norm.

    Raises PairDataError naming the problem: not 3x3 numbers, non-finite, zero, or not rank 2.
    """
    try:
        F = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise PairDataError(f"malformed F: not a 3x3 array of numbers ({exc})") from None
    if F.shape != (3, 3):
        raise PairDataError(f"malformed F: expected 3x3, got shape {F.shape}")
    if not np.all(np.isfinite(F)):
        raise PairDataError("malformed F: contains NaN or infinity")
    s = np.linalg.svd(F, compute_uv=False)
    if s[0] == 0.0:
        raise PairDataError("malformed F: all zeros")
    if s[2] / s[0] > RANK2_TOLERANCE:
        raise PairDataError(f"malformed F: not rank 2 (singular values {np.round(s / s[0], 6)})")
    return F / np.linalg.norm(F)


def _parse_size(value: object, key: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in value)  # type: ignore[union-attr]
    except (TypeError, ValueError):
        raise PairDataError(f"malformed {key}: expected [width, height], got {value!r}") from None
    if w <= 0 or h <= 0:
        raise PairDataError(f"malformed {key}: width and height must be positive, got {value!r}")
    return w, h


def _parse_points(value: object, key: str) -> np.ndarray:
    try:
        pts = np.asarray(value, dtype=np.float64).reshape(-1, 2)
    except (TypeError, ValueError):
        raise PairDataError(f"malformed {key}: expected a list of [u, v] pairs") from None
    if not np.all(np.isfinite(pts)):
        raise PairDataError(f"malformed {key}: contains NaN or infinity")
    return pts


def _entry_id(entry: dict, index: int) -> tuple[str, str]:
    scene = str(entry.get("scene", "")) or "unnamed"
    if entry.get("name"):
        return str(entry["name"]), scene
    a, b = entry.get("img_a"), entry.get("img_b")
    if isinstance(a, str) and isinstance(b, str):
        pa, pb = Path(a), Path(b)
        if pa.parts and pa.parts[0] == scene:
            pa = Path(*pa.parts[1:])
        if pb.parts and pb.parts[0] == scene:
            pb = Path(*pb.parts[1:])
        return f"{scene}/{pa.with_suffix('')}~{pb.with_suffix('')}", scene
    return f"{scene}#{index}", scene


def parse_entry(entry: object, index: int, root: Path) -> PairSpec:
    """Turn one manifest entry into a PairSpec; raise PairDataError naming the problem."""
    if not isinstance(entry, dict):
        raise PairDataError(f"entry {index} is not an object")
    pair_id, scene = _entry_id(entry, index)
    if "F" not in entry:
        raise PairDataError("missing key 'F' (ground-truth fundamental matrix)")
    F = parse_fundamental(entry["F"])
    spec = PairSpec(
        pair_id=pair_id,
        scene=scene,
        F_gt=F,
        kind=str(entry.get("kind", "")),
        baseline=str(entry.get("baseline", "")),
    )
    if "size_a" in entry:
        spec.size_a = _parse_size(entry["size_a"], "size_a")
        spec.size_b = _parse_size(entry.get("size_b", entry["size_a"]), "size_b")
    if "pts_a" in entry or "pts_b" in entry:
        if "pts_a" not in entry or "pts_b" not in entry:
            raise PairDataError("a points entry needs both 'pts_a' and 'pts_b'")
        spec.pts_a = _parse_points(entry["pts_a"], "pts_a")
        spec.pts_b = _parse_points(entry["pts_b"], "pts_b")
        if spec.pts_a.shape != spec.pts_b.shape:
            raise PairDataError(
                f"pts_a and pts_b differ in length ({len(spec.pts_a)} vs {len(spec.pts_b)})"
            )
        if spec.size_a is None:
            raise PairDataError("a points entry needs 'size_a' ([width, height])")
        return spec
    for key in ("img_a", "img_b"):
        if not isinstance(entry.get(key), str):
            raise PairDataError(f"missing key {key!r} (image path) or 'pts_a'/'pts_b'")
    spec.img_a = (root / entry["img_a"]).resolve()
    spec.img_b = (root / entry["img_b"]).resolve()
    for key, path in (("img_a", spec.img_a), ("img_b", spec.img_b)):
        if not path.is_file():
            raise PairDataError(f"{key} not found: {path}")
    return spec


def load_manifest(
    path: str | Path, root: str | Path | None = None
) -> tuple[list[PairSpec], list[PairError]]:
    """Load a manifest: (valid pairs in file order, per-entry errors).

    Args:
        path: the JSON manifest.
        root: folder image paths are relative to (default: the manifest's folder).
    Raises:
        ManifestError: the file is missing, not JSON, or not a list.
    """
    path = Path(path)
    try:
        data = json.loads(path.read_text())
    except OSError as exc:
        raise ManifestError(f"cannot read manifest {path}: {exc.strerror or exc}") from None
    except json.JSONDecodeError as exc:
        raise ManifestError(f"manifest {path} is not valid JSON: {exc}") from None
    if isinstance(data, dict) and isinstance(data.get("pairs"), list):
        data = data["pairs"]
    if not isinstance(data, list):
        raise ManifestError(f"manifest {path} must hold a JSON list of pair entries")
    base = Path(root) if root is not None else path.parent
    pairs: list[PairSpec] = []
    errors: list[PairError] = []
    seen: dict[str, int] = {}
    for i, entry in enumerate(data):
        try:
            spec = parse_entry(entry, i, base)
        except PairDataError as exc:
            pid, scene = _entry_id(entry, i) if isinstance(entry, dict) else (f"#{i}", "unnamed")
            errors.append(PairError(pid, scene, f"manifest entry {i}: {exc}"))
            continue
        if spec.pair_id in seen:
            seen[spec.pair_id] += 1
            spec.pair_id = f"{spec.pair_id}#{seen[spec.pair_id]}"
        else:
            seen[spec.pair_id] = 0
        pairs.append(spec)
    return pairs, errors


def load_cameras(path: str | Path, root: str | Path | None = None) -> dict[Path, np.ndarray]:
    """Ground-truth 3x4 cameras of images, keyed by image path (resolved like the manifest's).

    Reads ``path`` (a JSON object: image path -> 3x4 P = K [R | t], as the shared data's
    ``cameras.json``); entries that are not 3x4 finite numbers are left out. A missing file gives
    an empty dict: cameras are optional.
    """
    path = Path(path)
    if not path.is_file():
        return {}
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise ManifestError(f"cannot read cameras {path}: {exc}") from None
    if not isinstance(data, dict):
        raise ManifestError(f"cameras file {path} must hold a JSON object")
    base = Path(root) if root is not None else path.parent
    out = {}
    for key, value in data.items():
        try:
            P = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError):
            continue
        if P.shape == (3, 4) and np.all(np.isfinite(P)):
            out[(base / key).resolve()] = P
    return out
