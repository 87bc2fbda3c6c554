"""Quirks of bags recorded by other robots, through ``process`` (and the other bag commands).

Each bag is written in the test with rosbags alone (:mod:`robot_bags`), the way some robot's
driver or recorder left it: every Image with ``step`` 0, image topics without their leading
slash beside ``/.../camera_info``, QOI-compressed images, big-endian 16-bit images, one frame
only. The commands give decoded frames or a clear error with a non-zero exit.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from robot_bags import (
    COMPRESSED_T,
    IMAGE_T,
    LEFT_TOPIC,
    RIGHT_TOPIC,
    bag_path,
    big_endian_mono16,
    qoi_bytes,
    qoi_compressed,
    write_camera_bag,
    write_robot_bag,
    write_stereo_without_right,
    zero_step_image,
)
from sensor_msgs.msg import CompressedImage, Image

from sepfm_ros.evaluation.bags import load_bag_pairs
from sepfm_ros.ros.bags.errors import BagError
from sepfm_ros.ros.bags.inputs import detect_inputs
from sepfm_ros.ros.bags.reader import BagReader
from sepfm_ros.ros.bags.results import gt_error_px, read_results
from sepfm_ros.ros.msgs.image_conversion import ImageDecodeError, check_compressed, message_to_numpy
from sepfm_ros.ros.offline.process import ProcessInputs, run_process
from sepfm_ros.ros.session.parameters import parse_params
from sepfm_ros.synthetic.sequences import pair_fundamental, stereo_sequence

REPO = Path(__file__).resolve().parents[2]
N_FRAMES = 3
PARAMS = ["seed:=0"]


@pytest.fixture(scope="module")
def sequence():
    return stereo_sequence(n_frames=N_FRAMES, seed=5)


@pytest.fixture(scope="module")
def frames(sequence) -> list[tuple[np.ndarray, np.ndarray]]:
    return [(f.images[0], f.images[1]) for f in sequence]


@pytest.fixture(scope="module")
def reference_F(frames, tmp_path_factory) -> list[np.ndarray | None]:
    """F per pair of the same frames in a plain robot bag (mono8, packed step, slashes)."""
    folder = tmp_path_factory.mktemp("reference")
    bag = write_robot_bag(bag_path(folder, "mcap"), "mcap", frames)
    done, total = run_process(
        bag, folder / "out", parse_params(PARAMS + ["use_camera_info:=false"]), progress=False
    )
    assert done == total == N_FRAMES
    results = read_results(folder / "out")
    assert all(r.F is not None for r in results)
    return [r.F for r in results]


def _cli(*args: str, timeout: float = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "sepfm_ros", *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _same_F(results, reference) -> None:
    assert len(results) == len(reference) == N_FRAMES
    for r, ref in zip(results, reference, strict=True):
        np.testing.assert_array_equal(r.F, ref)


# ----------------------------------------------------------------------------- step 0
def test_step_zero_reads_as_packed_rows_only_when_the_length_agrees():
    img = np.arange(6 * 5 * 3, dtype=np.uint8).reshape(6, 5, 3)
    msg = Image(height=6, width=5, encoding="bgr8", step=0, data=img.tobytes())
    np.testing.assert_array_equal(message_to_numpy(msg, "bgr8"), img)
    short = Image(height=6, width=5, encoding="bgr8", step=0, data=img.tobytes()[:-3])
    with pytest.raises(ImageDecodeError, match="step 0 .* packed rows .* 87 B, packed rows 90 B"):
        message_to_numpy(short)
    deep = (np.arange(4 * 3).reshape(4, 3) * 300).astype(">u2")
    msg16 = Image(height=4, width=3, encoding="16UC1", is_bigendian=1, step=0, data=deep.tobytes())
    np.testing.assert_array_equal(
        message_to_numpy(msg16), np.rint(deep.astype(float) * 255 / deep.max()).astype(np.uint8)
    )


@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_process_reads_step_zero_images_and_says_so_once(
    fmt, frames, reference_F, tmp_path, capsys
):
    bag = write_robot_bag(bag_path(tmp_path, fmt), fmt, frames, image=zero_step_image)
    params = parse_params(PARAMS + ["use_camera_info:=false"])
    done, total = run_process(bag, tmp_path / "out", params, progress=False)
    assert done == total == N_FRAMES
    err = capsys.readouterr().err
    assert "skipping" not in err
    _same_F(read_results(tmp_path / "out"), reference_F)  # the same pixels as packed rows
    notes = [line for line in err.splitlines() if "step 0" in line]
    assert len(notes) == 2, err  # once per topic, not per frame
    for topic in (LEFT_TOPIC, RIGHT_TOPIC):
        assert sum(topic in line for line in notes) == 1, notes
    assert "read as packed rows of 480 B" in notes[0]


def test_calibration_check_reads_step_zero_images_and_says_so_once(frames, tmp_path):
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames, image=zero_step_image)
    res = _cli(
        "calibration_check",
        str(bag),
        "--out",
        str(tmp_path / "check"),
        "-p",
        "calibration_min_pairs:=2",
    )
    assert "Traceback" not in res.stderr and "decision: " in res.stdout, res.stdout + res.stderr
    assert f"[{N_FRAMES}/{N_FRAMES}]" in res.stdout  # every pair decoded
    notes = [line for line in res.stdout.splitlines() if "step 0" in line]
    assert len(notes) == 2 and all(line.startswith("warning: ") for line in notes), notes


# ----------------------------------------------------------------------------- leading slash
@pytest.mark.parametrize("fmt", ["mcap", "ros1"])
def test_image_topics_without_leading_slash_find_their_camera_info(fmt, frames, tmp_path, capsys):
    rel = ("camera/left/image_raw", "camera/right/image_raw")
    infos = ("/camera/left/camera_info", "/camera/right/camera_info")
    bag = write_robot_bag(bag_path(tmp_path, fmt), fmt, frames, topics=rel, info_topics=infos)
    with BagReader(bag) as reader:
        assert set(rel) <= set(reader.topics)  # the bag spells them without the slash
        assert detect_inputs(reader).topics == rel
        assert detect_inputs(reader, left=LEFT_TOPIC, right=RIGHT_TOPIC).topics == rel
        assert detect_inputs(reader, left=rel[0], right=rel[1]).topics == rel
    done, total = run_process(
        bag, tmp_path / "out", parse_params(PARAMS), ProcessInputs(left=LEFT_TOPIC,
        right=RIGHT_TOPIC), progress=False,
    )  # fmt: skip
    assert done == total == N_FRAMES
    err = capsys.readouterr().err
    assert f"camera_info from {infos[0]} + {infos[1]}" in err, err
    with BagReader(tmp_path / "out") as out:
        assert out.topics["/sepfm/relative_transform"].count == N_FRAMES


def test_a_slashed_image_topic_finds_a_camera_info_without_one(frames, tmp_path, capsys):
    infos = ("camera/left/camera_info", "camera/right/camera_info")
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames, info_topics=infos)
    done, total = run_process(bag, tmp_path / "out", parse_params(PARAMS), progress=False)
    assert done == total == N_FRAMES
    assert f"camera_info from {infos[0]} + {infos[1]}" in capsys.readouterr().err


def test_calibration_check_finds_camera_info_beside_slash_less_topics(frames, tmp_path):
    rel = ("camera/left/image_raw", "camera/right/image_raw")
    infos = ("/camera/left/camera_info", "/camera/right/camera_info")
    bag = write_robot_bag(bag_path(tmp_path, "ros1"), "ros1", frames, topics=rel, info_topics=infos)
    res = _cli(
        "calibration_check",
        str(bag),
        "--out",
        str(tmp_path / "check"),
        "-p",
        "calibration_min_pairs:=2",
    )
    assert "Traceback" not in res.stderr and "has no camera_info" not in res.stderr, res.stderr
    assert f"calibration from {infos[0]} and {infos[1]}" in res.stdout, res.stdout
    assert f"[{N_FRAMES}/{N_FRAMES}]" in res.stdout and "decision: " in res.stdout


# ----------------------------------------------------------------------------- -o out.bag
@pytest.mark.parametrize("name", ["out.bag", "out.db3"])
def test_an_output_named_as_another_format_is_refused_before_any_work(frames, tmp_path, name):
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames[:1])
    out = tmp_path / name
    runs = {
        "process": _cli("process", str(bag), "-o", str(out), "--quiet"),
        "make_bag": _cli("make_bag", "--synthetic", "motion", "--frames", "2", "-o", str(out)),
        "record": _cli("record", "-o", str(out), "--duration", "1", "/image_raw"),
    }
    for command, res in runs.items():
        assert res.returncode == 1, (command, res.stdout, res.stderr)
        assert "Traceback" not in res.stderr
        assert f"output {out} names a " in res.stderr, (command, res.stderr)
        assert f"give a folder name without {out.suffix}" in res.stderr
        assert not out.exists(), command
    assert "rosbags-convert" in runs["process"].stderr if name == "out.bag" else True
    assert "input stereo" not in runs["process"].stderr  # refused before reading the bag
    with pytest.raises(BagError, match="names a"):
        run_process(bag, out, parse_params([]), progress=False)


# ----------------------------------------------------------------------------- one frame
def test_a_one_frame_bag_says_what_the_mode_needs_and_fails(frames, tmp_path):
    motion = write_camera_bag(tmp_path / "one_frame", [frames[0][0]])
    res = _cli("process", str(motion), "-o", str(tmp_path / "out_m"), "--quiet")
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert "/camera/image_raw has 1 frame(s)" in res.stderr
    assert "needs at least frame_gap + 1 = 2 frames" in res.stderr
    assert "0 of 0" not in res.stdout and not (tmp_path / "out_m").exists()
    res = _cli("process", str(motion), "-o", str(tmp_path / "o3"), "-p", "frame_gap:=3")
    assert res.returncode == 1 and "frame_gap + 1 = 4 frames" in res.stderr, res.stderr

    stereo = write_stereo_without_right(tmp_path / "no_right", frames[0][0])
    res = _cli("process", str(stereo), "-o", str(tmp_path / "out_s"), "--quiet")
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"{LEFT_TOPIC} has 1 frame(s), {RIGHT_TOPIC} has 0 frame(s)" in res.stderr
    assert "stereo needs a frame on both topics" in res.stderr
    assert not (tmp_path / "out_s").exists()


def test_eval_bags_names_a_bag_that_gives_no_pair(frames, tmp_path):
    bag = write_stereo_without_right(tmp_path / "no_right", frames[0][0], ground_truth=True)
    pairs, errors = load_bag_pairs(bag, tmp_path / "frames")
    assert pairs == [] and len(errors) == 1
    assert f"{RIGHT_TOPIC} has 0 frame(s)" in errors[0].message
    flags = ["--cache", "none", "--methods", "cv-ransac", "--seeds", "0", "--no-progress"]
    res = _cli("eval", "--bags", str(bag), "--out", str(tmp_path / "eval"), *flags)
    assert res.returncode != 0 and f"{RIGHT_TOPIC} has 0 frame(s)" in res.stderr, res.stderr


# ----------------------------------------------------------------------------- QOI, big-endian
def test_qoi_images_decode_through_process(frames, reference_F, tmp_path, capsys):
    bag = write_robot_bag(
        bag_path(tmp_path, "mcap"), "mcap", frames, image=qoi_compressed, image_type=COMPRESSED_T
    )
    with BagReader(bag) as reader:
        assert detect_inputs(reader).transport == "compressed"
    params = parse_params(PARAMS + ["use_camera_info:=false"])
    done, total = run_process(bag, tmp_path / "out", params, progress=False)
    assert done == total == N_FRAMES
    assert "skipping" not in capsys.readouterr().err
    _same_F(read_results(tmp_path / "out"), reference_F)  # QOI is lossless: the same pixels


def test_a_compressed_format_not_decoded_is_named(frames, tmp_path):
    for data, name in ((b"GIF89a" + bytes(64), "gif"), (b"RIFF\x00\x00\x00\x00WEBPVP8 ", "webp")):
        with pytest.raises(ImageDecodeError, match=f"are {name} data; jpeg, png and qoi"):
            check_compressed(CompressedImage(format=name, data=data))
    cut = CompressedImage(format="qoi", data=qoi_bytes(frames[0][0])[:-20])
    with pytest.raises(ImageDecodeError, match="qoi data of .* no end marker") as err:
        check_compressed(cut)
    assert err.value.kind == "truncated_compressed"


def test_big_endian_16_bit_images_through_process(sequence, frames, tmp_path, capsys):
    bag = write_robot_bag(bag_path(tmp_path, "ros1"), "ros1", frames, image=big_endian_mono16)
    params = parse_params(PARAMS + ["use_camera_info:=false"])
    done, total = run_process(bag, tmp_path / "out", params, progress=False)
    assert done == total == N_FRAMES
    assert "skipping" not in capsys.readouterr().err
    results = read_results(tmp_path / "out")
    assert len(results) == N_FRAMES
    for r, frame in zip(results, sequence, strict=True):
        assert r.F is not None, r.status
        assert gt_error_px(r.F, pair_fundamental(*frame.cameras), *r.pts()) < 1.0


# ----------------------------------------------------------------------------- exit codes
def _padded_step_zero(ts, header, img: np.ndarray):
    """``step`` 0 on padded rows: the data length disagrees with packed rows (undecodable)."""
    msg = zero_step_image(ts, header, np.pad(img, ((0, 0), (0, 8))))
    msg.width = img.shape[1]
    return msg


def test_process_names_frames_skipped_for_their_fields(frames, tmp_path):
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames, image=_padded_step_zero)
    res = _cli("process", str(bag), "-o", str(tmp_path / "out"), "--quiet")
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stdout + res.stderr
    assert "step 0 is smaller than a row" in res.stderr  # the reason
    assert f"{LEFT_TOPIC} has 0 frame(s) ({N_FRAMES} more skipped: unusable fields)" in res.stderr
    assert not (tmp_path / "out").exists()


def _all_nan(ts, header, img: np.ndarray):
    """A 32FC1 image without one finite pixel: its fields pass, its pixels cannot be mapped."""
    h, w = img.shape[:2]
    data = np.full((h, w), np.nan, "<f4").tobytes()
    return ts.types[IMAGE_T](
        header=header, height=h, width=w, encoding="32FC1", is_bigendian=0, step=4 * w,
        data=np.frombuffer(data, np.uint8),
    )  # fmt: skip


def test_process_exits_non_zero_when_no_pair_decodes(frames, tmp_path):
    bag = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames, image=_all_nan)
    res = _cli("process", str(bag), "-o", str(tmp_path / "out"), "--quiet")
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stdout + res.stderr
    assert "has no finite pixel" in res.stderr  # the reason, per pair
    assert f"error: none of the {N_FRAMES} pairs could be decoded" in res.stderr


def test_record_exits_non_zero_when_nothing_was_recorded(tmp_path, ros_domain_id):
    out = tmp_path / "rec"
    res = _cli("record", "-o", str(out), "--duration", "1", "/nobody/publishes/this", timeout=120)
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert "warning: never saw a publisher of /nobody/publishes/this" in res.stderr
    assert "error: nothing recorded" in res.stderr
    with BagReader(out) as reader:  # still a readable (empty) bag
        assert reader.message_count == 0


def test_eval_exits_non_zero_when_a_bag_gives_no_pair(sequence, frames, tmp_path):
    gt = [pair_fundamental(*f.cameras) for f in sequence]
    good = write_robot_bag(bag_path(tmp_path, "mcap"), "mcap", frames, ground_truth=gt)
    bad = write_stereo_without_right(tmp_path / "no_right", frames[0][0], ground_truth=True)
    out = tmp_path / "eval"
    flags = ["--cache", "none", "--methods", "cv-ransac", "--seeds", "0", "--no-progress"]
    res = _cli("eval", "--bags", str(good), "--bags", str(bad), "--out", str(out), *flags)
    assert res.returncode == 1 and "Traceback" not in res.stderr, res.stderr
    assert f"error: no pair from --bags {bad}" in res.stderr
    rows = (out / "runs.csv").read_text().splitlines()[1:]
    assert len(rows) == N_FRAMES  # the good bag was still evaluated and reported
