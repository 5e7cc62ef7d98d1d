# SPDX-License-Identifier: Apache-2.0
"""Reconstruction stage: stereo pairing, triangulation, shape graph optimiser (Algorithm 1), grasp pose.

The ROS-free entry point is :func:`reconstruct`; ``reconstruction_node`` is its
rclpy adapter (the only module here that imports rclpy).
"""

from suture_reconstruction.core import Reconstruction, ReconstructionParams, reconstruct
from suture_reconstruction.errors import (
    ArcAlongViewError,
    EndDisparityError,
    GraspNotSeenError,
    GraspRefusedError,
    ImagePairError,
    InvalidSequenceError,
    NoStereoOverlapError,
    ReconstructionError,
    ThreadBehindSurfaceError,
    ThreadTooShortError,
    TipNotReconstructedError,
    TooFewPointsError,
    UncertainGraspError,
    UnexplainedArcError,
)
from suture_reconstruction.pairing import DisparitySmoothing, PairingParams, SelectionCosts
from suture_reconstruction.photometric import PhotometricParams
from suture_reconstruction.shape_graph import ShapeGraphParams
from suture_reconstruction.uncertainty import GraspUncertainty

__all__ = [
    "ArcAlongViewError",
    "DisparitySmoothing",
    "EndDisparityError",
    "GraspNotSeenError",
    "GraspRefusedError",
    "GraspUncertainty",
    "ImagePairError",
    "InvalidSequenceError",
    "NoStereoOverlapError",
    "PairingParams",
    "PhotometricParams",
    "Reconstruction",
    "ReconstructionError",
    "ReconstructionParams",
    "SelectionCosts",
    "ShapeGraphParams",
    "ThreadBehindSurfaceError",
    "ThreadTooShortError",
    "TipNotReconstructedError",
    "TooFewPointsError",
    "UncertainGraspError",
    "UnexplainedArcError",
    "reconstruct",
]
