"""The public names: every ``__all__`` entry exists, and the README's entry points keep working.

Packages and their public submodules (names without a leading underscore) are found by walking the
package folders, so a new module is checked without a new test. The README's
``python -m csgnet COMMAND`` / ``python -m shapeprog SYSTEM COMMAND`` commands are read from README.md itself, and
the shapeprog command line's systems, commands and earlier one-word names are pinned here.
"""
import importlib
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import csgnet
import shapeprog

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text(encoding="utf-8")
PACKAGES = ["csgnet", "csgnet.renderer", "csgnet.editor", "shapeprog", "shapeprog.vae", "shapeprog.pointcloud", "shapeprog.macros",
            "shapeprog.coder", "shapeprog.editor", "envs", "shapeio", "shapeedit"]


def _public_modules() -> list[str]:
    """The packages and every module file under them (namespace sub-packages such as ``csgnet/train``
    included) whose dotted name has no part with a leading underscore."""
    names = set(PACKAGES)
    for package in PACKAGES:
        folder = Path(importlib.import_module(package).__file__).parent
        for path in folder.rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            if not any(p.startswith("_") for p in parts):
                names.add(".".join(parts))
    return sorted(names)


MODULES = _public_modules()
# `python -m csgnet COMMAND` and `python -m shapeprog SYSTEM COMMAND` as the README writes them
COMMANDS = sorted(set(re.findall(r"python -m (csgnet) ([a-z][\w-]*)", README))
                  | {("shapeprog", f"{system} {command}")
                     for system, command in re.findall(r"python -m shapeprog ([a-z]+) ([a-z][\w-]*)", README)})

# The shapeprog command line: each system's commands, and the earlier one-word names that still work (each prints
# one line naming its new form). A change here is a change of the command line: make it on purpose.
SHAPEPROG_COMMANDS = {
    "assembly": {"run", "fit", "silhouettes", "volumes", "edit"},
    "vae": {"sample", "interpolate", "reconstruct", "evaluate", "novelty", "smoothness", "editability",
            "train-classifier", "export-weights"},
    "pointcloud": {"infer", "tables", "make-clouds", "export-weights"},
    "macros": {"discover", "refactor", "refactor-corpus", "tables", "ablation", "generation", "perturbation",
               "pointcloud"},
    "coder": {"discover", "infer", "tables", "ablation", "perturbation", "noise", "sample"},
}
SHAPEPROG_ALIASES = {
    "run": "assembly run", "fit": "assembly fit", "silhouettes": "assembly silhouettes", "edit": "assembly edit",
    "sample": "vae sample", "interpolate": "vae interpolate", "reconstruct": "vae reconstruct",
    "evaluate-generation": "vae evaluate", "train-classifier": "vae train-classifier",
    "export-weights": "None export-weights",  # vae or pointcloud, after the checkpoint
    "infer": "pointcloud infer", "pointcloud-tables": "pointcloud tables", "make-clouds": "pointcloud make-clouds",
    "discover-macros": "macros discover", "refactor": "macros refactor", "refactor-corpus": "macros refactor-corpus",
    "table1": "macros tables", "discover-abstractions": "coder discover", "abstract-infer": "coder infer",
    "table2-coder": "coder tables",
}


