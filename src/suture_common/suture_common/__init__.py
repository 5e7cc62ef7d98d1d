# SPDX-License-Identifier: Apache-2.0
"""Shared, ROS-free helpers of the suture grasping pipeline.

Modules: ``camera`` (rectified stereo model), ``grasp`` (grasp frame
convention), ``messages`` (message <-> numpy conversion), ``bag_io`` (MCAP
rosbag2 reading and writing). Nothing here imports rclpy, except the
``ros`` module, which nodes and node tests use.
"""
