"""Synthetic takes with ground truth: real or made-up marker motion, rendered through a camera rig.

Python API (the command is ``mocap synth``)::

    from mocap.synth import SynthSettings, ring_rig, marching_motion, motion_from_file, render_take, simulate

    rig = ring_rig(6, seed=1)
    truth = render_take("take1", rig, marching_motion(240, fps=120), SynthSettings(seed=1))

Modules: :mod:`~mocap.synth.rig` (camera ring), :mod:`~mocap.synth.motion` (C3D loading, up axis),
:mod:`~mocap.synth.body` (built-in marching person), :mod:`~mocap.synth.occlusion` (capsule body),
:mod:`~mocap.synth.render` (blob rasteriser and Cramer-Rao bound), :mod:`~mocap.synth.simulate`
(truth without pixels), :mod:`~mocap.synth.writer` (take folders), :mod:`~mocap.synth.cli`.
"""

from mocap.synth.body import marching_body, marching_motion
from mocap.synth.motion import Motion, as_motion, load_motion, motion_from_file
from mocap.synth.render import Sensor
from mocap.synth.rig import fit_ring_radius, rig_for_motion, ring_rig, walkway_rig
from mocap.synth.settings import SynthSettings
from mocap.synth.simulate import TakePlan, plan_take, render_frame, simulate
from mocap.synth.writer import default_truth_path, render_take

__all__ = [
    "Motion", "Sensor", "SynthSettings", "TakePlan", "as_motion", "default_truth_path", "fit_ring_radius",
    "load_motion", "marching_body", "marching_motion", "motion_from_file", "plan_take", "render_frame", "render_take",
    "rig_for_motion", "ring_rig", "simulate", "walkway_rig",
]
