#!/usr/bin/env python3
"""A matcher node for angle-i2p with rclpy, for ROS 2 users (needs a sourced ROS 2 and the
angle_i2p_msgs package built in the workspace; see docs/ros2.md, "For ROS 2 users"). The same
contract as examples/matcher_cyclonedds.py, which is the tested variant:

- one Correspondences message per camera image, header copied from the image (stamp exactly,
  frame_id = the camera's optical frame), map_frame_id = the map's frame;
- pixels in the image's pixel grid, (0, 0) = centre of the top-left pixel; K only is used (no
  undistortion yet): with a distorting lens, match on the rectified image;
- score in [0, 1], higher = surer.

    ros2 run <your_pkg> matcher_rclpy.py --ros-args -r __ns:=/cam0

Replace `match_frame` with your matcher.
"""
import rclpy
from rclpy.node import Node
from rclpy.qos import qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, PointCloud2
from rclpy.qos import QoSProfile, DurabilityPolicy, ReliabilityPolicy

from angle_i2p_msgs.msg import Correspondence, Correspondences


class Matcher(Node):
    def __init__(self):
        super().__init__("matcher")
        self.declare_parameter("map_frame_id", "map")
        self.map = None
        self.info = None
        # Relative names: `__ns:=/cam0` moves them beside the angle-i2p node of that camera.
        self.create_subscription(CameraInfo, "camera/camera_info", self.on_info, qos_profile_sensor_data)
        self.create_subscription(CompressedImage, "camera/image_raw/compressed", self.on_image, qos_profile_sensor_data)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL, reliability=ReliabilityPolicy.RELIABLE)
        self.create_subscription(PointCloud2, "map/points", self.on_map, latched)
        self.pub = self.create_publisher(Correspondences, "matcher/correspondences", 10)

    def on_map(self, msg):
        self.map = msg

    def on_info(self, msg):
        self.info = msg

    def on_image(self, image):
        if self.map is None or self.info is None:
            return
        out = Correspondences()
        out.header = image.header  # the contract: the image's stamp and frame, unchanged
        out.map_frame_id = self.get_parameter("map_frame_id").value
        for u, v, x, y, z, score in self.match_frame(image, self.info, self.map):
            out.correspondences.append(Correspondence(u=u, v=v, x=x, y=y, z=z, score=score))
        self.pub.publish(out)

    def match_frame(self, image, info, cloud):
        """Your matcher: [(u, v, x, y, z, score)] for this image against the map."""
        return []


def main():
    rclpy.init()
    rclpy.spin(Matcher())


if __name__ == "__main__":
    main()
