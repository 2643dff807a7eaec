"""The whole job: a take (images or 2D centroids) or an MCAP log in, labelled trajectories out.

Frame by frame: read every camera's frame -> detect blobs (full frame, or only the tracker's
predicted windows between periodic full scans; merged blobs split at the tracker's predicted
positions) -> :class:`mocap.tracker.Tracker` -> live MCAP log. At the end: C3D / TRC / CSV.
Memory stays flat apart from the output arrays.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import threading
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from mocap import __version__, kernels
from mocap.atomic import check_output_path
from mocap.blind import BlindCameras
from mocap.camera import Rig, rig_to_toml
from mocap.detect import StreamDetector
from mocap.detections import Detections
from mocap.errors import MocapError
from mocap.fitcheck import FitMonitor, FitReport
from mocap.relabel import RelabelConfig, RelabelStats, repair_identities
from mocap.tracker import Tracker, TrackerConfig
from mocap.trajectories import Trajectories, UnconfirmedPoints

__all__ = ["ReconstructOptions", "reconstruct", "write_outputs"]

log = logging.getLogger(__name__)

FIT_CHECK_FRAMES = 10  # frames holding detections per window of the calibration-fit check ...
FIT_CHECK_SPACING_S = 1.0  # ... whose windows start this far apart (a camera is named if poor in all)
COMPILE_NOTICE_S = 3.0  # with numba, a first frame slower than this, s, is said to be compiling the kernels


@dataclass
class ReconstructOptions:
    """How to run a reconstruction.

    Attributes:
        fps: frame rate override, Hz (else take.toml, else the videos).
        start: first frame to process.
        stop: frame to stop before (None: to the end).
        roi_scan_every: 0 scans every full frame; N > 0 searches only the tracker's predicted
            windows and scans the full frame every N frames (new markers wait at most N frames).
        progress: show a progress bar on a terminal.
        tracker: tracker settings.
        relabel: run the offline identity repair (:mod:`mocap.relabel`) on the finished take;
            the live MCAP log holds the tracker's online identities.
    """

    fps: float | None = None
    start: int = 0
    stop: int | None = None
    roi_scan_every: int = 0
    progress: bool = True
    tracker: TrackerConfig | None = None
    relabel: bool = True

    def __post_init__(self) -> None:
        if self.roi_scan_every < 0:
            raise MocapError(f"--roi-scan-every {self.roi_scan_every}: give 0 (scan every full frame) or a positive "
                             "number of frames between full-frame scans")


def _open_source(path: Path, fps: float | None) -> tuple[Any, str]:
    """Open a take folder or an MCAP log; returns the source and its kind ("images"/"centroids")."""
    if path.name.lower().endswith((".mcap", ".mcap.partial")):  # a run's log, or what a crashed run left
        from mocap.export.mcap import read_mcap_take

        return read_mcap_take(path), "centroids"
    from mocap.take import open_take

    take = open_take(path, fps=fps)
    return take, take.kind


@contextlib.contextmanager
def _opencv_threads(n: int) -> Iterator[None]:
    """Run the block with OpenCV's own thread pool set to ``n`` threads, then restore it."""
    before = cv2.getNumThreads()
    cv2.setNumThreads(n)
    try:
        yield
    finally:
        cv2.setNumThreads(before)


def _scan_every(opts: ReconstructOptions, kind: str) -> int:
    """Frames from one full-frame scan to the next (1: every frame; only images are searched in windows): frame f is
    scanned in full where (f - ``opts.start``) is a multiple of it."""
    return max(opts.roi_scan_every, 1) if kind == "images" else 1


def _detection_frames(source: Any, kind: str, tracker: Tracker, opts: ReconstructOptions
                      ) -> Iterator[tuple[int, list[Detections]]]:
    """Yield ``(frame_index, detections per camera)``, detecting blobs in images when needed."""
    if kind == "centroids":
        yield from source.centroids(opts.start, opts.stop)
        return
    every = _scan_every(opts, kind)
    detectors = [StreamDetector() for _ in source.rig]
    for frame_index, images in source.images(opts.start, opts.stop):
        rois = None if (frame_index - opts.start) % every == 0 else tracker.predicted_rois()
        seeds = tracker.predicted_centres()
        dets = []
        for c, image in enumerate(images):
            if image is None:  # undecodable frame: the take reader has logged it
                dets.append(Detections.empty())
            else:
                dets.append(detectors[c](image, rois=None if rois is None else rois[c], seeds=seeds[c]))
        yield frame_index, dets


