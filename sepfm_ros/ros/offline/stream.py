"""A bag's input stream set up as the node sets up a live one: its session, pairing and
camera_info. ``process``, ``calibration_check`` and ``audit`` open a :class:`BagStream` and answer
its pairs through it; nothing else in ``offline/`` builds a pipeline or answer settings.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from sepfm_ros.ros.bags.inputs import InputSpec
from sepfm_ros.ros.bags.pairing import (
    CameraInfos,
    InputStamps,
    PairJob,
    iter_pairs,
    pairing_slop_ns,
    read_camera_infos,
    warn_on_stderr,
)
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.msgs.headers import stamp_ns
from sepfm_ros.ros.session.answer import PairAnswer
from sepfm_ros.ros.session.session import Session


@dataclass
class BagStream:
    """One bag's input stream.

    Attributes:
        reader: the bag (or a view of it from a start time: anything with ``messages``).
        spec: the input topics and mode.
        session: the stream's session, built from the node's parameter values.
        slop_ns: the stereo pairing slop (None: ``sync_slop_s``; motion: unused).
        infos: the bag's camera_info of each camera, by stamp (None: none, or not used).
        warn: told once per topic of images read as packed rows (step 0).
    """

    reader: Any
    spec: InputSpec
    session: Session
    slop_ns: int | None
    infos: CameraInfos | None
    warn: Callable[[str], None] = warn_on_stderr

    @classmethod
    def open(
        cls,
        reader: BagReader,
        spec: InputSpec,
        values: Mapping[str, Any],
        slop_ns: int | None = None,
        info_topics: Sequence[str | None] = (),
    ) -> BagStream:
        """The stream of ``spec``'s topics in ``reader`` with parameter ``values``
        (ParameterError when invalid). ``info_topics``: camera_info topics other than the ones
        beside the image topics (None: that default)."""
        session = Session(values, spec.mode == "stereo", spec.topics)
        infos = None
        if session.uses_camera_info:
            infos = read_camera_infos(reader, spec, info_topics)
        return cls(reader, spec, session, slop_ns, infos)

    def pairs(self) -> Iterator[PairJob]:
        """The pairs the node would form, in bag order (:func:`~..bags.pairing.iter_pairs`)."""
        return iter_pairs(self.reader, self.spec, self.session, self.slop_ns, self.warn)

    def pair_count(self, inputs: InputStamps) -> int:
        """How many pairs :meth:`pairs` gives, from the input stamps alone."""
        return inputs.pair_count(self.spec, self.session, self.slop_ns)

    def answer(self, job: PairJob) -> PairAnswer:
        """The node's answer to one pair, with the camera_info of the pair's stamp."""
        infos = None
        if self.infos is not None:
            infos = self.infos.at(stamp_ns(job.header.stamp))
        keys = (job.key_a, job.key_b)
        return self.session.answer(job.headers(), job.msg_a, job.msg_b, keys, infos)


def stereo_slop_ns(
    spec: InputSpec, values: Mapping[str, Any], left_stamps: list[int], slop_given: bool
) -> int | None:
    """The pairing slop of a bag's stream (:func:`~..bags.pairing.pairing_slop_ns`; None for
    motion): ``sync_slop_s`` when the user set it, else up to half the left frame period."""
    if spec.mode != "stereo":
        return None
    return pairing_slop_ns(dict(values), left_stamps, slop_given)
