# SPDX-License-Identifier: Apache-2.0
"""The published sequence of one view: the visible centreline with the stretches the search
bridged across gaps put back and flagged as not seen.

The published sequence is (N, 3) float64: u, v and the *not-seen flag*, 1.0 for a point
interpolated across a gap in the mask (e.g. under an instrument shaft), 0.0 for a point seen in
the mask (docs/interfaces.md). ordering_node publishes it as the PolygonStamped's x, y, z.
"""

from __future__ import annotations

import numpy as np


def flagged_runs(flags: np.ndarray) -> list[tuple[int, int]]:
    """(start, stop) index pairs of the runs of True in the (K,) bool ``flags``, in order."""
    edges = np.diff(np.concatenate(([0], np.asarray(flags, dtype=np.int8), [0])))
    return list(zip(np.flatnonzero(edges == 1).tolist(), np.flatnonzero(edges == -1).tolist(), strict=True))


def flagged_sequence(
    sequence: np.ndarray, points: np.ndarray, bridged: np.ndarray, mask: np.ndarray | None = None
) -> np.ndarray:
    """(N', 3) ``sequence`` with the bridged stretches of ``points`` put back, flagged 1.0.

    ``sequence`` (N, 2): the visible points of a search, possibly extended or spliced by the
    other view (:mod:`suture_ordering.stereo_fill`), which keeps the search's own points
    exactly. ``points`` (M, 2) and ``bridged`` (M,) bool: the search's ordered points and which
    of them were interpolated across a gap. A bridged stretch goes back between the points
    before and after it where those two still follow each other in ``sequence``; elsewhere
    (a stretch the other view replaced) it is left out. ``mask`` (H, W), optional: the mask the
    search read; the ends of a bridged stretch that still lie on it (the bridge leaves from the
    last point the search reached, before the mask's edge) go back as seen.
    """
    sequence = np.asarray(sequence, dtype=np.float64).reshape(-1, 2)
    flagged = np.column_stack([sequence, np.zeros(len(sequence))])
    bridged = np.asarray(bridged, dtype=bool)
    if not bridged.any() or len(sequence) < 2:
        return flagged
    not_seen = bridged.astype(np.float64)
    pieces, taken = [], 0
    for start, stop in flagged_runs(bridged):  # one per gap: few
        if stop >= len(points):
            continue
        if start == 0:  # a cut end the mask lost, in front of the first point seen
            if taken == 0 and np.all(sequence[0] == points[stop]):
                flags = np.ones(stop) if mask is None else _off_mask_between_ends(points[:stop], mask)
                pieces.append(np.column_stack([points[:stop], flags]))
            continue
        before, after = points[start - 1], points[stop]
        at = np.flatnonzero(
            np.all(sequence[taken:-1] == before, axis=1) & np.all(sequence[taken + 1 :] == after, axis=1)
        )
        if at.size == 0:
            continue
        cut = taken + int(at[0]) + 1
        pieces.append(flagged[taken:cut])
        if mask is not None:
            not_seen[start:stop] = _off_mask_between_ends(points[start:stop], mask)
        pieces.append(np.column_stack([points[start:stop], not_seen[start:stop]]))
        taken = cut
    pieces.append(flagged[taken:])
    return np.vstack(pieces)


def _off_mask_between_ends(stretch: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(K,) float 1.0 for the points of a bridged ``stretch`` (K, 2) from the first to the last
    that lies off ``mask`` (no mask pixel within 1 px), 0.0 for the points on the mask before and
    after them. A point on the mask in the middle of the stretch (another strand crossing the
    gap) stays not seen."""
    height, width = mask.shape
    u = np.clip(np.rint(stretch[:, 0]).astype(int), 0, width - 1)
    v = np.clip(np.rint(stretch[:, 1]).astype(int), 0, height - 1)
    on_mask = np.zeros(len(stretch), dtype=bool)
    for du in (-1, 0, 1):
        for dv in (-1, 0, 1):
            on_mask |= mask[np.clip(v + dv, 0, height - 1), np.clip(u + du, 0, width - 1)] > 0
    off = np.flatnonzero(~on_mask)
    flags = np.zeros(len(stretch))
    if off.size:
        flags[off[0] : off[-1] + 1] = 1.0
    return flags


def seen_in_low_mask(sequence: np.ndarray, low_mask: np.ndarray) -> np.ndarray:
    """(N, 3) published ``sequence`` with its not-seen stretches re-read on ``low_mask`` (H, W):
    in each stretch, only the points from the first to the last that lie off the low mask stay
    flagged (:func:`_off_mask_between_ends`); a stretch the low mask covers throughout is seen."""
    flagged = np.array(sequence, dtype=np.float64)
    not_seen = flagged[:, 2] > 0.5
    if not not_seen.any():
        return flagged
    low_mask = np.asarray(low_mask)
    for start, stop in flagged_runs(not_seen):
        flagged[start:stop, 2] = _off_mask_between_ends(flagged[start:stop, :2], low_mask)
    return flagged
