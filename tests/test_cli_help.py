"""Every subcommand's --help works (a bare % in a help text once broke two of them)."""

import argparse

import pytest

from angiohull.cli import build_parser, main


def _subcommands():
    parser = build_parser()
    actions = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    assert len(actions) == 1
    return sorted(actions[0].choices)


def test_the_subcommands_are_found():
    assert {"reconstruct", "evaluate", "demo", "synth", "segment", "study-from-dicom", "experiment", "report",
            "qca", "dicom-info"} <= set(_subcommands())


@pytest.mark.parametrize("command", _subcommands())
def test_help_of_every_subcommand(command, capsys):
    with pytest.raises(SystemExit) as info:
        main([command, "--help"])
    assert info.value.code == 0
    captured = capsys.readouterr()
    assert captured.out.startswith("usage: angiohull " + command)
    assert captured.err == ""


def test_top_level_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    for command in _subcommands():
        assert command in out
