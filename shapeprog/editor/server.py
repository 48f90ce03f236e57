"""The editor's browser page: a ``viser`` server over an :class:`~shapeprog.editor.session.EditSession`.

``viser`` (the ``editor`` extra) is imported when an :class:`EditorApp` is made, never when this module is
imported. The page shows:

* the executed shape in 3D (one mesh per program line, coloured by line as in the PNG pictures; orbit and
  zoom), y up, framed by the camera when the page opens, after "Run text" and on reset (seen from the PNG
  pictures' direction, the target included);
* a target shape as a grey wireframe with the live corner distance to it (goal-directed mode);
* one GUI control per free parameter (sliders for floats and counts, checkboxes, drop-downs), grouped by
  program line; moving one re-executes the program and replaces the geometry;
* the parts a control moves, outlined in yellow when the control changes or is picked in "Show the parts
  moved by" (viser reports no hover on GUI controls); a click on a part selects its program line and
  lists the controls that move it;
* the program text, editable ("Run text"), the last error (file, line, column), undo / redo / reset and
  export (text, OBJ, PNG) buttons;
* for a macro program, a checkbox that shows the expanded base-language program and its parameters.

:attr:`EditorApp.state` holds what the page shows (for tests and benchmarks).
"""
from __future__ import annotations

import dataclasses
import time

import numpy as np

from shapeedit import frame_box, show_pose
from shapeedit.page import EditorPage

from ..geometry import CORNER_SIGNS, mesh_arrays
from ..picture import VIEW_DIRECTION, part_colors
from .controls import BOOL, FLOAT, INT, Control, page_value
from .session import EditSession

__all__ = ["EditorApp", "cuboid_edges"]

#: Step of float sliders (the corpus writes 3 decimals).
FLOAT_STEP = 0.001
_HIGHLIGHT_RGB = (255, 200, 0)
_TARGET_RGB = (110, 110, 110)
# the 12 edges of a cuboid: corner pairs that differ in one sign (spec corner order)
_EDGES = [(i, j) for i in range(8) for j in range(i + 1, 8)
          if int((CORNER_SIGNS[i] != CORNER_SIGNS[j]).sum()) == 1]


def cuboid_edges(corners) -> np.ndarray:
    """``(12 L, 2, 3) float32`` edge segments of cuboids ``corners: (L, 8, 3)`` (a wireframe)."""
    c = np.asarray(corners.detach().cpu() if hasattr(corners, "detach") else corners, dtype=np.float32)
    i, j = np.array(_EDGES).T
    return np.stack([c[:, i], c[:, j]], axis=2).reshape(-1, 2, 3)


def _signature(cs: list[Control]) -> tuple:
    """What the page's controls are made from, values aside."""
    return tuple((c.name, c.kind, c.low, c.high, c.choices, c.line) for c in cs)


def _heads(cs: list[Control]) -> dict[int, str]:
    """The folder title of each program line's controls (``line 6 attach(cube1, cube0)``)."""
    return {c.line: c.label.rsplit(" ", 1)[0] for c in cs}