# The packages' public names. A change here is a change of the public API: make it on purpose (and say so
# in the docs), not by accident.
PUBLIC = {
    "csgnet": {"Draw", "Op", "ParseError", "Program", "Vocabulary", "is_valid", "parse", "parse_lines", "render",
               "to_text", "vocabulary"},
    "csgnet.renderer": {"Execution", "PrimitiveCache", "SIZE", "StackMachine", "apply_op_", "draw_packed",
                        "encode_programs", "encode_programs_ids", "encode_tokens", "execute", "pack", "popcount",
                        "primitive_cache", "render_programs", "render_tokens", "stack_trace", "unpack"},
    "csgnet.editor": {"CHOICE", "INT", "CSGEditError", "CSGEditSession", "Control", "apply", "controls",
                      "page_value", "render_png_bytes"},
    "shapeprog": {"ExecutionError", "ParseError", "corpus", "execute", "execute_batch", "fit", "parse",
                  "print_program", "to_text"},
    "shapeprog.vae": {"LOSS_WEIGHTS", "VAE", "Decoded", "Decoder", "Encoder", "InvalidSample", "TreeBatch",
                      "VectorNode", "batch_forward", "batch_loss", "decode", "decode_latent", "encode", "interpolate",
                      "load_pretrained", "program_loss", "program_to_tree", "sample", "tree_to_program",
                      "LineLayout", "MACRO_LOSS_WEIGHTS", "MacroDecoded", "MacroNode", "MacroVAE", "decode_macro",
                      "encode_macro", "macro_program_loss", "macro_program_to_tree", "sample_macro",
                      "tree_to_macro_program", "structural_novelty", "structure_key", "edit_distance"},
    "shapeprog.pointcloud": {"CANONICAL_DIAGONAL", "CloudDataset", "CloudModel", "Inference", "Match", "PointCloudError", "PointNet2SSG",
                             "RetrievalIndex", "SetAbstraction", "Transform", "ball_query", "collate_clouds",
                             "corpus_cloud", "farthest_point_sample", "gather_points", "group_all", "group_points",
                             "infer", "load_cache", "load_model", "make_clouds", "normalize", "program_cloud", "query_and_group",
                             "read_cloud", "scale_program"},
    "shapeprog.macros": {"BlockRefactor", "Call", "Conversion", "CorpusData", "Cube", "Failure", "Library", "Linear",
                         "Literal", "MacroDef", "MacroError", "MacroProgram", "Name", "Ordering", "Param", "Refactored",
                         "SubProgram", "collection", "convert_corpus", "convert_program", "execute", "execute_batch",
                         "expand", "from_lines", "load_library", "order_errors", "parse", "program_parameters",
                         "program_stats", "refactor", "to_text", "load_refactored", "read_refactored", "refactor_corpus",
                         "write_refactored"},
    "shapeprog.coder": {"LANG_2D", "LANG_3D", "WEIGHTS", "Abstraction", "Execution", "ExecutionError", "Library",
                        "Param", "ParseError", "ProgramError", "Type", "check", "data", "execute", "expand", "limits",
                        "match", "naive_cost", "naive_program", "naive_summary", "objective", "omega", "parse",
                        "parse_abstraction", "preference", "program_cost", "run", "to_text", "Config",
                        "DiscoveryResult", "Inferred", "RefactorError", "Refactored", "Summary", "discover", "infer",
                        "load_library", "refactor", "summarize"},
    "shapeprog.editor": {"BOOL", "CHOICE", "FLOAT", "INT", "Control", "EditSession", "apply", "controls",
                         "corner_distance", "load_program", "page_value"},
    "envs": set(),
    "shapeio": {"InputError", "atomic_write", "refuse_overwrite", "remove_stale_temps", "write_new"},
    "shapeedit": {"EDITOR_EXTRA", "MAX_HISTORY", "MAX_PORT", "CameraPose", "History", "UndoableSession",
                  "check_port", "editor_preflight", "export_stem", "frame_box", "import_viser", "port_argument", "refused_request",
                  "serve_until_interrupted", "show_pose", "viser_server"},
}


@pytest.mark.parametrize("package", PACKAGES)
def test_packages_declare_exactly_their_public_names(package):
    module = importlib.import_module(package)
    assert isinstance(module.__all__, (list, tuple))
    assert set(module.__all__) == PUBLIC[package]


@pytest.mark.parametrize("name", MODULES)
def test_every_name_in___all___exists(name):
    module = importlib.import_module(name)
    exported = getattr(module, "__all__", [])
    assert len(set(exported)) == len(exported), f"{name}.__all__ lists a name twice"
    missing = [n for n in exported if not hasattr(module, n)]
    assert not missing, f"{name}.__all__ names missing attributes: {missing}"


