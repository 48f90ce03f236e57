"""Print a training run's validation curve (per epoch) from its TensorBoard event files, as markdown.

Every run of ``train.py`` alike: supervised runs and REINFORCE runs (validation reward, and the policy
entropy per counted step of the last training step logged), and the VAE and point-cloud runs (``val/mse``,
``val/fscore``; "-" where a validation did not compute a column). Below each table: the learning-rate
changes (when a ``LearningRateMonitor`` logged them) and the first and last logged policy entropy.

    python bench/training_curve.py runs/csgnet2d_small/version_0
    python bench/training_curve.py runs/rl_csgnet2d_small/version_0 --every 5
"""
from __future__ import annotations

import argparse
import shlex
import sys
from pathlib import Path


def curve(run: Path, every: int = 1) -> str:
    return _curve(run, every)[0]


def _curve(run: Path, every: int = 1) -> tuple[str, list[dict], list[str]]:
    """The markdown table, its rows as dicts (epoch, step, minutes, train_loss and the validation columns)
    and the validation columns' tags."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    ea = EventAccumulator(str(run), size_guidance={"scalars": 0})
    ea.Reload()
    tags = ea.Tags()["scalars"]
    epochs = {e.step: int(e.value) for e in ea.Scalars("epoch")} if "epoch" in tags else {}
    cols = [t for t in ("val/loss", "val/reward", "val/iou", "val/chamfer", "val/valid", "val/mse", "val/fscore") if t in tags]
    train = ea.Scalars("train/loss") if "train/loss" in tags else []
    entropy = ea.Scalars("train/entropy") if "train/entropy" in tags else []
    rows = {}
    for t in cols:
        for e in ea.Scalars(t):
            rows.setdefault(e.step, {})[t] = e.value
            rows[e.step]["wall"] = e.wall_time
    if not rows:
        raise SystemExit(f"{run}: no validation scalars")
    t0 = min([e.wall_time for e in train] + [r["wall"] for r in rows.values()])  # the first event logged
    extra = ["train/entropy"] if entropy else []
    head = "| epoch | step | minutes | train loss | " + " | ".join(extra + cols) + " |"
    lines = [head, "|" + "---|" * (4 + len(extra) + len(cols))]
    steps = sorted(rows)
    data = []
    for i, step in enumerate(steps):
        if i % every and i != len(steps) - 1:
            continue
        r = rows[step]
        tl = [e.value for e in train if e.step <= step]
        seen = [e.value for e in entropy if e.step <= step]
        ent = [f"{seen[-1] if seen else float('nan'):.3f}"] if entropy else []
        data.append({"epoch": epochs.get(step, ""), "step": step + 1, "minutes": (r["wall"] - t0) / 60,
                     "train_loss": tl[-1] if tl else None, **{t: r.get(t) for t in cols}})
        lines.append(f"| {epochs.get(step, '')} | {step + 1} | {(r['wall'] - t0) / 60:.1f} | "
                     f"{tl[-1] if tl else float('nan'):.3f} | "
                     + " | ".join(ent + [f"{r[t]:.4f}" if t in r else "-" for t in cols]) + " |")
    lines += _schedule(ea, tags, entropy)
    return "\n".join(lines), data, cols


def _schedule(ea, tags, entropy) -> list[str]:
    """The learning-rate changes (LearningRateMonitor's ``lr-*`` scalars) and the first and last logged
    policy entropy, at their TensorBoard steps."""
    out = []
    for tag in (t for t in tags if t.startswith("lr-")):
        changes, prev = [], None
        for e in ea.Scalars(tag):
            if e.value != prev:
                changes.append(f"{e.value:.3g} from step {e.step}")
                prev = e.value
        out.append(f"\n{tag}: " + ", ".join(changes))
    if entropy:
        out.append(f"\ntrain/entropy: {entropy[0].value:.3f} at step {entropy[0].step} (first logged), "
                   f"{entropy[-1].value:.3f} at step {entropy[-1].step} (last)")
    return out


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("runs", nargs="+")
    ap.add_argument("--every", type=int, default=1, help="print every N-th validation (and the last)")
    ap.add_argument("--out", default=None, help="also write the (first) run's curve as a result file (JSON)")
    ap.add_argument("--title", default=None, help="the result file's title (default: the run folder)")
    args = ap.parse_args(argv)
    command = "python " + shlex.join([sys.argv[0]] + (argv if argv is not None else sys.argv[1:]))
    for i, run in enumerate(args.runs):
        print(f"#### {run}\n")
        text, data, cols = _curve(Path(run), args.every)
        print(text)
        print()
        if args.out and i == 0:
            from shapeio.results import column, make_result, write_result

            columns = [column("epoch", "epoch"), column("step", "step"), column("minutes", "minutes", 1),
                       column("train_loss", "train loss", 3)] + [column(t, t, 4) for t in cols]
            result = make_result(args.title or f"Validation curve of {run}", columns, data, (), command)
            print(f"wrote {write_result(args.out, result)}")
    print("command: " + command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
