"""Executor tests: hand-computed programs per rule, invariants, gradients, corpus sample."""
import math

import pytest
import torch

from shapeprog.errors import ExecutionError
from shapeprog.execute import ExecutionPlan, execute, execute_batch, parameter_names, program_parameters
from shapeprog.lang import parse

FACES = {"right": (0, 1.0), "left": (0, 0.0), "top": (1, 1.0), "bot": (1, 0.0), "front": (2, 1.0), "back": (2, 0.0)}


def flat(*lines):
    return parse("\n".join(lines) + "\n")


def point(center, dims, coords):
    """Global point of local coords on an axis-aligned box (independent of the executor)."""
    return [c + (x - 0.5) * d for c, d, x in zip(center, dims, coords)]


def close(a, b, tol=1e-5):
    return torch.allclose(torch.as_tensor(a, dtype=torch.float64), torch.as_tensor(b, dtype=torch.float64), atol=tol)


def local_point(s, i, coords):
    """Global point of local coords on leaf i of an executed shape."""
    c = torch.tensor(coords, dtype=s.dims.dtype)
    return s.centers[i] + ((c - 0.5) * s.dims[i]) @ s.axes[i]


def corner_set(c):
    return sorted(tuple(round(float(x), 5) for x in p) for p in c.reshape(-1, 3))


# ----------------------------------------------------------------------------- first


def test_first_attach_translates_point_onto_target():
    p = flat("bbox = Cuboid(2.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.5, 0.2, 0.4, True)",
             "attach(cube0, bbox, 0.0, 0.0, 1.0, 0.25, 0.0, 0.5)")
    s = execute(p, dtype=torch.float64)
    # point (0,0,1) of cube0 goes to bbox point (0.25, 0, 0.5) = (-0.5, -0.5, 0.0)
    assert close(s.centers[0], [-0.5 + 0.25, -0.5 + 0.1, 0.0 - 0.2])
    assert close(s.dims[0], [0.5, 0.2, 0.4]) and close(s.axes[0], torch.eye(3))
    assert s.line.tolist() == [1] and s.node.tolist() == [0] and close(s.root_dims, [2.0, 1.0, 1.0])


# ----------------------------------------------------------------------------- second

# A non-aligned post 0.5 high whose bottom and then top are attached to the bbox's: the second
# attach (the second rule) stretches it to height 1. A third attach runs the general rule.
POST = ("bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.1, 0.5, 0.1, False)",
        "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)",
        "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)")


def test_second_attach_stretches_along_height():
    s = execute(flat(*POST), dtype=torch.float64)
    # |(0,.5,0) + s(0,1,0)| = 1  ->  s = 0.5: height 1.0, bottom stays at -0.5
    assert close(s.dims[0], [0.1, 1.0, 0.1]) and close(s.centers[0], [0.0, 0.0, 0.0])


def test_second_attach_stretches_and_rotates_onto_target():
    s = execute(flat(*POST[:3], "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.7, 1.0, 0.5)"), dtype=torch.float64)
    h = math.sqrt(0.2 ** 2 + 1.0)  # grows to the distance between the two targets
    assert close(s.dims[0], [0.1, h, 0.1])
    assert close(local_point(s, 0, [0.5, 0.0, 0.5]), [0.0, -0.5, 0.0])
    assert close(local_point(s, 0, [0.5, 1.0, 0.5]), [0.2, 0.5, 0.0])
    assert close(s.axes[0][1], torch.tensor([0.2, 1.0, 0.0], dtype=torch.float64) / h)
    assert close(s.axes[0] @ s.axes[0].T, torch.eye(3)) and close(torch.linalg.det(s.axes[0]), 1.0)


def test_second_attach_counts_target_records():
    # cube1 is first the *target* of cube0; that record counts, so cube1's own first attach
    # already uses the second rule: it stretches (keeping its top where cube0 sits) instead
    # of translating.
    p = flat("bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.2, 0.2, 0.2, True)",
             "cube1 = Cuboid(0.1, 0.5, 0.1, False)",
             "attach(cube0, cube1, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)",
             "attach(cube1, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)")
    s = execute(p, dtype=torch.float64)
    # |(0,-.5,0) + s(0,-1,0)| = 0.75  ->  s = 0.25
    assert close(s.dims[1], [0.1, 0.75, 0.1]) and close(s.centers[1], [0.0, -0.125, 0.0])


