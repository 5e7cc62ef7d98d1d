# SPDX-License-Identifier: Apache-2.0
"""Bag replay and recording for the suture pipeline, without rosbag2.

``player_node`` publishes the input frames of a bag (recorded timing or as fast as the
graph keeps up) and reports the pipeline's latency; ``recorder_node`` records pipeline
outputs into an MCAP bag. :mod:`suture_replay.replay` is their ROS-free core.
"""
