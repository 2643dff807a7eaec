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
        every: frames between the frames offered (searching only the tracker's predicted windows, the run offers
            its full-frame scans alone: a window can miss its marker); blind frames this far apart form one run.
    """

    def __init__(self, rig: Rig, every: int = 1) -> None:
        self.rig = rig
        self.every = every
        self._runs: list[list[list[int]]] = [[] for _ in range(len(rig))]  # per camera, [first, last] frames
        self._count = [0] * len(rig)  # per camera, blind frames

    def offer(self, frame_index: int, blob_counts: list[int], positions: np.ndarray, min_markers: int = 3) -> None:
        """One frame: each camera's number of blobs, and the markers reconstructed in it, (K, 3) m. A camera with no
        blob is blind in the frame where ``min_markers`` of them (all, if fewer) lie in its image: one or two
        markers at its edge may be hidden behind the body."""
        if len(positions) == 0:
            return
        need = min(min_markers, len(positions))
        for c, count in enumerate(blob_counts):
            if count == 0 and np.count_nonzero(self.rig[c].in_image(self.rig[c].project(positions))) >= need:
                runs = self._runs[c]  # (runs, not frames: a camera black for an hour keeps memory flat)
                if runs and frame_index - runs[-1][1] <= self.every:
                    runs[-1][1] = frame_index
                else:
                    runs.append([frame_index, frame_index])
                self._count[c] += 1

    def report(self, min_frames: int = 3) -> list[tuple[str, int, list[tuple[int, int]]]]:
        """``(camera name, blind frames, runs of consecutive frames as (first, last))`` for every camera blind in
        ``min_frames`` frames or more (a single undecodable frame is reported by the take reader)."""
        return [(name, n, [(a, b) for a, b in runs])
                for name, n, runs in zip(self.rig.names, self._count, self._runs, strict=True) if n >= min_frames]
