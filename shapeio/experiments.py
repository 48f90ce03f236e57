"""The papers' experiments as a list: one id per table or study, its status, and the commands that rebuild it.

Each system keeps its list (:mod:`csgnet.paper.experiments`, :mod:`shapeprog.paper`); both command lines
read it through :func:`register`:

    python -m csgnet paper --list                 one line per experiment: ID STATUS description
    python -m csgnet paper run csg-t3             the full protocol; writes the result file the docs show
    python -m csgnet paper run csg-t3 --quick     a scaled-down run (minutes), written under paper_output/

An experiment's steps are command lines of the package's own ``main``; a step whose ``creates`` path exists is
skipped (the data a protocol needs is generated once). ``{out}`` in a step stands for the result file.
"""
from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

from .results import column, make_result, write_result

__all__ = ["STATUSES", "Step", "Experiment", "check_experiments", "listing", "list_result", "register", "QUICK_DIR"]

#: What an experiment's status may be: built and reproducing its table, built in part, not built, or
#: impossible here (the reason says why).
STATUSES = ("done", "partial", "not-built", "impossible")
#: Where ``paper run ID --quick`` writes its result unless ``--out`` says otherwise.
QUICK_DIR = "paper_output"


@dataclass(frozen=True)
class Step:
    """One command line (``argv`` of the package's ``main``), skipped when ``creates`` exists already."""
    argv: tuple[str, ...]
    creates: str | None = None

    def text(self, prog: str, out: str) -> str:
        return " ".join([prog, *(shlex.quote(a.replace("{out}", out)) for a in self.argv)])

    @classmethod
    def of(cls, words: str, result: bool = True, creates: str | None = None) -> "Step":
        """A step from its command's words (split on spaces), followed by ``--json {out} --overwrite`` when it
        writes the experiment's result file (``result``)."""
        return cls((*words.split(), *(("--json", "{out}", "--overwrite") if result else ())), creates)


@dataclass(frozen=True)
class Experiment:
    """A table or study of a paper: ``id``, ``status`` (:data:`STATUSES`), a one-line ``description``, the
    full protocol's ``steps`` writing ``result``, the scaled-down ``quick`` steps, and ``why`` (what is
    missing for ``partial`` / ``not-built``, or why it is ``impossible``)."""
    id: str
    status: str
    description: str
    result: str | None = None
    steps: tuple[Step, ...] = ()
    quick: tuple[Step, ...] = ()
    why: str = ""
    scale: str = field(default="", compare=False)

    @property
    def runnable(self) -> bool:
        return bool(self.steps)


def check_experiments(experiments: Sequence[Experiment]) -> None:
    """Refuse a malformed list (distinct ids, known statuses, a reason where one is due, steps where runnable)."""
    seen = set()
    for e in experiments:
        if e.id in seen:
            raise ValueError(f"experiment {e.id!r} is listed twice")
        seen.add(e.id)
        if e.status not in STATUSES:
            raise ValueError(f"experiment {e.id!r}: unknown status {e.status!r} (expected {', '.join(STATUSES)})")
        if e.status != "done" and not e.why:
            raise ValueError(f"experiment {e.id!r} is {e.status} and needs a reason")
        if e.status in ("done", "partial") and not (e.steps and e.quick and e.result):
            raise ValueError(f"experiment {e.id!r} is {e.status} and needs steps, quick steps and a result file")


def listing(experiments: Sequence[Experiment], verbose: bool = False, prog: str = "") -> str:
    """``ID STATUS description`` lines (with the reason after ``--``; ``verbose`` adds the commands)."""
    width = max(len(e.id) for e in experiments)
    lines = []
    for e in experiments:
        line = f"{e.id:<{width}}  {e.status:<10}  {e.description}"
        if e.why:
            line += f" -- {e.why}"
        lines.append(line)
        if verbose and e.steps:
            lines += [f"{'':<{width}}    $ {s.text(prog, e.result or '')}" for s in e.steps]
            if e.scale:
                lines.append(f"{'':<{width}}    scale: {e.scale}")
    return "\n".join(lines)


