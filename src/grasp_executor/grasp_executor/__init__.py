# SPDX-License-Identifier: Apache-2.0
"""Grasp executor: grasp poses in the camera frame -> safe robot motion (docs/interfaces.md, "Robots").

ROS-free core: ``geometry`` (Pose, quaternion <-> rotation vector), ``handeye``
(T_base_camera), ``planning`` (grasp plan), ``keypoints`` (key-point mode),
``safety`` (SafetyGate, GuardedBackend: every check in one place), ``executor``
(GraspExecutor: states, runs, faults), ``backends`` (dry_run, dvrk over a CRTK
transport seam, ur over ur_rtde), ``psm_sim`` (kinematic PSM model).
rclpy side: ``executor_node``, ``psm_sim_node`` and ``crtk_ros`` (the CRTK
transport). docs/executor.md describes the node, its parameters and the robots.
"""