def test_general_rule_scales_the_best_matching_free_dimension():
    # third attach of a non-aligned cuboid: two colinear records (bottom and top), so orient is
    # skipped (the target is already in the rotation plane) and maybeScale widens the length:
    # d = 1 / |cv_x(src) - cv_x(bottom)| = 2, s = |t . x| = 0.15, length += 0.3.
    s = execute(flat(*POST, "attach(cube0, bbox, 1.0, 0.5, 0.5, 0.7, 0.5, 0.5)"), dtype=torch.float64)
    assert close(s.dims[0], [0.4, 1.0, 0.1]) and close(s.centers[0], [0.0, 0.0, 0.0])
    assert close(local_point(s, 0, [1.0, 0.5, 0.5]), [0.2, 0.0, 0.0])


def _general_rotation_program(cx, cz):
    """A vertical post (bottom and top attached) whose front-face centre is then attached to the
    bbox point (cx, 0, cz): a third attach of a non-aligned cuboid, i.e. the general rule."""
    return flat(*POST, f"attach(cube0, bbox, 0.5, 0.5, 1.0, {0.5 + cx}, 0.5, {0.5 + cz})")


def test_general_rule_orients_about_the_colinear_axis():
    # After two attaches the post is 1 high, centred at the origin; records at (0,-.5,0), (0,.5,0)
    # are colinear along y. Front-face centre b = (0, 0, .05), target c = (.03, 0, .04):
    # projected on the plane through b normal to y, a_p = (0,0,0), fn = b, noc = c, s = |c|/|b| - 1 = 0,
    # angle = acos(fn.noc / .05^2) = acos(.8). The turn about -y does not map fn onto noc, so the
    # rule turns about +y: front (0,0,1) -> (.6,0,.8), right (1,0,0) -> (.8,0,-.6), up unchanged,
    # about the centre (the records' axis). Then b = c: maybeScale stops.
    s = execute(_general_rotation_program(0.03, 0.04), dtype=torch.float64)
    assert close(s.axes[0], [[0.8, 0.0, -0.6], [0.0, 1.0, 0.0], [0.6, 0.0, 0.8]], 1e-7)
    assert close(s.dims[0], [0.1, 1.0, 0.1]) and close(s.centers[0], [0.0, 0.0, 0.0])
    assert close(local_point(s, 0, [0.5, 0.5, 1.0]), [0.03, 0.0, 0.04], 1e-7)
    assert close(local_point(s, 0, [0.5, 0.0, 0.5]), [0.0, -0.5, 0.0])  # earlier records kept


def test_general_rule_orients_then_scales():
    # Same post, target twice as far: c = (.06, 0, .08). Orient turns by acos(.8) as above
    # (nob = fn (1 + s) with s = 1 only sets the angle; no scaling there). Then b = (.03, 0, .04),
    # t = c - b, |t| = .05. Eligible dims: width and length (both records have cv = 0 there), not
    # height. cv_width(src) = .5 front is parallel to t (cos 1 > .9), cv_length(src) = 0: width wins.
    # d = 1 / |.5 front - 0| = 2, s = |t . front| = .05, width += .1. The bottom record does not
    # move, so the centre stays.
    s = execute(_general_rotation_program(0.06, 0.08), dtype=torch.float64)
    assert close(s.axes[0], [[0.8, 0.0, -0.6], [0.0, 1.0, 0.0], [0.6, 0.0, 0.8]], 1e-7)
    assert close(s.dims[0], [0.1, 1.0, 0.2], 1e-7) and close(s.centers[0], [0.0, 0.0, 0.0])
    assert close(local_point(s, 0, [0.5, 0.5, 1.0]), [0.06, 0.0, 0.08], 1e-7)
    # the target on the other side: the turn about -y is the one that maps fn onto noc
    s = execute(_general_rotation_program(-0.03, 0.04), dtype=torch.float64)
    assert close(s.axes[0], [[0.8, 0.0, 0.6], [0.0, 1.0, 0.0], [-0.6, 0.0, 0.8]], 1e-7)
    assert close(local_point(s, 0, [0.5, 0.5, 1.0]), [-0.03, 0.0, 0.04], 1e-7)