class EditorApp(EditorPage):
    """A running editor page (what it shares with the CSG editor's is :class:`shapeedit.page.EditorPage`'s).

    Args:
        session: the program to edit.
        host: the address to bind (``127.0.0.1``: this machine only).
        port: the port (0 is not allowed by viser; pick a free one).
        export_dir: the folder exports are written to (nothing is written elsewhere).

    Attributes:
        server: the ``viser.ViserServer``.
        state: ``{"version", "corners" (L, 8, 3) array, "lines" (L,), "text", "error", "distance",
            "highlight" (leaf indices), "update_ms"}``, replaced after every change.
    """

    def __init__(self, session: EditSession, host: str = "127.0.0.1", port: int = 8080, export_dir=".",
                 source_text: str | None = None):
        super().__init__(session, host, port, export_dir, source_text)
        self.base = session  # the session as opened (a macro program's, when it is one)
        self._folders: dict[int, object] = {}
        self._signature = None
        self._line_nodes: list = []
        self._layout = None
        self.server.scene.set_up_direction("+y")
        self.server.gui.configure_theme(control_width="large")
        self._build_static()
        with self.lock:
            self._rebuild_controls()
            self._draw(highlight=())
            self.frame()

    # -- page parts that never change
    def _build_static(self) -> None:
        gui = self.server.gui
        s = self.session
        self._add_head(f"**{s.file}**", "Export text, OBJ and PNG")
        self.expanded = None
        if s.is_macro:
            self.expanded = gui.add_checkbox("Expanded base-language parameters", False)
            self.expanded.on_update(lambda _: self._toggle_expanded())
        self.highlight_pick = gui.add_dropdown("Show the parts moved by", ("(none)",), initial_value="(none)")
        self.highlight_pick.on_update(lambda _: self._pick_highlight())
        with gui.add_folder("Program text", expand_by_default=False):
            self.text_box = gui.add_text("Program", self.source_text, multiline=True)
            run = gui.add_button("Run text")
            run.on_click(lambda _: self.run_text())
        self.controls_folder = None

    # -- controls
    def _rebuild_controls(self) -> None:
        """Remove and re-add the controls (the set of controls changed)."""
        if self.controls_folder is not None:
            self.controls_folder.remove()
        self._handles = {}
        cs = self.session.controls()
        self._controls = {c.name: c for c in cs}
        self._signature = _signature(cs)
        gui = self.server.gui
        self.controls_folder = gui.add_folder("Parameters")
        with self._quiet():
            with self.controls_folder:
                groups: dict[int, list[Control]] = {}
                for c in self._controls.values():
                    groups.setdefault(c.line, []).append(c)
                self._folders = {}
                heads = _heads(list(self._controls.values()))
                for line, cs in groups.items():
                    self._folders[line] = folder = gui.add_folder(heads[line],
                                                                  expand_by_default=len(self._controls) <= 40)
                    with folder:
                        for c in cs:
                            self._handles[c.name] = self._add_control(c)
            names = ("(none)",) + tuple(self._controls)
            self.highlight_pick.options = names
            self.highlight_pick.value = "(none)"

    def _add_control(self, c: Control):
        gui = self.server.gui
        label = c.label.rsplit(" ", 1)[1]
        hint = f"{c.name} (line {c.line})"
        if c.kind == FLOAT:
            h = gui.add_slider(label, min=float(c.low), max=float(c.high), step=FLOAT_STEP,
                               initial_value=float(c.value), hint=hint)
        elif c.kind == INT:
            h = gui.add_slider(label, min=int(c.low), max=int(c.high), step=1, initial_value=int(c.value), hint=hint)
        elif c.kind == BOOL:
            h = gui.add_checkbox(label, bool(c.value), hint=hint)
        else:
            h = gui.add_dropdown(label, tuple(c.choices), initial_value=c.value, hint=hint)
        h.on_update(lambda e, name=c.name: self._changed(name, e.target.value))
        return h

    def _sync_values(self, cuboids: bool = True) -> None:
        """Put the session's values into the controls (after undo / redo / a discrete or refused edit); the
        controls are rebuilt only when their set (names, kinds, ranges, choices) changed. ``cuboids=False``
        leaves the cuboids each control moves to be found later."""
        if self.session.program is None:
            return
        cs = self.session.controls(cuboids)
        if _signature(cs) != self._signature:
            self._rebuild_controls()
            return
        with self._quiet():
            self._put_values(cs)
            for line, head in _heads(cs).items():  # a new attach target is in its line's title
                if self._folders[line].label != head:
                    self._folders[line].label = head
            self._controls = {c.name: c for c in cs}

    # -- events
    def _set(self, name: str, value, t0: float) -> None:
        c = self._controls.get(name)
        value = page_value(c, value)  # a browser slider's 0.30000000000000004; NaN is left for the check
        ok = self.session.set({name: value})
        if not ok:
            self._sync_values()
            self._show()
            return
        if c is not None and c.kind == FLOAT:  # numbers only: the controls and the cuboids they move stay
            self._controls[name] = dataclasses.replace(c, value=value)
            self._draw(highlight=self._controls[name].cuboids, t0=t0)
            return
        # a new structure: the geometry first, then the cuboids each control moves (a backward pass per
        # leaf) and the highlight
        self._sync_values(cuboids=False)
        self._draw(highlight=(), t0=t0)
        self._controls = {c.name: c for c in self.session.controls()}
        self._draw(highlight=self._controls[name].cuboids if name in self._controls else (), geometry=False)

    def _redraw(self) -> None:
        self._draw(highlight=())

    def frame(self) -> None:
        """Point the view at the shape and the target (their cuboids' bounding box; a unit box when there is
        no geometry), from the PNG pictures' direction, for new pages, "Reset View" and the pages open now."""
        s = self.session
        corners = [x.corners.detach().reshape(-1, 3).numpy() for x in (s.shape, s.target)
                   if x is not None and len(x)]
        if corners:
            points = np.concatenate(corners)
            low, high = points.min(0), points.max(0)
        else:
            low, high = np.full(3, -0.5), np.full(3, 0.5)
        pose = frame_box(low, high, direction=VIEW_DIRECTION, up=(0, 1, 0))
        show_pose(self.server, pose)
        self.state["camera"] = pose

    def _toggle_expanded(self) -> None:
        if self._syncing:
            return
        with self.lock:
            if self.expanded.value:
                sess = EditSession(self.base.expanded_text(), self.base.file + " (expanded)", name=self.base.name)
                sess.target = self.base.target
                self.session = sess
            else:
                self.session = self.base
            self._rebuild_controls()
            self._draw(highlight=())

    def _pick_highlight(self) -> None:
        if self._syncing:
            return
        with self.lock:
            c = self._controls.get(self.highlight_pick.value)
            self._draw(highlight=() if c is None else c.cuboids, geometry=False)

    def _clicked(self, line: int) -> None:
        with self.lock:
            shape = self.session.shape
            leaves = tuple(int(k) for k in np.nonzero(shape.line.numpy() == line)[0])
            movers = [c.name for c in self._controls.values() if set(c.cuboids) & set(leaves)]
            text = self.session.text.split("\n")
            shown = text[line].strip() if line < len(text) else ""
            self.status.content = (f"line {line + 1}: `{shown}` — moved by {len(movers)} controls: "
                                   + ", ".join(f"`{m}`" for m in movers[:12]) + (" ..." if len(movers) > 12 else ""))
            self._draw(highlight=leaves, geometry=False)

    # -- drawing
    def _show(self) -> None:
        """The error and status texts."""
        s = self.session
        err = s.error
        content = "" if err is None else f"**Error:** `{err}`"
        if self.error_md.content != content:
            self.error_md.content = content
        n = 0 if s.shape is None else len(s.shape)
        d = s.distance()
        parts = [f"{n} cuboids", f"{len(self._controls)} controls"]
        if d is not None:
            parts.append(f"corner distance to the target: **{d:.4f}**")
        if self.state.get("update_ms") is not None:
            parts.append(f"update {self.state['update_ms']:.1f} ms")
        self.status.content = " · ".join(parts)
        self.state.update(error=None if err is None else str(err), distance=d)

    def _draw(self, highlight=(), t0: float | None = None, geometry: bool = True) -> None:
        s = self.session
        scene = self.server.scene
        if geometry:
            if s.shape is not None:
                corners = s.shape.corners.detach()
                lines = s.shape.line.numpy()
                colors = part_colors(len(lines), lines)
                groups = sorted(set(lines.tolist()))
                layout = [(ln, int((lines == ln).sum())) for ln in groups]
                same = layout == self._layout
                if not same:
                    for node in self._line_nodes:
                        node.remove()
                    self._line_nodes = []
                for k, ln in enumerate(groups):
                    idx = np.nonzero(lines == ln)[0]
                    v, f = mesh_arrays(corners[idx])
                    if same:  # only the vertices move: one small message per line
                        self._line_nodes[k].vertices = v.numpy().astype(np.float32)
                        continue
                    rgb = tuple(int(x) for x in colors[idx[0]])
                    node = scene.add_mesh_simple(f"/shape/part{k}", v.numpy(), f.numpy(), color=rgb,
                                                 flat_shading=True, side="double")
                    node.on_click(lambda _, ln=int(ln): self._clicked(ln))
                    self._line_nodes.append(node)
                self._layout = layout
                if s.target is not None and "target" not in self.state:
                    scene.add_line_segments("/target", cuboid_edges(s.target.corners), _TARGET_RGB,
                                            thickness=0.004)
                    self.state["target"] = True
                self.state.update(corners=corners.numpy().copy(), lines=lines.copy())
            self.text_box.value = s.text if s.program is not None else self.source_text
        if s.shape is not None and len(highlight):
            scene.add_line_segments("/highlight", cuboid_edges(s.shape.corners[list(highlight)]), _HIGHLIGHT_RGB,
                                    thickness=0.008)
        else:
            scene.add_line_segments("/highlight", np.zeros((0, 2, 3), np.float32), _HIGHLIGHT_RGB, thickness=0.008)
        self.state.update(version=self.state["version"] + 1, text=s.text, highlight=tuple(highlight))
        if t0 is not None:
            self.state["update_ms"] = 1000 * (time.perf_counter() - t0)
        self._show()
