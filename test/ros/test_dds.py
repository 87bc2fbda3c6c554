"""The Fast DDS settings of the image-subscribing processes (sepfm_ros/ros/dds.py): when they
apply and what they set. Their effect on a live node: test_node_field.py (best-effort colour
and stereo cameras) and the fuzz tests in test_robustness_live.py (memory)."""

from __future__ import annotations

import xml.etree.ElementTree as ET

import pytest

from sepfm_ros.ros.node import dds

NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"
MIB = 1024 * 1024


def test_profiles_file_gives_subscribers_dynamic_history_and_keeps_publisher_defaults():
    root = ET.parse(dds.DDS_PROFILES).getroot()
    subs = root.findall(f"{NS}profiles/{NS}subscriber")
    pubs = root.findall(f"{NS}profiles/{NS}publisher")
    assert len(subs) == 1 and subs[0].get("is_default_profile") == "true"
    assert subs[0].findtext(f"{NS}historyMemoryPolicy") == "DYNAMIC"
    assert len(pubs) == 1 and pubs[0].get("is_default_profile") == "true"
    # what rmw_fastrtps (Jazzy) sets itself when it is not told to read the XML
    assert pubs[0].findtext(f"{NS}historyMemoryPolicy") == "PREALLOCATED_WITH_REALLOC"
    assert pubs[0].findtext(f"{NS}qos/{NS}publishMode/{NS}kind") == "SYNCHRONOUS"
    # the transport is chosen at run time (it depends on the kernel's limit), not in the XML
    assert root.find(f"{NS}profiles/{NS}participant") is None


def test_udp_input_with_the_buffers_the_kernel_allows(tmp_path):
    env = {}
    setup = dds.configure_dds(env, cwd=tmp_path, rmem_max=4 * MIB)
    assert setup == dds.DdsSetup(True, dds.UDP, socket_bytes=4 * MIB, rmem_max=4 * MIB)
    assert env == {
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(dds.DDS_PROFILES),
        "RMW_FASTRTPS_USE_QOS_FROM_XML": "1",
        "FASTDDS_BUILTIN_TRANSPORTS": f"UDPv4?sockets_size={4 * MIB}",
    }
    assert setup.describe() == "UDP, 4096 KiB socket buffers"
    # a generous kernel: the buffers stop at UDP_SOCKET_BYTES
    env = {
        "RMW_IMPLEMENTATION": "rmw_fastrtps_dynamic_cpp",
        "ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET",
    }
    setup = dds.configure_dds(env, cwd=tmp_path, rmem_max=64 * MIB)
    assert setup.transport == dds.UDP and setup.socket_bytes == dds.UDP_SOCKET_BYTES
    assert env["FASTDDS_BUILTIN_TRANSPORTS"] == f"UDPv4?sockets_size={dds.UDP_SOCKET_BYTES}"


def test_small_kernel_limit_keeps_shared_memory_and_names_the_sysctl(tmp_path):
    env = {}
    setup = dds.configure_dds(env, cwd=tmp_path, rmem_max=212992)  # Linux's default
    assert setup.transport == dds.SHARED_MEMORY and setup.profiles
    assert "FASTDDS_BUILTIN_TRANSPORTS" not in env
    advice = setup.lost_sample_advice()
    assert dds.RMEM_SYSCTL in advice and "512 KiB" in advice and "publish reliable" in advice
    assert "208 KiB" in setup.describe()


@pytest.mark.parametrize(
    "env", [{"ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST"}, {"ROS_LOCALHOST_ONLY": "1"}]
)
def test_localhost_discovery_range_keeps_rmw_transports_and_says_so(env, tmp_path):
    given = dict(env)
    setup = dds.configure_dds(env, cwd=tmp_path, rmem_max=64 * MIB)
    assert setup.transport == dds.LOCALHOST and setup.profiles
    assert "FASTDDS_BUILTIN_TRANSPORTS" not in env
    assert "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET" in setup.lost_sample_advice()
    assert dds.RMEM_SYSCTL not in setup.lost_sample_advice()  # the kernel allows UDP
    assert "run the recorder with" in setup.lost_sample_advice("the recorder")
    small = dds.configure_dds(given, cwd=tmp_path, rmem_max=212992)
    assert small.transport == dds.LOCALHOST and dds.RMEM_SYSCTL in small.lost_sample_advice()


@pytest.mark.parametrize(
    "env",
    [
        {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
        {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
        {"RMW_FASTRTPS_USE_QOS_FROM_XML": "0"},
        {"RMW_FASTRTPS_PUBLICATION_MODE": "ASYNCHRONOUS"},
        {"FASTDDS_BUILTIN_TRANSPORTS": "LARGE_DATA"},
    ],
)
def test_user_fast_dds_configuration_is_left_alone(env, tmp_path):
    before = dict(env)
    setup = dds.configure_dds(env, cwd=tmp_path, rmem_max=64 * MIB)
    assert setup == dds.DdsSetup(False, dds.USER)
    assert env == before
    assert "publish reliable" in setup.lost_sample_advice()


def test_other_middleware_is_left_alone(tmp_path):
    env = {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}
    assert dds.configure_dds(env, cwd=tmp_path, rmem_max=64 * MIB).transport == (
        dds.OTHER_MIDDLEWARE
    )
    assert env == {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}


def test_default_xml_in_working_directory_is_left_alone(tmp_path):
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<dds/>")
    env = {}
    assert dds.configure_dds(env, cwd=tmp_path, rmem_max=64 * MIB).transport == dds.USER
    assert env == {}


def test_kernel_limit_is_read_from_proc_or_zero(tmp_path):
    path = tmp_path / "rmem_max"
    path.write_text("4194304\n")
    assert dds.read_rmem_max(path) == 4194304
    path.write_text("garbage")
    assert dds.read_rmem_max(path) == 0
    assert dds.read_rmem_max(tmp_path / "missing") == 0
