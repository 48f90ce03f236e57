"""Command line of shapeprog: ``python -m shapeprog SYSTEM COMMAND ...``, a dispatcher over the systems' command
modules (:data:`SYSTEMS`).

    python -m shapeprog assembly run chair/173 -o chair.obj --png chair.png
    python -m shapeprog assembly fit table/33075 --points example --steps 400 -o fitted.txt
    python -m shapeprog assembly silhouettes --out silhouettes.npz
    python -m shapeprog assembly volumes --out data/assembly_volumes.npz --workers 2
    python -m shapeprog assembly edit chair/173 --port 8080 --no-browser --target chair/37982
    python -m shapeprog vae sample --category chair -n 16 --seed 0 --out samples --png grid.png
    python -m shapeprog vae interpolate chair/173 chair/44017 --steps 8 --png interp.png
    python -m shapeprog vae reconstruct chair/173 -o recon.txt
    python -m shapeprog vae evaluate --category chair -n 1000 --out table.md --json table.json
    python -m shapeprog vae novelty --category chair table storage -n 1000 --json novelty.json
    python -m shapeprog vae train-classifier --out runs/pointnet_cls.pt
    python -m shapeprog vae export-weights runs/vae_chair/checkpoints/last.ckpt --out vae_chair.pt
    python -m shapeprog pointcloud make-clouds --category chair --points 10000 --workers 2 --out clouds
    python -m shapeprog pointcloud infer scan.ply --category chair --fit --out result/
    python -m shapeprog pointcloud tables --category chair --clouds clouds --out pointcloud_chair.md
    python -m shapeprog macros discover --category chair --rounds 5 --workers 2 --out runs/shapemod_chair
    python -m shapeprog macros refactor chair/173 --library chair
    python -m shapeprog macros refactor-corpus --category chair --library chair --workers 2 --out chair_macros
    python -m shapeprog macros tables --category chair --limit 200 --out table1.md
    python -m shapeprog coder discover --category chair --out runs/chair_abs --workers 2
    python -m shapeprog coder infer coder-chair:401 --library chair
    python -m shapeprog coder tables --category chair table storage --workers 2 --out shapecoder_tables.md

``python -m shapeprog SYSTEM COMMAND --help`` lists a command's options with their defaults and an example.
The conventions every command follows are in :mod:`shapeprog.cli`. The earlier one-word commands (``run``,
``sample``, ``infer``, ``table1``, ...) still work (:data:`ALIASES`) and print one line naming their new form.
Errors name the file, line and column; exit status 2 for a program that does not parse or execute, 1 for a file
that cannot be read or written.
"""
from __future__ import annotations

import argparse
import importlib
import re
import sys
import warnings
from pathlib import Path

from shapeio import InputError, experiments
from shapeio.files import output_problem

from .errors import ExecutionError, ParseError, RefactorError

#: Each system: the module that registers its commands (``register(sub)``) and its one-line summary. The
#: modules are imported only when their system is named, so ``--help`` and each system start without the others.
SYSTEMS = {
    "assembly": ("shapeprog.commands", "ShapeAssembly programs: run, fit, silhouettes, volumes, edit"),
    "vae": ("shapeprog.vae.commands",
            "the ShapeAssembly VAE: sample, interpolate, reconstruct, evaluate, novelty, smoothness, editability, "
            "train-classifier, export-weights"),
    "pointcloud": ("shapeprog.pointcloud.commands", "point clouds to programs: infer, tables, make-clouds, "
                                                    "export-weights"),
    "macros": ("shapeprog.macros.commands", "ShapeMOD macros: discover, refactor, refactor-corpus, tables, "
                                            "generation, pointcloud, ablation, perturbation"),
    "coder": ("shapeprog.coder.commands",
              "ShapeCoder abstractions: discover, infer, tables, ablation, perturbation, noise, sample"),
}

_CATEGORIES = ("chair", "table", "storage")


def _positional_category(rest: list[str], flags: tuple[str, ...] = ("--quiet", "--overwrite")) -> list[str]:
    """The earlier ``sample chair`` / ``discover-abstractions chair``: a bare category (not an option's value)
    becomes ``--category chair``."""
    out = list(rest)
    for i, token in enumerate(out):
        follows_option = i > 0 and out[i - 1].startswith("-") and out[i - 1] not in flags
        if token in _CATEGORIES and not follows_option:
            return out[:i] + ["--category", token] + out[i + 1:]
    return out


def _renamed(old: str, new: str):
    """A rewrite of the earlier option ``old`` (also ``old=VALUE``) to ``new``."""
    return lambda rest: [new + t[len(old):] if t == old or t.startswith(old + "=") else t for t in rest]


def _edit_sample(rest: list[str]) -> list[str]:
    """The earlier ``edit --sample CATEGORY``: now ``--sample --category CATEGORY``."""
    out = []
    for i, token in enumerate(rest):
        if token.startswith("--sample="):
            out += ["--sample", "--category", token.partition("=")[2]]
        elif i > 0 and rest[i - 1] == "--sample" and token in _CATEGORIES:
            out += ["--category", token]
        else:
            out.append(token)
    return out


