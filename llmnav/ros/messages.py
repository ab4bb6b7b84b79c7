"""Standard ROS 2 messages (Humble definitions) built from llmnav's planar poses, serialised as CDR.

rosbags' type store carries the message definitions (written into each MCAP schema as ROS 2 concatenated
`.msg` text, the form `ros2 bag` stores) and serialises the messages. Frames follow REP 105: `map` (the
world), `odom` (odometry's origin), `base_link` (the robot's centre, where the LiDAR sits too).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

MAP_FRAME = "map"
ODOM_FRAME = "odom"
BASE_FRAME = "base_link"
CAMERA_FRAME = "camera"

TYPES = {
    "odometry": "nav_msgs/msg/Odometry",
    "pose": "geometry_msgs/msg/PoseStamped",
    "tf": "tf2_msgs/msg/TFMessage",
    "scan": "sensor_msgs/msg/LaserScan",
    "map": "nav_msgs/msg/OccupancyGrid",
    "image": "sensor_msgs/msg/CompressedImage",
    "twist": "geometry_msgs/msg/Twist",
    "path": "nav_msgs/msg/Path",
}


def missing_dependency() -> str | None:
    """None when the MCAP writer's libraries import, else the one-line hint to install them."""
    try:
        # deferred: mcap and rosbags are the optional 'ros' extra; this checks for them
        import mcap.writer  # noqa: F401
        import rosbags.typesys  # noqa: F401
    except ImportError as err:
        return f"MCAP export needs the 'ros' extra ({err.name} is missing): pip install 'llmnav[ros]'"
    return None


def quaternion(yaw: float) -> tuple[float, float, float, float]:
    """(x, y, z, w) of a rotation by `yaw` [rad] about +z."""
    return (0.0, 0.0, math.sin(yaw / 2.0), math.cos(yaw / 2.0))


