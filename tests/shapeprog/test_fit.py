"""Fitting: the loss decreases, the result is a valid program in the corpus format."""
import pytest
import torch

import shapeprog
from shapeprog.lang import numbers, parse
from shapeprog.sampling import sample_surface

PROG = """Assembly Program_0 {
\tbbox = Cuboid(1.0, 1.0, 1.0, True)
\tProgram_1 = Cuboid(0.6, 0.3, 0.6, True)
\tcube1 = Cuboid(0.1, 0.6, 0.1, False)
\tattach(Program_1, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)
\tsqueeze(cube1, bbox, Program_1, bot, 0.3, 0.3)
\treflect(cube1, X)
}
Assembly Program_1 {
\tbbox = Cuboid(0.6, 0.3, 0.6, True)
\tcube0 = Cuboid(0.6, 0.1, 0.6, True)
\tattach(cube0, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)
}
"""


def test_fit_recovers_a_stretched_shape_and_writes_corpus_text():
    p = parse(PROG)
    g = torch.Generator().manual_seed(0)
    target_prog = parse(PROG.replace("Cuboid(0.6, 0.3, 0.6, True)", "Cuboid(0.7, 0.3, 0.6, True)")
                        .replace("Cuboid(0.6, 0.1, 0.6, True)", "Cuboid(0.7, 0.1, 0.6, True)"))
    with torch.no_grad():
        target, _ = sample_surface(shapeprog.execute(target_prog).corners, 4096, generator=g)
    r = shapeprog.fit(p, target, steps=40, lr=1e-2, reg=1e-4, samples=1024, target_samples=1024, generator=g)
    assert len(r.losses) == 40 and sum(r.chamfer[-5:]) < sum(r.chamfer[:5])
    q = parse(r.text)
    assert q == r.program and len(q.blocks) == 2
    vals = numbers(q)
    assert all(round(v, 3) == v for v in vals)
    # the sub-program's bbox line keeps repeating its Program_1 line
    assert q.blocks[1].statements[0].l == q.root.statements[1].l
    assert q.blocks[1].statements[1].l > 0.62  # the table top widened towards 0.7
    # the squeeze's u, v stay in [0, 1]
    assert all(0.0 <= v <= 1.0 for v in (q.root.statements[4].u, q.root.statements[4].v))


def test_fit_zero_steps_returns_the_program_and_checks_points():
    p = parse(PROG)
    r = shapeprog.fit(p, torch.zeros(10, 3), steps=0)
    assert r.program == p and r.text == PROG and r.losses == []
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        shapeprog.fit(p, torch.zeros(10, 2))


def test_a_step_that_breaks_execution_is_undone_and_the_fit_stops_there(monkeypatch):
    """A step that moves the numbers where the program no longer executes to finite cuboids (seen on decoded
    programs whose rotated cuboids have two attachments) is undone: the result is the numbers before it."""
    from shapeprog.errors import ExecutionError
    from shapeprog.execute import ExecutionPlan

    p = parse(PROG)
    g = torch.Generator().manual_seed(0)
    with torch.no_grad():
        target, _ = sample_surface(shapeprog.execute(p).corners * 1.1, 2048, generator=g)
    kw = dict(lr=1e-2, samples=512, target_samples=512)
    four = shapeprog.fit(p, target, steps=4, generator=torch.Generator().manual_seed(1), **kw)
    assert four.stopped is None
    run = ExecutionPlan.run
    calls = []

    def breaks_at_the_sixth_run(self, params):
        calls.append(1)
        if len(calls) == 6:
            raise ExecutionError("execution gives a non-finite cuboid (created by this line)", 10)
        return run(self, params)

    monkeypatch.setattr(ExecutionPlan, "run", breaks_at_the_sixth_run)
    r = shapeprog.fit(p, target, steps=20, generator=torch.Generator().manual_seed(1), **kw)
    assert r.stopped == ("step 5 of 20 undone and the fit stopped: line 10: execution gives a non-finite cuboid "
                         "(created by this line)")
    assert len(r.losses) == 5 and r.losses[:4] == four.losses
    assert torch.equal(r.params, four.params) and r.text == four.text
    # the last update is executed too before it is returned
    calls.clear()
    last = shapeprog.fit(p, target, steps=5, generator=torch.Generator().manual_seed(1), **kw)
    assert last.stopped.startswith("step 5 of 5 undone and the fit stopped: line 10")
    assert len(last.losses) == 5 and torch.equal(last.params, four.params)
    # the starting program itself: the error is raised
    calls.clear()
    calls.extend([1] * 5)
    with pytest.raises(ExecutionError, match="line 10"):
        shapeprog.fit(p, target, steps=3, **kw)
