"""The ShapeCoder executor: hand-computed cases of the semantics, errors, primitives and their order."""
import math

import numpy as np
import pytest

from shapeprog.coder import data
from shapeprog.coder.execute import (ExecutionError, corners, euler_xyz, execute, order, position_key, primitives,
                                     reorient, rotation_xyz, run)
from shapeprog.coder.lang import LANG_2D, Library, ProgramError, expand, parse, parse_abstraction
from shapeprog.coder.objective import naive_program


def ex(text, lib=None, **kw):
    return execute(parse(text, lib), lib, **kw)


def test_base_functions_by_hand():
    assert ex("Cuboid(1,2,0.5)") == ((1.0, 2.0, 0.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),)
    assert ex("Move(Move(Cuboid(0.5,0.5,0.5),0.1,0.2,0.3),0.1,0,-0.3)") == ((0.5, 0.5, 0.5, 0.2, 0.2, 0.0, 0, 0, 0),)
    # Rotate turns each part about its own centre: the centre stays, the angle is recorded
    assert ex("Rotate(Move(Cuboid(0.2,0.4,0.6),0.1,0.2,0.3),AY,0.3)") == ((0.2, 0.4, 0.6, 0.1, 0.2, 0.3, 0, 0.3, 0),)
    # ... so Move and Rotate commute
    assert ex("Move(Rotate(Rotate(Cuboid(0.2,0.4,0.6),AX,0.2),AZ,-0.1),0.1,0.2,0.3)") \
        == ex("Rotate(Rotate(Move(Cuboid(0.2,0.4,0.6),0.1,0.2,0.3),AX,0.2),AZ,-0.1)") \
        == ((0.2, 0.4, 0.6, 0.1, 0.2, 0.3, 0.2, 0.0, -0.1),)
    # Rotate about x, then y, then z gives the x-y-z Euler angles back
    assert ex("Rotate(Rotate(Rotate(Cuboid(1,1,1),AX,0.25),AY,-0.4),AZ,0.1)")[0][6:] == (0.25, -0.4, 0.1)
    # Union keeps both; primitives come ordered by position key (lowest x + y + z first)
    assert ex("Union(Move(Cuboid(1,1,1),0.5,0,0),Move(Cuboid(2,2,2),-0.5,0,0))") == (
        (2.0, 2.0, 2.0, -0.5, 0.0, 0.0, 0, 0, 0), (1.0, 1.0, 1.0, 0.5, 0.0, 0.0, 0, 0, 0))
    # SymTrans: K copies at k/K * D, K + 1 instances
    assert [p[3] for p in ex("SymTrans(Move(Cuboid(0.1,0.1,0.1),-0.5,0,0),AX,INT#2#,1.0)")] == [-0.5, 0.0, 0.5]
    assert [p[5] for p in ex("SymTrans(Cuboid(0.1,0.1,0.1),AZ,INT#4#,0.8)")] == [0.0, 0.2, 0.4, 0.6, 0.8]
    # float operators
    assert ex("Cuboid(Add(0.1,0.2),Mul(2,Sub(0.5,0.25)),Div(1,4))")[0][:3] == (0.3, 0.5, 0.25)
    assert ex("Move(Cuboid(1,1,1),Inv(0.3),Inv(Inv(0.2)),0)")[0][3:5] == (-0.3, 0.2)


def test_symref_mirrors_position_and_rotation():
    # a part turned about z, mirrored across x = 0: the copy turns the other way
    assert ex("SymRef(Rotate(Move(Cuboid(0.2,0.4,0.6),-0.5,0.1,0.2),AZ,0.3),AX)") == (
        (0.2, 0.4, 0.6, -0.5, 0.1, 0.2, 0.0, 0.0, 0.3), (0.2, 0.4, 0.6, 0.5, 0.1, 0.2, 0.0, 0.0, -0.3))
    # turned about x, mirrored across x = 0: the same rotation
    assert ex("SymRef(Rotate(Move(Cuboid(0.2,0.4,0.6),-0.5,0.1,0.2),AX,0.3),AX)")[1] == (
        0.2, 0.4, 0.6, 0.5, 0.1, 0.2, 0.3, 0.0, 0.0)
    # the copy is the mirror image: its corners are the mirrored corners of the source
    prims = ex("SymRef(Rotate(Rotate(Move(Cuboid(0.2,0.4,0.6),0.1,-0.3,0.2),AX,0.2),AY,0.35),AY)", prec=12)
    a, b = corners([prims[0]]), corners([prims[1]])
    mirrored = a * np.array([1, -1, 1])
    assert np.allclose(np.sort(mirrored.reshape(-1, 3), 0), np.sort(b.reshape(-1, 3), 0), atol=1e-9)


def test_soft_and_hard_errors():
    r = run(parse("SymRef(Move(Cuboid(0.1,0.1,0.1),0.2,0,0),AX)"))
    assert r.ok and len(r.soft_errors) == 1 and "X >= 0" in r.soft_errors[0]
    r = run(parse("SymTrans(Cuboid(0.1,0.1,0.1),AY,INT#2#,-0.5)"))
    assert r.ok and "distance is <= 0" in r.soft_errors[0]
    r = run(parse("Union(Cuboid(0.1,0,0.1),Cuboid(Div(1,0),0.1,0.1))"))
    assert not r.ok and r.hard_errors == ("Cuboid(0.1,0.0,0.1): a dimension is <= 0", "Div(1.0,0.0): division by 0",
                                          "Cuboid(Div(1.0,0.0),0.1,0.1): a dimension is <= 0")  # Div by 0 gives 0
    assert r.primitives()[0][:3] == (0.0, 0.1, 0.1)  # the shape is still built
    with pytest.raises(ExecutionError, match=r"^Cuboid\(-0.1,0.1,0.1\): a dimension is <= 0"):
        ex("Cuboid(-0.1,0.1,0.1)")
    assert ex("Cuboid(-0.1,0.1,0.1)", strict=False)[0][0] == -0.1


