"""Centroid files: CSV and NPZ round trips, chunked streaming, and the errors users see."""

from __future__ import annotations

import logging

import numpy as np
import pytest

import mocap.centroids as centroids
from mocap.centroids import open_centroids, write_centroids
from mocap.detections import Detections
from mocap.errors import MocapError


def random_frames(rng: np.random.Generator, n_frames: int, skip: frozenset[int] = frozenset()
                  ) -> list[tuple[int, Detections]]:
    frames = []
    for k in range(n_frames):
        if k in skip:
            continue
        n = int(rng.integers(0, 5))
        a = rng.normal(size=(n, 2, 2)) * 0.01
        frames.append((k, Detections(rng.uniform(0, 1024, (n, 2)), rng.uniform(1, 80, n), rng.uniform(0.3, 1, n),
                                     a @ a.transpose(0, 2, 1), rng.random(n) < 0.3)))
    return frames


@pytest.mark.parametrize("suffix", [".centroids.csv", ".centroids.npz"])
def test_round_trip(tmp_path, suffix):
    rng = np.random.default_rng(1)
    frames = random_frames(rng, 30, skip={0, 7, 8})
    path = tmp_path / f"cam1{suffix}"
    written = write_centroids(path, frames, n_frames=33)
    assert written == sum(len(d) for _, d in frames)
    f = open_centroids(path)
    assert f.n_frames == 33
    got = list(f.frames())
    assert len(got) == 33
    by_frame = dict(frames)
    for k, det in enumerate(got):
        want = by_frame.get(k, Detections.empty())
        assert len(det) == len(want)
        np.testing.assert_allclose(det.xy, want.xy, atol=1e-6)
        np.testing.assert_allclose(det.area, want.area, atol=1e-3)
        np.testing.assert_allclose(det.roundness, want.roundness, atol=1e-5)
        np.testing.assert_allclose(det.cov, want.cov, rtol=1e-5, atol=1e-12)
        np.testing.assert_array_equal(det.merged, want.merged)
    middle = list(f.frames(10, 14))
    assert [len(d) for d in middle] == [len(by_frame.get(k, Detections.empty())) for k in range(10, 14)]
    assert all(np.isnan(det.flux).all() for det in got)  # (written without light: none comes back)


@pytest.mark.parametrize("suffix", [".centroids.csv", ".centroids.npz"])
def test_the_blobs_light_makes_the_round_trip_where_every_blob_has_it(tmp_path, suffix):
    rng = np.random.default_rng(2)
    frames = [(k, Detections(d.xy, d.area, d.roundness, d.cov, d.merged, rng.uniform(50, 9000, len(d))))
              for k, d in random_frames(rng, 12)]
    path = tmp_path / f"cam1{suffix}"
    write_centroids(path, frames)
    for (_, want), got in zip(frames, open_centroids(path).frames(), strict=True):
        np.testing.assert_allclose(got.flux, want.flux, rtol=1e-5)
    if suffix.endswith("csv"):
        assert "merged,flux" in path.read_text().splitlines()[0]


@pytest.mark.parametrize("suffix", [".centroids.csv", ".centroids.npz"])
def test_the_cut_flag_makes_the_round_trip_where_some_blob_has_it(tmp_path, suffix):
    rng = np.random.default_rng(3)
    frames = [(k, Detections(d.xy, d.area, d.roundness, d.cov, d.merged, rng.uniform(50, 9000, len(d)),
                             rng.random(len(d)) < 0.3)) for k, d in random_frames(rng, 12)]
    assert any(d.cut.any() for _, d in frames)
    path = tmp_path / f"cam1{suffix}"
    write_centroids(path, frames)
    for (_, want), got in zip(frames, open_centroids(path).frames(), strict=True):
        np.testing.assert_array_equal(got.cut, want.cut)
        np.testing.assert_allclose(got.flux, want.flux, rtol=1e-5)
    if suffix.endswith("csv"):
        assert path.read_text().splitlines()[0].endswith("merged,flux,cut")
    plain = tmp_path / f"cam2{suffix}"  # (no blob cut: no column, and none read back cut)
    write_centroids(plain, [(k, d.subset(~d.cut)) for k, d in frames])
    assert not any(d.cut.any() for d in open_centroids(plain).frames())
    if suffix.endswith("csv"):
        assert "cut" not in plain.read_text().splitlines()[0]


