"""Every example command in the two command lines' module docstrings (printed by ``--help``) and in the epilog of
every ``python -m shapeprog`` command parses with their parsers: an example with a renamed or missing option fails
here, not in a user's shell. Every shapeprog option has help text."""
import argparse
import shlex

import pytest

import csgnet.__main__ as csg_cli
import shapeprog.__main__ as sp_cli


def _examples(module, prefix):
    lines = [ln.strip() for ln in module.__doc__.splitlines() if ln.strip().startswith(prefix)]
    assert lines, f"no example commands in {module.__name__}'s docstring"
    return [shlex.split(ln.split("  (")[0])[len(shlex.split(prefix)):] for ln in lines]


def _commands(parser):
    """``(system, command, its parser)`` of every shapeprog command."""
    systems = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    for system, sp in systems.choices.items():
        if system == "paper":  # the experiment list: one command of its own (test_the_paper_command_has_help)
            continue
        commands = next(a for a in sp._actions if isinstance(a, argparse._SubParsersAction))
        for command, cp in commands.choices.items():
            yield system, command, cp


def test_every_csgnet_docstring_example_parses():
    parser = csg_cli.build_parser()
    examples = _examples(csg_cli, "python -m csgnet ")
    for argv in examples:
        args = parser.parse_args(argv)  # argparse exits (SystemExit) on an unknown or missing option
        assert args.cmd == argv[0] and callable(args.func)
    assert len({a[0] for a in examples}) >= 8  # the examples cover most sub-commands


def test_every_shapeprog_docstring_example_parses():
    parser = sp_cli.build_parser()
    examples = _examples(sp_cli, "python -m shapeprog ")
    for argv in examples:
        args = parser.parse_args(argv)
        assert (args.system, args.command) == tuple(argv[:2]) and callable(args.func)
    assert {a[0] for a in examples} == set(sp_cli.SYSTEMS)  # one example of each system at least


def test_every_shapeprog_command_has_an_example_and_help_for_every_option():
    parser = sp_cli.build_parser()
    commands = list(_commands(parser))
    assert len(commands) == 33
    for system, command, cp in commands:
        argv = shlex.split(cp.get_default("example"))
        assert argv[:2] == [system, command], f"{system} {command}: the epilog's example runs {argv[:2]}"
        assert parser.parse_args(argv).func is cp.get_default("func")
        assert f"example:\n  python -m shapeprog {system} {command}" in cp.format_help()
        undocumented = [a.dest for a in cp._actions if not a.help]
        assert not undocumented, f"{system} {command}: options without help: {undocumented}"


def test_help_shows_defaults_but_not_none_or_off():
    parser = sp_cli.build_parser()
    help_text = {(s, c): cp.format_help() for s, c, cp in _commands(parser)}
    text = " ".join(help_text[("vae", "sample")].split())
    assert "grid columns (default: 4)" in text
    assert "(default: None)" not in text and "(default: False)" not in text
    assert "the shipped model to use (default: the --weights model's, else chair)" in text
    assert "--category {chair,table,storage} the corpus category (default: chair)" in " ".join(
        help_text[("pointcloud", "make-clouds")].split())


def test_a_wrong_option_in_an_example_would_be_caught(capsys):
    with pytest.raises(SystemExit):
        sp_cli.build_parser().parse_args(shlex.split("macros tables --categories chair --limit 200 --out table1.md"))
    assert "unrecognized arguments: --categories chair" in capsys.readouterr().err


@pytest.mark.parametrize("cli, prog", [(sp_cli, "python -m shapeprog"), (csg_cli, "python -m csgnet")])
def test_the_paper_command_has_help_and_an_example(cli, prog):
    parser = cli.build_parser()
    systems = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    paper = systems.choices["paper"]
    assert not [a.dest for a in paper._actions if not a.help]
    example = paper.epilog.removeprefix("example: ")
    assert example.startswith(f"{prog} paper run ") and example.endswith(" --quick")
    args = parser.parse_args(shlex.split(example)[len(shlex.split(prog)):])
    assert args.action == "run" and args.quick