# ----------------------------------------------------------------------------- aligned


def _aligned_program(top_y):
    return flat("bbox = Cuboid(1.0, 1.0, 1.0, True)", f"cube0 = Cuboid(1.0, {top_y}, 1.0, True)",
                "cube1 = Cuboid(0.2, 0.2, 0.2, True)",
                "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)",
                "attach(cube1, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)",
                "attach(cube1, cube0, 0.9, 1.0, 0.5, 0.3, 0.0, 0.1)")


def test_aligned_grows_towards_target_cuboid_only():
    s = execute(_aligned_program(0.1), dtype=torch.float64)
    # cube1 (top at -0.3) grows up to cube0's bottom (0.4), keeping its bottom; the requested
    # target point (0.3, 0, 0.1) is ignored: x and z are unchanged.
    assert close(s.dims[1], [0.2, 0.9, 0.2]) and close(s.centers[1], [0.0, -0.05, 0.0])


def test_aligned_small_gap_is_left_alone():
    # gap 0.04 < 5% of the largest dim (1.0): nothing changes
    s = execute(_aligned_program(0.76), dtype=torch.float64)
    assert close(s.dims[1], [0.2, 0.2, 0.2]) and close(s.centers[1], [0.0, -0.4, 0.0])


def test_aligned_never_shrinks():
    p = flat("bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.2, 0.2, 0.2, True)",
             "cube1 = Cuboid(0.2, 0.8, 0.2, True)",
             "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.9, 0.0, 0.5)",
             "attach(cube1, bbox, 0.5, 0.0, 0.5, 0.1, 0.0, 0.5)",
             "attach(cube1, cube0, 0.5, 1.0, 0.5, 0.5, 0.0, 0.5)")
    s = execute(p, dtype=torch.float64)
    # cube1 spans y in [-0.5, 0.3], cube0 [-0.5, -0.3], x gap 0.6: cube1 grows in x only
    # (towards cube0), never in y where the nearest points would need shrinking.
    assert close(s.dims[1][1:], [0.8, 0.2]) and float(s.dims[1][0]) > 0.7
    assert close(local_point(s, 1, [0.0, 0.0, 0.5])[0], -0.5)  # the far (left) face stays


# ----------------------------------------------------------------------------- squeeze


@pytest.mark.parametrize("face", list(FACES))
def test_squeeze_each_face(face):
    k, side = FACES[face]
    opp_side = 1.0 - side
    dims_c = [0.3, 0.3, 0.3]
    dims_c[k] = 0.1
    # C sits against the bbox face opposite to `face`
    c_at = [0.5, 0.5, 0.5]
    c_at[k] = opp_side
    src_c = list(c_at)
    lines = ["bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid({}, {}, {}, True)".format(*dims_c),
             "cube1 = Cuboid(0.1, 0.1, 0.1, False)",
             "attach(cube0, bbox, {}, {}, {}, {}, {}, {})".format(*src_c, *c_at),
             f"squeeze(cube1, bbox, cube0, {face}, 0.3, 0.6)"]
    s = execute(flat(*lines), dtype=torch.float64)
    free = [d for d in range(3) if d != k]
    # target on bbox: the same face of bbox at (u, v)
    tb = [0.0, 0.0, 0.0]
    tb[k] = side
    tb[free[0]], tb[free[1]] = 0.3, 0.6
    gb = point([0, 0, 0], [1, 1, 1], tb)
    # target on C: C's face on the `face` side (the face looking at cube1) at (u, v)
    center_c = point([0, 0, 0], [1, 1, 1], c_at)
    center_c[k] -= (c_at[k] - 0.5) * dims_c[k]  # C is inside the bbox, touching the face
    tc = list(tb)
    gc = point(center_c, dims_c, tc)
    a_face = [0.5, 0.5, 0.5]
    a_face[k] = side
    a_opp = [0.5, 0.5, 0.5]
    a_opp[k] = opp_side
    assert close(local_point(s, 1, a_face), gb)
    assert close(local_point(s, 1, a_opp), gc)


