"""Command line of csgnet: a dispatcher over the command modules of :mod:`csgnet.cli`.

    python -m csgnet render "c(32,32,28)s(32,32,20)-" -o out.png      (.png, .obj, .scad, .npy)
    python -m csgnet render "sp(32,32,32,20)cu(32,32,32,28)*" --dim 3 -o out.obj
    python -m csgnet generate --dim 2 --scale 0.001 --out data/synthetic --workers 2
    python -m csgnet demo --out demo_output
    python -m csgnet parse examples/house.png examples/snowman.stl --refine --out parse_output
    python -m csgnet evaluate --dim 3 --data data/synthetic --beams 1 10 --out table5.json
    python -m csgnet export-weights runs/x/checkpoints/best-012.ckpt --out runs_in_progress/x.pt
    python -m csgnet table4 --weights "CSGNet RL=runs/rl.pt" csgnet/weights/csgnet2d.pt --images 50 --out table4.md
    python -m csgnet table6 --data data/synthetic --weights csgnet/weights/csgnet2d.pt --out table6.md
    python -m csgnet table1 --steps 900 --out table1.json          (the reward-shaping sweep)
    python -m csgnet paper --list                                   (the paper's experiments; paper run ID)
    python -m csgnet edit "c(32,32,28)s(32,32,20)-" --port 8081 --no-browser

Each module of :mod:`csgnet.cli` registers its subcommands (``register(sub)``); the modules that import torch
or Lightning are imported inside the commands that need them, so that ``--help`` and ``render`` start
without loading torch.
"""
from __future__ import annotations

import argparse
import os
import sys

from shapeio import experiments
from shapeio.files import existing_outputs, output_problem
from shapeio.options import HelpFormatter

from .cli import edit, parse, programs, tables
from .paper.experiments import EXPERIMENTS

COMMAND_MODULES = (programs, parse, tables, edit)


def build_parser() -> argparse.ArgumentParser:
    """The command line's parser, every sub-command with its options (``main`` runs what it parses)."""
    ap = argparse.ArgumentParser(prog="python -m csgnet",
                                 description="CSG programs: render, generate datasets, parse shapes, evaluate parsers.")
    sub = ap.add_subparsers(dest="cmd", required=True)
    for module in COMMAND_MODULES:
        module.register(sub)
    experiments.register(sub, EXPERIMENTS, main, "python -m csgnet")
    for name, p in sub.choices.items():  # one convention: defaults and an example in every command's help
        if name in EXAMPLES:
            p.formatter_class = HelpFormatter
            p.epilog = f"example:\n  python -m csgnet {name} {EXAMPLES[name]}"
        if OUTPUTS.get(name) == "file+" or name in ("render", "parse"):
            p.add_argument("--overwrite", action="store_true", help="replace existing output files (an output that "
                           "is one of the inputs is always refused)")
    return ap


#: One command line per command, shown under its ``--help`` (a test runs each through the parser).
EXAMPLES = {
    "render": '"c(32,32,28)s(32,32,20)-" -o out.png',
    "generate": "--dim 2 --scale 0.001 --out data/synthetic --workers 2",
    "demo": "--out demo_output",
    "parse": "examples/house.png examples/snowman.stl --refine --out parse_output",
    "evaluate": "--dim 3 --data data/synthetic --beams 1 10 --per-length 20 --out table5.json",
    "export-weights": "runs/csgnet3d_lite/checkpoints/last.ckpt --out csgnet3d.pt",
    "table4": "--weights csgnet/weights/csgnet2d.pt --images 50 --out table4.json",
    "table1": "--steps 900 --gammas 1 20 --out table1.json",
    "datasize": "--data data/synthetic --fractions 0.1 1.0 --steps 300 --out datasize.json",
    "table6": "--data data/synthetic --weights csgnet/weights/csgnet2d.pt --per-length 20 --out table6.json",
    "edit": '"c(32,32,28)s(32,32,20)-" --port 8081 --no-browser',
}


#: Each command's output options and what they name: ``"folder"`` (created with its parents) or ``"file+"`` (a
#: file, its folder created); :func:`main` checks them with :func:`shapeio.files.output_problem` before the
#: command's work starts (``render -o`` is a list of files in existing folders, checked by ``render``).
OUTPUTS = {"generate": "folder", "demo": "folder", "parse": "folder", "evaluate": "file+",
           "export-weights": "file+", "table1": "file+", "datasize": "file+", "table4": "file+", "table6": "file+"}


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    kind = OUTPUTS.get(args.cmd)
    if kind and getattr(args, "out", None):
        problem = output_problem(args.out, folder=kind == "folder")
        if problem:
            print(f"error: --out {args.out}: {problem}", file=sys.stderr)
            return 2
        problem = kind == "file+" and existing_outputs([args.out], args.overwrite)
        if problem:
            print(f"error: {problem}", file=sys.stderr)
            return 2
    args.argv = list(argv) if argv is not None else sys.argv[1:]
    try:
        return args.func(args)
    except BrokenPipeError:  # the reader went away (`... | head -1`): stop quietly
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except (ValueError, OSError) as e:  # bad input files (ParseError, InputError, ...): the message names them
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
