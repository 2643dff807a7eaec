"""The mocap command: every subcommand loads and describes itself; no subcommand prints help."""

from __future__ import annotations

import pytest

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
