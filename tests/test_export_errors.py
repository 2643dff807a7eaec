"""Bad input gives a clear MocapError naming the file; an existing output is never left half-written."""

from __future__ import annotations

import tempfile
from pathlib import Path

import pytest
from helpers_export import synthetic_trajectories

from mocap.errors import MocapError
from mocap.export import c3d as c3d_module
from mocap.export.c3d import read_c3d, write_c3d
from mocap.export.csv import read_csv, write_csv
from mocap.export.formats import read_trajectories, write_trajectories
from mocap.export.mcap import write_mcap
from mocap.export.trc import read_trc, write_trc
from mocap.trajectories import Trajectories

WRITERS = {".c3d": write_c3d, ".trc": write_trc, ".csv": write_csv, ".mcap": write_mcap}


@pytest.fixture
def traj() -> Trajectories:
    return synthetic_trajectories(n_frames=60, n_markers=4, seed=1)


def test_truncated_c3d_is_reported_with_frame_counts(traj, tmp_path):
    write_c3d(traj, tmp_path / "a.c3d")
    data = (tmp_path / "a.c3d").read_bytes()
    for cut, match in ((100, "cannot read as C3D"), (len(data) // 2, "truncated: its header declares 60 frames")):
        (tmp_path / "cut.c3d").write_bytes(data[:cut])
        with pytest.raises(MocapError, match=match) as err:
            read_c3d(tmp_path / "cut.c3d")
        assert "cut.c3d" in str(err.value)


def test_trc_with_a_ragged_row_names_the_line(traj, tmp_path):
    write_trc(traj, tmp_path / "a.trc")
    lines = (tmp_path / "a.trc").read_text().splitlines()
    lines[10] = "\t".join(lines[10].split("\t")[:-4])  # a row that lost its last cells
    (tmp_path / "bad.trc").write_text("\n".join(lines))
    with pytest.raises(MocapError, match=r"bad.trc: line 11 has 10 fields, expected 14"):
        read_trc(tmp_path / "bad.trc")
    lines = (tmp_path / "a.trc").read_text().splitlines()
    lines[8] = lines[8].replace(lines[8].split("\t")[3], "12,5", 1)
    (tmp_path / "bad2.trc").write_text("\n".join(lines))
    with pytest.raises(MocapError, match=r"bad2.trc: line 9, field 4: '12,5' is not a number"):
        read_trc(tmp_path / "bad2.trc")


def test_not_a_trc_or_motive_csv(tmp_path):
    (tmp_path / "x.trc").write_text("hello\n")
    with pytest.raises(MocapError, match="x.trc: not a TRC file"):
        read_trc(tmp_path / "x.trc")
    (tmp_path / "x.csv").write_text("a,b,c\n1,2,3\n")
    with pytest.raises(MocapError, match="x.csv: not a Motive CSV export"):
        read_csv(tmp_path / "x.csv")
    (tmp_path / "bin.trc").write_bytes(b"\xff\xfe\x00binary")
    with pytest.raises(MocapError, match="not a text file"):
        read_trc(tmp_path / "bin.trc")
    with pytest.raises(MocapError, match="unknown trajectory file type '.txt'"):
        read_trajectories(tmp_path / "x.txt")


@pytest.mark.parametrize("suffix", [".c3d", ".trc", ".csv"])
@pytest.mark.parametrize("label", ["Épaule", "tab\there", ""])
def test_labels_other_programs_cannot_read_are_refused_and_the_old_file_kept(traj, tmp_path, suffix, label):
    out = tmp_path / f"out{suffix}"
    out.write_bytes(b"old")
    traj.labels[2] = label
    with pytest.raises(MocapError, match=rf"out{suffix}: marker 2 label .* printable ASCII"):
        WRITERS[suffix](traj, out)
    assert out.read_bytes() == b"old"


def test_mcap_keeps_non_ascii_labels(traj, tmp_path):
    traj.labels[2] = "Épaule gauche"
    write_mcap(traj, tmp_path / "a.mcap")
    assert read_trajectories(tmp_path / "a.mcap").labels[2] == "Épaule gauche"


@pytest.mark.parametrize("suffix", sorted(WRITERS))
def test_output_in_a_missing_folder(traj, tmp_path, suffix):
    with pytest.raises(MocapError, match="does not exist; create it first"):
        write_trajectories(traj, tmp_path / "no" / f"out{suffix}")


@pytest.mark.parametrize("suffix", [".trc", ".csv"])
def test_a_failure_while_writing_text_leaves_the_existing_file_untouched(traj, tmp_path, suffix, monkeypatch):
    out = tmp_path / f"out{suffix}"
    write_trajectories(traj, out)
    before = out.read_bytes()
    real_write = Path.write_bytes

    def half_write(self, payload):
        real_write(self, payload[: len(payload) // 2])
        raise OSError("disk full")

    monkeypatch.setattr(Path, "write_bytes", half_write)
    with pytest.raises(MocapError, match=rf"out\{suffix}: could not be written \(disk full\)"):
        write_trajectories(synthetic_trajectories(n_frames=90, n_markers=4, seed=9), out)
    assert out.read_bytes() == before
    assert list(tmp_path.iterdir()) == [out]  # no temporary file left behind


def test_a_failure_inside_the_c3d_writer_leaves_the_existing_file_untouched(traj, tmp_path, monkeypatch):
    out = tmp_path / "out.c3d"
    write_c3d(traj, out)
    before = out.read_bytes()

    def half_write(self, path):
        with open(path, "wb") as f:
            f.write(before[: len(before) // 2])
        raise RuntimeError("ezc3d failed")

    monkeypatch.setattr(c3d_module.ezc3d.c3d, "write", half_write)
    with pytest.raises(RuntimeError, match="ezc3d failed"):
        write_c3d(synthetic_trajectories(n_frames=90, n_markers=4, seed=9), out)
    assert out.read_bytes() == before
    assert list(tmp_path.iterdir()) == [out]  # no temporary file left behind


@pytest.mark.parametrize("suffix", sorted(WRITERS))
def test_a_folder_that_refuses_new_files_is_reported_before_writing(traj, tmp_path, suffix, monkeypatch):
    """access() tells root every folder is writable; creating a file there is the real test (a read-only mount,
    /proc)."""
    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied")

    monkeypatch.setattr(tempfile, "mkstemp", refuse)
    with pytest.raises(MocapError, match=rf"out\{suffix}: cannot create files in .* \(Permission denied\)"):
        write_trajectories(traj, tmp_path / f"out{suffix}")
    assert list(tmp_path.iterdir()) == []
