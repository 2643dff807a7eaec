"""Evaluate and time the optional 2D front ends (head tracker, hand tracker) on rendered video.

Subcommands (default: all but ``train``):

* ``train``        render labelled hands (seed 1), fit the posture classifier, write mocap/frontends/postures.json.
* ``recognition``  per-posture recognition rate on held-out rendered hands (seed 2).
* ``head``         per-segment success rate (centre error < 20 % of head size) of fused / colour-only / shape-only
                   on the 128x96 head video, several seeds; 3D head error for a six-camera rendered take.
* ``hand``         fingertip accuracy (5 px), posture accuracy and recovery after a forced loss, six views;
                   3D fingertip error.
* ``speed``        frames/s per view, with a baseline measured in the same run (head: the per-frame feature
                   images; hand: skin mask + contour), and the machine.

All videos are rendered by :mod:`mocap.frontends.render_head` / :mod:`mocap.frontends.render_hand`: the truth is
exact, the images are synthetic. Run: ``python tools/bench_frontends.py [subcommand ...]``.
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import cv2  # noqa: E402
import numpy as np  # noqa: E402
from machine_info import describe  # noqa: E402  (tools/ is on sys.path when run as a script)

from mocap.frontends.hand import HandTracker, hand_contour, posture_features, track_hand  # noqa: E402
from mocap.frontends.head import CueMode, HeadConfig, HeadTracker, track_head  # noqa: E402
from mocap.frontends.lift import lift_tracks  # noqa: E402
from mocap.frontends.postures import DEFAULT_MODEL_PATH, FINGERS, POSTURES, PostureModel  # noqa: E402
from mocap.frontends.render_hand import hand_clip, posture_samples  # noqa: E402
from mocap.frontends.render_head import HEAD_SEGMENTS, head_clip, head_take  # noqa: E402
from mocap.frontends.scenes import hand_rig, head_rig  # noqa: E402
from mocap.frontends.skin import skin_mask  # noqa: E402

cv2.setNumThreads(1)


def _box(centre: np.ndarray, axes: np.ndarray) -> tuple[float, float, float, float]:
    return (centre[0] - axes[0], centre[1] - axes[1], 2 * axes[0], 2 * axes[1])


def train(per_class: int) -> None:
    images, labels = posture_samples(hand_rig(), per_class, seed=1)
    features, found = posture_features(images, 10)
    model = PostureModel.fit(features[found], list(np.asarray(labels)[found]), 10)
    model.save(DEFAULT_MODEL_PATH)
    print(f"trained on {found.sum()} rendered hands ({per_class} per posture, seed 1) -> {DEFAULT_MODEL_PATH}")


def recognition(per_class: int) -> None:
    model = PostureModel.load()
    images, labels = posture_samples(hand_rig(), per_class, seed=2)
    features, found = posture_features(images, model.harmonics)
    pred = np.array([model.classify(f)[0] if ok else "" for f, ok in zip(features, found, strict=True)])
    labels = np.asarray(labels)
    target = {"A": 100, "B": 100, "C": 99, "D": 93.5, "E": 92, "F": 98}
    print(f"posture recognition, held-out rendered hands (seed 2, {per_class} per posture, 6 roughly frontal views)")
    print("posture  rate %  paper %  confused with")
    for c in POSTURES:
        row = pred[labels == c]
        wrong = {str(p): int((row == p).sum()) for p in sorted(set(row) - {c})}
        print(f"   {c}     {100 * (row == c).mean():6.1f}  {target[c]:6.1f}   {wrong or ''}")


def head(seeds: int, segment_frames: int) -> None:
    rates = {m: [] for m in CueMode}
    for seed in range(seeds):
        clip = head_clip(segment_frames, seed=seed)
        for mode in CueMode:
            row = []
            for a, b in clip.segments.values():  # each segment on its own, from its true first box
                centre, _, _ = track_head(clip.frames[a:b], _box(clip.centre[a], clip.axes[a]), HeadConfig(mode=mode),
                                          seed=seed)
                row.append((np.linalg.norm(centre - clip.centre[a:b], axis=1) < 0.2 * clip.head_size[a:b]).mean())
            rates[mode].append(row)
    print(f"head tracking success rate % (centre error < 20 % of head size), 128x96, {seeds} seeds x "
          f"{len(HEAD_SEGMENTS)} segments of {segment_frames} frames, each tracked from its true first box: "
          "mean [min]")
    print("mode     " + "".join(f"{s:>14s}" for s in HEAD_SEGMENTS))
    for mode, r in rates.items():
        r = 100 * np.array(r)
        print(f"{mode.value:8s} " + "".join(f"{m:8.1f} [{lo:3.0f}]" for m, lo in zip(r.mean(0), r.min(0), strict=True)))
    r = 100 * np.array([rates[m] for m in CueMode])  # (mode, seed, segment)
    beats = (r[0] > r[1:].max(axis=0)).mean(axis=0)
    print("fused strictly above both single cues, % of seeds: "
          + ", ".join(f"{s} {100 * b:.0f}" for s, b in zip(HEAD_SEGMENTS, beats, strict=True)))
    rig = head_rig(6)
    for stripes in (0.25, 0.1):
        take = head_take(rig, 150, seed=0, stripes=stripes)
        tracks = np.stack([track_head(take.videos[c], _box(take.centre[c, 0], take.axes[c, 0]), seed=c)[0]
                           for c in range(len(rig))])
        err2 = np.linalg.norm(tracks - take.centre, axis=2)
        ok = 100 * (err2 < 0.4 * np.sqrt(take.axes.prod(axis=2))).mean(axis=1)
        traj = lift_tracks(rig, tracks[:, :, None], ["head"], take.fps, max_error_px=5.0)
        err = 1000 * np.linalg.norm(traj.positions[:, 0] - take.position, axis=1)
        print(f"six-camera head take, striped panel on the left {100 * stripes:.0f} % of each image (150 frames, "
              f"128x96, f = 180 px, 1.5 m):\n  2D success % per camera {np.round(ok).astype(int).tolist()}, "
              f"2D error median {np.median(err2):.2f} px; 3D error median {np.nanmedian(err):.1f} mm, "
              f"p90 {np.nanpercentile(err, 90):.1f} mm, max {np.nanmax(err):.1f} mm, "
              f"lifted {100 * traj.valid.mean():.0f} %")


def _tips_ok(tips: np.ndarray, truth: np.ndarray) -> np.ndarray:
    visible = np.isfinite(truth).all(axis=-1)
    return np.where(visible, np.linalg.norm(tips - truth, axis=-1) < 5.0, True).all(axis=-1)


def hand(seed: int) -> None:
    rig = hand_rig(6)
    blank = (150, 154)
    clip = hand_clip(rig, "FBCEDAFCB", hold=30, seed=seed, blank=blank)
    scored = np.isfinite(clip.tips[0]).all(axis=-1).any(axis=-1)
    stable = (clip.posture != "") & ~np.isin(np.arange(len(clip.posture)), np.arange(*blank))
    print(f"hand take: {len(rig)} views, 320x240, {len(clip.posture)} frames, postures FBCEDAFCB (30 frames each, "
          f"6-frame transitions), hand removed in frames {blank[0]}..{blank[1] - 1} (forced loss)")
    print("view  tips<5px % (frames with a visible tip; all visible tips right)  tip samples<5px %  "
          "posture % (stable)  recovery (frames)")
    tracks = []
    for c in range(len(rig)):
        tips, palm, posture = track_hand(clip.videos[c], seed=c)
        tracks.append(np.concatenate([tips, palm[:, None]], axis=1))
        ok = _tips_ok(tips, clip.tips[c])
        vis = np.isfinite(clip.tips[c]).all(axis=-1)
        samples = (np.linalg.norm(tips - clip.tips[c], axis=-1)[vis] < 5).mean()
        back = np.flatnonzero(ok[blank[1]:] & np.isfinite(tips[blank[1]:]).any(axis=(1, 2)))
        recovery = int(back[0]) if len(back) else -1
        print(f"cam{c + 1}  {100 * ok[scored].mean():10.1f}{'':52s}{100 * samples:8.1f}{'':10s}"
              f"{100 * (posture[stable] == clip.posture[stable]).mean():8.1f}{recovery:14d}")
    traj = lift_tracks(rig, np.stack(tracks), [*FINGERS, "palm"], clip.fps, max_error_px=4.0)
    err = 1000 * np.linalg.norm(traj.positions[:, :5] - clip.tips_world, axis=2)
    vis = np.isfinite(clip.tips_world).all(axis=-1)
    e = err[vis]
    per_finger = ", ".join(f"{f} {np.nanmedian(err[:, i][vis[:, i]]):.2f}" for i, f in enumerate(FINGERS))
    print(f"3D fingertips ({vis.sum()} truth samples): lifted {100 * np.isfinite(e).mean():.1f} %, error median "
          f"{np.nanmedian(e):.2f} mm, RMS {np.sqrt(np.nanmean(e**2)):.2f} mm, p95 {np.nanpercentile(e, 95):.2f} mm; "
          f"per finger median {per_finger}")


def _rate(fn, frames: np.ndarray, repeat: int = 3) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn(frames)
        best = min(best, time.perf_counter() - t0)
    return len(frames) / best


def speed() -> None:
    print(f"machine: {describe()} (OpenCV and BLAS limited to 1 thread)")
    clip = head_clip(60, seed=0)
    box = _box(clip.centre[0], clip.axes[0])
    probe = HeadTracker(clip.frames[0], box)

    def head_baseline(frames: np.ndarray) -> None:
        for f in frames:
            probe._features(f)

    def head_run(frames: np.ndarray) -> None:
        tracker = HeadTracker(frames[0], box, HeadConfig(particles=200), np.random.default_rng(0))
        for f in frames:
            tracker.update(f)

    base, run = _rate(head_baseline, clip.frames), _rate(head_run, clip.frames)
    print(f"head 128x96, 200 particles, fused: {run:7.0f} frames/s (target >= 300); baseline (feature images only) "
          f"{base:7.0f} frames/s; ratio {base / run:.1f}x")
    hclip = hand_clip(hand_rig(1), "FBCEDA", hold=30, seed=0)
    frames = hclip.videos[0]
    model = PostureModel.load()

    def hand_baseline(frames: np.ndarray) -> None:
        for f in frames:
            hand_contour(skin_mask(f), 300.0)

    def hand_run(frames: np.ndarray) -> None:
        tracker = HandTracker(model, rng=np.random.default_rng(0))
        for f in frames:
            tracker.update(f)

    base, run = _rate(hand_baseline, frames), _rate(hand_run, frames)
    print(f"hand 320x240, 40 particles per fingertip, postures FBCEDA: {run:7.0f} frames/s per view (target >= 200); "
          f"baseline (skin mask + contour only) {base:7.0f} frames/s; ratio {base / run:.1f}x")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", nargs="*", default=["recognition", "head", "hand", "speed"],
                        choices=["train", "recognition", "head", "hand", "speed"])
    parser.add_argument("--per-class", type=int, default=300, help="rendered hands per posture (train: 300)")
    parser.add_argument("--seeds", type=int, default=5, help="head videos (seeds) to average")
    parser.add_argument("--segment-frames", type=int, default=60, help="frames per head-video segment")
    args = parser.parse_args()
    for what in args.what:
        t0 = time.perf_counter()
        if what == "train":
            train(args.per_class)
        elif what == "recognition":
            recognition(args.per_class)
        elif what == "head":
            head(args.seeds, args.segment_frames)
        elif what == "hand":
            hand(seed=0)
        else:
            speed()
        print(f"({what}: {time.perf_counter() - t0:.0f} s)\n")


if __name__ == "__main__":
    main()
