"""The ``rectify`` node: rectified stereo images from the sepfm node's estimates, without
camera_info (see ``sepfm_ros rectify --help``)."""

from __future__ import annotations

import threading
from collections import Counter, OrderedDict
from dataclasses import replace
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import Header

from sepfm_msgs.msg import MatchArray, TwoViewEstimate
from sepfm_ros.pipeline.rectification import (
    MIN_COVERAGE,
    MIN_INLIERS,
    Rectification,
    RectificationError,
    rectify_uncalibrated,
    vertical_disparity,
)
from sepfm_ros.ros.msgs.diagnostics import (
    diagnostic_array,
    health_status,
    status_name,
)
from sepfm_ros.ros.msgs.fundamental import (
    fundamental_from_msg,
)
from sepfm_ros.ros.msgs.headers import copy_header, stamp_ns
from sepfm_ros.ros.msgs.image_conversion import (
    COLOR_SPACES,
    ImageDecodeError,
    numpy_to_image,
    pair_to_numpy,
)
from sepfm_ros.ros.node.dds import UNCONFIGURED, DdsSetup
from sepfm_ros.ros.node.keep_serving import ThrottledLog, guarded
from sepfm_ros.ros.node.lifecycle import ManagedNode, start_when_ready, state_name
from sepfm_ros.ros.node.outputs import RELIABLE
from sepfm_ros.ros.node.subscriptions import InputSubscription, input_topic
from sepfm_ros.ros.session.parameters import (
    DIAGNOSTIC_PERIOD,
    ParamSpec,
    descriptor,
    parameter_error,
    renamed_values,
)
from sepfm_ros.ros.session.parameters import PARAMS as NODE_PARAMS
from sepfm_ros.stream.pairing import Frame, StereoPairing
from sepfm_ros.stream.sync import LEFT, RIGHT

NODE_NAME = "rectify"


# estimates (or match arrays) kept while their other half has not arrived
PENDING_ESTIMATES = 20


_PARAMS: dict[str, ParamSpec] = {
    name: NODE_PARAMS[name]
    for name in (
        "image_transport",
        "input_reliability",
        "sync_slop_s",
        "sync_queue_size",
        "autostart",
    )
} | {
    "encoding": ParamSpec(
        "mono8", "encoding of the rectified images", choices=COLOR_SPACES, read_only=True
    ),
    "min_inliers": ParamSpec(
        MIN_INLIERS, "fewest inlier matches an estimate needs to be used", 8, 100000
    ),
    "max_vertical_px": ParamSpec(
        1.0,
        "an estimate whose inliers keep a larger median vertical disparity after rectification"
        " is not used, px",
        0.01,
        100.0,
    ),
    "min_coverage": ParamSpec(
        MIN_COVERAGE,
        "an estimate whose framed rectified images cover less of the output, or keep less of"
        " themselves in it (share), is not used",
        0.0,
        1.0,
    ),
    DIAGNOSTIC_PERIOD: ParamSpec(1.0, "period of the /diagnostics report, s", 0.1, 60.0),
}


# the rectifier's parameters are all read-only (set at start)
PARAMS = {name: replace(spec, read_only=True) for name, spec in _PARAMS.items()}


def inlier_points(matches: MatchArray) -> tuple[np.ndarray, np.ndarray]:
    """The inlier matches of a MatchArray: (N, 2) pixels in image a and (N, 2) in image b."""
    rows = [(m.u_a, m.v_a, m.u_b, m.v_b) for m in matches.matches if m.inlier]
    pts = np.asarray(rows, dtype=np.float64).reshape(-1, 4)
    return pts[:, :2], pts[:, 2:]


def rectification_from_estimate(
    est: TwoViewEstimate, matches: MatchArray, values: dict[str, Any]
) -> tuple[Rectification, float]:
    """A TwoViewEstimate and its MatchArray -> (the rectification, its inliers' median vertical
    disparity after it, px).

    Raises:
        RectificationError: the estimate is not ok, has no F, is not in image pixels, or its
            rectification is refused (``kind`` says why).
    """
    if est.status != TwoViewEstimate.STATUS_OK or not est.has_f:
        raise RectificationError("estimate_not_ok", f"estimate not ok: {est.status_text}")
    if est.coordinates != "image":
        raise RectificationError(
            "coordinates",
            f"F is in {est.coordinates!r} pixels, not image pixels (the sepfm node used"
            " camera_info: rectify with it instead)",
        )
    pts_a, pts_b = inlier_points(matches)
    rect = rectify_uncalibrated(
        fundamental_from_msg(est),
        pts_a,
        pts_b,
        (est.width_a, est.height_a),
        (est.width_b, est.height_b),
        min_inliers=int(values["min_inliers"]),
        min_coverage=float(values["min_coverage"]),
        max_vertical_px=float(values["max_vertical_px"]),
    )
    return rect, float(np.median(vertical_disparity(rect.H_a, rect.H_b, pts_a, pts_b)))


