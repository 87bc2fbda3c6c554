"""Fast DDS settings of the processes that subscribe to images (the node, ``record``), made in
the environment before ``rclpy.init`` creates the DDS participant.

Two settings, each only when the user has not configured Fast DDS (an XML profiles file, a
default XML in the working directory, ``FASTDDS_BUILTIN_TRANSPORTS``, rmw_fastrtps's QoS
variables) and Fast DDS is the middleware:

- **Subscriber history** (``data/fastdds_node_profiles.xml``): DYNAMIC, so a sample's payload is
  freed when it is taken (the memory side: see :mod:`sepfm_ros.ros.node.memory`).
- **Input transport**: Fast DDS sends a sample to a participant on the same host through shared
  memory, in the *writer's* segment of 512 KiB. A best-effort sample larger than that (640x480
  ``bgr8`` is 900 KiB, a 1241x376 ``mono8`` pair 2 x 456 KiB) does not fit with the rest of its
  fragments and is lost whole, every time: a camera driver publishing best effort (the sensor-data
  QoS) delivered nothing. Only the writer's configuration can enlarge its segment, so the
  subscriber leaves shared memory out: with ``FASTDDS_BUILTIN_TRANSPORTS=UDPv4`` a local writer
  sends over UDP loopback, and socket buffers of ``UDP_SOCKET_BYTES`` (the kernel caps them at
  ``net.core.rmem_max``) hold a whole frame's fragments until they are read. This needs
  ``rmem_max`` >= ``MIN_UDP_SOCKET_BYTES``: below it (Linux's default is 208 KiB) UDP would lose
  even the images that shared memory delivers, so shared memory stays and the lost-sample
  message names the ``sysctl`` that lifts the limit. With ``ROS_AUTOMATIC_DISCOVERY_RANGE``
  ``LOCALHOST`` (or ``ROS_LOCALHOST_ONLY=1``), rmw_fastrtps installs shared memory and UDP itself
  and ignores both the variable and the XML's transports.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

DDS_PROFILES = Path(__file__).resolve().parents[2] / "data" / "fastdds_node_profiles.xml"
#: Fast DDS reads these; when any is set (or the working directory holds Fast DDS's default XML),
#: the user configures the middleware and we leave it alone.
USER_DDS_CONFIG = (
    "FASTRTPS_DEFAULT_PROFILES_FILE",
    "FASTDDS_DEFAULT_PROFILES_FILE",
    "RMW_FASTRTPS_USE_QOS_FROM_XML",
    "RMW_FASTRTPS_PUBLICATION_MODE",
    "FASTDDS_BUILTIN_TRANSPORTS",
)
DEFAULT_XML_NAMES = ("DEFAULT_FASTRTPS_PROFILES.xml", "DEFAULT_FASTDDS_PROFILES.xml")
#: where Linux keeps the largest receive buffer a process may ask for
RMEM_MAX = Path("/proc/sys/net/core/rmem_max")
#: UDP socket buffers asked for (bytes; the kernel grants at most ``rmem_max``)
UDP_SOCKET_BYTES = 16 * 1024 * 1024
#: the least ``rmem_max`` at which the input goes over UDP (four shared-memory segments)
MIN_UDP_SOCKET_BYTES = 2 * 1024 * 1024
#: Fast DDS's default shared-memory segment: the largest best-effort sample it delivers locally
SHM_SAMPLE_BYTES = 512 * 1024
#: the ``sysctl`` the lost-sample advice names
RMEM_SYSCTL = f"sudo sysctl -w net.core.rmem_max={UDP_SOCKET_BYTES}"

#: :attr:`DdsSetup.transport` values
UDP, SHARED_MEMORY, LOCALHOST, USER, OTHER_MIDDLEWARE, UNCONFIGURED = (
    "udp", "shared_memory", "localhost", "user", "other_middleware", "unconfigured",
)  # fmt: skip


@dataclass(frozen=True)
class DdsSetup:
    """What :func:`configure_dds` chose.

    Attributes:
        profiles: the subscriber-history profiles were set.
        transport: ``"udp"`` (shared memory left out), ``"shared_memory"`` (rmem_max too small),
            ``"localhost"`` (rmw_fastrtps's own localhost transports), ``"user"`` (the user's
            Fast DDS configuration), ``"other_middleware"``, or ``"unconfigured"`` (a node made
            in a process that did not call :func:`configure_dds`).
        socket_bytes: UDP socket buffer the kernel grants (``"udp"``), else 0.
        rmem_max: the kernel's limit read (bytes; 0 when unknown).
    """

    profiles: bool
    transport: str
    socket_bytes: int = 0
    rmem_max: int = 0

    def describe(self) -> str:
        """One line for the node's log and ``/diagnostics``."""
        if self.transport == UDP:
            return f"UDP, {self.socket_bytes // 1024} KiB socket buffers"
        if self.transport == SHARED_MEMORY:
            return (
                f"shared memory + UDP (net.core.rmem_max {self.rmem_max // 1024} KiB is below "
                f"{MIN_UDP_SOCKET_BYTES // 1024} KiB)"
            )
        if self.transport == LOCALHOST:
            return "shared memory + UDP (rmw_fastrtps's localhost discovery range)"
        if self.transport == USER:
            return "the user's Fast DDS configuration"
        if self.transport == OTHER_MIDDLEWARE:
            return "the middleware's own"
        return "not configured by sepfm_ros"

    def lost_sample_advice(self, who: str = "the node") -> str:
        """Why best-effort samples are lost with this setup, and the fix (one sentence);
        ``who`` names the subscribing process."""
        reliable = f"publish reliable ({who} then subscribes reliable)"
        big = f"best-effort samples over {SHM_SAMPLE_BYTES // 1024} KiB from this host"
        if self.transport == UDP:
            return (
                "a best-effort frame is lost with any one of its UDP fragments (socket buffers "
                f"{self.socket_bytes // 1024} KiB): {reliable}, or lower the camera's rate"
            )
        if self.transport == SHARED_MEMORY:
            return (
                f"{big} do not fit Fast DDS's shared memory and are lost whole: {reliable}, "
                f"or raise the kernel's UDP buffer limit ({RMEM_SYSCTL}) and restart {who}, "
                "which then receives over UDP"
            )
        if self.transport == LOCALHOST:
            also = f" and raise the kernel's UDP buffer limit ({RMEM_SYSCTL})"
            return (
                f"with the localhost discovery range rmw_fastrtps sends {big} through shared "
                f"memory, where they are lost whole: {reliable}, or run {who} with "
                "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET"
                + (also if self.rmem_max < MIN_UDP_SOCKET_BYTES else "")
                + " (it then receives over UDP)"
            )
        return (
            "large images over a best-effort subscription lose a frame per lost fragment: "
            f"{reliable}"
        )


