"""Results as data: the files the table commands write, and the docs' tables generated from them.

A result file is JSON (``FORMAT``, version ``VERSION``)::

    {"format": "shape-programs result", "version": 1, "title": "...",
     "columns": [{"key": "iou", "label": "IoU (%)", "scale": 100, "digits": 2}, ...],
     "rows": [{"method": "...", "iou": 0.8123, ...}, ...],
     "notes": ["..."], "command": "python -m ...", "machine": "...", "date": "YYYY-MM-DD"}

A docs page shows one with a block whose first line names the file (relative to the repository root)::

    <!-- result: docs/results/csgnet/table5.json -->
    ...the table, written by `python -m shapeio.results`...
    <!-- end result -->

``python -m shapeio.results README.md docs/*.md docs/tables/*.md`` rewrites every such block from its file; with
``--check`` it changes nothing and exits 1 when a block differs, so that a test keeps the docs and the data
in step: a table and the number quoted from it cannot disagree.
"""
from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import re
import sys
from pathlib import Path
from typing import Iterable, Sequence

from .files import atomic_write

__all__ = ["FORMAT", "VERSION", "MAX_RESULT_BYTES", "column", "make_result", "write_result", "read_result",
           "markdown", "sync", "machine", "headline"]

FORMAT = "shape-programs result"
VERSION = 1
MAX_RESULT_BYTES = 4 * 2**20
"""Largest result file read (a result is a table, not a data set)."""

_BLOCK = re.compile(r"(<!-- result: (?P<path>[^\s>]+) -->\n)(?P<body>.*?)(<!-- end result -->)", re.DOTALL)


def column(key: str, label: str, digits: int | None = None, scale: float = 1.0) -> dict:
    """A column: ``rows[i][key]`` shown under ``label``; numbers times ``scale`` with ``digits`` decimals."""
    out = {"key": key, "label": label}
    if digits is not None:
        out["digits"] = int(digits)
    if scale != 1.0:
        out["scale"] = float(scale)
    return out


def machine() -> str:
    """What the figures were measured on: architecture, CPUs, torch (when imported) and the load."""
    torch = sys.modules.get("torch")
    parts = [platform.machine(), f"{os.cpu_count()} CPUs"]
    if torch is not None:
        parts.append(f"torch {torch.__version__}")
    if hasattr(os, "getloadavg"):
        parts.append(f"load average {os.getloadavg()[0]:.1f}")
    return ", ".join(parts)


def make_result(title: str, columns: Sequence[dict], rows: Iterable[dict], notes: Iterable[str] = (),
                command: str | None = None) -> dict:
    """A result (see the module docstring); ``command`` defaults to this process's command line."""
    columns = [dict(c) for c in columns]
    keys = [c.get("key") for c in columns]
    if not columns or not all(isinstance(k, str) and k for k in keys) or len(set(keys)) != len(keys):
        raise ValueError(f"columns need distinct, non-empty keys, got {keys}")
    rows = [dict(r) for r in rows]
    for i, r in enumerate(rows):
        missing = [k for k in keys if k not in r]
        if missing:
            raise ValueError(f"row {i} of {title!r} has no {missing}")
    return {"format": FORMAT, "version": VERSION, "title": str(title), "columns": columns, "rows": rows,
            "notes": [str(n) for n in notes],
            "command": command or " ".join(["python", *sys.argv]),
            "machine": machine(), "date": datetime.date.today().isoformat()}


def _clean(value):
    """NaN and infinities as None (JSON has neither)."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def write_result(path, result: dict) -> Path:
    """Write ``result`` (:func:`make_result`) as JSON, atomically; returns the path."""
    return atomic_write(path, json.dumps(_clean(result), indent=1, ensure_ascii=False) + "\n", mkdir=True)


def read_result(path) -> dict:
    """Read a result file, checking its format, version and shape; errors name the file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such result file")
    if path.stat().st_size > MAX_RESULT_BYTES:
        raise ValueError(f"{path}: larger than {MAX_RESULT_BYTES} bytes, not a result file")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"{path}: not a result file ({e})") from None
    if not isinstance(data, dict) or data.get("format") != FORMAT:
        raise ValueError(f"{path}: not a result file (no 'format': {FORMAT!r})")
    if data.get("version") != VERSION:
        raise ValueError(f"{path}: result format version {data.get('version')!r}, this reader knows {VERSION}")
    try:
        make_result(data["title"], data["columns"], data["rows"], data.get("notes", ()), data.get("command", "-"))
    except (KeyError, TypeError, ValueError, AttributeError) as e:
        raise ValueError(f"{path}: malformed result ({e})") from None
    return data


def _cell(value, col: dict) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        return str(value).replace("|", "\\|")
    if "scale" in col:
        value = value * col["scale"]
    digits = col.get("digits")
    if digits is None:
        return f"{value:,}" if isinstance(value, int) else f"{value:g}"
    return f"{value:,.{digits}f}"


