"""Optional 2D front ends: per-camera head and hand trackers whose labelled 2D tracks are lifted to 3D.

Nothing in the core engine imports this package. Modules:

* :mod:`~mocap.frontends.particles` - the shared, vectorised particle-filter core.
* :mod:`~mocap.frontends.head` - colour + shape head tracker with democratic-integration fusion (paper 003).
* :mod:`~mocap.frontends.hand` - per-fingertip arc particle filters, fingertips, palm (paper 000).
* :mod:`~mocap.frontends.postures` - Fourier-descriptor features and the Gaussian Bayes posture classifier.
* :mod:`~mocap.frontends.skin` - skin segmentation and the grey-scale check.
* :mod:`~mocap.frontends.render_head`, :mod:`~mocap.frontends.render_hand`, :mod:`~mocap.frontends.scenes` -
  rendered test videos with ground truth, rigs, writing colour takes.
* :mod:`~mocap.frontends.lift` - per-camera labelled 2D tracks -> 3D :class:`~mocap.trajectories.Trajectories`.
* :mod:`~mocap.frontends.video` - reading a colour take (videos or PNG folders per camera).
* :mod:`~mocap.frontends.head_cli`, :mod:`~mocap.frontends.hand_cli`, :mod:`~mocap.frontends.command` -
  ``mocap track-head`` / ``track-hand``.
"""
