"""The rules of semantic validity that decoding applies to every line (spec section (d), "Decoding with
semantic validity": the reference's ``sem_valid.semValidGen``).

Each rule is a function of the decoder's logits and of a :class:`NodeState` (the block written so far), so
that it can be tested on its own:

* :func:`allowed_commands`: the command masks of each mode (plus the 10-Cuboid-line limit);
* :func:`clean_cuboid`, :func:`choose_attach`, :func:`clean_attach`, :func:`choose_reflect`,
  :func:`choose_reflect_axis`, :func:`choose_translate`, :func:`clean_translate`, :func:`choose_squeeze`,
  :func:`choose_squeeze_face`: the cuboid, coordinate, axis and face rules;
* :func:`try_line`: executes a candidate line on a copy of the block (:class:`~shapeprog.vae.local.LocalProgram`)
  and refuses it unless every moved or new cuboid stays inside 1.5x the bbox;
* :func:`remove_ungrounded`: drops the Cuboid lines that nothing attached, with their slots renumbered.

A refused line raises :class:`InvalidSample`. The decoding loop that calls these rules is
:mod:`shapeprog.vae.decode`; where the rules follow the reference code, where the paper, and the decisions
the specification leaves open: ``docs/shapeassembly_vae.md`` ("Decoding with semantic validity").
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterable, Sequence

from .. import limits
from ..lang import AXES, FACES
from .local import LocalProgram
from .vectors import MIN_DIM
from .vectors import (ALIGNED, ATTACH, AXIS, COMMANDS, COUNT, CUBE1, CUBE2, CUBE3, DIMS, DIST, FACE, LINE_DIM,
                      MAX_CUBOID_LINES, NUM_SLOTS, UV)

__all__ = [
    "ATTACH_CMD",
    "CUBOID",
    "MIN_DIM",
    "REFLECT",
    "SQUEEZE",
    "START",
    "STOP",
    "TRANSLATE",
    "ATTACH_MODE",
    "CUBOID_MODE",
    "DecodeOptions",
    "FORBIDDEN",
    "InvalidSample",
    "Line",
    "NodeState",
    "START_MODE",
    "SYM_MODE",
    "allowed_commands",
    "argmax_allowed",
    "choose_attach",
    "choose_reflect",
    "choose_reflect_axis",
    "choose_squeeze",
    "choose_squeeze_face",
    "choose_translate",
    "clean_attach",
    "clean_cuboid",
    "clean_translate",
    "line_vector",
    "remove_ungrounded",
    "try_line",
]

#: Command indices (the one-hot order of :data:`~shapeprog.vae.vectors.COMMANDS`).
START, CUBOID, ATTACH_CMD, REFLECT, TRANSLATE, SQUEEZE, STOP = map(
    COMMANDS.index, ("start", "Cuboid", "attach", "reflect", "translate", "squeeze", "stop"))
#: Decoding modes: what the last accepted line was (they select the command masks).
START_MODE, CUBOID_MODE, ATTACH_MODE, SYM_MODE = "start", "cuboid", "attach", "sym"
#: Commands forbidden in each mode (the reference's ``bad_inds``).
FORBIDDEN = {
    START_MODE: (),
    CUBOID_MODE: (START, REFLECT, TRANSLATE),
    ATTACH_MODE: (START, CUBOID),
    SYM_MODE: (START, CUBOID, ATTACH_CMD, SQUEEZE),
}
_TOP_BOT = (FACES.index("top"), FACES.index("bot"))


class InvalidSample(Exception):
    """A decoded line that breaks a rule of semantic validity.

    Raised by the rule functions, and by :func:`decode_latent` with ``reject=True`` (the whole sample is
    refused, as the reference's rejection sampling does).

    Attributes:
        reason: what was wrong, e.g. ``"attach: no grounded cuboid to attach to"``.
        node: index of the program node (breadth first, root 0) being decoded, when known.
        step: the decoder step within that node (0-based), when known.
    """

    def __init__(self, reason: str, node: int | None = None, step: int | None = None):
        self.reason, self.node, self.step = reason, node, step
        where = "" if node is None else f"node {node}, step {step}: "
        super().__init__(where + reason)




@dataclass(frozen=True)
class DecodeOptions:
    """The options of :func:`decode_latent` (keyword arguments; the defaults follow the reference code).

    Attributes:
        max_lines: decoder steps per node, refused lines included (reference 100).
        max_nodes: nodes decoded per program (reference: it stops after more than 10, i.e. 11); a
            sub-program beyond them is written as a leaf cuboid.
        max_refeed: a refused line re-feeds the previous input; every ``max_refeed``-th refused line of a
            node feeds the refused line instead (reference 10).
        bbox_margin: a line is refused unless every cuboid it moves or creates has its axis-aligned box
            strictly inside ``bbox_margin`` times the bbox's (reference code 1.5, paper 1.1).
        bbox_attach: ``"snap"`` (reference code): the target height y2 of an attach to bbox snaps,
            (0.1, 0.5] to 0.1 and [0.5, 0.9) to 0.9; ``"tolerance"`` (paper): the line is refused unless
            y2 is within ``bbox_tolerance`` of the bottom (0) or the top (1).
        bbox_tolerance: the paper's allowable error (0.05).
        max_cuboid_lines: Cuboid lines per node, bbox included (10, the line vector's limit; the
            reference has none).
    """

    max_lines: int = 100
    max_nodes: int = 11
    max_refeed: int = 10
    bbox_margin: float = 1.5
    bbox_attach: str = "snap"
    bbox_tolerance: float = 0.05
    max_cuboid_lines: int = MAX_CUBOID_LINES

    def __post_init__(self):
        for name in ("max_lines", "max_nodes", "max_refeed"):
            v = getattr(self, name)
            if not isinstance(v, int) or isinstance(v, bool) or v < 1:
                raise ValueError(f"{name} must be a positive integer, got {v!r}")
        if not isinstance(self.max_cuboid_lines, int) or not 1 <= self.max_cuboid_lines <= MAX_CUBOID_LINES:
            raise ValueError(f"max_cuboid_lines must be an integer in [1, {MAX_CUBOID_LINES}], "
                             f"got {self.max_cuboid_lines!r}")
        if not (isinstance(self.bbox_margin, (int, float)) and math.isfinite(self.bbox_margin)
                and self.bbox_margin > 0):
            raise ValueError(f"bbox_margin must be a positive number, got {self.bbox_margin!r}")
        if self.bbox_attach not in ("snap", "tolerance"):
            raise ValueError(f"bbox_attach must be 'snap' or 'tolerance', got {self.bbox_attach!r}")
        if not (isinstance(self.bbox_tolerance, (int, float)) and 0 <= self.bbox_tolerance < 0.5):
            raise ValueError(f"bbox_tolerance must be a number in [0, 0.5), got {self.bbox_tolerance!r}")


# ----------------------------------------------------------------------------- lines and node state


@dataclass(frozen=True)
class Line:
    """One decoded line in slot form (cuboids are slots: 0 bbox, j = the j-th Cuboid line).

    Attributes:
        cmd: the command index (1 Cuboid, 2 attach, 3 reflect, 4 translate, 5 squeeze, 6 stop).
        cubes: the slots it names: (a, b) for attach, (a, b, c) for squeeze, (a,) for reflect/translate.
        nums: Cuboid dims (3), attach coordinates (6), squeeze (u, v) or translate (d,).
        axis: reflect/translate axis index (X, Y, Z), else -1.
        face: squeeze face index (right, left, top, bot, front, back), else -1.
        count: translate count.
        aligned: the Cuboid flag.
    """

    cmd: int
    cubes: tuple[int, ...] = ()
    nums: tuple[float, ...] = ()
    axis: int = -1
    face: int = -1
    count: int = 0
    aligned: bool = False


def line_vector(line: Line) -> list[float]:
    """The 63-entry line vector of ``line`` (the decoder's next input): one-hots and clean values."""
    v = [0.0] * LINE_DIM
    v[line.cmd] = 1.0
    for start, c in zip((CUBE1.start, CUBE2.start, CUBE3.start), line.cubes):
        v[start + c] = 1.0
    if line.cmd == CUBOID:
        v[DIMS] = line.nums
        v[ALIGNED] = float(line.aligned)
    elif line.cmd == ATTACH_CMD:
        v[ATTACH] = line.nums
    elif line.cmd in (REFLECT, TRANSLATE):
        v[AXIS.start + line.axis] = 1.0
        if line.cmd == TRANSLATE:
            v[COUNT], v[DIST] = float(line.count), line.nums[0]
    elif line.cmd == SQUEEZE:
        v[FACE.start + line.face] = 1.0
        v[UV] = line.nums
    return v


@dataclass
class NodeState:
    """The block being decoded, as the validity rules read it.

    Attributes:
        bbox_dims: (3,) float, the node's bbox dims (the upper clamp of its Cuboid lines).
        program: the local program executed so far (None before the bbox line).
        grounded: slots that have been moved by an attach or squeeze, and bbox (0).
        atts: per slot, the slots it was attached to or that were attached to it (with repeats).
        mode: the last accepted line's mode (:data:`START_MODE`, ...).
        cuboid_lines: Cuboid lines accepted, bbox included.
        copies: per slot, the reflect/translate copies made of it.
    """

    bbox_dims: tuple[float, float, float]
    program: LocalProgram | None = None
    grounded: set = field(default_factory=lambda: {0})
    atts: dict = field(default_factory=dict)
    mode: str = START_MODE
    cuboid_lines: int = 0
    copies: dict = field(default_factory=dict)

    @property
    def num_cubes(self) -> int:
        """Cuboids of the local program (bbox, Cuboid lines and macro copies): slots below are declared."""
        return 0 if self.program is None else len(self.program)

    def accept(self, line: Line, program: LocalProgram | None = None) -> None:
        """Record an accepted line (``program``: the local program after it, from :func:`try_line`)."""
        if program is not None:
            self.program = program
        c = line.cmd
        if c == CUBOID:
            if self.program is None:
                self.program = LocalProgram(line.nums)
            elif program is None:
                self.program.add_cuboid(line.nums, line.aligned)
            self.cuboid_lines += 1
            self.mode = CUBOID_MODE
        elif c in (ATTACH_CMD, SQUEEZE):
            a, *targets = line.cubes
            self.grounded.add(a)
            for t in targets:
                self.atts.setdefault(t, []).append(a)
            self.atts.setdefault(a, []).extend(targets)
            self.mode = ATTACH_MODE
        elif c in (REFLECT, TRANSLATE):
            a = line.cubes[0]
            self.copies[a] = self.copies.get(a, 0) + (1 if c == REFLECT else line.count)
            self.mode = SYM_MODE


# ----------------------------------------------------------------------------- rules


def argmax_allowed(logits: Sequence[float], allowed: Iterable[int]) -> int | None:
    """The allowed index with the largest logit (the first on ties), None when nothing is allowed."""
    best = None
    for i in allowed:
        if best is None or logits[i] > logits[best]:
            best = i
    return best


def allowed_commands(state: NodeState, max_cuboid_lines: int = MAX_CUBOID_LINES) -> list[int]:
    """The commands the decoder may emit next: those not forbidden by the mode (the reference subtracts
    1000 from their logits), and no Cuboid line once the node has ``max_cuboid_lines``."""
    bad = set(FORBIDDEN[state.mode])
    if state.cuboid_lines >= max_cuboid_lines:
        bad.add(CUBOID)
    return [c for c in range(7) if c not in bad]


def clean_cuboid(dims: Sequence[float], align_logit: float, bbox_dims: Sequence[float]) -> tuple[tuple, bool]:
    """A Cuboid line's dims clamped to [0.01, the node's bbox dims] and its aligned flag (logit > 0)."""
    return tuple(min(max(float(d), MIN_DIM), float(b)) for d, b in zip(dims, bbox_dims)), float(align_logit) > 0.0


def _bad_pair(atts: dict, a: int, b: int) -> bool:
    """Whether attaching ``a`` to ``b`` repeats a pair: a to itself, a to a cuboid it is already attached
    to (bbox excepted), or a to bbox a third time."""
    done = atts.get(a, ())
    return a == b or (b != 0 and b in done) or (b == 0 and done.count(0) >= 2)


def _pick_pair(cube: Sequence[float], state: NodeState, what: str) -> tuple[int, int]:
    """Cube-1 and cube-2 of an attach or squeeze: cube-1 declared and not bbox, cube-2 declared and
    grounded; a repeated pair knocks down the lower of the two logits until the pair is new."""
    n = min(state.num_cubes, NUM_SLOTS)
    ok1 = [i for i in range(1, n)]
    ok2 = [i for i in range(n) if i in state.grounded]
    l1, l2 = cube[0:NUM_SLOTS], cube[NUM_SLOTS:2 * NUM_SLOTS]
    a, b = argmax_allowed(l1, ok1), argmax_allowed(l2, ok2)
    while a is not None and b is not None and _bad_pair(state.atts, a, b):
        if l1[a] < l2[b]:
            ok1.remove(a)
            a = argmax_allowed(l1, ok1)
        else:
            ok2.remove(b)
            b = argmax_allowed(l2, ok2)
    if a is None:
        raise InvalidSample(f"{what}: no declared cuboid to move")
    if b is None:
        raise InvalidSample(f"{what}: no grounded cuboid to attach cube{a - 1} to")
    return a, b


def choose_attach(cube: Sequence[float], state: NodeState) -> tuple[int, int]:
    """The slots of an attach line from the 33 cube logits (the reference's ``getSVAtt``).

    Raises:
        InvalidSample: no allowed pair is left.
    """
    return _pick_pair(cube, state, "attach")


def clean_attach(coords: Sequence[float], target: int, mode: str = "snap", tolerance: float = 0.05) -> tuple:
    """Attach coordinates clamped to [0, 1]; when the target is bbox, the height y2 either snaps
    (``"snap"``: (0.1, 0.5] -> 0.1, [0.5, 0.9) -> 0.9) or must be within ``tolerance`` of 0 or 1
    (``"tolerance"``).

    Raises:
        InvalidSample: ``"tolerance"`` and y2 is mid-height on bbox.
    """
    c = [min(max(float(x), 0.0), 1.0) for x in coords]
    if target == 0:
        y = c[4]
        if mode == "snap":
            if 0.1 < y <= 0.5:
                c[4] = 0.1
            elif 0.5 <= y < 0.9:
                c[4] = 0.9
        elif tolerance < y < 1.0 - tolerance:
            raise InvalidSample(f"attach: target height {y:.3g} on bbox is neither its bottom nor its top")
    return tuple(c)


def choose_reflect(cube: Sequence[float], state: NodeState) -> int:
    """The slot of a reflect line (``getSVRefCube``): declared, grounded, not bbox and not entirely on
    the positive side (centre > 0 on all three axes); such a cuboid's logit is knocked down in turn.

    Raises:
        InvalidSample: no allowed cuboid is left.
    """
    n = min(state.num_cubes, NUM_SLOTS)
    ok = [i for i in range(1, n) if i in state.grounded and not all(x > 0.0 for x in state.program.boxes[i].pos)]
    a = argmax_allowed(cube[0:NUM_SLOTS], ok)
    if a is None:
        raise InvalidSample("reflect: no grounded cuboid with a centre on the negative side")
    return a


def choose_reflect_axis(axis_logits: Sequence[float], a: int, state: NodeState) -> int:
    """The reflect axis (``getSVRefAxis``): the most likely axis on which cuboid ``a``'s centre is <= 0
    (copies are made from the negative side).

    Raises:
        InvalidSample: no such axis.
    """
    pos = state.program.boxes[a].pos
    k = argmax_allowed(axis_logits, [j for j in range(3) if pos[j] <= 0.0])
    if k is None:
        raise InvalidSample("reflect: the cuboid is on the positive side of every axis")
    return k


def choose_translate(cube: Sequence[float], state: NodeState) -> int:
    """The slot of a translate line (``getSVTransCube``): declared, grounded and not bbox (the reference
    knocks the others down by 100 rather than 1000; they are never chosen here).

    Raises:
        InvalidSample: no allowed cuboid.
    """
    n = min(state.num_cubes, NUM_SLOTS)
    a = argmax_allowed(cube[0:NUM_SLOTS], [i for i in range(1, n) if i in state.grounded])
    if a is None:
        raise InvalidSample("translate: no grounded cuboid")
    return a


def clean_translate(count: float, d: float) -> tuple[int, float]:
    """Translate count ``max(round(count), 1)`` (at most :data:`shapeprog.limits.MAX_TRANSLATE_COPIES`)
    and distance ``d`` clamped to [0, 1]."""
    if not (math.isfinite(count) and math.isfinite(d)):
        raise InvalidSample("translate: non-finite count or distance")
    n = min(max(round(count), 1), limits.MAX_TRANSLATE_COPIES)
    return n, min(max(float(d), 0.0), 1.0)


def choose_squeeze(cube: Sequence[float], state: NodeState) -> tuple[int, int, int]:
    """The slots of a squeeze line (``getSVSqueezeCube``): cube-1 declared and not bbox; cubes 2 and 3
    declared and grounded; (cube-1, cube-2) with the attach pair rule, then (cube-1, cube-3) knocking
    down cube-3 only.

    Raises:
        InvalidSample: no allowed triple.
    """
    a, b = _pick_pair(cube, state, "squeeze")
    n = min(state.num_cubes, NUM_SLOTS)
    ok3 = [i for i in range(n) if i in state.grounded]
    l3 = cube[2 * NUM_SLOTS:3 * NUM_SLOTS]
    c = argmax_allowed(l3, ok3)
    while c is not None and _bad_pair(state.atts, a, c):
        ok3.remove(c)
        c = argmax_allowed(l3, ok3)
    if c is None:
        raise InvalidSample(f"squeeze: no grounded cuboid to squeeze cube{a - 1} against")
    return a, b, c


def choose_squeeze_face(face_logits: Sequence[float], b: int, c: int) -> int:
    """The squeeze face (``getSVSqueezeFace``): top or bot only when either target is bbox."""
    return argmax_allowed(face_logits, _TOP_BOT if 0 in (b, c) else range(6))


def try_line(state: NodeState, line: Line, margin: float = 1.5) -> LocalProgram:
    """Execute an attach, squeeze, reflect or translate ``line`` on a copy of the node's local program.

    Only the cuboids the line moves or creates are tested: every other cuboid was inside before (new
    Cuboid lines sit at the origin, no larger than the bbox), and a line changes no other cuboid.

    Returns:
        The local program after the line.

    Raises:
        InvalidSample: the line cannot execute, or a moved or new cuboid's axis-aligned box is not
            strictly inside ``margin`` times the bbox's (or is not finite).
    """
    trial = state.program.copy()
    c = line.cmd
    try:
        if c == ATTACH_CMD:
            changed = trial.attach(line.cubes[0], line.cubes[1], line.nums[:3], line.nums[3:])
        elif c == SQUEEZE:
            changed = trial.squeeze(*line.cubes, FACES[line.face], *line.nums)
        elif c == REFLECT:
            changed = trial.reflect(line.cubes[0], AXES[line.axis])
        elif c == TRANSLATE:
            changed = trial.translate(line.cubes[0], AXES[line.axis], line.count, line.nums[0])
        else:
            raise ValueError(f"command {c} is not executed on the local program")
    except (ArithmeticError, ValueError) as e:
        raise InvalidSample(f"the line does not execute ({e})") from None
    if not trial.inside(changed, margin):
        raise InvalidSample(f"the line takes a cuboid outside {margin:g}x the bbox")
    return trial


def remove_ungrounded(lines: Sequence[Line], grounded: set) -> tuple[list[Line], list[int]]:
    """Drop the Cuboid lines whose slot was never grounded (bbox always stays) and renumber the slots of
    the other lines; a line naming a dropped slot is dropped too (the reference's ``cuboid_line_clean``).

    Returns:
        (the kept lines: Cuboid lines first, then the others in order; the old slot of each kept
        Cuboid line).
    """
    kept, ri = [], 0
    for ln in lines:
        if ln.cmd == CUBOID:
            if ri in grounded:
                kept.append(ri)
            ri += 1
    new = {old: k for k, old in enumerate(kept)}
    out = [ln for ln in lines if ln.cmd == CUBOID]
    out = [out[i] for i in kept]
    for ln in lines:
        if ln.cmd == CUBOID:
            continue
        if any(c not in new for c in ln.cubes):
            continue
        out.append(Line(ln.cmd, tuple(new[c] for c in ln.cubes), ln.nums, ln.axis, ln.face, ln.count, ln.aligned))
    return out, kept
