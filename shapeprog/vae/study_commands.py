"""``python -m shapeprog vae novelty | smoothness | editability``: the ShapeAssembly paper's measures of samples
beyond the generation tables (structural novelty, Table 6's interpolation smoothness, Table 3's editability),
each writing a result file. :mod:`shapeprog.vae.commands` registers them beside the other ``vae`` commands."""
from __future__ import annotations

import sys
import time

from shapeio.results import column

from .. import corpus
from ..cli import (add_category, add_command, add_result_options, add_seed, check_outputs, command_result, int_at_least,
                   refuse_existing, write_json)
from .decode import MAX_SAMPLES, MAX_TRIES, sample
from .genmetrics import novelty
from .gentable import EVALUATE_TRIES
from .pretrained import load_pretrained
from .smoothness import MAX_SEQUENCES, MAX_STEPS, interpolation_smoothness
from .structure import mean_editability, structural_novelty


def _shipped_models(args):
    """Each category of ``--category`` once with its shipped VAE, after ``--json`` is checked (a study's output)."""
    check_outputs(others=[args.json])
    refuse_existing([args.json], args.overwrite)
    for category in dict.fromkeys(args.category):
        yield category, load_pretrained(category)


def cmd_novelty(args) -> int:
    """structural novelty of VAE samples and of the val split against the train split

    Sample the shipped VAE of each category and measure the share of samples, and of the corpus val split, whose
    structure (the program with its continuous numbers abstracted) no training program has (ShapeAssembly §7.1.3),
    beside the text novelty.

    Example: vae novelty --category chair table storage -n 1000 --json novelty.json"""
    rows = []
    for category, vae in _shipped_models(args):
        t0 = time.perf_counter()
        samples = [r.program for r in sample(vae, args.n, seed=args.seed, max_tries=args.max_tries)]
        val = [p for _, p in corpus.load(category, "val")]
        train = [p for _, p in corpus.load(category, "train")]  # read once: both rows and both measures use it
        for name, progs in ((f"VAE samples (shipped {category} model, at most {args.max_tries} draws)", samples),
                            ("corpus val split", val)):
            rows.append({"category": category, "row": name, "programs": len(progs),
                         "structure": 100.0 * structural_novelty(progs, training=train),
                         "text": novelty(progs, train)})
            print(f"{category}: {name}: {len(progs)} programs, {rows[-1]['structure']:.1f} % novel structure, "
                  f"{rows[-1]['text']:.1f} % novel text ({time.perf_counter() - t0:.1f} s)")
    write_json(args, command_result(
        args, "Structural novelty (ShapeAssembly §7.1.3)",
        [column("category", "category"), column("row", "programs of"), column("programs", "programs"),
         column("structure", "% novel (structure)", 1), column("text", "% novel (text)", 1)], rows,
        ["% novel (structure): programs whose structure (every continuous number abstracted; names, faces, axes, "
         "aligned flags, translate counts and hierarchy kept) no program of the category's corpus train split has "
         "(`shapeprog.vae.structural_novelty`). % novel (text): whose text with numbers to 3 decimals none has.",
         "The paper's figures for this measure are not in the specification; its samples were 1,000 per category.",
         f"Samples: seed {args.seed}, decoded with validity checks and rejection."]))
    return 0


def cmd_smoothness(args) -> int:
    """interpolation smoothness: geometric and program steps between random latents

    Decode programs along lines between random latents of the shipped VAE of each category and measure consecutive
    steps: the chamfer distance of their shapes (same sampling seed) and the token edit distance of their programs
    (ShapeAssembly Table 6).

    Example: vae smoothness --category chair --sequences 100 --steps 100 --json smooth.json"""
    rows = []
    for category, vae in _shipped_models(args):
        log = None if args.quiet else (lambda s, c=category: print(f"{c}: {s}", file=sys.stderr, flush=True))
        r = interpolation_smoothness(vae, args.sequences, args.steps, seed=args.seed, log=log)
        rows.append({"category": category, **r})
        print(f"{category}: {args.sequences} sequences x {args.steps} steps: geometric step {r['geometric']:.4f}, "
              f"program step {r['program']:.1f} tokens, structure step {r['structure']:.2f} tokens "
              f"(ends: {r['geometric_ends']:.4f}, {r['program_ends']:.1f}, {r['structure_ends']:.1f}) in "
              f"{r['seconds']:.0f} s")
    write_json(args, command_result(
        args, "Interpolation smoothness (ShapeAssembly Table 6)",
        [column("category", "category"), column("sequences", "sequences"), column("steps", "steps"),
         column("geometric", "geometric step (chamfer)", 4), column("program", "program step (token edits)", 2),
         column("structure", "structure step (token edits)", 2),
         column("unchanged", "% steps with unchanged structure", 1),
         column("geometric_ends", "chamfer between the ends", 4),
         column("program_ends", "token edits between the ends", 1), column("tokens", "tokens per program", 1)], rows,
        ["Each sequence: two latents drawn from N(0, I), decoded at `steps` evenly spaced points of the line between "
         "them, ends included (non-rejecting decoding). Geometric step: chamfer distance between consecutive "
         "executed shapes, each scaled to unit bounding-box diagonal and sampled (1,024 points) with the same seed, "
         "so equal shapes score 0. Program step: Levenshtein distance between the consecutive program texts' "
         "tokens (names, keywords, numbers to 3 decimals, punctuation), so each changed number is one edit. "
         "Structure step: the same on the programs with every number abstracted. Lower is smoother.",
         "The paper's Table 6 figures are not in the specification (it gives the protocol: 100 sequences of 100 "
         "steps), and its tokenisation is not specified: compare categories and models here, not values with the "
         "paper's.", f"Seed {args.seed}; the shipped models."]))
    return 0


