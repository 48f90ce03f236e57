"""Results as data: result files, their markdown, and docs blocks kept in step with them."""
import json

import pytest

from shapeio.results import (FORMAT, MAX_RESULT_BYTES, column, main, make_result, markdown, read_result, sync,
                             write_result)


def _result():
    cols = [column("method", "method"), column("iou", "IoU (%)", 2, 100.0), column("n", "programs")]
    rows = [{"method": "a|b", "iou": 0.81234, "n": 1400}, {"method": "nn", "iou": float("nan"), "n": 7}]
    return make_result("Table 5", cols, rows, ["A note."], command="python -m csgnet evaluate --dim 3")


def test_result_round_trip_and_markdown(tmp_path):
    path = write_result(tmp_path / "r" / "t.json", _result())
    data = read_result(path)
    assert data["format"] == FORMAT and data["rows"][1]["iou"] is None  # NaN is written as null
    text = markdown(data)
    assert text.splitlines()[:5] == ["**Table 5**", "", "| method | IoU (%) | programs |", "|---|---:|---:|",
                                     "| a\\|b | 81.23 | 1,400 |"]
    assert "| nn | – | 7 |" in text and "A note." in text and "`python -m csgnet evaluate --dim 3`" in text


def test_docs_blocks_follow_their_files_and_check_reports_drift(tmp_path, capsys):
    write_result(tmp_path / "docs" / "t.json", _result())
    page = tmp_path / "page.md"
    page.write_text("# Page\n\n<!-- result: docs/t.json -->\nold table\n<!-- end result -->\n\nAfter.\n")
    assert main([str(page), "--root", str(tmp_path), "--check"]) == 1
    assert page.read_text().count("old table") == 1  # --check writes nothing
    assert main([str(page), "--root", str(tmp_path)]) == 0
    text = page.read_text()
    assert "old table" not in text and "| a\\|b | 81.23 | 1,400 |" in text and text.endswith("\n\nAfter.\n")
    assert sync([page], tmp_path, check=True) == []
    assert main([str(page), "--root", str(tmp_path), "--check"]) == 0
    page.write_text("<!-- result: docs/none.json -->\n<!-- end result -->\n")
    assert main([str(page), "--root", str(tmp_path)]) == 2
    assert "none.json: no such result file" in capsys.readouterr().err


@pytest.mark.parametrize("content, reason", [
    (b"\xff\xfe", "not a result file"),
    (b"[1, 2]", "not a result file"),
    (json.dumps({"format": FORMAT, "version": 99}).encode(), "version 99"),
    (json.dumps({"format": FORMAT, "version": 1, "title": "t", "columns": [{"key": "a", "label": "A"}],
                 "rows": [{"b": 1}]}).encode(), "malformed result"),
    (json.dumps({"format": FORMAT, "version": 1, "title": "t", "columns": [], "rows": []}).encode(),
     "malformed result"),
])
def test_bad_result_files_are_refused_naming_the_file(tmp_path, content, reason):
    path = tmp_path / "bad.json"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=f"bad.json: .*{reason}"):
        read_result(path)


def test_oversized_result_file_is_refused_before_it_is_read(tmp_path):
    path = tmp_path / "big.json"
    with open(path, "wb") as f:
        f.truncate(MAX_RESULT_BYTES + 1)
    with pytest.raises(ValueError, match="larger than"):
        read_result(path)


def test_make_result_refuses_rows_without_a_column_and_repeated_keys():
    with pytest.raises(ValueError, match="has no"):
        make_result("t", [column("a", "A")], [{"b": 1}])
    with pytest.raises(ValueError, match="distinct"):
        make_result("t", [column("a", "A"), column("a", "B")], [])


def test_headline_picks_a_formatted_cell_and_refuses_ambiguous_rows(tmp_path):
    import json

    from shapeio.results import column, headline, make_result, write_result

    write_result(tmp_path / "t.json", make_result("t", [column("method", "method"), column("iou", "IoU", 2, 100.0)],
                                                  [{"method": "a", "iou": 0.87604}, {"method": "b", "iou": 0.5}]))
    spec = {"title": "H", "rows": [{"system": "s", "measure": "m", "file": "t.json", "row": {"method": "a"},
                                    "column": "iou", "paper": "91.33", "page": "p.md"}]}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    got = headline(tmp_path / "spec.json", tmp_path, "h.json")
    assert got["rows"] == [{"system": "s", "measure": "m", "ours": "87.60", "paper": "91.33", "page": "p.md"}]
    spec["rows"][0]["row"] = {}
    (tmp_path / "spec.json").write_text(json.dumps(spec))
    with pytest.raises(ValueError, match=r"row 0: 2 rows of t.json match \{\}"):
        headline(tmp_path / "spec.json", tmp_path)
