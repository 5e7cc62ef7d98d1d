# SPDX-License-Identifier: Apache-2.0
"""Exceptions of the reconstruction stage.

Every problem with the inputs raises a subclass of :class:`ReconstructionError`
(itself a ``ValueError``) whose text says what is wrong and what to do, so that
the node can drop the frame with one log line. Camera problems (not rectified,
zero baseline) raise :class:`suture_common.camera.CameraModelError` instead,
which is also a ``ValueError``.
"""

from __future__ import annotations


class ReconstructionError(ValueError):
    """The stereo pair cannot be reconstructed; the text names the reason."""


class InvalidSequenceError(ReconstructionError):
    """A sequence is not an (N, 2) array of finite pixels (wrong shape, NaN or inf)."""


class TooFewPointsError(ReconstructionError):
    """A sequence, or what is left of it after pairing, has too few points to reconstruct."""


class NoStereoOverlapError(ReconstructionError):
    """The left and right sequences share too few epipolar rows within the disparity limits."""


class ThreadTooShortError(ReconstructionError):
    """The reconstructed thread is shorter than the reserved grasp arc length."""


class TipNotReconstructedError(ReconstructionError):
    """The reconstructed thread does not start at the cut tip: the stretch next to the tip had no
    stereo support, so the arc length to the grasp point would be counted from a later point."""


class UnexplainedArcError(ReconstructionError):
    """A stretch of a view's seen sequence between the cut tip and the grasp point lies off the
    reconstructed thread's projection: thread that view saw there is missing from the 3D thread
    (or the views followed different branches), so the grasp point is misplaced along the thread."""


class ArcAlongViewError(ReconstructionError):
    """The 3D arc from the cut tip to the grasp point runs mostly along the viewing rays: it is
    many times longer than the stretch its image covers, so its length, which places the grasp
    point, rests on disparity alone (or on pairs of different thread points in the two views)."""


class ThreadBehindSurfaceError(ReconstructionError):
    """Where the thread runs along the image rows at the grasp point (its depth not measured by the
    pair but carried from elsewhere), the reconstruction puts it behind the textured surface beside
    it, whose depth the pair does measure: the carried depth, and the grasp point, are wrong."""


class EndDisparityError(ReconstructionError):
    """The thread crosses the image rows nowhere steeply, so its depth rests on its two ends' pairs,
    and the images put an end at another disparity than the masks' sequences do: the depth carried
    between the ends is wrong."""


class ImagePairError(ReconstructionError):
    """The stereo images given for the photometric refinement cannot be used (sizes differ from each
    other or from the camera, not (H, W) or (H, W, C))."""


class GraspRefusedError(ReconstructionError):
    """The thread was reconstructed but its grasp point is not trusted; ``uncertainty`` holds the
    :class:`~suture_reconstruction.uncertainty.GraspUncertainty` that says why (None where the
    thread ends under an instrument before the grasp point, which then has no estimate)."""

    def __init__(self, message: str, uncertainty: object) -> None:
        super().__init__(message)
        self.uncertainty = uncertainty


class GraspNotSeenError(GraspRefusedError):
    """The grasp point lies on a stretch of thread that a view does not see (hidden or bridged)."""


class UncertainGraspError(GraspRefusedError):
    """The grasp point's estimated uncertainty exceeds ``max_grasp_uncertainty_mm``."""
