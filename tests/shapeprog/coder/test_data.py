"""The vendored ShapeCoder primitive data: the files, the splits, the primitives, and errors with their place."""
import hashlib
import statistics
import warnings

import pytest

from shapeprog.coder import data
from shapeprog.coder.execute import order
from shapeprog.errors import ParseError

MD5 = {"chair": "a3758e7258d3a872dfa3e07d35046719", "table": "9b0ae159dff19926348708e74fcd425e",
       "storage": "985f82e9774174d84570e39d67f43914"}


def test_vendored_files_are_the_published_ones():
    files = data._files()
    for cat in data.CATEGORIES:
        assert hashlib.md5(files[f"PN_{cat}.txt"]).hexdigest() == MD5[cat]
        lines = data.read_lines(cat)
        assert len(lines) == 1100
        # shapes with any rotation ([checked] in the specification)
        assert sum("Rotate" in line for line in lines) == {"chair": 436, "table": 173, "storage": 121}[cat]


@pytest.mark.parametrize("cat, mean", [("chair", 9.11), ("table", 8.29), ("storage", 10.21)])
def test_discovery_split(cat, mean):
    shapes = data.load(cat)
    assert len(shapes) == data.DISCOVERY_SIZE == 400
    assert [s.index for s in shapes] == list(range(400)) == [s.line - 1 for s in shapes]
    ids = [s.partnet_id for s in shapes]
    assert ids == sorted(ids) and all(s.key == f"{s.partnet_id}_0_{s.index}" for s in shapes)
    assert round(statistics.mean(len(s.prims) for s in shapes), 2) == mean
    for s in shapes:
        assert 3 <= len(s.prims) <= 16 and s.prims == order(s.prims)
        assert all(len(p) == 9 and all(round(v, 2) == v for v in p) for p in s.prims)
        assert all(min(p[:3]) > 0 for p in s.prims)


def test_first_shape_by_hand():
    s = data.load("chair")[0]
    assert (s.key, s.partnet_id, s.index, s.line) == ("172_0_0", 172, 0, 1)
    assert len(s.prims) == 11
    assert s.prims[0] == (0.06, 0.6, 0.06, -0.31, -0.51, -0.17, 0.0, 0.0, 0.0)  # lowest x + y + z first
    assert (0.68, 0.09, 0.66, 0.0, -0.17, 0.0, 0.0, 0.0, 0.0) in s.prims  # '-0.0' read as 0.0


def test_heldout_lines_with_zero_dims_and_reoriented_axes():
    lines = data.read_lines("chair")
    # six cuboids with a 0.0 dimension, on three held-out lines: kept, as published
    for n in (689, 747, 786):
        rec = data.parse_record(lines[n - 1], "PN_chair.txt", n)
        assert sum(p[:3].count(0.0) for p in rec.prims) == 2
    # the one part of the data turned by more than 45 degrees: its y and z axes (and dims) swap
    rec = data.parse_record(lines[551], "PN_chair.txt", 552)
    assert "Rotate(Move(Cuboid(0.55,0.24,0.86),-0.0,-0.25,0.32),AX,-0.79)" in lines[551]
    assert (0.55, 0.86, 0.24, 0.0, -0.25, 0.32, 0.78, 0.0, 0.0) in rec.prims


@pytest.mark.parametrize("text, col, token, reason", [
    ("172_0_0 Move(Cuboid(1,1,1),0,0,0)", 1, "172_0_0 Move(Cuboid(", "expected '<PartNet id>_0_<index>:<program>'"),
    ("172_a_0:Cuboid(1,1,1)", 1, "172_a_0", "malformed shape key"),
    (":Cuboid(1,1,1)", 1, "", "malformed shape key"),
    ("172_0_0:Union(Move(Cubiod(1,1,1),0,0,0),Cuboid(1,1,1))", 20, "Cubiod", "unknown function 'Cubiod'"),
    ("172_0_0:Union(Cuboid(1,1,1),Move(Cuboid(1,-0.2,1),0,0,0))", 34, "Cuboid",
     "a negative cuboid dimension in Cuboid(1.0,-0.2,1.0)"),
    ("172_0_0:Union(Cuboid(1,1,1),Move(Cuboid(1,1,Div(1,0)),0,0,0))", 9, "Union(Cuboid(1,1,1),",
     "Div(1.0,0.0): division by 0"),
    ("172_0_0:Union(Cuboid(1,1,1),Move(Cuboid(1,1,1),0,0,0)", 54, "", "expected ')' closing Union"),
    ("172_0_0:Move(Cuboid(1,1,1),0,0,x_1)", 32, "x_1", "a data line has no variables"),
    ("1_0_0:SymTrans(SymTrans(Cuboid(1,1,1),AX,INT#40#,1),AY,INT#40#,1)", 7, "SymTrans(SymTrans(Cu",
     "more than 1000 parts (MAX_PARTS)"),
    ("1_0_0:Cuboid(1,1,1)" + " " * 100_000, 100_001, " " * 10, "line longer than 100000 characters"),
])
def test_malformed_lines_name_file_line_column_token(text, col, token, reason):
    with pytest.raises(ParseError) as err:
        data.parse_record(text, "PN_chair.txt", 12)
    e = err.value
    assert (e.file, e.line, e.column, e.token) == ("PN_chair.txt", 12, col, token)
    assert reason in e.reason and text[col - 1:].startswith(token)
    assert len(str(e)) < 200


def test_bad_lines_are_reported_and_the_rest_loads(monkeypatch):
    lines = ["1_0_0:Cuboid(1,1,1)", "2_0_1:Cuboid(1,1)", "3_0_2:Move(Cuboid(1,1,1),0.1,0,0)"]
    monkeypatch.setattr(data, "_load", lambda cat, split: data._parse_lines(lines, "PN_chair.txt", 0, 3))
    with pytest.warns(data.DataWarning, match=r"1 data line\(s\) skipped: PN_chair.txt:2:17: Cuboid takes 3"):
        shapes = data.load("chair")
    assert [s.key for s in shapes] == ["1_0_0", "3_0_2"] and shapes[1].prims[0][3] == 0.1
    with pytest.raises(ParseError, match="^PN_chair.txt:2:17: "):
        data.load("chair", strict=True)


def test_bad_bytes_and_bad_arguments(monkeypatch):
    monkeypatch.setattr(data, "_files", lambda: {"PN_table.txt": b"1_0_0:Cuboid(1,1,1)\n2_0_1:Cub\xffoid"})
    with pytest.raises(ParseError, match=r"^PN_table.txt:2:10: not UTF-8"):
        data.read_lines("table")
    with pytest.raises(ValueError, match="unknown category 'sofa'"):
        data.load("sofa")
    with pytest.raises(ValueError, match="unknown split 'test'; expected one of discovery, heldout, all"):
        data.load("chair", "test")


def test_published_data_loads_without_warnings():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        for cat in data.CATEGORIES:
            assert data.load(cat) == data.load(cat, strict=True)
