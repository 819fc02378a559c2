"""ROS 2 without ROS: PointCloud2 in, Detection3DArray out, bags as batch scans.

>>> from pointclm.ros import read_pointcloud2, detection3d_array   # doctest: +SKIP
>>> scan = read_pointcloud2(msg)               # rclpy, rosbags or dict message -> PointCloud
>>> reg = pointclm.register_point_clouds(model, scan.points)
>>> out = detection3d_array(reg, header=msg.header, class_id="bracket")

Design decisions
----------------
- **No ROS needed.** A PointCloud2 is read from its bytes and layout with numpy
  (:func:`parse_pointcloud2`), from a dict, or from any message object with its attributes
  (rclpy, ``rosbags``), duck-typed; nothing here imports rclpy to read.
- **Detections in the caller's world.** :func:`detection3d_array` builds rclpy messages
  when rclpy and vision_msgs import (a node publishes them as they are), objects of a
  ``rosbags`` typestore when given one (to write a bag without ROS), and nested dicts
  otherwise, with the same field names.
- **Bags are scans.** ``pointclm batch MODEL run.mcap --out r.jsonl`` registers every
  PointCloud2 message of the bag (:mod:`pointclm.ros.bags`); ``rosbags`` (pure Python) is
  in the ``[io]`` extra and imported only for bags.
"""

from __future__ import annotations

from .bags import BAG_SUFFIXES, bag_scans, is_bag, is_bag_message, read_bag_scan
from .detections import (
    OUTPUTS,
    UNKNOWN_COVARIANCE,
    VISION_MSGS,
    add_vision_msgs,
    detection3d_array,
)
from .pointcloud2 import DATATYPES, parse_pointcloud2, read_pointcloud2

__all__ = [
    "BAG_SUFFIXES",
    "DATATYPES",
    "OUTPUTS",
    "UNKNOWN_COVARIANCE",
    "VISION_MSGS",
    "add_vision_msgs",
    "bag_scans",
    "detection3d_array",
    "is_bag",
    "is_bag_message",
    "parse_pointcloud2",
    "read_bag_scan",
    "read_pointcloud2",
]