def test_squeeze_between_two_cuboids_uses_opposite_faces():
    p = flat("bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.2, 0.2, 0.2, True)",
             "cube1 = Cuboid(0.2, 0.2, 0.2, True)", "cube2 = Cuboid(0.1, 0.1, 0.1, False)",
             "attach(cube0, bbox, 1.0, 0.5, 0.5, 0.3, 0.5, 0.5)",
             "attach(cube1, bbox, 0.0, 0.5, 0.5, 0.7, 0.5, 0.5)",
             "squeeze(cube2, cube0, cube1, left, 0.5, 0.5)")
    s = execute(p, dtype=torch.float64)
    # left face of cube2 to cube0's right face (x=-0.2), right face to cube1's left face (x=0.2)
    assert close(local_point(s, 2, [0.0, 0.5, 0.5]), [-0.2, 0.0, 0.0])
    assert close(local_point(s, 2, [1.0, 0.5, 0.5]), [0.2, 0.0, 0.0])
    assert close(s.dims[2], [0.4, 0.1, 0.1])


# ----------------------------------------------------------------------------- reflect


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("aligned", [True, False])
def test_reflect_is_mirror_image(axis, aligned):
    name = "XYZ"[axis]
    lines = ["bbox = Cuboid(1.0, 1.2, 0.8, True)", f"cube0 = Cuboid(0.1, 0.2, 0.3, {aligned})",
             "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.2, 0.1, 0.3)"]
    if not aligned:
        lines.append("attach(cube0, bbox, 0.5, 1.0, 0.5, 0.3, 0.4, 0.35)")
    lines.append(f"reflect(cube0, {name})")
    s = execute(flat(*lines), dtype=torch.float64)
    assert len(s) == 2 and s.line.tolist() == [1, len(lines) - 1]
    mirrored = s.corners[0].clone()
    mirrored[:, axis] = -mirrored[:, axis]
    assert corner_set(mirrored) == corner_set(s.corners[1])
    assert close(s.dims[0], s.dims[1])
    assert close(torch.linalg.det(s.axes[1]), 1.0)


# ----------------------------------------------------------------------------- translate


def test_translate_spacing_and_clamp():
    p = flat("bbox = Cuboid(2.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.1, 0.1, 0.1, True)",
             "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.1, 0.0, 0.5)",
             "translate(cube0, X, 4, 0.6)")
    s = execute(p, dtype=torch.float64)
    x0 = -1.0 + 0.2
    step = 2.0 * 0.6 / 4
    assert close(s.centers[:, 0], [x0 + i * step for i in range(5)])
    p = flat("bbox = Cuboid(2.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.1, 0.1, 0.1, True)",
             "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.8, 0.0, 0.5)",
             "translate(cube0, X, 2, 0.5)")
    s = execute(p, dtype=torch.float64)
    # targets x = 0.6+0.5 and 0.6+1.0 leave the bbox: both pinned to its right face
    assert close(s.centers[:, 0], [0.6, 1.0, 1.0])


def test_macro_names_count_all_cuboids():
    p = flat("bbox = Cuboid(2.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.1, 0.1, 0.1, True)",
             "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.1, 0.0, 0.5)",
             "translate(cube0, X, 2, 0.6)", "reflect(cube2, Z)")  # cube1, cube2 are the copies
    s = execute(p, dtype=torch.float64)
    assert len(s) == 4 and s.line.tolist() == [1, 3, 3, 4]


# ----------------------------------------------------------------------------- hierarchy

HIER = """Assembly Program_0 {
\tbbox = Cuboid(2.0, 1.0, 1.0, True)
\tProgram_1 = Cuboid(0.4, 0.4, 0.4, False)
\tattach(Program_1, bbox, 0.5, 0.0, 0.5, 0.2, 0.01, 0.5)
\tattach(Program_1, bbox, 0.5, 1.0, 0.5, 0.2, 0.99, 0.5)
\treflect(Program_1, X)
}
Assembly Program_1 {
\tbbox = Cuboid(0.4, 0.4, 0.4, True)
\tcube0 = Cuboid(0.1, 0.1, 0.2, True)
\tattach(cube0, bbox, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
}
"""