def test_variables_abstractions_and_limits():
    lib = Library().add(parse_abstraction("Leg(w: Float, x: Float, a: Axis) = SymRef(Move(Cuboid(w,h,w),x,0,x),a)"
                                          .replace("h,", "Mul(w,5.0),")))
    prog = parse("Union(Leg(0.1,-0.4,AZ),Leg(u,v,b))", lib)
    env = {"u": 0.2, "v": -0.1, "b": "AX"}
    assert execute(prog, lib, env) == execute(expand(prog, lib), None, env)
    assert len(execute(prog, lib, env)) == 4
    with pytest.raises(ExecutionError, match="variable 'v' has no value"):
        execute(prog, lib, {"u": 0.2, "b": "AX"})
    with pytest.raises(ExecutionError, match="variable 'b' needs one of AX, AY, AZ"):
        execute(prog, lib, {**env, "b": "AW"})
    with pytest.raises(ExecutionError, match="needs a finite float"):
        execute(prog, lib, {**env, "u": math.inf})
    with pytest.raises(ProgramError, match="unknown function 'Leg'"):
        run(prog)  # the base library does not know Leg
    with pytest.raises(ExecutionError, match="MAX_PARTS"):
        ex("SymTrans(SymTrans(Cuboid(1,1,1),AX,INT#40#,1),AY,INT#40#,1)")


def test_2d_domain():
    assert execute(parse("SymRef(Move(Rectangle(0.2,0.1),-0.3,0.4),AX)", LANG_2D), LANG_2D) == (
        (0.2, 0.1, -0.3, 0.4), (0.2, 0.1, 0.3, 0.4))
    assert execute(parse("SymTrans(Move(Rectangle(0.1,0.1),0,-0.5),AY,INT#2#,Mul(0.5,2))", LANG_2D), LANG_2D) == (
        (0.1, 0.1, 0.0, -0.5), (0.1, 0.1, 0.0, 0.0), (0.1, 0.1, 0.0, 0.5))
    assert run(parse("SymRef(Move(Rectangle(0.2,0.1),0.3,0),AY)", LANG_2D), LANG_2D).soft_errors


def test_rotations_and_reorientation():
    rng = np.random.default_rng(0)
    for _ in range(20):
        angles = rng.uniform(-1.2, 1.2, 3)
        assert np.allclose(euler_xyz(rotation_xyz(angles)), angles, atol=1e-12)
    assert euler_xyz(rotation_xyz((0.3, math.pi / 2, 0.0)))[1] == pytest.approx(math.pi / 2)
    # a box turned by more than 45 degrees about x gets its y and z axes (and dims) swapped back
    rot = rotation_xyz((0.9, 0.0, 0.0))
    dims, new = reorient(np.array([0.5, 0.2, 0.8]), rot)
    assert dims.tolist() == [0.5, 0.8, 0.2] and euler_xyz(new)[0] == pytest.approx(0.9 - math.pi / 2)
    assert np.linalg.det(new) == pytest.approx(1.0)
    box = corners([(0.5, 0.2, 0.8, 0, 0, 0, 0.9, 0, 0)])
    back = corners([(*dims, 0, 0, 0, *euler_xyz(new))])
    assert np.allclose(np.sort(box[0], 0), np.sort(back[0], 0))
    # primitives() applies it
    assert ex("Rotate(Cuboid(0.5,0.2,0.8),AX,0.9)") == ((0.5, 0.8, 0.2, 0.0, 0.0, 0.0, -0.67, 0.0, 0.0),)
    # a half turn about y (written 3.14) is snapped to no rotation
    assert ex("Rotate(Cuboid(0.5,0.2,0.8),AY,3.14)", orient=False)[0][6:] == (0.0, 0.0, 0.0)


def test_position_key_order():
    p = [(1, 1, 1, 0.02, 0.0, 0.0, 0, 0, 0), (1, 1, 1, -0.02, 0.0, 0.0, 0, 0, 0), (1, 1, 1, 0.0, -0.2, 0.1, 0, 0, 0)]
    assert position_key(p[0]) == position_key(p[1]) == 0.0  # centres rounded to multiples of 0.05
    assert position_key(p[2]) == pytest.approx(-1000 - 20 + 1)
    assert order(p) == (tuple(p[2]), tuple(p[1]), tuple(p[0]))  # ties broken by the tuples
    assert position_key((0.1, 0.1, 0.3, 0.2)) == pytest.approx(5000 + 300 + 20)  # 2D: z = 0


def test_naive_programs_of_the_data_execute_back_to_their_primitives():
    for cat in data.CATEGORIES:
        for rec in data.load(cat)[::8]:
            expr, env = naive_program(rec.prims)
            assert execute(expr, env=env) == rec.prims
    two_d = ((0.2, 0.1, -0.3, 0.4), (0.2, 0.1, 0.0, 0.0))
    expr, env = naive_program(two_d)
    assert execute(expr, LANG_2D, env) == order(two_d)


def test_primitives_of_parts_in_any_order():
    r = run(parse("Union(Move(Cuboid(1,1,1),0.5,0,0),Union(Cuboid(0.3,0.3,0.3),Move(Cuboid(2,2,2),-0.5,0,0)))"))
    assert primitives(r.parts) == primitives(r.parts[::-1]) == r.primitives()