@contextlib.contextmanager
def _compile_notice() -> Iterator[threading.Timer | None]:
    """A timer that logs, unless cancelled within ``COMPILE_NOTICE_S``, that the numba kernels are compiling: the
    first run after installing mocap pauses ~25 s on the first frame, later runs load the kernels from numba's
    on-disk cache in ~0.3 s. Only numba knows, when it compiles, whether its cache holds a kernel, so the pause
    itself is the sign."""
    if not kernels.HAVE_NUMBA:
        yield None
        return
    timer = threading.Timer(COMPILE_NOTICE_S, log.info, args=(
        "compiling the numba kernels (the first run after installing mocap: about 25 s; later runs load them "
        "from the cache) ...",))
    timer.daemon = True
    timer.start()
    try:
        yield timer
    finally:
        timer.cancel()


def _report_calibration_fit(rig: Rig, verdict: tuple[FitReport, list[str]], where: Path) -> None:
    """Warn about the cameras :class:`mocap.fitcheck.FitMonitor` named (support shown from its first window)."""
    report, poor = verdict
    if int(report.blobs.sum()) == 0:
        return
    if poor:
        pct = ", ".join(f"{n} {100 * s:.0f} %" for n, s in zip(rig.names, report.support, strict=True)
                        if n in poor)
        log.warning(
            "%s: the calibration does not seem to fit the images: few blobs of camera(s) %s have a partner on "
            "their epipolar line in another camera (%s in the first %d frames, tolerance %.0f px; as few in "
            "windows of frames %.0f s apart). Check that calibration.toml belongs to this take, that camera names "
            "match their recordings, and that no camera moved since calibration; re-run 'mocap calibrate' if in "
            "doubt.", where, ", ".join(poor), pct, FIT_CHECK_FRAMES, report.tolerance_px, FIT_CHECK_SPACING_S,
        )
    else:
        log.debug("calibration fit: epipolar support per camera %s", np.round(report.support, 3))


def _report_blind_cameras(blind: BlindCameras, where: Path) -> None:
    """Warn about the cameras that saw no blob in frames where the calibration put reconstructed markers in view."""
    judged = "frames" if blind.every == 1 else f"full-frame scans (one every {blind.every} frames)"
    for name, n, runs in blind.report():
        spans = ", ".join(f"{a}-{b}" if b > a else f"{a}" for a, b in runs[:3]) + (", ..." if len(runs) > 3 else "")
        log.warning("%s: camera %s saw no blob in %d %s (%s) although the calibration puts reconstructed markers "
                    "in its view there; those markers come from the other cameras alone. Check that camera's lens, "
                    "cable, exposure and lighting, and that it was not moved.", where, name, n, judged, spans)


