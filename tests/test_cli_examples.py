"""Every example command in the two command lines' module docstrings (printed by ``--help``) parses with
their parsers: an example with a renamed or missing option fails here, not in a user's shell."""
import shlex

import pytest

import csgnet.__main__ as csg_cli
import shapeprog.__main__ as sp_cli


def _examples(module, prefix):
    lines = [ln.strip() for ln in module.__doc__.splitlines() if ln.strip().startswith(prefix)]
    assert lines, f"no example commands in {module.__name__}'s docstring"
    return [shlex.split(ln.split("  (")[0])[len(shlex.split(prefix)):] for ln in lines]


@pytest.mark.parametrize("module,prefix", [(sp_cli, "python -m shapeprog "), (csg_cli, "python -m csgnet ")])
def test_every_docstring_example_parses(module, prefix):
    parser = module.build_parser()
    examples = _examples(module, prefix)
    for argv in examples:
        args = parser.parse_args(argv)  # argparse exits (SystemExit) on an unknown or missing option
        assert args.cmd == argv[0] and callable(args.func)
    assert len({a[0] for a in examples}) >= 8  # the examples cover most sub-commands


def test_a_wrong_option_in_an_example_would_be_caught(capsys):
    with pytest.raises(SystemExit):
        sp_cli.build_parser().parse_args(shlex.split("table1 --category chair --limit 200 --out table1.md"))
    assert "unrecognized arguments: --category chair" in capsys.readouterr().err