def test_the_readme_python_entry_points():
    for name in ("parse", "render", "vocabulary", "load_pretrained", "infer", "refine", "parse_shape"):
        assert callable(getattr(csgnet, name))
    for name in ("parse", "execute", "corpus", "fit"):
        assert hasattr(shapeprog, name)
    # "A first look"
    prog = csgnet.parse("c(32,32,28)c(32,32,24)-s(32,32,28)s(32,32,20)-+t(32,32,20)+")
    img = csgnet.render(prog)
    assert img.shape == (1, 64, 64) and img.dtype == np.bool_ and img.any()
    vol = csgnet.render(["sp(32,32,32,20)cu(32,32,32,28)*"], dim=3)
    assert vol.shape == (1, 64, 64, 64) and vol.any()
    tokens = csgnet.vocabulary(2).encode(prog)
    assert len(tokens) == len(prog.tokens) and len(csgnet.vocabulary(2)) == 400
    assert csgnet.metrics.chamfer(img[0], img[0]) == 0.0
    model = csgnet.load_pretrained(2)
    (res,) = csgnet.infer(model, img, beam=2)
    assert isinstance(res.text, str) and np.isfinite(res.score) and 0.0 <= res.iou <= 1.0
    refined = csgnet.refine(res.text, img[0], maxiter=0)
    assert refined.score == refined.initial_score
    # shapeprog
    sa = shapeprog.parse(shapeprog.corpus.read("chair", 173), "chair/173.txt")
    shape = shapeprog.execute(sa)
    assert tuple(shape.corners.shape) == (6, 8, 3)
    fitted = shapeprog.fit(sa, shape.corners.reshape(-1, 3).detach(), steps=1, samples=64, target_samples=None,
                           generator=torch.Generator().manual_seed(0))
    assert len(fitted.losses) == len(fitted.chamfer) == 1 and np.isfinite(fitted.losses).all()
    assert shapeprog.parse(fitted.text) == fitted.program  # the text is the program
    kinds = lambda p: [[type(s).__name__ for s in b.statements] for b in p.blocks]  # noqa: E731
    assert kinds(fitted.program) == kinds(sa)  # fitting keeps the structure


def test_the_readme_names_its_commands():
    assert ("csgnet", "parse") in COMMANDS and ("shapeprog", "assembly run") in COMMANDS


#: The commands of ``python -m csgnet``.
CSGNET_COMMANDS = ["render", "generate", "demo", "parse", "evaluate", "export-weights", "table4", "table1", "datasize",
                   "table6", "edit", "paper"]


def test_csgnet_commands():
    import argparse

    from csgnet.__main__ import build_parser

    sub = next(a for a in build_parser()._actions if isinstance(a, argparse._SubParsersAction))
    assert list(sub.choices) == CSGNET_COMMANDS


def test_shapeprog_systems_commands_and_aliases():
    import argparse

    from shapeprog.__main__ import ALIASES, SYSTEMS, build_parser

    def choices(parser):
        return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices

    systems = choices(build_parser())
    assert [*SYSTEMS, "paper"] == list(systems) == [*SHAPEPROG_COMMANDS, "paper"]  # paper: the experiment list
    assert {name: set(choices(sp)) for name, sp in systems.items() if name != "paper"} == SHAPEPROG_COMMANDS
    assert {old: f"{system} {command}" for old, (system, command, _) in ALIASES.items()} == SHAPEPROG_ALIASES
    for name, (module, summary) in SYSTEMS.items():  # the summary names the commands its module registers
        assert module.startswith("shapeprog.") and module.endswith("commands")
        assert set(summary.split(": ", 1)[1].split(", ")) == SHAPEPROG_COMMANDS[name]


@pytest.mark.parametrize("package, command", COMMANDS)
def test_readme_subcommand_help(package, command, capsys):
    main = importlib.import_module(f"{package}.__main__").main
    with pytest.raises(SystemExit) as exit_:
        main([*command.split(), "--help"])
    assert exit_.value.code == 0
    assert f"python -m {package} {command}" in capsys.readouterr().out


@pytest.mark.parametrize("package", ["csgnet", "shapeprog"])
def test_python_m_help(package):
    out = subprocess.run([sys.executable, "-m", package, "--help"], cwd=ROOT, capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr
    for p, command in COMMANDS:
        if p == package:
            assert command.split()[0] in out.stdout