def reconstruct(take: str | os.PathLike, options: ReconstructOptions | None = None,
                mcap: str | os.PathLike | None = None) -> Trajectories:
    """Reconstruct labelled 3D trajectories from a take folder or an MCAP log.

    Args:
        take: a take folder (DESIGN.md) or an ``.mcap`` written by an earlier run (re-runs the 3D
            stage from its logged 2D centroids).
        options: run settings (:class:`ReconstructOptions`).
        mcap: if given, log cameras, 2D centroids and 3D markers to this MCAP file while running.

    Returns:
        :class:`Trajectories`: (frames, identities, 3) metres in the calibration's world frame.
    """
    opts = options or ReconstructOptions()
    path = Path(take)
    source, kind = _open_source(path, opts.fps)
    rig: Rig = source.rig
    fps = float(opts.fps or source.fps)
    stop = source.n_frames if opts.stop is None else min(opts.stop, source.n_frames)
    if not 0 <= opts.start < stop:
        raise MocapError(f"{path}: frame range {opts.start}:{stop} is empty; the take has {source.n_frames} frames")
    tracker = Tracker(rig, fps, opts.tracker)
    logger = _open_mcap_logger(mcap, rig, fps, path) if mcap is not None else contextlib.nullcontext()
    fit = FitMonitor(rig, FIT_CHECK_FRAMES, spacing=max(1, int(round(FIT_CHECK_SPACING_S * fps))))
    scan_every = _scan_every(opts, kind)
    blind = BlindCameras(rig, every=scan_every)
    # OpenCV and BLAS on one thread while streaming: detection's OpenCV calls are small (a dilation, labelling of
    # small images) and a second OpenCV thread mostly waits for a core that the take reader's decoders hold
    # (labelling 0.08 ms per call on one thread, 0.3-3 ms on two on the shared 2-core machine); the tracker's
    # matrix products are small too (the tracking benchmark with one core busy elsewhere: 1,162 frames/s with one
    # BLAS thread, 1,015 with two).
    # The logger closes the MCAP on success; on failure it keeps a readable <name>.partial.
    with logger, _opencv_threads(1), threadpool_limits(1, user_api="blas"), _compile_notice() as notice:
        frames = _detection_frames(source, kind, tracker, replace(opts, stop=stop))
        bar = tqdm(frames, total=stop - opts.start, unit="frame", desc="reconstruct",
                   disable=None if opts.progress else True, leave=False)
        blobs = 0  # detections over the whole run, all cameras
        for frame_index, dets in bar:
            counts = [len(d) for d in dets]
            blobs += sum(counts)
            verdict = fit.offer(frame_index, dets)
            if verdict is not None:
                _report_calibration_fit(rig, verdict, path)
            result = tracker.step(frame_index, dets)
            if (frame_index - opts.start) % scan_every == 0:  # (a window that missed its marker is not blind)
                blind.offer(frame_index, counts, result.positions)
            if notice is not None:
                notice.cancel()  # (the first frame is done)
            if mcap is not None:
                logger.log_frame(frame_index, dets, result.ids, result.positions, result.residuals_mm,
                                 result.camera_masks)
        verdict = fit.finish()
        if verdict is not None:
            _report_calibration_fit(rig, verdict, path)
    _report_blind_cameras(blind, path)
    traj = tracker.finish()
    confirm = (opts.tracker or TrackerConfig()).confirm_frames
    if traj.n_frames < confirm:
        log.info("%s: %d frames, fewer than the %d a new marker needs for an identity: the markers seen in every "
                 "frame get identities (two-view points that stand still do not)", path, traj.n_frames, confirm)
    if opts.relabel:
        before = traj.n_markers
        log.info("identity repair: %d identities over %d frames ...", before, traj.n_frames)
        stats = _repair_or_keep(traj, confirm, tracker.unconfirmed(), path)
        if stats is not None:
            _report_repair(stats, before, traj.n_markers, confirm)
    withheld = tracker.withheld().apply(traj)
    rewritten = tracker.rewritten().apply(traj)
    if rewritten:
        log.info("partly hidden markers: %d points written without a view that held under %.0f %% of the marker's "
                 "light there", rewritten, 100 * (opts.tracker or TrackerConfig()).dim_light)
    if withheld:
        log.info("partly hidden markers: %d samples withheld (points leaning on a blob that held less light than the "
                 "marker's: two-view points off their predictions, markers re-acquired from such blobs)", withheld)
    traj.camera_names = rig.names
    traj.metadata.update({"source": str(path), "software": f"mocap {__version__}", "cameras": len(rig)})
    if traj.n_markers == 0 and blobs == 0:
        log.warning("%s: no markers were reconstructed: no camera saw a blob in %d frames. Check that the markers "
                    "show as small bright spots on a darker background (exposure, lighting, strobes; a blank or "
                    "saturated image has none)", path, traj.n_frames)
    elif traj.n_markers == 0:
        log.warning("%s: no markers were reconstructed from %.1f blobs per camera and frame: no blob was matched "
                    "in two cameras or more long enough to confirm a marker (%d frames running). Check that the "
                    "markers are seen by two cameras at least, that calibration.toml belongs to this take, and that "
                    "the blobs are markers, not noise or reflections", path,
                    blobs / (len(rig) * max(traj.n_frames, 1)), confirm)
    return traj


def _report_repair(stats: RelabelStats, before: int, after: int, confirm: int) -> None:
    """Log what the identity repair did (``before`` -> ``after`` identities)."""
    log.info("identity repair: %d duplicate samples dropped; %d swaps undone; %d identities -> %d (fragments "
             "re-linked, tracks cut where they jumped; %d joined by the shapes of rigid clusters); %d exchanges "
             "undone where markers passed close; %d bursts of hops unscrambled; %d samples labelled by rigid "
             "plates' shapes; %d fragments joined by their distances to rigid neighbours, %d samples moved to the "
             "identity whose neighbours they fit; %d unconfirmed points joined identities' paths; %d gaps "
             "bridged by where the neighbours carry a marker; %d exchanges undone where two markers came back "
             "from a shared gap; %d junctions of three or more identities undone; %d exchanges undone in "
             "skin-mounted clusters; %d samples that hopped off their identity's path given to the identity whose "
             "path they lie on or continue, %d withheld; %d pairs of identities of "
             "one marker that took turns or followed each other merged; %d identities that ended joined to "
             "their marker's return by its rigid neighbours; %d scattered identities (no %d frames running) "
             "withdrawn",
             stats.duplicates, stats.swaps, before, after, stats.reunited, stats.exchanges,
             stats.unscrambled, stats.plate_samples, stats.rejoined, stats.anchor_moves, stats.filled,
             stats.bridged, stats.gap_exchanges, stats.junctions, stats.skin_exchanges, stats.hops_given,
             stats.off_path, stats.merged, stats.orphans, stats.withdrawn, confirm)