def compose(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float]:
    """Planar transform a ∘ b: pose b, given in frame a, expressed in a's parent frame."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (a[0] + c * b[0] - s * b[1], a[1] + s * b[0] + c * b[1], a[2] + b[2])


def inverse(a: Sequence[float]) -> tuple[float, float, float]:
    """The planar transform that undoes `a`."""
    c, s = math.cos(a[2]), math.sin(a[2])
    return (-(c * a[0] + s * a[1]), s * a[0] - c * a[1], -a[2])


class RosMessages:
    """Builds and serialises the ROS 2 messages of an export; one instance per file (the store is loaded once)."""

    def __init__(self) -> None:
        # deferred: rosbags is the optional 'ros' extra
        from rosbags.typesys import Stores, get_typestore

        self.store = get_typestore(Stores.ROS2_HUMBLE)
        self._t = self.store.types

    def definition(self, msgtype: str) -> str:
        """The ROS 2 concatenated message definition MCAP's `ros2msg` schema encoding expects."""
        text, _ = self.store.generate_msgdef(msgtype, ros_version=2)
        return str(text)

    def serialize(self, message: Any) -> bytes:
        """CDR bytes (little endian, with the encapsulation header) of a message."""
        return bytes(self.store.serialize_cdr(message, message.__msgtype__))

    # --- building blocks ---------------------------------------------------------------------------

    def _header(self, t_sim: float, frame: str) -> Any:
        sec = math.floor(t_sim)
        nanosec = min(round((t_sim - sec) * 1e9), 999_999_999)
        stamp = self._t["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
        return self._t["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def _pose(self, pose: Sequence[float]) -> Any:
        qx, qy, qz, qw = quaternion(pose[2])
        point = self._t["geometry_msgs/msg/Point"](x=float(pose[0]), y=float(pose[1]), z=0.0)
        orientation = self._t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)
        return self._t["geometry_msgs/msg/Pose"](position=point, orientation=orientation)

    def _twist(self, v: float, w: float) -> Any:
        vector = self._t["geometry_msgs/msg/Vector3"]
        return self._t["geometry_msgs/msg/Twist"](linear=vector(x=v, y=0.0, z=0.0), angular=vector(x=0.0, y=0.0, z=w))

    def _transform(self, t_sim: float, parent: str, child: str, pose: Sequence[float]) -> Any:
        qx, qy, qz, qw = quaternion(pose[2])
        translation = self._t["geometry_msgs/msg/Vector3"](x=float(pose[0]), y=float(pose[1]), z=0.0)
        rotation = self._t["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw)
        transform = self._t["geometry_msgs/msg/Transform"](translation=translation, rotation=rotation)
        return self._t["geometry_msgs/msg/TransformStamped"](
            header=self._header(t_sim, parent), child_frame_id=child, transform=transform
        )

    # --- messages ----------------------------------------------------------------------------------

    def odometry(self, t_sim: float, odom: Sequence[float], velocity: tuple[float, float] | None) -> Any:
        """nav_msgs/Odometry in `odom`; the twist (in base_link) when the run logged it, else zero."""
        covariance = np.zeros(36, dtype=np.float64)
        pose = self._t["geometry_msgs/msg/PoseWithCovariance"](pose=self._pose(odom), covariance=covariance)
        v, w = velocity if velocity is not None else (0.0, 0.0)
        twist = self._t["geometry_msgs/msg/TwistWithCovariance"](twist=self._twist(v, w), covariance=covariance)
        return self._t["nav_msgs/msg/Odometry"](
            header=self._header(t_sim, ODOM_FRAME), child_frame_id=BASE_FRAME, pose=pose, twist=twist
        )

    def pose_stamped(self, t_sim: float, pose: Sequence[float], frame: str = MAP_FRAME) -> Any:
        """geometry_msgs/PoseStamped (the true pose, in `map`)."""
        return self._t["geometry_msgs/msg/PoseStamped"](header=self._header(t_sim, frame), pose=self._pose(pose))

    def tf(self, t_sim: float, true_pose: Sequence[float], odom: Sequence[float]) -> Any:
        """tf2_msgs/TFMessage map → odom → base_link: map → odom is what a perfect localiser would publish."""
        map_to_odom = compose(true_pose, inverse(odom))
        transforms = [
            self._transform(t_sim, MAP_FRAME, ODOM_FRAME, map_to_odom),
            self._transform(t_sim, ODOM_FRAME, BASE_FRAME, odom),
        ]
        return self._t["tf2_msgs/msg/TFMessage"](transforms=transforms)

    def scan(self, t_sim: float, scan: dict[str, Any]) -> Any:
        """sensor_msgs/LaserScan from a recorded `sample` scan; no return is +inf (REP 117)."""
        ranges = np.asarray(scan["ranges"], dtype=np.float32)
        increment = float(scan["angle_increment"])
        return self._t["sensor_msgs/msg/LaserScan"](
            header=self._header(t_sim, BASE_FRAME),
            angle_min=float(scan["angle_min"]),
            angle_max=float(scan["angle_min"]) + increment * (len(ranges) - 1),
            angle_increment=increment,
            time_increment=0.0,  # every ray of a scan is cast at one instant
            scan_time=0.0,
            range_min=float(scan["range_min"]),
            range_max=float(scan["range_max"]),
            ranges=ranges,
            intensities=np.zeros(0, dtype=np.float32),
        )

    def occupancy_grid(self, t_sim: float, grid: dict[str, Any], occupied: np.ndarray) -> Any:
        """nav_msgs/OccupancyGrid: row-major from the lower-left cell, 100 = occupied, 0 = free."""
        height, width = occupied.shape
        origin = self._pose([float(grid["origin"][0]), float(grid["origin"][1]), 0.0])
        info = self._t["nav_msgs/msg/MapMetaData"](
            map_load_time=self._header(t_sim, MAP_FRAME).stamp,
            resolution=float(grid["resolution"]),
            width=width,
            height=height,
            origin=origin,
        )
        data = np.where(occupied, 100, 0).astype(np.int8).ravel()
        return self._t["nav_msgs/msg/OccupancyGrid"](header=self._header(t_sim, MAP_FRAME), info=info, data=data)

    def compressed_image(self, t_sim: float, jpeg: bytes) -> Any:
        """sensor_msgs/CompressedImage of a stored JPEG."""
        return self._t["sensor_msgs/msg/CompressedImage"](
            header=self._header(t_sim, CAMERA_FRAME), format="jpeg", data=np.frombuffer(jpeg, dtype=np.uint8)
        )

    def string(self, text: str) -> Any:
        """std_msgs/String."""
        return self._t["std_msgs/msg/String"](data=text)

    def twist(self, v: float, w: float) -> Any:
        """geometry_msgs/Twist: forward speed v [m/s], turn rate w [rad/s]."""
        return self._twist(v, w)

    def path(self, t_sim: float, points: Sequence[Sequence[float]]) -> Any:
        """nav_msgs/Path through (x, y) points in `map`, each pose facing the next point."""
        poses = []
        for i, point in enumerate(points):
            ahead = points[i + 1] if i + 1 < len(points) else None
            behind = points[i - 1] if i > 0 else None
            if ahead is not None:
                yaw = math.atan2(ahead[1] - point[1], ahead[0] - point[0])
            elif behind is not None:
                yaw = math.atan2(point[1] - behind[1], point[0] - behind[0])
            else:
                yaw = 0.0
            poses.append(self.pose_stamped(t_sim, [point[0], point[1], yaw]))
        return self._t["nav_msgs/msg/Path"](header=self._header(t_sim, MAP_FRAME), poses=poses)


def json_schema(title: str, properties: dict[str, str]) -> dict[str, Any]:
    """A JSON Schema for one JSON topic: the named fields' types; further fields allowed (logs grow)."""
    return {
        "$schema": "https://json-schema.org/draft/2020-12/schema",
        "title": title,
        "type": "object",
        "properties": {name: {"type": kind} if kind != "any" else {} for name, kind in properties.items()},
        "additionalProperties": True,
    }


# The run log's decisions as JSON topics: topic -> (schema title, the fields every such event carries)
JSON_TOPICS: dict[str, tuple[str, dict[str, str]]] = {
    "/llmnav/llm_call": (
        "llmnav.LlmCall",
        {"step": "integer", "purpose": "string", "reply": "any", "error": "any", "t_sim": "number"},
    ),
    "/llmnav/guard": (
        "llmnav.GuardVerdict",
        {"step": "integer", "outcome": "string", "error": "any", "attempt": "integer", "value": "any"},
    ),
    "/llmnav/action": (
        "llmnav.Action",
        {"step": "integer", "command": "string", "parameters": "any", "collided": "boolean", "pose_after": "array"},
    ),
    "/llmnav/veto": ("llmnav.Veto", {"step": "integer", "command": "string", "veto": "any"}),
    "/llmnav/planner": ("llmnav.PlannerRecord", {"kind": "string"}),
    "/llmnav/end": ("llmnav.End", {"outcome": "string", "reason": "string", "iterations": "integer"}),
}
