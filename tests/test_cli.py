"""The mocap command: every subcommand loads and describes itself; no subcommand prints help; an operating system
error (a full disk) is reported in a line, not a traceback."""

from __future__ import annotations

import errno

import pytest

import mocap.pipeline
from mocap.cli import SUBCOMMANDS, main


@pytest.mark.parametrize("command", sorted(SUBCOMMANDS))
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: mocap {command}") and SUBCOMMANDS[command][1].split()[0] in out


def test_no_subcommand_prints_usage(capsys):
    assert main([]) == 1
    out = capsys.readouterr().out
    assert all(name in out for name in SUBCOMMANDS)


def test_a_full_disk_is_reported_in_a_line(tmp_path, monkeypatch, capsys):
    def full(*args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(mocap.pipeline, "reconstruct", full)
    (tmp_path / "take").mkdir()
    assert main(["reconstruct", str(tmp_path / "take"), "--c3d", str(tmp_path / "out.c3d")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("mocap reconstruct: error: No space left on device; free some space")
    assert "Traceback" not in err
