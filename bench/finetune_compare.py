"""Compare fine-tuning runs (REINFORCE, self-training) by a validation scalar against wall-clock time.

Reads each run's TensorBoard event files and prints, per run, the validation curve against the minutes since
the run's logger started, the best value and when it was first reached; with ``--png`` it draws the curves
in one plot. Runs to compare should share the machine alike (started together, same priority and threads).

    python bench/finetune_compare.py runs/rl_csgnet2d_small/version_0 runs/st_csgnet2d_small/version_0 \\
        --labels REINFORCE self-training --tag val/chamfer --png docs/figures/finetune_compare.png
"""
from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path

from shapeio.files import atomic_write


def load(run: Path, tag: str) -> list[tuple[float, float]]:
    """``(minutes since the logger started, value)`` of every ``tag`` event of ``run``, in order."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(run), size_guidance={"scalars": 0})
    ea.Reload()
    if tag not in ea.Tags()["scalars"]:
        raise SystemExit(f"{run}: no {tag!r} scalars (has: {', '.join(ea.Tags()['scalars'])})")
    t0 = ea.FirstEventTimestamp()
    return [((e.wall_time - t0) / 60.0, float(e.value)) for e in ea.Scalars(tag)]


def best(points, lower_is_better: bool):
    """``(value, minutes)`` of the best value, at the first time it was reached."""
    key = (lambda p: (p[1], p[0])) if lower_is_better else (lambda p: (-p[1], p[0]))
    m, v = min(points, key=key)
    return v, m


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("runs", nargs="+", type=Path, help="TensorBoard run folders (runs/<name>/version_N)")
    ap.add_argument("--labels", nargs="+", help="one label per run (default: the folder names)")
    ap.add_argument("--tag", default="val/chamfer")
    ap.add_argument("--higher-is-better", action="store_true", help="for tags such as val/reward, val/iou")
    ap.add_argument("--png", type=Path, help="write the plot here (needs matplotlib)")
    args = ap.parse_args(argv)
    labels = args.labels or [r.parent.name for r in args.runs]
    if len(labels) != len(args.runs):
        ap.error("give one label per run")
    print("command: python bench/finetune_compare.py " + " ".join(shlex.quote(a) for a in (argv or sys.argv[1:])))
    curves = {lab: load(run, args.tag) for lab, run in zip(labels, args.runs)}
    for lab, pts in curves.items():
        v, m = best(pts, not args.higher_is_better)
        print(f"\n{lab}: best {args.tag} {v:.4f} first reached at {m:.1f} min; "
              f"{len(pts)} validations over {pts[-1][0]:.1f} min")
        print(f"| minutes | {args.tag} |\n|---|---|")
        for m, v in pts:
            print(f"| {m:.1f} | {v:.4f} |")
    if args.png:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6, 4), dpi=100)
        for lab, pts in curves.items():
            ax.plot([p[0] for p in pts], [p[1] for p in pts], marker="o", ms=3, label=lab)
        ax.set_xlabel("wall-clock minutes")
        ax.set_ylabel(args.tag)
        ax.grid(alpha=0.3)
        ax.legend()
        fig.tight_layout()
        args.png.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(args.png, lambda f: fig.savefig(f, format="png"))
        print(f"\nwrote {args.png}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
