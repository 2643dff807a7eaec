"""The calibration utility: intrinsics from boards, fundamental matrices, wand-wave rig calibration.

Modules, one job each:

* :mod:`calibration.boards` — board definitions (checkerboard, ChArUco) and corner detection;
* :mod:`calibration.intrinsics` — images or videos -> board views -> K and distortion per camera;
* :mod:`calibration.stereo` — a two-camera rig from stereo board images;
* :mod:`calibration.fundamental` — pairwise fundamental matrices (from a rig or from correspondences);
* :mod:`calibration.wand` — wand definition and finding the wand's markers among a frame's blobs;
* :mod:`calibration.takes` — reading calibration takes as blobs (the engine's take reader and detector);
* :mod:`calibration.initial` — pairwise essential matrices, view graph, first rig estimate;
* :mod:`calibration.bundle` — bundle adjustment of camera poses (and optionally focal, k1) and wand poses;
* :mod:`calibration.align` — rigid/similarity transforms, L-frame and floor alignment;
* :mod:`calibration.extrinsics` — the whole wand calibration, wand observations to a rig and a report;
* :mod:`calibration.quality` — plain-language quality gates;
* :mod:`calibration.report` — report (text / JSON) and coverage plot;
* :mod:`calibration.compare` — recovered vs true calibration, and reconstruction scores with each;
* :mod:`calibration.cli` — ``mocap calibrate ...``.

Arrows point one way: this package imports :mod:`mocap`; the engine never imports it.
"""
