# SPDX-License-Identifier: Apache-2.0
"""Segmentation stage: the suture U-Net, its training and export CLI (``suture-seg``), inference.

The ROS-free entry point is :class:`suture_segmentation.core.Segmenter` (and
:func:`suture_segmentation.core.segment_stereo` with the shipped weights);
``segmentation_node`` is its rclpy adapter. The package does not import torch on import:
import :mod:`suture_segmentation.core` for inference.
"""
