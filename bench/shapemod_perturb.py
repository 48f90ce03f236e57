"""ShapeMOD's perturbation study (the paper's Fig. 7), now the command ``python -m shapeprog macros
perturbation`` (``shapeprog.macros.perturb_study``); this script passes its arguments on to it.

    python bench/shapemod_perturb.py --category chair --n 500 --repeats 3 --json fig7.json \\
        --png docs/figures/shapemod_perturbation.png
"""
from __future__ import annotations

import sys

from shapeprog.__main__ import main as shapeprog_main


def main(argv=None) -> int:
    return shapeprog_main(["macros", "perturbation", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    raise SystemExit(main())
