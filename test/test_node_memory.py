"""The node's memory settings (sepfm_ros/ros/memory.py): when they apply and what they set.
Their effect on a live node is measured by the fuzz tests in test_robustness_live.py."""

from __future__ import annotations

import ctypes.util
import platform
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

from sepfm_ros.ros import memory

REPO = Path(__file__).resolve().parent.parent
NS = "{http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles}"


def test_profiles_file_gives_subscribers_dynamic_history_and_keeps_publisher_defaults():
    root = ET.parse(memory.DDS_PROFILES).getroot()
    subs = root.findall(f"{NS}profiles/{NS}subscriber")
    pubs = root.findall(f"{NS}profiles/{NS}publisher")
    assert len(subs) == 1 and subs[0].get("is_default_profile") == "true"
    assert subs[0].findtext(f"{NS}historyMemoryPolicy") == "DYNAMIC"
    assert len(pubs) == 1 and pubs[0].get("is_default_profile") == "true"
    # what rmw_fastrtps (Jazzy) sets itself when it is not told to read the XML
    assert pubs[0].findtext(f"{NS}historyMemoryPolicy") == "PREALLOCATED_WITH_REALLOC"
    assert pubs[0].findtext(f"{NS}qos/{NS}publishMode/{NS}kind") == "SYNCHRONOUS"


def test_profiles_set_for_fast_dds_without_user_configuration(tmp_path):
    env = {}
    assert memory.use_node_dds_profiles(env, cwd=tmp_path)
    assert env == {
        "FASTRTPS_DEFAULT_PROFILES_FILE": str(memory.DDS_PROFILES),
        "RMW_FASTRTPS_USE_QOS_FROM_XML": "1",
    }
    env = {"RMW_IMPLEMENTATION": "rmw_fastrtps_dynamic_cpp"}
    assert memory.use_node_dds_profiles(env, cwd=tmp_path)


@pytest.mark.parametrize(
    "env",
    [
        {"FASTRTPS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
        {"FASTDDS_DEFAULT_PROFILES_FILE": "/etc/mine.xml"},
        {"RMW_FASTRTPS_USE_QOS_FROM_XML": "0"},
        {"RMW_FASTRTPS_PUBLICATION_MODE": "ASYNCHRONOUS"},
        {"RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"},
    ],
)
def test_user_middleware_configuration_is_left_alone(env, tmp_path):
    before = dict(env)
    assert not memory.use_node_dds_profiles(env, cwd=tmp_path)
    assert env == before


def test_default_xml_in_working_directory_is_left_alone(tmp_path):
    (tmp_path / "DEFAULT_FASTRTPS_PROFILES.xml").write_text("<dds/>")
    env = {}
    assert not memory.use_node_dds_profiles(env, cwd=tmp_path)
    assert env == {}


def test_malloc_settings_apply_on_glibc_and_are_harmless_elsewhere():
    # process-wide settings: in a child process, so the test process's allocator stays as is
    on_glibc = platform.libc_ver()[0] == "glibc" and ctypes.util.find_library("c") is not None
    code = (
        "from sepfm_ros.ros import memory\n"
        "print(memory.configure_malloc())\n"
        "memory.release_free_memory()\n"  # no-op without glibc; must not raise either way
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(on_glibc)
