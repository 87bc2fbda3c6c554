"""Which image topics of a bag feed the pipeline: chosen by the user or picked from the bag.

A bag recorded on a robot names its cameras its own way (``/camera/left/image_raw``,
``/zed/right/image_rect``, ``/front/image_raw/compressed``, ...). :func:`detect_inputs` takes the
topics from ``--left``/``--right`` (stereo) or ``--image`` (motion) when given; otherwise it picks
them from the bag's ``sensor_msgs/Image`` and ``sensor_msgs/CompressedImage`` topics:

- a topic and its ``.../compressed`` twin count as one camera stream (the raw one is used);
- one stream: motion; two streams whose names differ only by ``left`` / ``right``: stereo;
- anything else (none, three cameras, two unrelated ones): :class:`TopicNotFoundError` listing
  the bag's image topics and the flags to choose with.

Topics that are not camera images are never picked: ``/ground_truth/fundamental`` and the node's
own outputs (``.../fundamental``, ``.../debug_image``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from sepfm_ros.ros.bags.errors import BagError, TopicNotFoundError
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.types import COMPRESSED_IMAGE, GROUND_TRUTH_TOPIC, IMAGE_TYPES
from sepfm_ros.ros.msgs.headers import camera_info_topic

COMPRESSED_SUFFIX = "/compressed"
NOT_CAMERA_SUFFIXES = ("/fundamental", "/debug_image")
# the node's own input names (its topics when not remapped)
NODE_INPUTS = {"stereo": ("/left/image_raw", "/right/image_raw"), "motion": ("/image_raw",)}


@dataclass(frozen=True)
class InputSpec:
    """Which topics of a bag feed the pipeline and how.

    ``picked`` is True when the topics were picked from the bag (no ``--left``/``--image``).
    """

    mode: str  # "stereo" or "motion"
    transport: str  # "raw" or "compressed"
    topics: tuple[str, ...]  # (left, right) or (image,)
    picked: bool = False

    def node_params(self) -> list[str]:
        """``--ros-args`` for a node that consumes this bag as recorded (remaps when needed)."""
        args = ["-p", f"mode:={self.mode}", "-p", f"image_transport:={self.transport}"]
        for default, topic in zip(NODE_INPUTS[self.mode], self.topics, strict=True):
            base = (
                topic.removesuffix(COMPRESSED_SUFFIX) if self.transport == "compressed" else topic
            )
            if base != default:
                args += ["-r", f"{default.lstrip('/')}:={base}"]
        return args

    def camera_info_topics(self) -> tuple[str, ...]:
        """The ``camera_info`` beside each input image topic (image_transport's convention)."""
        return tuple(camera_info_topic(t) for t in self.topics)

    def describe(self) -> str:
        """One line for the user: mode and topics."""
        return f"{self.mode} from {' + '.join(self.topics)}"


def _resolve(reader: BagReader, topic: str) -> str:
    """A topic named by the user as the bag spells it (with or without the leading slash)."""
    return reader.resolve(topic if topic.startswith("/") else "/" + topic)


def camera_info_topics(reader: BagReader, spec: InputSpec) -> tuple[str, ...]:
    """The ``camera_info`` topic beside each input topic as the bag spells it: an image topic
    recorded without its leading slash still finds ``/camera/left/camera_info``, and the other
    way round (:meth:`~sepfm_ros.ros.bags.reader.BagReader.resolve`)."""
    return tuple(reader.resolve(t) for t in spec.camera_info_topics())


def image_topics(reader: BagReader) -> list[str]:
    """The bag's camera image topics (Image or CompressedImage), sorted; not GT or outputs."""
    return sorted(
        t
        for t, info in reader.topics.items()
        if info.msgtype in IMAGE_TYPES
        and t != GROUND_TRUTH_TOPIC
        and not t.endswith(NOT_CAMERA_SUFFIXES)
    )


def camera_streams(topics: Sequence[str]) -> list[str]:
    """One topic per camera: a raw topic hides its ``.../compressed`` twin."""
    names = set(topics)
    return [
        t
        for t in topics
        if not (t.endswith(COMPRESSED_SUFFIX) and t.removesuffix(COMPRESSED_SUFFIX) in names)
    ]


def stereo_pairs(streams: Sequence[str]) -> list[tuple[str, str]]:
    """(left, right) pairs among ``streams``: names equal once ``left`` becomes ``right``."""
    names = set(streams)
    pairs = []
    for t in streams:
        if "left" in t:
            other = t.replace("left", "right")
            if other in names:
                pairs.append((t, other))
    return pairs


def _spec(reader: BagReader, mode: str, topics: tuple[str, ...], picked: bool) -> InputSpec:
    types = {reader.require(t, IMAGE_TYPES).msgtype for t in topics}
    if len(types) > 1:
        raise BagError(
            f"{' and '.join(topics)} in {reader.path} are of different types "
            f"({', '.join(sorted(types))}); choose topics of one type"
        )
    transport = "compressed" if types == {COMPRESSED_IMAGE} else "raw"
    return InputSpec(mode, transport, topics, picked)


def _choices_text(reader: BagReader, why: str, mode: str | None = None) -> str:
    have = image_topics(reader)
    listing = ", ".join(f"{t} ({reader.topics[t].msgtype})" for t in have) or "none"
    others = sorted(set(reader.topics) - set(have))
    flags = {
        "stereo": "--left TOPIC --right TOPIC (stereo input is needed here)",
        "motion": "--image TOPIC (motion input is needed here)",
    }.get(mode, "--left TOPIC --right TOPIC (stereo) or --image TOPIC (motion)")
    return (
        f"bag {reader.path}: {why}; its image topics: {listing}"
        + (f" (other topics: {', '.join(others)})" if others else "")
        + f"; choose with {flags}"
    )


def detect_inputs(
    reader: BagReader,
    mode: str | None = None,
    left: str | None = None,
    right: str | None = None,
    image: str | None = None,
) -> InputSpec:
    """The input topics: ``left``/``right`` or ``image`` when given, else picked from the bag.

    Args:
        reader: the open bag.
        mode: "stereo" or "motion" to restrict the pick (None: whatever the bag holds).
        left, right: stereo topics (both or neither).
        image: the motion topic.
    Raises:
        BagError (bad flag combination), TopicNotFoundError (topic missing, or nothing or more
        than one choice to pick: the message lists the bag's image topics and the flags),
        UnknownTypeError (a chosen topic is not an Image/CompressedImage).
    """
    if (left is None) != (right is None):
        raise BagError("--left and --right go together (stereo); use --image for one camera")
    if left is not None and image is not None:
        raise BagError("give --left/--right (stereo) or --image (motion), not both")
    if left is not None and right is not None:
        if mode == "motion":
            raise BagError("--left/--right select stereo input; --mode motion takes --image")
        return _spec(reader, "stereo", (_resolve(reader, left), _resolve(reader, right)), False)
    if image is not None:
        if mode == "stereo":
            raise BagError("--image selects motion input; --mode stereo takes --left/--right")
        return _spec(reader, "motion", (_resolve(reader, image),), False)
    streams = camera_streams(image_topics(reader))
    pairs = stereo_pairs(streams)
    if mode in (None, "stereo") and len(pairs) == 1 and (mode == "stereo" or len(streams) == 2):
        return _spec(reader, "stereo", pairs[0], True)
    if mode in (None, "motion") and len(streams) == 1:
        return _spec(reader, "motion", (streams[0],), True)
    if not streams:
        for defaults in NODE_INPUTS.values():  # the usual names with another type: say so
            for t in defaults:
                if t in reader.topics:
                    reader.require(t, IMAGE_TYPES)
        why = "no input images (no sensor_msgs/Image or CompressedImage camera topic)"
    elif mode == "stereo" and not pairs:
        why = "no two image topics whose names differ by left/right"
    else:
        why = f"{len(streams)} camera image topics, cannot tell which to use"
    raise TopicNotFoundError(_choices_text(reader, why, mode))


def no_pairs_reason(
    spec: InputSpec,
    frames: dict[str, int],
    frame_gap: int,
    slop_ns: int | None,
    slop_flag: str | None,
    skipped: dict[str, int] | None = None,
) -> str:
    """Why the input topics give no pair, for the error of a command that found none.

    Args:
        spec: the input topics.
        frames: usable frames per input topic.
        frame_gap: motion pairs frame t - ``frame_gap`` with frame t.
        slop_ns: the stereo pairing slop (ns), None in motion.
        slop_flag: how the user sets the slop (``-p sync_slop_s:=SECONDS``, ``--sync-slop``;
            None: the command has no way).
        skipped: frames per topic skipped for unusable fields (as the node skips them).
    """
    skipped = skipped or {}
    counts = ", ".join(
        f"{t} has {frames.get(t, 0)} frame(s)"
        + (f" ({skipped[t]} more skipped: unusable fields)" if skipped.get(t) else "")
        for t in spec.topics
    )
    if spec.mode == "stereo":
        if min(frames.get(t, 0) for t in spec.topics) == 0:
            return (
                f"no stereo pairs: {counts}; stereo needs a frame on both topics, paired by "
                "header stamp"
            )
        return (
            f"no stereo pairs: no {spec.topics[0]} image has a {spec.topics[1]} image within "
            f"{(slop_ns or 0) / 1e6:.1f} ms of its stamp ({counts}"
            + (f"; set {slop_flag})" if slop_flag else ")")
        )
    need = frame_gap + 1
    if frames.get(spec.topics[0], 0) < need:
        return (
            f"no motion pairs: {counts}; motion pairs frame t - frame_gap with frame t, so it "
            f"needs at least frame_gap + 1 = {need} frames"
        )
    return (
        f"no motion pairs: {counts}, but no {need} of them with increasing header stamps "
        "(stamps that repeat or step back are skipped)"
    )