def markdown(result: dict) -> str:
    """The result as a markdown table, its notes, and the command and machine that produced it."""
    cols = result["columns"]

    def numeric(c):
        values = [r.get(c["key"]) for r in result["rows"]]
        return any(isinstance(v, (int, float)) and not isinstance(v, bool) for v in values)

    lines = ["| " + " | ".join(re.sub(r"(?<!\\)\|", r"\\|", c["label"]) for c in cols) + " |",
             "|" + "|".join("---:" if numeric(c) else "---" for c in cols) + "|"]
    for r in result["rows"]:
        lines.append("| " + " | ".join(_cell(r.get(c["key"]), c) for c in cols) + " |")
    out = [f"**{result['title']}**", "", *lines, ""]
    out += [n for n in result.get("notes", ()) if n] + ([""] if result.get("notes") else [])
    out.append(f"`{result.get('command', '')}` ({result.get('machine', '')}, {result.get('date', '')})")
    return "\n".join(out) + "\n"


def sync(pages: Iterable, root=".", check: bool = False) -> list[Path]:
    """Rewrite the result blocks of ``pages`` from their files (paths relative to ``root``); returns the
    pages whose blocks changed (with ``check``, would change: nothing is written)."""
    changed = []
    for page in map(Path, pages):
        text = page.read_text(encoding="utf-8")

        def body(m):
            return m.group(1) + markdown(read_result(Path(root) / m.group("path"))) + m.group(4)

        try:
            new = _BLOCK.sub(body, text)
        except (OSError, ValueError) as e:
            raise ValueError(f"{page}: {e}") from None
        if new != text:
            changed.append(page)
            if not check:
                atomic_write(page, new)
    return changed


def headline(spec_path, root=".", out: str = "FILE") -> dict:
    """A summary result whose cells are picked from other result files, as a JSON spec names them::

        {"title": "...", "notes": ["..."],
         "rows": [{"system": "...", "measure": "...", "file": "docs/results/x.json",
                   "row": {"method": "..."}, "column": "iou", "paper": "91.33", "page": "docs/x.md"}, ...]}

    Each row's ``ours`` is the cell of ``column`` in the row of ``file`` whose values match ``row``, formatted as
    that file formats it, so that a figure quoted in the summary is the figure of its table."""
    spec_path = Path(spec_path)
    try:
        spec = json.loads(spec_path.read_text(encoding="utf-8"))
        items = spec["rows"]
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, KeyError, TypeError) as e:
        raise ValueError(f"{spec_path}: not a headline spec ({e})") from None
    rows = []
    for i, item in enumerate(items):
        try:
            src = read_result(Path(root) / item["file"])
            col = next(c for c in src["columns"] if c["key"] == item["column"])
            match = [r for r in src["rows"] if all(r.get(k) == v for k, v in item["row"].items())]
        except (KeyError, TypeError, StopIteration) as e:
            raise ValueError(f"{spec_path}: row {i}: no column {item.get('column')!r} ({e})") from None
        if len(match) != 1:
            raise ValueError(f"{spec_path}: row {i}: {len(match)} rows of {item['file']} match {item['row']}")
        rows.append({"system": item["system"], "measure": item["measure"], "ours": _cell(match[0][col["key"]], col),
                     "paper": item.get("paper", "–"), "page": item.get("page", "")})
    cols = [column("system", "system"), column("measure", "measure"), column("ours", "ours"),
            column("paper", "paper"), column("page", "details")]
    return make_result(spec.get("title", "Headline figures"), cols, rows, spec.get("notes", ()),
                       command=f"python -m shapeio.results --headline {spec_path} --out {out}")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m shapeio.results",
                                 description="Rewrite the result tables of docs pages from their result files.")
    ap.add_argument("pages", nargs="*", help="markdown pages with <!-- result: FILE --> blocks")
    ap.add_argument("--root", default=".", help="the folder result paths are relative to (default: .)")
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 if a page is out of step")
    ap.add_argument("--headline", metavar="SPEC", help="write the summary result that SPEC (JSON) picks from other "
                    "result files to --out (before the pages are rewritten)")
    ap.add_argument("--out", help="with --headline: the result file to write")
    args = ap.parse_args(argv)
    if not args.pages and not args.headline:
        ap.error("give markdown pages, or --headline SPEC --out FILE")
    if args.headline and not args.out:
        ap.error("--headline needs --out")
    try:
        if args.headline:
            print(f"wrote {write_result(args.out, headline(args.headline, args.root, args.out))}")
        changed = sync(args.pages, args.root, args.check)
    except (OSError, ValueError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    for page in changed:
        print(f"{'out of step' if args.check else 'rewrote'}: {page}")
    return 1 if args.check and changed else 0


if __name__ == "__main__":
    raise SystemExit(main())
