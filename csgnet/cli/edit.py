"""``edit``: a CSG program in the browser editor (the optional ``editor`` extra)."""
from __future__ import annotations

import sys
from pathlib import Path

from shapeedit import editor_preflight, port_argument, serve_until_interrupted

from ..primitives import primitives


def cmd_edit(args) -> int:
    from ..editor import CSGEditSession  # lazy: loaded when the command runs

    problem = editor_preflight(args.export_dir)
    if problem:
        print(f"error: {problem}", file=sys.stderr)
        return 1
    text, name = args.program, "csg"
    path = Path(args.program)
    if path.is_file():  # a file holding a program (e.g. a parse result): its first non-blank line
        try:
            lines = [ln.strip() for ln in path.read_text(encoding="utf-8").splitlines() if ln.strip()]
        except UnicodeDecodeError as e:
            print(f"error: {path}: not UTF-8 text (byte offset {e.start})", file=sys.stderr)
            return 1
        if not lines:
            print(f"error: {path}: no program in the file", file=sys.stderr)
            return 1
        text, name = lines[0], path.stem
    if args.dim is None:
        args.dim = 3 if any(h + "(" in text for p in primitives(3) for h in (p.kind, p.long) if h) else 2
    session = CSGEditSession(text, args.dim, name=name)
    if session.error is not None:
        print(f"error: {session.error} (the page shows it; fix the text there)", file=sys.stderr)
    from ..editor.server import CSGEditorApp  # lazy: loaded when the command runs

    app = CSGEditorApp(session, host=args.host, port=args.port, export_dir=args.export_dir, source_text=text)
    return serve_until_interrupted(app, repr(text), args.export_dir, not args.no_browser)


def register(sub) -> None:
    """Add this module's subcommands to ``python -m csgnet``."""
    ed = sub.add_parser("edit", help="edit a program in the browser (needs the 'editor' extra: viser)",
                        description="Serve an editor page for a CSG program: the live render, one slider per "
                                    "primitive parameter, undo / redo / reset, export. Runs until interrupted. "
                                    "See docs/editor.md.")
    ed.add_argument("program", help='program text, e.g. "c(32,32,28)s(32,32,20)-", or a file whose first line is one')
    ed.add_argument("--dim", type=int, choices=(2, 3), default=None, help="2 or 3 (default: guessed from the text)")
    ed.add_argument("--port", type=port_argument, default=8080, help="port of the page (0: a free one)")
    ed.add_argument("--host", default="127.0.0.1", help="address to bind (default: this machine only)")
    ed.add_argument("--export-dir", default=".", help="the folder exports are written to (never elsewhere)")
    ed.add_argument("--no-browser", action="store_true", help="do not open a browser")
    ed.set_defaults(func=cmd_edit)
