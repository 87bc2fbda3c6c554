"""The sepfm_msgs interface package: F through its one helper, the typed messages between two
processes over real DDS, and in a bag written by the project that plain rosbags reads without
any type registered in advance (RIHS01 hashes equal rosidl's).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np
import pytest

pytest.importorskip("rclpy")
from rclpy.serialization import deserialize_message, serialize_message  # noqa: E402
from typed_msgs_sample import SAMPLE_F, plain, sample_estimate, sample_matches  # noqa: E402

from sepfm_msgs.msg import MatchArray, TwoViewEstimate  # noqa: E402
from sepfm_ros.ros.bags.types import (  # noqa: E402
    MATCH_ARRAY,
    SEPFM_MSG_TYPES,
    TWO_VIEW_ESTIMATE,
    TYPESTORE,
    sepfm_msgs_share,
)
from sepfm_ros.ros.bags.writer import BagWriter  # noqa: E402
from sepfm_ros.ros.msgs.fundamental import fundamental_field, fundamental_from_msg

REPO = Path(__file__).resolve().parents[2]
DDS_TIMEOUT_S = 60.0  # generous: discovery on a loaded 2-core machine


def rosidl_hash(msgtype: str) -> str:
    """The RIHS01 hash rosidl generated for ``msgtype`` (share/<pkg>/msg/<Name>.json)."""
    share = sepfm_msgs_share()
    assert share is not None, "sepfm_msgs is not installed"
    description = json.loads((share / "msg" / f"{msgtype.rsplit('/', 1)[1]}.json").read_text())
    entry = description["type_hashes"][0]
    assert entry["type_name"] == msgtype
    return entry["hash_string"]


def unchanged_fields(value: Any, default: Any, path: str = "") -> list[str]:
    """Paths of the fields of ``value`` (plain message values) equal to ``default``'s."""
    if isinstance(value, dict):
        return [p for k in value for p in unchanged_fields(value[k], default[k], f"{path}.{k}")]
    return [path] if value == default else []


# ------------------------------------------------------------------ F through the one helper
def test_fundamental_field_flattens_a_3x3_row_major_and_contiguous():
    for F in (SAMPLE_F, np.asfortranarray(SAMPLE_F), SAMPLE_F.T.copy().T, SAMPLE_F.tolist()):
        f = fundamental_field(F)
        assert f.shape == (9,) and f.dtype == np.float64 and f.flags["C_CONTIGUOUS"]
        assert [f[3 * i + j] for i in range(3) for j in range(3)] == SAMPLE_F.flatten().tolist()
    assert np.array_equal(fundamental_field(SAMPLE_F.flatten()), SAMPLE_F.flatten())
    back = fundamental_from_msg(SimpleNamespace(f=fundamental_field(SAMPLE_F)))
    assert back.shape == (3, 3) and np.array_equal(back, SAMPLE_F)


@pytest.mark.parametrize(
    "bad",
    [np.zeros((3, 4)), np.zeros((9, 1)), np.zeros((1, 9)), np.zeros(8), np.zeros((3, 3, 1))]
    + [np.float64(1.0), [[1.0, 2.0], [3.0, 4.0]], "F", None, [[1, 2, 3], [4, 5], [6]]],
)
def test_fundamental_field_rejects_anything_but_3x3_or_9(bad):
    with pytest.raises(ValueError, match="F must"):
        fundamental_field(bad)


def test_fundamental_from_msg_rejects_a_field_without_9_values():
    with pytest.raises(ValueError, match="9 values"):
        fundamental_from_msg(SimpleNamespace(f=[0.0] * 8))


def test_a_3x3_assigned_directly_serialises_garbage_the_helper_round_trips_exactly():
    direct = TwoViewEstimate()
    direct.f = SAMPLE_F  # the generated setter accepts the (3, 3) array without a word...
    received = deserialize_message(serialize_message(direct), TwoViewEstimate)
    # ...and serialises something else than F's nine entries
    assert not np.array_equal(np.asarray(received.f), SAMPLE_F.flatten())

    helped = TwoViewEstimate(f=fundamental_field(SAMPLE_F))
    received = deserialize_message(serialize_message(helped), TwoViewEstimate)
    assert np.array_equal(fundamental_from_msg(received), SAMPLE_F)  # bit for bit


# ------------------------------------------------------------------ type registration
def test_rosbags_rihs01_of_each_type_equals_rosidls():
    assert sepfm_msgs_share() is not None
    assert set(SEPFM_MSG_TYPES) == {
        f"sepfm_msgs/msg/{p.stem}" for p in (sepfm_msgs_share() / "msg").glob("*.msg")
    }
    for msgtype in SEPFM_MSG_TYPES:
        assert TYPESTORE.hash_rihs01(msgtype) == rosidl_hash(msgtype), msgtype


def test_samples_set_every_field():
    # the comparisons below could not see a field that the sample leaves at its default
    for sample, cls in ((sample_estimate(), TwoViewEstimate), (sample_matches(), MatchArray)):
        assert unchanged_fields(plain(sample), plain(cls())) == []


