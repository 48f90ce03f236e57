"""The docs' result tables (README, docs/ and docs/tables/) are generated from the result files under docs/results:
they must agree."""
from pathlib import Path

from shapeio.results import _BLOCK, read_result, sync

ROOT = Path(__file__).resolve().parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), *sorted((ROOT / "docs" / "tables").glob("*.md"))]


def test_every_result_block_matches_its_file():
    stale = sync(PAGES, ROOT, check=True)
    assert not stale, f"run `python -m shapeio.results README.md docs/*.md docs/tables/*.md`: out of step: {stale}"


def test_every_result_file_is_shown_and_readable():
    shown = {m.group("path") for page in PAGES for m in _BLOCK.finditer(page.read_text(encoding="utf-8"))}
    # docs/results/<system>/runs/ holds the outputs of discovery runs that table commands read, not result files
    files = {str(p.relative_to(ROOT)) for p in (ROOT / "docs" / "results").rglob("*.json")
             if "runs" not in p.relative_to(ROOT / "docs" / "results").parts}
    for f in files:
        read_result(ROOT / f)
    assert shown <= files, f"blocks naming missing files: {sorted(shown - files)}"


def test_the_readme_headline_is_picked_from_the_current_result_files():
    """docs/results/headline.json holds exactly what `python -m shapeio.results --headline` picks today."""
    from shapeio.results import headline

    got = headline(ROOT / "docs" / "headline_spec.json", ROOT)
    assert read_result(ROOT / "docs" / "results" / "headline.json")["rows"] == got["rows"]
