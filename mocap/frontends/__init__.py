"""Optional 2D front ends: per-camera head and hand trackers whose labelled 2D tracks are lifted to 3D.

Nothing in the core engine imports this package. Modules:

* :mod:`~mocap.frontends.particles` - the shared, vectorised particle-filter core.
* :mod:`~mocap.frontends.head` - colour + shape head tracker with democratic-integration fusion (paper 003).
* :mod:`~mocap.frontends.hand` - posture recognition and per-fingertip arc particle filters (paper 000).
* :mod:`~mocap.frontends.scenes` - rendered test videos with ground truth.
* :mod:`~mocap.frontends.lift` - per-camera labelled 2D tracks -> 3D :class:`~mocap.trajectories.Trajectories`.
* :mod:`~mocap.frontends.video` - reading a colour take (videos or PNG folders per camera).
* :mod:`~mocap.frontends.head_cli`, :mod:`~mocap.frontends.hand_cli` - ``mocap track-head`` / ``track-hand``.
"""