def read_rmem_max(path: Path = RMEM_MAX) -> int:
    """The kernel's receive-buffer limit in bytes (0 when it cannot be read)."""
    try:
        return int(path.read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return 0


def configure_dds(
    environ: dict[str, str] | None = None, cwd: Path | None = None, rmem_max: int | None = None
) -> DdsSetup:
    """Set the subscriber-history profiles and the input transport in ``environ`` (default:
    ``os.environ``) as the module says; must run before ``rclpy.init``.

    Args:
        cwd: where Fast DDS looks for a default XML (default: the working directory).
        rmem_max: the kernel's limit in bytes (default: read from /proc).
    """
    env = os.environ if environ is None else environ
    rmw = env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    if not rmw.startswith("rmw_fastrtps"):
        return DdsSetup(False, OTHER_MIDDLEWARE)
    where = Path.cwd() if cwd is None else cwd
    if any(env.get(k) for k in USER_DDS_CONFIG) or any(
        (where / name).is_file() for name in DEFAULT_XML_NAMES
    ):
        return DdsSetup(False, USER)
    profiles = DDS_PROFILES.is_file()
    if profiles:
        env["FASTRTPS_DEFAULT_PROFILES_FILE"] = str(DDS_PROFILES)
        env["RMW_FASTRTPS_USE_QOS_FROM_XML"] = "1"
    limit = read_rmem_max() if rmem_max is None else int(rmem_max)
    localhost = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").upper() == "LOCALHOST"
    if localhost or env.get("ROS_LOCALHOST_ONLY", "") == "1":
        return DdsSetup(profiles, LOCALHOST, rmem_max=limit)
    if limit < MIN_UDP_SOCKET_BYTES:
        return DdsSetup(profiles, SHARED_MEMORY, rmem_max=limit)
    granted = min(limit, UDP_SOCKET_BYTES)
    env["FASTDDS_BUILTIN_TRANSPORTS"] = f"UDPv4?sockets_size={granted}"
    return DdsSetup(profiles, UDP, socket_bytes=granted, rmem_max=limit)
