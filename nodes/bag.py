"""rosbag2 episodes: a bag directory in MCAP storage written with the ``rosbags`` package, the layout
``ros2 bag record -s mcap -o NAME`` makes (``NAME/metadata.yaml`` and ``NAME/NAME.mcap``), so ``ros2 bag
info/play NAME`` and Foxglove (on the .mcap file) read it. Messages arrive already serialised (CDR); each
topic's schema is its ROS 2 message definition from ``nodes.msgs.STORE`` (Humble)."""

from __future__ import annotations

import threading
from pathlib import Path

from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer

from nodes.msgs import STORE
from pegasus_gen.errors import PegasusError

BAG_VERSION = 8  # rosbag2's metadata version of Humble (Jazzy reads it too)


def bag_directory(path: str | Path) -> Path:
    """The bag directory ``path`` names: itself, or for ``NAME.mcap`` the directory ``NAME`` (holding
    ``NAME.mcap``). PegasusError when it exists already: a bag never overwrites anything."""
    path = Path(path)
    if path.suffix == ".mcap":
        path = path.with_suffix("")
    if not path.name:
        raise PegasusError(f"record: {str(path)!r} names no bag")
    if path.exists():
        raise PegasusError(f"record: {path} exists already; give a new name (a bag never overwrites)")
    return path


def offered_qos(reliable: bool, transient_local: bool, depth: int) -> Qos:
    """A publisher's QoS as rosbag2 stores it in the topic's metadata (``ros2 bag play`` offers it again)."""
    infinite = QosTime(sec=0x7FFFFFFF, nsec=0xFFFFFFFF)
    return Qos(history=QosHistory.KEEP_LAST, depth=depth,
               reliability=QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               durability=QosDurability.TRANSIENT_LOCAL if transient_local else QosDurability.VOLATILE,
               deadline=infinite, lifespan=infinite, liveliness=QosLiveliness.AUTOMATIC,
               liveliness_lease_duration=infinite, avoid_ros_namespace_conventions=False)


class BagWriter:
    """One bag being written; thread-safe (an executor's callbacks may write at once)."""

    def __init__(self, path: str | Path):
        self.path = bag_directory(path)
        self.writer = Writer(self.path, version=BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
        self.writer.open()
        self.connections: dict[str, object] = {}
        self.counts: dict[str, int] = {}
        self.lock = threading.Lock()

    def add_topic(self, topic: str, type_name: str, qos: list[Qos] = ()) -> None:
        """Start the topic ``topic`` (fully qualified) of messages ``type_name`` (``"sensor_msgs/msg/Image"``)."""
        with self.lock:
            self.connections[topic] = self.writer.add_connection(topic, type_name, typestore=STORE,
                                                                 offered_qos_profiles=list(qos))
            self.counts[topic] = 0

    def write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        """One message of ``topic``: CDR ``data`` received at ``stamp_ns`` (ns since the epoch)."""
        with self.lock:
            if self.writer is None:  # closed: the node is going down
                return
            self.writer.write(self.connections[topic], stamp_ns, data)
            self.counts[topic] += 1

    def close(self) -> None:
        """Write the index and metadata.yaml (a bag without them is only readable in part)."""
        with self.lock:
            if self.writer is not None:
                self.writer.close()
                self.writer = None
