# SPDX-License-Identifier: Apache-2.0
"""Stereo suture simulator with exact ground truth (ROS-free core and the `suture-sim` CLI)."""