def test_hierarchy_scales_dims_not_positions_and_flips_reflected_copy():
    s = execute(parse(HIER), dtype=torch.float64)
    # Program_1 is stretched to height 0.98 (ratio 2.45 in y) at x = -0.6; the child's cube0
    # keeps its local position (-0.15, -0.15, -0.1) unscaled while its dims scale per axis.
    assert close(s.dims[0], [0.1, 0.1 * 0.98 / 0.4, 0.2])
    assert close(s.centers[0], [-0.6 - 0.15, -0.15, -0.1])
    assert s.node.tolist() == [1, 1] and s.line.tolist() == [9, 9]
    # the reflected copy is the mirror image of the original (the sub-program is flipped)
    mirrored = s.corners[0].clone()
    mirrored[:, 0] = -mirrored[:, 0]
    assert corner_set(mirrored) == corner_set(s.corners[1])


def test_batch_equals_single_calls():
    progs = [parse(HIER), _aligned_program(0.1), flat(*POST[:3], "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.7, 1.0, 0.5)")]
    batch = execute_batch(progs)
    for p, b in zip(progs, batch):
        one = execute(p)
        assert torch.equal(one.corners, b.corners) and torch.equal(one.line, b.line)


def test_plan_runs_repeatedly_like_execute():
    progs = [parse(HIER), parse(GRAD_PROGRAMS["squeeze_translate_reflect"])]
    plan = ExecutionPlan(progs, dtype=torch.float64)
    assert len(plan) == 2 and plan.n_params == [program_parameters(p).numel() for p in progs]
    assert all(torch.equal(x, program_parameters(p, torch.float64)) for x, p in zip(plan.parameters(), progs))
    for shift in (0.0, 0.013, -0.02):  # the same plan with other numbers
        xs = [(program_parameters(p, torch.float64) + shift).requires_grad_(True) for p in progs]
        got = plan.run(xs)
        for p, x, s in zip(progs, xs, got):
            one = execute(p, dtype=torch.float64, params=x.detach())
            assert torch.equal(s.corners, one.corners) and torch.equal(s.node, one.node)
        # gradients reach every program's parameters through the shared plan
        sum(s.corners.square().sum() for s in got).backward()
        assert all(x.grad is not None and x.grad.abs().sum() > 0 for x in xs)
    # None: the program's own numbers
    assert torch.equal(plan.run([None, None])[1].corners, execute(progs[1], dtype=torch.float64).corners)
    with pytest.raises(ValueError, match="2 tensors"):
        plan.run([None])
    with pytest.raises(TypeError, match="list of programs"):
        ExecutionPlan(progs[0])


def test_redeclared_cuboid_keeps_position():
    p = flat("bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.2, 0.2, 0.2, True)",
             "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)", "cube0 = Cuboid(0.4, 0.4, 0.4, False)")
    s = execute(p, dtype=torch.float64)
    assert len(s) == 1 and close(s.dims[0], [0.4, 0.4, 0.4]) and close(s.centers[0], [0.0, -0.4, 0.0])


# ----------------------------------------------------------------------------- gradients


def _aligned_grad_program():
    return "\n".join(["bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.9, 0.13, 0.8, True)",
                      "cube1 = Cuboid(0.21, 0.23, 0.19, True)",
                      "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.52, 0.97, 0.49)",
                      "attach(cube1, bbox, 0.5, 0.0, 0.5, 0.47, 0.02, 0.51)",
                      "attach(cube1, cube0, 0.9, 1.0, 0.5, 0.3, 0.0, 0.1)"]) + "\n"


# Targets on the [0, 1] clamp bounds of reflect/translate are kinks (one-sided derivatives),
# so the programs below keep them strictly inside.
GRAD_PROGRAMS = {
    "hierarchy_second": HIER,
    "squeeze_translate_reflect": "\n".join([
        "bbox = Cuboid(1.2, 1.0, 0.9, True)", "cube0 = Cuboid(0.9, 0.1, 0.7, True)",
        "cube1 = Cuboid(0.1, 0.3, 0.1, False)", "cube2 = Cuboid(0.05, 0.2, 0.05, True)",
        "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.48, 0.93, 0.52)",
        "squeeze(cube1, bbox, cube0, bot, 0.21, 0.33)",
        "attach(cube2, cube0, 0.4, 1.0, 0.6, 0.3, 0.02, 0.2)",
        "translate(cube2, X, 3, 0.45)", "reflect(cube1, Z)"]) + "\n",
    "aligned_growth": _aligned_grad_program(),
    "general_orient_scale": "\n".join(POST + ("attach(cube0, bbox, 0.5, 0.5, 1.0, 0.56, 0.5, 0.58)",)) + "\n",
}