def cmd_editability(args) -> int:
    """lines per program and the share of macro-like lines, of the val split and VAE samples

    Count the lines of the corpus val split's programs and of VAE samples per category: lines per program, per statement
    kind, the share of squeeze / reflect / translate lines and of the parts they make (ShapeAssembly Table 3).

    Example: vae editability --category chair table storage -n 300 --json edit.json"""
    rows = []
    for category, vae in _shipped_models(args):
        samples = [r.program for r in sample(vae, args.n, seed=args.seed, max_tries=EVALUATE_TRIES)]
        for name, progs in (("corpus val split", [p for _, p in corpus.load(category, "val")]),
                            (f"VAE samples (shipped {category} model)", samples)):
            rows.append({"category": category, "row": name, **mean_editability(progs)})
            r = rows[-1]
            print(f"{category}: {name}: {r['programs']} programs, {r['lines']:.1f} lines, {r['macro_lines']:.1f} % "
                  f"squeeze / reflect / translate lines, {r['macro_parts']:.1f} % of parts made by reflect / "
                  "translate")
    write_json(args, command_result(
        args, "Editability (ShapeAssembly Table 3)",
        [column("category", "category"), column("row", "programs of"), column("programs", "programs"),
         column("lines", "lines per program", 1), column("blocks", "blocks", 2),
         column("cuboid_lines", "Cuboid lines", 1), column("attach_lines", "attach lines", 1),
         column("squeeze_lines", "squeeze lines", 2), column("reflect_lines", "reflect lines", 2),
         column("translate_lines", "translate lines", 2),
         column("macro_lines", "% squeeze / reflect / translate lines", 1),
         column("macro_parts", "% parts made by reflect / translate", 1)], rows,
        ["Lines: statements over all blocks, each block's bbox line included (`shapeprog.vae.structure.editability`). "
         "Squeeze, reflect and translate are the language's macro-like lines: one line places a part between two "
         "others or copies it, where attach lines would spell it out. Parts: each block's non-bbox Cuboid lines "
         "plus the copies that reflect (1) and translate (n) make.",
         "The paper's Table 3 figures are not in the specification.",
         f"Samples: {args.n} per category, seed {args.seed}, validity-checked decoding with rejection (at most "
         f"{EVALUATE_TRIES} draws)."]))
    return 0


def register(sub) -> None:
    """Add the study commands to ``sub``."""
    nv = add_command(sub, "novelty", cmd_novelty, outputs={"json": "file"})
    add_category(nv, multiple=True)
    nv.add_argument("-n", type=int_at_least(1, MAX_SAMPLES), default=1000, help="samples per category")
    nv.add_argument("--max-tries", type=int_at_least(1, MAX_TRIES), default=EVALUATE_TRIES,
                    help="draws per sample before a sample is decoded without rejection")
    add_seed(nv, "seed of the latents")
    add_result_options(nv, "the novelty table", quiet=None)
    sm = add_command(sub, "smoothness", cmd_smoothness, outputs={"json": "file"})
    add_category(sm, multiple=True)
    sm.add_argument("--sequences", type=int_at_least(1, MAX_SEQUENCES), default=100, help="lines between latents")
    sm.add_argument("--steps", type=int_at_least(2, MAX_STEPS), default=100, help="decodes per line, ends included")
    add_seed(sm, "seed of the latents and the surface samples")
    add_result_options(sm, "the smoothness table", quiet="progress lines on stderr")
    ed = add_command(sub, "editability", cmd_editability, outputs={"json": "file"})
    add_category(ed, multiple=True)
    ed.add_argument("-n", type=int_at_least(1, MAX_SAMPLES), default=300, help="samples per category")
    add_seed(ed, "seed of the latents")
    add_result_options(ed, "the editability table", quiet=None)