def _repair_or_keep(traj: Trajectories, confirm: int, unconfirmed: UnconfirmedPoints, path: Path
                    ) -> RelabelStats | None:
    """The offline identity repair of ``traj``, in place; where a pass of it fails (a fault of this software, not of
    the take), the trajectories are kept as that pass left them, with an error logged, instead of the whole run
    lost: every pass only moves or withholds whole samples, so they are a valid result, with the tracker's
    identities where the repair had not yet reached. Returns the repair's figures, or None where it failed."""
    try:
        return repair_identities(traj, RelabelConfig(confirm_frames=confirm), unconfirmed=unconfirmed)
    except MocapError:
        raise
    except Exception as err:  # noqa: BLE001 (any fault of a pass: the take's trajectories are kept)
        log.error("%s: the identity repair failed (%s: %s), a fault of this software: the outputs keep the identities "
                  "as they stood then (some markers may change identity after gaps; --no-relabel gives the tracker's "
                  "own). Please report it with the run's --mcap log, which reproduces it", path, type(err).__name__,
                  err)
        log.debug("identity repair failure", exc_info=True)
        traj.drop_empty()  # (columns a join emptied)
        return None


def _open_mcap_logger(mcap: str | os.PathLike, rig: Rig, fps: float, take: Path) -> Any:
    from mocap.export.mcap import McapLogger

    return McapLogger(Path(mcap), rig, fps, rig_to_toml(rig),
                      {"take": str(take), "fps": str(fps), "software": f"mocap {__version__}"})


def write_outputs(traj: Trajectories, c3d: str | None = None, trc: str | None = None,
                  csv: str | None = None) -> list[Path]:
    """Write the requested trajectory files (each atomically); returns the paths written."""
    written = []
    if c3d:
        from mocap.export.c3d import write_c3d

        write_c3d(traj, c3d)
        written.append(Path(c3d))
    if trc:
        from mocap.export.trc import write_trc

        write_trc(traj, trc)
        written.append(Path(trc))
    if csv:
        from mocap.export.csv import write_csv

        write_csv(traj, csv)
        written.append(Path(csv))
    return written


# ------------------------------------------------------------------------ CLI
def configure_parser(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("take", help="take folder (calibration.toml + one recording per camera) or a run's .mcap")
    parser.add_argument("--c3d", required=True, metavar="OUT.c3d", help="labelled trajectories, mm")
    parser.add_argument("--mcap", metavar="OUT.mcap", help="Foxglove-ready log of cameras, 2D centroids, 3D markers")
    parser.add_argument("--trc", metavar="OUT.trc", help="OpenSim TRC trajectories")
    parser.add_argument("--csv", metavar="OUT.csv", help="Motive-style CSV trajectories")
    parser.add_argument("--fps", type=float, help="frame rate, Hz, when neither take.toml nor the videos say")
    parser.add_argument("--start", type=int, default=0, help="first frame to process (default 0)")
    parser.add_argument("--stop", type=int, help="frame to stop before (default: the end)")
    parser.add_argument("--roi-scan-every", type=int, default=0, metavar="N",
                        help="search only predicted windows, with a full-frame scan every N frames (0: always scan; "
                             "it ignores blobs outside the windows between scans, and saves no time)")
    parser.add_argument("--no-relabel", action="store_true",
                        help="keep the tracker's online identities (skip the offline swap repair and re-linking)")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")


def run(args: argparse.Namespace) -> int:
    outputs = [p for p in (args.c3d, args.mcap, args.trc, args.csv) if p]
    for out in outputs:
        check_output_path(out)
    if args.mcap and Path(args.mcap).resolve() == Path(args.take).resolve():
        raise MocapError(f"{args.mcap}: the output MCAP would overwrite the input log; choose another name")
    opts = ReconstructOptions(fps=args.fps, start=args.start, stop=args.stop, roi_scan_every=args.roi_scan_every,
                              progress=not args.no_progress, relabel=not args.no_relabel)
    traj = reconstruct(args.take, opts, mcap=args.mcap)
    written = write_outputs(traj, c3d=args.c3d, trc=args.trc, csv=args.csv)
    if args.mcap:
        written.append(Path(args.mcap))
    gaps = 100.0 * (1.0 - traj.valid.mean()) if traj.n_markers else 0.0
    print(f"{traj.n_markers} markers, {traj.n_frames} frames at {traj.fps:g} Hz ({gaps:.1f} % gaps) -> "
          + ", ".join(map(str, written)))
    return 0
