"""Cameras that saw nothing where the markers were in their view.

A camera whose image holds no blob in a frame while the calibration puts reconstructed markers inside its image
was blind there: a covered lens, a loose cable, an exposure too short, a light switched off, or a camera that was
moved. The tracker carries on with the other cameras (a documented degradation), so nothing else would tell the
user; :class:`BlindCameras` collects those frames per camera for one warning at the end of the run.
"""

from __future__ import annotations

import numpy as np

from mocap.camera import Rig

__all__ = ["BlindCameras"]


class BlindCameras:
    """Per camera, the frames in which it had no blob although reconstructed markers lay in its calibrated view.

    Args:
        rig: the calibrated cameras (rig order, as the detections).
    """

    def __init__(self, rig: Rig) -> None:
        self.rig = rig
        self._frames: list[list[int]] = [[] for _ in range(len(rig))]

    def offer(self, frame_index: int, blob_counts: list[int], positions: np.ndarray, min_markers: int = 3) -> None:
        """One frame: each camera's number of blobs, and the markers reconstructed in it, (K, 3) m. A camera with no
        blob is blind in the frame where ``min_markers`` of them (all, if fewer) lie in its image: one or two
        markers at its edge may be hidden behind the body."""
        if len(positions) == 0:
            return
        need = min(min_markers, len(positions))
        for c, count in enumerate(blob_counts):
            if count == 0 and np.count_nonzero(self.rig[c].in_image(self.rig[c].project(positions))) >= need:
                self._frames[c].append(frame_index)

    def report(self, min_frames: int = 3) -> list[tuple[str, int, list[tuple[int, int]]]]:
        """``(camera name, blind frames, runs of consecutive frames as (first, last))`` for every camera blind in
        ``min_frames`` frames or more (a single undecodable frame is reported by the take reader)."""
        out = []
        for name, frames in zip(self.rig.names, self._frames, strict=True):
            if len(frames) < min_frames:
                continue
            f = np.asarray(frames)
            breaks = np.flatnonzero(np.diff(f) > 1)
            firsts, lasts = np.r_[f[0], f[breaks + 1]], np.r_[f[breaks], f[-1]]
            out.append((name, len(frames), list(zip(firsts.tolist(), lasts.tolist(), strict=True))))
        return out