def _coder_shape(rest: list[str]) -> list[str]:
    """The earlier ``abstract-infer chair/401`` (a line of PN_chair.txt): now ``coder-chair:401``."""
    return [f"coder-{m['c']}:{m['n']}" if (m := re.fullmatch(r"(?P<c>chair|table|storage)/(?P<n>\d+)", t))
            and not Path(t).exists() else t for t in rest]


def _export_weights(rest: list[str]) -> tuple[str, list[str]]:
    """The earlier ``export-weights`` took both models' checkpoints: the point-cloud one goes to its system."""
    # reads the checkpoint's keys with torch: only when the earlier name is used
    from .vae.commands import is_pointcloud_checkpoint

    values = {"--out"}
    files = [t for i, t in enumerate(rest) if not t.startswith("-") and (i == 0 or rest[i - 1] not in values)]
    return "pointcloud" if files and is_pointcloud_checkpoint(files[0]) else "vae", rest


def _coder_discover(rest: list[str]) -> list[str]:
    """The earlier ``discover-abstractions chair``: a bare category becomes ``--category chair``."""
    return _positional_category(rest, ("--quiet", "--no-semantic-rewrites"))


_OUTPUT = _renamed("--output", "--out")
_CATEGORIES_OPTION = _renamed("--categories", "--category")

#: The earlier one-word commands: name -> (system, command, rewrite of the earlier argument forms or None).
ALIASES = {
    "run": ("assembly", "run", _OUTPUT), "fit": ("assembly", "fit", _OUTPUT),
    "silhouettes": ("assembly", "silhouettes", None), "edit": ("assembly", "edit", _edit_sample),
    "sample": ("vae", "sample", _positional_category), "interpolate": ("vae", "interpolate", None),
    "reconstruct": ("vae", "reconstruct", _OUTPUT), "evaluate-generation": ("vae", "evaluate", None),
    "train-classifier": ("vae", "train-classifier", None), "export-weights": (None, "export-weights", None),
    "infer": ("pointcloud", "infer", None), "pointcloud-tables": ("pointcloud", "tables", None),
    "make-clouds": ("pointcloud", "make-clouds", None), "discover-macros": ("macros", "discover", None),
    "refactor": ("macros", "refactor", _OUTPUT), "refactor-corpus": ("macros", "refactor-corpus", None),
    "table1": ("macros", "tables", _CATEGORIES_OPTION), "discover-abstractions": ("coder", "discover", _coder_discover),
    "abstract-infer": ("coder", "infer", _coder_shape), "table2-coder": ("coder", "tables", _CATEGORIES_OPTION),
}


def resolve_alias(argv: list[str]) -> list[str]:
    """``argv`` in the ``SYSTEM COMMAND ...`` form: an earlier one-word command (:data:`ALIASES`) is rewritten,
    with one line on stderr naming its new form."""
    if not argv or argv[0] not in ALIASES:
        return list(argv)
    system, verb, rewrite = ALIASES[argv[0]]
    rest = list(argv[1:])
    if system is None:
        system, rest = _export_weights(rest)
    elif rewrite is not None:
        rest = rewrite(rest)
    print(f"note: '{argv[0]}' is now '{system} {verb}'", file=sys.stderr)
    return [system, verb, *rest]


def build_parser(systems=None) -> argparse.ArgumentParser:
    """The command line's parser; the commands of ``systems`` (default: all of :data:`SYSTEMS`) registered."""
    ap = argparse.ArgumentParser(prog="python -m shapeprog", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="system", required=True, metavar="SYSTEM")
    for name, (module, summary) in SYSTEMS.items():
        sp = sub.add_parser(name, help=summary, description=summary)
        commands = sp.add_subparsers(dest="command", required=True, metavar="COMMAND")
        if systems is None or name in systems:
            importlib.import_module(module).register(commands)
    if systems is None or "paper" in systems:
        from .paper import EXPERIMENTS  # the three systems' lists: only when `paper` (or the full help) is asked for

        experiments.register(sub, EXPERIMENTS, main, "python -m shapeprog")
    return ap


def _output_problem(args) -> str | None:
    """The first of ``args``' outputs (the command's ``outputs``) that cannot be written, as an error line."""
    for attr, kind in getattr(args, "outputs", {}).items():
        value = getattr(args, attr, None)
        if value:
            problem = output_problem(value, folder=kind == "folder", create=kind != "file")
            if problem:
                return f"error: --{attr} {value}: {problem}"
    return None


def main(argv=None) -> int:
    argv = resolve_alias(list(sys.argv[1:] if argv is None else argv))
    args, extra = build_parser([argv[0]] if argv and argv[0] in (*SYSTEMS, "paper") else ()).parse_known_args(argv)
    if extra:  # named by the command's own parser, with its usage
        args.parser.error(f"unrecognized arguments: {' '.join(extra)}")
    problem = _output_problem(args)
    if problem:
        raise SystemExit(problem)
    args.argv = argv  # the command line in its SYSTEM COMMAND form, recorded by the commands that write it
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("default")
            return args.func(args)
    except (ParseError, ExecutionError, RefactorError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (OSError, InputError) as e:  # unreadable inputs, unwritable outputs: the message names the file
        print(f"error: {e}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
