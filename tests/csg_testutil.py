"""Random CSG programs for tests (vocabulary programs and arbitrary-parameter programs)."""

from __future__ import annotations

import random

from csgnet.lang import Draw, Op, Program
from csgnet.vocab import vocabulary

N_PARAMS = {"c": 3, "s": 3, "t": 3, "p": 4, "u": 4, "y": 5}


def random_program(rng: random.Random, dim: int, n_prims: int, vocab_only: bool = False,
                   lo: int = -12, hi: int = 76) -> Program:
    """A valid random postfix program with ``n_prims`` primitives."""
    kinds = "cst" if dim == 2 else "puy"
    vocab = vocabulary(dim)
    toks, depth, placed = [], 0, 0
    while placed < n_prims or depth > 1:
        if placed < n_prims and (depth < 2 or rng.random() < 0.5):
            if vocab_only:
                toks.append(vocab.decode([rng.randrange(vocab.num_primitives)]).tokens[0])
            else:
                k = rng.choice(kinds)
                n = N_PARAMS[k]
                n_pos = dim
                pos = [rng.randint(lo, hi) for _ in range(n_pos)]
                sizes = [rng.randint(0, 64) for _ in range(n - n_pos)]
                toks.append(Draw(k, tuple(pos + sizes)))
            depth += 1
            placed += 1
        else:
            toks.append(Op(rng.choice("+*-")))
            depth -= 1
    return Program(tuple(toks), dim)