# ------------------------------------------------------------------ two processes over DDS
def test_typed_messages_arrive_whole_from_another_process(ros, tmp_path):
    estimate_topic = f"/sepfm_typed_{os.getpid()}/estimate"
    matches_topic = f"/sepfm_typed_{os.getpid()}/matches"
    got: dict[str, Any] = {}
    both = threading.Event()

    def keep(topic: str, msg: Any) -> None:
        got.setdefault(topic, msg)
        if len(got) == 2:
            both.set()

    from rclpy.qos import QoSProfile, ReliabilityPolicy

    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
    subs = [
        ros.node.create_subscription(cls, topic, lambda m, t=topic: keep(t, m), qos)
        for cls, topic in ((TwoViewEstimate, estimate_topic), (MatchArray, matches_topic))
    ]
    log_path = tmp_path / "publisher.log"
    with open(log_path, "w") as log:
        publisher = subprocess.Popen(
            [sys.executable, str(REPO / "test" / "typed_msgs_sample.py")]
            + [estimate_topic, matches_topic],
            cwd=REPO,
            env=dict(os.environ, PYTHONUNBUFFERED="1"),
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        try:
            deadline = time.monotonic() + DDS_TIMEOUT_S
            while not both.wait(0.2) and publisher.poll() is None:
                assert time.monotonic() < deadline, f"nothing received:\n{log_path.read_text()}"
            hashes = {
                topic: {
                    str(i.topic_type_hash) for i in ros.node.get_publishers_info_by_topic(topic)
                }
                for topic in (estimate_topic, matches_topic)
            }
        finally:
            publisher.terminate()
            try:
                publisher.wait(30)
            except subprocess.TimeoutExpired:  # never leave a publisher behind
                publisher.kill()
                publisher.wait()
            for sub in subs:
                ros.node.destroy_subscription(sub)
    assert both.is_set(), f"publisher exited early:\n{log_path.read_text()}"
    assert plain(got[estimate_topic]) == plain(sample_estimate())
    assert plain(got[matches_topic]) == plain(sample_matches())
    assert np.array_equal(fundamental_from_msg(got[estimate_topic]), SAMPLE_F)
    # the publisher's type support announces rosidl's hash, the one the bags store
    assert hashes[estimate_topic] == {rosidl_hash(TWO_VIEW_ESTIMATE)}
    assert hashes[matches_topic] == {rosidl_hash(MATCH_ARRAY)}


# ------------------------------------------------------------------ bags
# Runs in a fresh interpreter that imports neither this project nor sepfm_msgs: rosbags alone,
# with the types only from the definitions stored in the bag.
PLAIN_ROSBAGS_READER = """
import json, sys
from pathlib import Path
import numpy as np
from rosbags.highlevel import AnyReader

with AnyReader([Path(sys.argv[1])]) as reader:
    store = reader.typestore

    def plain(v):
        if hasattr(v, "__msgtype__"):
            return {name: plain(getattr(v, name)) for name, _ in store.fielddefs[v.__msgtype__][1]}
        if isinstance(v, (list, tuple, np.ndarray)):
            return [plain(x) for x in v]
        return v.item() if isinstance(v, np.generic) else v

    out = {}
    for conn, _, raw in reader.messages():
        msg = reader.deserialize(raw, conn.msgtype)
        constants = {name: value for name, _, value in store.fielddefs[conn.msgtype][0]}
        out[conn.topic] = dict(
            msgtype=conn.msgtype, digest=conn.digest, values=plain(msg), constants=constants
        )
assert not any(m.startswith(("sepfm_ros", "sepfm_msgs", "rclpy")) for m in sys.modules), "imported"
print(json.dumps(out))
"""


def test_bag_written_by_the_project_is_read_by_plain_rosbags(tmp_path):
    bag = tmp_path / "typed"
    estimate, matches = sample_estimate(), sample_matches()
    stamp = estimate.header.stamp.sec * 1_000_000_000 + estimate.header.stamp.nanosec
    with BagWriter(bag) as writer:
        writer.add_topic("/sepfm/estimate", TWO_VIEW_ESTIMATE)
        writer.add_topic("/sepfm/matches", MATCH_ARRAY)
        writer.write("/sepfm/estimate", stamp, serialize_message(estimate))
        writer.write("/sepfm/matches", stamp, serialize_message(matches))
    done = subprocess.run(
        [sys.executable, "-I", "-c", PLAIN_ROSBAGS_READER, str(bag)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode == 0, done.stderr
    read = json.loads(done.stdout)
    assert read["/sepfm/estimate"]["msgtype"] == TWO_VIEW_ESTIMATE
    assert read["/sepfm/estimate"]["digest"] == rosidl_hash(TWO_VIEW_ESTIMATE)
    assert read["/sepfm/matches"]["digest"] == rosidl_hash(MATCH_ARRAY)
    assert read["/sepfm/estimate"]["values"] == plain(estimate)
    assert read["/sepfm/matches"]["values"] == plain(matches)
    constants = read["/sepfm/estimate"]["constants"]
    assert len(constants) == 10  # STATUS_* and POSE_*
    assert constants == {name: getattr(TwoViewEstimate, name) for name in constants}


def test_bag_written_today_reads_back_with_every_estimate_field(tmp_path):
    """The results reader on a bag of today's types: nothing is migrated, every field (the
    escape's ``line_search_skipped`` among them) reads back as written."""
    from sepfm_ros.ros.bags.reader import BagReader
    from sepfm_ros.ros.bags.results import read_results

    bag = tmp_path / "today"
    estimate = sample_estimate()
    stamp = estimate.header.stamp.sec * 1_000_000_000 + estimate.header.stamp.nanosec
    with BagWriter(bag) as writer:
        writer.add_topic("/sepfm/estimate", TWO_VIEW_ESTIMATE)
        writer.write("/sepfm/estimate", stamp, serialize_message(estimate))
    with BagReader(bag) as reader:
        assert reader.migrated == set()
    (result,) = read_results(bag)
    assert result.line_search_skipped is True and result.estimate.line_search_skipped is True
    assert plain(result.estimate) == plain(estimate)
