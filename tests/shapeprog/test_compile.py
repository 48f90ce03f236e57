"""Tests for shapeprog.compile: the static lowering of blocks (rules, parameters, macros, tree)."""
from shapeprog.compile import ALIGNED, FIRST, GENERAL, SECOND, compile_program
from shapeprog.execute import program_parameters
from shapeprog.lang import parse


def modes(code):
    return [(op.a, op.b, op.mode) for kind, op in code.ops if kind == "attach"]


def test_rule_depends_on_the_records_and_the_aligned_flag():
    p = parse(
        "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"
        "cube0 = Cuboid(0.5, 0.2, 0.5, False)\n"
        "cube1 = Cuboid(0.5, 0.2, 0.5, True)\n"
        "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
        "attach(cube1, cube0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)\n"
        "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)\n"
        "attach(cube1, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)\n"
    )
    code = compile_program(p).blocks[0]
    # cube0: first, then general (a record as target of cube1 counts); cube1 aligned: first, then aligned
    assert modes(code) == [(1, 0, FIRST), (2, 1, FIRST), (1, 0, GENERAL), (2, 0, ALIGNED)]


def test_second_rule_for_a_non_aligned_cuboid_with_one_record():
    p = parse(
        "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"
        "cube0 = Cuboid(0.5, 0.2, 0.5, False)\n"
        "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
        "attach(cube0, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)\n"
    )
    assert [m for *_, m in modes(compile_program(p).blocks[0])] == [FIRST, SECOND]


def test_parameter_count_slots_and_macro_names():
    p = parse(
        "bbox = Cuboid(1.0, 1.0, 1.0, True)\n"
        "cube0 = Cuboid(0.2, 0.2, 0.2, True)\n"
        "attach(cube0, bbox, 0.5, 0.0, 0.5, 0.1, 0.0, 0.5)\n"
        "translate(cube0, X, 2, 0.8)\n"
        "reflect(cube0, Z)\n"
    )
    c = compile_program(p)
    assert c.n_params == len(program_parameters(p)) == 3 + 3 + 6 + 1
    block = c.blocks[0]
    assert block.slots == ["bbox", "cube0", "cube1", "cube2", "cube3"]
    assert block.slot_source == [None, None, 1, 1, 1]
    assert block.slot_reflect_axis == [None, None, None, None, 2]
    assert c.leaf_slots == [[1, 2, 3, 4]]
    # the copies depend on cube0's attach: they run at later levels than it
    assert [kind for kind, _ in block.steps[0]] == ["attach"]


def test_sub_programs_are_placed_breadth_first():
    text = (
        "Assembly Program_0 {\n"
        "\tbbox = Cuboid(1.0, 1.0, 1.0, True)\n"
        "\tProgram_1 = Cuboid(0.5, 0.5, 0.5, True)\n"
        "\tcube0 = Cuboid(0.2, 0.2, 0.2, True)\n"
        "\tattach(Program_1, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
        "\tattach(cube0, bbox, 0.5, 1.0, 0.5, 0.5, 1.0, 0.5)\n"
        "\treflect(Program_1, X)\n"
        "}\n"
        "Assembly Program_1 {\n"
        "\tbbox = Cuboid(0.5, 0.5, 0.5, True)\n"
        "\tcube0 = Cuboid(0.1, 0.1, 0.1, True)\n"
        "\tattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.5)\n"
        "}\n"
    )
    c = compile_program(parse(text))
    # (block, parent instance, parent slot, flip axis): the root, Program_1, its reflected copy
    assert c.instances == [(0, -1, -1, None), (1, 0, 1, None), (1, 0, 3, 0)]
    assert c.leaf_slots == [[2], [1]]