@pytest.mark.parametrize("text", list(GRAD_PROGRAMS.values()), ids=list(GRAD_PROGRAMS))
def test_gradcheck_all_parameters(text):
    prog = parse(text)
    x0 = program_parameters(prog, dtype=torch.float64).requires_grad_(True)
    f = lambda x: execute(prog, dtype=torch.float64, params=x).corners  # noqa: E731
    assert torch.autograd.gradcheck(f, (x0,), eps=1e-6, atol=1e-5)
    # every kind of continuous parameter receives a gradient somewhere
    g = torch.autograd.grad(f(x0).square().sum(), x0)[0]
    names = parameter_names(prog)
    for kind in ("cuboid.", "attach.", "squeeze.", "translate."):
        idx = [i for i, n in enumerate(names) if kind in n and ":0:" not in n]
        if idx:
            assert g[idx].abs().sum() > 0, kind


def test_aligned_growth_depends_on_target_dims():
    prog = parse(_aligned_grad_program())
    x = program_parameters(prog, dtype=torch.float64).requires_grad_(True)
    s = execute(prog, dtype=torch.float64, params=x)
    (g,) = torch.autograd.grad(s.dims[1, 1], x)
    # cube1's grown height = distance from its bottom to cube0's bottom: d/d(cube0 height) = -1
    assert abs(float(g[4]) + 1.0) < 1e-6


def test_params_shape_is_checked():
    prog = parse(HIER)
    with pytest.raises(ValueError, match=r"shape \(\d+,\)"):
        execute(prog, params=torch.zeros(3))


def test_defect4_far_attach_then_second_attach_gives_no_index_error():
    """``attach(cube1, bbox, 1e25, ...)`` then a second attach: the text is refused by the parser's
    number limit; the same value given as a parameter (the executor's parameters are not range-checked, only
    required finite) executes without an IndexError, to a finite shape with cube1 where the first attach put
    it: moved by -(1e25 - 0.5) * 0.5 along x (its length 0.5 is lost in float32 beside 5e24), its bottom on the
    bbox's bottom and centred in z."""
    p = flat("bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.5, 0.1, 0.5, False)",
             "cube1 = Cuboid(0.5, 0.1, 0.5, False)", "attach(cube1, bbox, 1.0, 0.0, 0.5, 0.5, 0.0, 0.5)",
             "attach(cube1, cube0, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)")
    x = program_parameters(p)
    assert parameter_names(p)[9] == "Program_0:3:attach.x1"
    x[9] = 1e25
    s = execute(p, params=x)
    assert bool(s.corners.isfinite().all())
    assert torch.allclose(s.corners[1, :, 0], torch.full((8,), -5e24), rtol=1e-6)
    # y and z as without the far x: cube1's bottom face on the bbox's bottom face, centred in z
    assert torch.allclose(s.corners[1, :, 1].unique(), torch.tensor([-0.5, -0.4]))
    assert torch.allclose(s.corners[1, :, 2].unique(), torch.tensor([-0.25, 0.25]))


def test_defect3_non_finite_execution_raises_execution_error_naming_the_line():
    p = flat("bbox = Cuboid(0.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.5, 0.5, 0.5, True)",
             "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)")  # a zero bbox extent
    with pytest.raises(ExecutionError, match=r"^line 2: execution gives a non-finite cuboid"):
        execute(p)
    good = flat("bbox = Cuboid(1.0, 1.0, 1.0, True)", "cube0 = Cuboid(0.5, 0.5, 0.5, True)",
                "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)")
    with pytest.raises(ExecutionError, match=r"^program 1, line 2: ") as ei:
        execute_batch([good, p])
    assert (ei.value.index, ei.value.line) == (1, 2)
    x = program_parameters(good)
    x[3] = float("nan")
    with pytest.raises(ExecutionError, match="^line 2: "):
        execute(good, params=x)