@pytest.mark.parametrize("suffix", [".centroids.csv", ".centroids.npz"])
def test_a_blob_with_no_light_is_read_as_not_measured_with_a_warning(tmp_path, suffix, caplog):
    """Zero or negative light (a corrupt or hand-made file) would make the tracker take the blob for its marker
    partly hidden: it is read as not measured, and the file named in a warning; the other blobs keep theirs."""
    rng = np.random.default_rng(3)
    frames = [(k, Detections(d.xy, d.area, d.roundness, d.cov, d.merged, rng.uniform(50, 9000, len(d))))
              for k, d in random_frames(rng, 6)]
    k0, first = next((k, d) for k, d in frames if len(d) >= 2)
    first.flux[:2] = 0.0, -40.0
    path = tmp_path / f"cam1{suffix}"
    write_centroids(path, frames)
    with caplog.at_level("WARNING"):
        got = list(open_centroids(path).frames())
    assert np.isnan(got[k0].flux[:2]).all()
    np.testing.assert_allclose(got[k0].flux[2:], first.flux[2:], rtol=1e-5)
    assert "2 blob(s) with zero or negative light" in caplog.text and path.name in caplog.text


def test_csv_streams_in_chunks(tmp_path, monkeypatch):
    monkeypatch.setattr(centroids, "_CHUNK_ROWS", 3)
    rng = np.random.default_rng(2)
    frames = random_frames(rng, 40)
    path = tmp_path / "c.centroids.csv"
    write_centroids(path, frames)
    got = list(open_centroids(path).frames(5, 40))
    for (k, want), det in zip(frames[5:], got, strict=True):
        np.testing.assert_allclose(det.xy, want.xy, atol=1e-6, err_msg=f"frame {k}")


def test_minimal_csv_and_defaults(tmp_path):
    path = tmp_path / "cam2.centroids.csv"
    path.write_text("x,y,frame\n1.5,2.5,0\n3,4,0\n5,6,2\n")
    f = open_centroids(path)
    assert f.n_frames == 3
    d0, d1, d2 = f.frames()
    np.testing.assert_allclose(d0.xy, [[1.5, 2.5], [3, 4]])
    assert len(d1) == 0 and len(d2) == 1
    assert np.all(d0.roundness == 1) and not d0.merged.any()
    assert d0.cov.shape == (2, 2, 2)


def test_nan_rows_dropped_with_warning(tmp_path, caplog):
    path = tmp_path / "cam.centroids.csv"
    path.write_text("frame,x,y\n0,1,2\n0,nan,3\n1,4,5\n")
    with caplog.at_level(logging.WARNING):
        dets = list(open_centroids(path).frames())
    assert [len(d) for d in dets] == [1, 1]
    assert "NaN" in caplog.text and "cam.centroids.csv" in caplog.text


@pytest.mark.parametrize("text, message", [
    ("frame,x\n0,1\n", "lacks column"),
    ("frame,x,y\n-1,1,2\n", "negative frame"),
    ("frame,x,y\n0.5,1,2\n", "whole number"),
    ("frame,x,y\n2,1,2\n1,1,2\n", "not sorted"),
    ("frame,x,y\n0,1,2\n1,abc,2\n2,1,2\n", "unreadable"),
    ("", "empty file"),
    ("# frames = 2\nframe,x,y\n5,1,2\n", "declares 2 frames"),
])
def test_csv_errors(tmp_path, text, message):
    path = tmp_path / "bad.centroids.csv"
    path.write_text(text)
    with pytest.raises(MocapError, match=message) as info:
        list(open_centroids(path).frames())
    assert "bad.centroids.csv" in str(info.value)


def test_npz_errors(tmp_path):
    path = tmp_path / "bad.centroids.npz"
    np.savez(path, frame=np.arange(3))
    with pytest.raises(MocapError, match="lacks array"):
        open_centroids(path)
    np.savez(path, frame=np.arange(3), xy=np.zeros((2, 2)))
    with pytest.raises(MocapError, match="shape"):
        open_centroids(path)
    path.write_bytes(b"not a zip")
    with pytest.raises(MocapError, match="not a readable"):
        open_centroids(path)


def test_npz_unsorted_rows_are_sorted(tmp_path):
    path = tmp_path / "c.centroids.npz"
    np.savez(path, frame=np.array([2, 0, 2]), xy=np.array([[1.0, 1], [2, 2], [3, 3]]))
    d = list(open_centroids(path).frames())
    assert [len(x) for x in d] == [1, 0, 2]
    np.testing.assert_allclose(d[2].xy, [[1, 1], [3, 3]])


def test_bad_names(tmp_path):
    with pytest.raises(MocapError, match="not found"):
        open_centroids(tmp_path / "missing.centroids.csv")
    with pytest.raises(MocapError, match="must end in"):
        write_centroids(tmp_path / "x.csv", [])