def list_result(experiments: Sequence[Experiment], prog: str, path: str) -> dict:
    """The list as a result file's content (:mod:`shapeio.results`): id, status, description, reason, result."""
    rows = [{"id": e.id, "status": e.status, "description": e.description, "why": e.why or "",
             "result": e.result or "", "scale": e.scale or ""} for e in experiments]
    cols = [column("id", "id"), column("status", "status"), column("description", "experiment"),
            column("scale", "scale"), column("why", "what is missing or why not"), column("result", "result file")]
    return make_result("The paper's experiments", cols, rows,
                       [f"`{prog} paper run ID` rebuilds an experiment's result file (`--quick`: a check in minutes)."],
                       command=f"{prog} paper --list --json {path}")


def register(sub, experiments: Sequence[Experiment], main: Callable[[list[str]], int], prog: str) -> None:
    """Add the ``paper`` command (``--list``, ``run ID [--quick] [--out FILE]``) to a sub-parser set."""
    check_experiments(experiments)
    ids = [e.id for e in experiments]
    p = sub.add_parser("paper", help="the papers' experiments: list them, or rebuild one's table",
                       description="The papers' experiments. `paper --list` prints ID STATUS description; "
                                   "`paper run ID` runs the full protocol and writes its result file; "
                                   "`--quick` runs a scaled-down version.",
                       epilog=f"example: {prog} paper run {ids[0]} --quick")
    p.add_argument("--list", action="store_true", help="print one line per experiment (the default)")
    p.add_argument("--verbose", action="store_true", help="with --list: print each experiment's commands too")
    p.add_argument("action", nargs="?", choices=["run"], help="run an experiment")
    p.add_argument("id", nargs="?", metavar="ID", help=f"the experiment ({', '.join(ids)})")
    p.add_argument("--quick", action="store_true", help="the scaled-down protocol (minutes on a 2-core CPU)")
    p.add_argument("--out", default=None,
                   help=f"the result file (default: the docs' file, or {QUICK_DIR}/ID.json with --quick)")
    p.add_argument("--dry-run", action="store_true", help="print the commands without running them")
    p.add_argument("--json", default=None, metavar="FILE",
                   help="with --list: also write the list as a result file (shapeio.results; the docs show it)")

    def run(args) -> int:
        if args.action is None:
            if args.id is not None:
                p.error("give 'run ID' to run an experiment, or --list")
            print(listing(experiments, args.verbose, prog))
            if args.json:
                print(f"wrote {write_result(args.json, list_result(experiments, prog, args.json))}")
            return 0
        if args.id is None:
            p.error("'run' needs an experiment ID (see --list)")
        by_id = {e.id: e for e in experiments}
        if args.id not in by_id:
            p.error(f"unknown experiment {args.id!r}; expected one of {', '.join(ids)}")
        e = by_id[args.id]
        if not e.runnable:
            print(f"error: {e.id} is {e.status}: {e.why}", file=sys.stderr)
            return 2
        steps = e.quick if args.quick else e.steps
        out = args.out or (str(Path(QUICK_DIR) / f"{e.id}.json") if args.quick else e.result)
        for step in steps:
            if step.creates and Path(step.creates).exists():
                print(f"[{e.id}] {step.creates} exists: skipping `{step.text(prog, out)}`", flush=True)
                continue
            print(f"[{e.id}] $ {step.text(prog, out)}", flush=True)
            if args.dry_run:
                continue
            rc = main([a.replace("{out}", out) for a in step.argv])
            if rc:
                print(f"error: {e.id}: the step `{step.text(prog, out)}` failed (exit {rc})", file=sys.stderr)
                return rc
        if not args.dry_run:
            print(f"[{e.id}] wrote {out}")
        return 0

    p.set_defaults(func=run, parser=p)

