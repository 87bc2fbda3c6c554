"""``sepfm_ros make_bag``: build a bag from a folder of images, ``../shared/data`` or the renderer.

Sources (one of):

- ``--images DIR`` (motion) or ``--left DIR --right DIR`` (stereo, files paired by sorted order);
- ``--shared kitti_stereo|kitti_motion|templeRing`` with ``--data`` (default ``../shared/data``):
  the sequences of cameras.json, with ground truth;
- ``--synthetic stereo|motion``: the package's own renderer (:mod:`sepfm_ros.synthetic`), with
  exact ground truth.

Topics: stereo ``/left/image_raw`` + ``/right/image_raw`` with equal stamps, motion ``/image_raw``
(``.../compressed`` with ``--encoding compressed``), frame ids ``left_camera_optical_frame``,
``right_camera_optical_frame``, ``camera_optical_frame``. When the cameras are known the bag also
holds a ``sensor_msgs/CameraInfo`` per camera next to its images (``/left/camera_info``,
``/right/camera_info``, ``/camera_info``; same stamp and frame id as the image, see
:func:`camera_infos`) and ``/ground_truth/fundamental``: sensor_msgs/Image 64FC1 3x3 row-major
F with ``x_b^T F x_a = 0`` (a = left or previous frame, b = right or current frame), stamped like
the node's ``~/estimate`` (the left image's stamp in stereo, the current frame's in motion).
Stamps are ``--start-time`` + k / ``--rate``, message log times equal the stamps.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.synthesis import (
    DEFAULT_START_TIME_S,
    ENCODINGS,
    SHARED_SEQUENCES,
    SourceFrame,
    _image_files,
    make_bag,
    shared_frames,
    synthetic_frames,
)
from sepfm_ros.ros.bags.writer import check_output_path


def _parse(argv: list[str]) -> argparse.Namespace:
    p = argparse.ArgumentParser(
        prog="sepfm_ros make_bag",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--images", type=Path, help="folder of images (motion)")
    src.add_argument("--left", type=Path, help="folder of left images (stereo, with --right)")
    src.add_argument("--shared", choices=SHARED_SEQUENCES, help="a sequence of --data")
    src.add_argument("--synthetic", choices=("stereo", "motion"), help="rendered scene")
    p.add_argument("--right", type=Path, help="folder of right images (stereo)")
    p.add_argument("--data", type=Path, default=Path("../shared/data"), help="shared data folder")
    p.add_argument("-o", "--output", type=Path, required=True, help="output bag (must not exist)")
    p.add_argument("--rate", type=float, default=10.0, help="frames per second (default 10)")
    p.add_argument("--encoding", choices=ENCODINGS, default="mono8")
    p.add_argument("--compressed-format", choices=("png", "jpeg"), default="png")
    p.add_argument("--start", type=int, default=0, help="first frame index (default 0)")
    p.add_argument("--count", type=int, default=0, help="number of frames (0 = all)")
    p.add_argument("--step", type=int, default=1, help="take every STEP-th frame (default 1)")
    p.add_argument("--frames", type=int, default=12, help="--synthetic: frames to render")
    p.add_argument("--seed", type=int, default=0, help="--synthetic: scene seed")
    p.add_argument("--start-time", type=float, default=DEFAULT_START_TIME_S, help="first stamp, s")
    p.add_argument("--compress", action="store_true", help="zstd-compress mcap chunks")
    return p.parse_args(argv)


def main(argv: list[str]) -> int:
    args = _parse(argv)
    try:
        check_output_path(args.output)
        if args.shared:
            mode, frames = shared_frames(args.data, args.shared)
        elif args.synthetic:
            mode, frames = synthetic_frames(args.synthetic, args.frames, args.seed)
        elif args.images:
            mode = "motion"
            frames = [SourceFrame((f,), None, None) for f in _image_files(args.images)]
        else:
            if args.right is None:
                raise BagError("--left needs --right")
            lefts, rights = _image_files(args.left), _image_files(args.right)
            if len(lefts) != len(rights):
                raise BagError(f"{len(lefts)} left images but {len(rights)} right images")
            mode = "stereo"
            frames = [SourceFrame((a, b), None, None) for a, b in zip(lefts, rights, strict=True)]
        if args.start < 0 or args.count < 0 or args.step < 1:
            raise BagError("--start and --count must be >= 0, --step >= 1")
        stop = None if args.count == 0 else args.start + args.count * args.step
        frames = frames[args.start : stop : args.step]
        n = make_bag(
            args.output,
            mode,
            frames,
            args.rate,
            args.encoding,
            args.start_time,
            args.compress,
            args.compressed_format,
        )
    except BagError as err:
        print(f"sepfm_ros make_bag: error: {err}", file=sys.stderr)
        return 1
    gt = " with ground truth" if frames[0].cameras is not None else ""
    print(f"wrote {args.output}: {mode}, {len(frames)} frames, {n} messages{gt}")
    return 0
