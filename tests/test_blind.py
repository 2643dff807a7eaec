"""Cameras blind where the calibration puts reconstructed markers in their view are reported, with their frames."""

from __future__ import annotations

import numpy as np

from mocap.blind import BlindCameras
from tests.conftest import ring_rig


def test_blind_frames_are_reported_in_runs_and_markers_out_of_view_do_not_count():
    rig = ring_rig(3)
    rng = np.random.default_rng(4)
    blind = BlindCameras(rig)
    for frame in range(40):
        markers = rng.uniform([-0.3, -0.3, 0.8], [0.3, 0.3, 1.4], (10, 3))  # (in every camera's view)
        counts = [10, 0 if (5 <= frame < 9 or 20 <= frame < 30) else 10, 10]
        if frame == 30:
            counts[2] = 0  # (one frame: the take reader's business)
        blind.offer(frame, counts, markers)
        blind.offer(100 + frame, [0, 0, 0], markers + [0.0, 0.0, 50.0])  # (far above: in no camera's view)
        far = np.concatenate([markers[:2], markers[2:] + [0.0, 0.0, 50.0]])  # (two in view: may be hidden by the body)
        blind.offer(200 + frame, [0, 0, 0], far)
    assert blind.report() == [("cam2", 14, [(5, 8), (20, 29)])]
    assert [r[0] for r in blind.report(min_frames=1)] == ["cam2", "cam3"]