class RectifyNode(ManagedNode):
    """The ``rectify`` node (see the module docstring), a lifecycle node
    (:class:`~sepfm_ros.ros.node.lifecycle.ManagedNode`): configure creates the publishers,
    activate the subscriptions; deactivated it holds no subscription and publishes nothing."""

    def __init__(
        self, node_name: str = NODE_NAME, dds: DdsSetup | None = None, **kwargs: Any
    ) -> None:
        super().__init__(node_name, None, **kwargs)
        self._dds = dds or DdsSetup(False, UNCONFIGURED)
        # values given under an old name: warned, and used unless the new name is given too
        aliased, texts = renamed_values(getattr(self, "_parameter_overrides", {}), PARAMS)
        for text in texts:
            self.get_logger().warning(text)
        for name, spec in PARAMS.items():
            self.declare_parameter(name, aliased.get(name, spec.default), descriptor(name, spec))
        self._values = {name: self.get_parameter(name).value for name in PARAMS}
        errors = [e for n, v in self._values.items() if (e := parameter_error(n, v, PARAMS))]
        if errors:
            raise ValueError("invalid parameters: " + "; ".join(errors))
        self._encoding = str(self._values["encoding"])
        self._lock = threading.Lock()
        self._log = ThrottledLog(self)
        self.counts: Counter[str] = Counter()  #: events by kind (also in /diagnostics)
        self.rectification: Rectification | None = None  #: the homographies in use
        self._rect_stamp_ns: int | None = None
        self._rect_vertical_px = float("nan")
        self._pending: tuple[OrderedDict[int, Any], OrderedDict[int, Any]] = (
            OrderedDict(),
            OrderedDict(),
        )
        self._pairing: StereoPairing[Image] = StereoPairing(
            int(round(self._values["sync_slop_s"] * 1e9)), int(self._values["sync_queue_size"])
        )
        self._pub: tuple[Any, ...] = ()
        self._subs: list[InputSubscription] = []
        self._estimate_subs: list[Any] = []
        self._diagnostics = self.create_lifecycle_publisher(
            DiagnosticArray, "/diagnostics", RELIABLE
        )
        self.create_timer(float(self._values[DIAGNOSTIC_PERIOD]), self._report)
        if self._values["autostart"]:
            start_when_ready(self)

    def configure_node(self, warm_s: float) -> None:
        """The rectified image publishers."""
        self._pub = (
            self.create_lifecycle_publisher(Image, "left/image_rect", RELIABLE),
            self.create_lifecycle_publisher(Image, "right/image_rect", RELIABLE),
        )

    def release_node(self) -> None:
        for pub in self._pub:
            self.destroy_lifecycle_publisher(pub)
        self._pub = ()

    def activate_inputs(self) -> None:
        """Subscribe to the images and to the sepfm node's estimates and matches."""
        transport = self._values["image_transport"]
        msg_type = CompressedImage if transport == "compressed" else Image
        self._subs = [
            InputSubscription(
                self,
                input_topic(self, base, transport),
                msg_type,
                lambda msg, side=side: self._on_image(msg, side),
                self._values["input_reliability"],
                on_lost=self._on_lost,
                on_incompatible=self._on_incompatible,
                on_created=lambda topic, rel: self.get_logger().info(f"{topic}: {rel}"),
                on_switched=self._on_qos_switch,
            )
            for base, side in (("left/image_raw", LEFT), ("right/image_raw", RIGHT))
        ]
        self._estimate_subs = [
            self.create_subscription(
                TwoViewEstimate, "sepfm/estimate", self._on_estimate, RELIABLE
            ),
            self.create_subscription(MatchArray, "sepfm/matches", self._on_matches, RELIABLE),
        ]
        self.get_logger().info(
            f"rectifying {', '.join(s.topic for s in self._subs)} with the estimates of "
            f"{self.resolve_topic_name('sepfm/estimate')} into "
            f"{self.resolve_topic_name('left/image_rect')}, "
            f"{self.resolve_topic_name('right/image_rect')} ({self._encoding})"
        )

    def deactivate_inputs(self) -> None:
        """Destroy every subscription."""
        for sub in self._subs:
            sub.destroy()
        for est in self._estimate_subs:
            self.destroy_subscription(est)
        self._subs, self._estimate_subs = [], []

    # ---------------------------------------------------------------- logging and counting
    def count(self, kind: str, n: int = 1) -> None:
        with self._lock:
            self.counts[kind] += n

    def _problem(self, kind: str, text: str, error: bool = True) -> None:
        self.count(kind)
        self._log.log(kind, text, error)

    def internal_error(self, kind: str, text: str) -> None:
        """An exception in a callback (:func:`guarded`): counted, logged."""
        self._problem(kind, text)

    @guarded
    def _on_lost(self, topic: str, n: int) -> None:
        if n > 0:
            self._problem(
                "lost_samples",
                f"{n} samples of {topic} lost: {self._dds.lost_sample_advice('the rectifier')}",
                error=False,
            )

    @guarded
    def _on_incompatible(self, topic: str, policy: str) -> None:
        self._problem("incompatible_qos", f"a publisher of {topic} has an incompatible {policy}")

    @guarded
    def _on_qos_switch(self, topic: str, old: str, new: str) -> None:
        """input_reliability auto recreated the subscription of ``topic`` with ``new``."""
        self.count("input_qos_switches")
        self.count(f"input_qos_switches_to_{new}")
        self.get_logger().info(f"the publishers of {topic} changed: {old} -> {new}")

    # ---------------------------------------------------------------- estimates
    @guarded
    def _on_estimate(self, msg: TwoViewEstimate) -> None:
        self.count("estimates")
        self._join(0, msg)

    @guarded
    def _on_matches(self, msg: MatchArray) -> None:
        self._join(1, msg)

    def _join(self, which: int, msg: Any) -> None:
        """Keep ``msg`` (0: estimate, 1: matches) until the other half with its stamp comes."""
        key = stamp_ns(msg.header.stamp)
        other = self._pending[1 - which].pop(key, None)
        if other is None:
            mine = self._pending[which]
            mine[key] = msg
            while len(mine) > PENDING_ESTIMATES:
                mine.popitem(last=False)
                self._problem(
                    "estimate_without_matches",
                    "an estimate or match array whose other half never came was dropped"
                    " (check that both sepfm/estimate and sepfm/matches are remapped)",
                    error=False,
                )
            return
        est, matches = (msg, other) if which == 0 else (other, msg)
        self._use(est, matches)

    def _use(self, est: TwoViewEstimate, matches: MatchArray) -> None:
        try:
            rect, vd = rectification_from_estimate(est, matches, self._values)
        except RectificationError as err:
            held = "holding the previous homographies" if self.rectification else "none yet"
            self._problem(f"refused_{err.kind}", f"estimate not used ({held}): {err}", False)
            return
        first = self.rectification is None
        with self._lock:
            self.rectification = rect
            self._rect_stamp_ns = stamp_ns(est.header.stamp)
            self._rect_vertical_px = vd
            self.counts["estimates_used"] += 1
        if first:
            self.get_logger().info(
                f"rectifying from now on: {rect.inliers} inliers, median vertical disparity "
                f"{vd:.2f} px, output {rect.size[0]}x{rect.size[1]}"
            )

    # ---------------------------------------------------------------- images
    @guarded
    def _on_image(self, msg: Any, side: int) -> None:
        self.count("images_left" if side == LEFT else "images_right")
        outcome = self._pairing.add(side, Frame(msg, stamp_ns(msg.header.stamp)))
        if outcome.pair is not None:
            self._rectify(outcome.pair[0].item, outcome.pair[1].item)

    def _rectify(self, left: Any, right: Any) -> None:
        self.count("pairs")
        rect = self.rectification
        if rect is None:
            self._problem("waiting", "no good estimate yet: image pairs are not rectified", False)
            return
        try:
            img_a, img_b = pair_to_numpy(left, right, self._encoding)
        except ImageDecodeError as err:
            self._problem(err.kind, f"skipping bad input ({err.kind}): {err}")
            return
        try:
            out_a, out_b = rect.warp(img_a, img_b)
        except ValueError as err:
            self._problem("size_change", f"skipping an image pair: {err}")
            return
        if len(self._pub) != 2:
            return  # cleaned up meanwhile
        self._pub[0].publish(numpy_to_image(out_a, self._encoding, copy_header(left.header)))
        self._pub[1].publish(numpy_to_image(out_b, self._encoding, copy_header(right.header)))
        self.count("published")

    # ---------------------------------------------------------------- health
    @guarded
    def _report(self) -> None:
        if state_name(self) != "active":
            return  # no output unless active
        with self._lock:
            values: dict[str, Any] = dict(sorted(self.counts.items()))
            rect, stamp, vd = self.rectification, self._rect_stamp_ns, self._rect_vertical_px
        values["homographies_stamp_ns"] = stamp if stamp is not None else "none"
        values["homographies_vertical_px"] = vd
        if rect is None:
            level, text = DiagnosticStatus.WARN, "waiting for a good estimate"
        else:
            level, text = DiagnosticStatus.OK, f"rectifying ({rect.inliers} inliers)"
        name = status_name(self.get_fully_qualified_name(), "rectify")
        status = health_status(name, level, text, values, self.get_fully_qualified_name())
        header = Header(stamp=self.get_clock().now().to_msg())
        self._diagnostics.publish(diagnostic_array(header, [status]))
