"""Long fuzzing runs of every registered target (docs/fuzzing.md).

    python bench/fuzz.py --minutes 10              # the time is shared by the targets
    python bench/fuzz.py --minutes 1 --only csg/npy --out fuzz_findings

Prints inputs per second and findings per target; writes each finding's input under ``--out``.
"""

from __future__ import annotations

import argparse
import hashlib
import sys
from pathlib import Path

# the targets live with the tests; this script's own folder leaves the path so that `fuzz` is that package
_ROOT = Path(__file__).resolve().parents[1]
sys.path[0:1] = [str(_ROOT / "tests"), str(_ROOT)]

from fuzz import registry  # noqa: E402
from fuzz.engine import fuzz  # noqa: E402

from shapeio import atomic_write  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description="Fuzz every registered parser and loader.")
    ap.add_argument("--minutes", type=float, default=1.0, help="total minutes, shared by the targets")
    ap.add_argument("--only", nargs="*", default=None, help="target names to run (default: all)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the mutator")
    ap.add_argument("--out", default=None, help="folder for the inputs of findings")
    args = ap.parse_args(argv)
    targets = [t for t in registry.targets() if not args.only or t.name in args.only]
    if not targets:
        raise SystemExit("error: no target selected")
    per = 60.0 * args.minutes / len(targets)
    print("| target | inputs | inputs/s | findings |\n|---|---:|---:|---:|")
    found = 0
    for t in targets:
        stats = fuzz(t, seconds=per, seed=args.seed)
        print(f"| {t.name} | {stats.inputs} | {stats.rate:.0f} | {len(stats.findings)} |", flush=True)
        for f in stats.findings:
            print(f"    {f.kind}: {f.detail}", file=sys.stderr)
            if args.out:  # named by the input's hash: a later run adds its findings, never replaces one
                digest = hashlib.sha256(f.data).hexdigest()[:16]
                path = Path(args.out) / f"{t.name.replace('/', '_')}_{digest}.bin"
                if not path.exists():
                    atomic_write(path, f.data, mkdir=True)
        found += len(stats.findings)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
