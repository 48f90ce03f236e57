"""The CSG editor's browser page: a ``viser`` server over a :class:`~csgnet.editor.CSGEditSession`.

``viser`` (the ``editor`` extra) is imported when a :class:`CSGEditorApp` is made. The page's main view shows
the live render, framed by the camera when the page opens, after "Run text" and on reset (2D: the 64x64
canvas as an image plane facing the camera, upscaled; 3D: the voxel volume's marching-cubes mesh). The side
panel holds one slider per primitive parameter and a drop-down per primitive (by name) and operator, the
program text (editable, "Run text"), the last error, and undo / redo / reset / export buttons.
:attr:`CSGEditorApp.state` holds what the page shows.
"""
from __future__ import annotations

import time

import numpy as np

from shapeedit import frame_box, show_pose
from shapeedit.page import EditorPage

from ..export import voxels_to_mesh
from . import CHOICE, CSGEditSession, Control, page_value

__all__ = ["CSGEditorApp"]

#: Pixels per canvas pixel in the page's 2D image.
IMAGE_SCALE = 6
#: Side of the 2D image plane in scene units (the plane is centred on the origin, facing the camera at -z).
PLANE_SIZE = 1.0
#: From the shape towards the camera in the 3D view (three-quarter view, z up as viser's scene).
VIEW_DIRECTION_3D = (1.0, -1.2, 0.9)
#: The 3D mesh's coordinates: voxel index v maps to (v - VOXEL_CENTRE) / VOXEL_HALF, so the canvas is [-1, 1]^3.
VOXEL_CENTRE, VOXEL_HALF = 31.5, 32.0


class CSGEditorApp(EditorPage):
    """A running CSG editor page (see :class:`shapeprog.editor.server.EditorApp` for the ShapeAssembly one; what
    both share is :class:`shapeedit.page.EditorPage`'s).

    Args:
        session: the program to edit.
        host, port: where to serve (``127.0.0.1``: this machine only).
        export_dir: the folder exports go to.
        source_text: the text as given (shown when it does not parse).
    """

    def __init__(self, session: CSGEditSession, host: str = "127.0.0.1", port: int = 8080, export_dir=".",
                 source_text: str | None = None):
        super().__init__(session, host, port, export_dir, source_text)
        self._names: tuple = ()
        if session.dim == 2:  # viser draws an image with its top row towards -y (OpenCV's camera frame)
            self.server.scene.set_up_direction("-y")
        self._add_head(f"**CSG program ({session.dim}D)**", "Export text and render")
        self.image = None
        if session.dim == 2:
            self.image = self.server.scene.add_image("/render", self._picture(), PLANE_SIZE, PLANE_SIZE, format="png",
                                                     cast_shadow=False, receive_shadow=False)
        gui = self.server.gui
        self.text_box = gui.add_text("Program", self.source_text)
        gui.add_button("Run text").on_click(lambda _: self.run_text())
        self.folder = None
        with self.lock:
            self._rebuild_controls()
            self._draw()
            self.frame()

    def _picture(self) -> np.ndarray:
        c = self.session.canvas
        if c is None:
            c = np.zeros((64, 64), bool)
        img = np.where(c, 0, 255).astype(np.uint8)
        img = np.repeat(np.repeat(img, IMAGE_SCALE, 0), IMAGE_SCALE, 1)
        return np.repeat(img[:, :, None], 3, 2)

    def _rebuild_controls(self) -> None:
        if self.folder is not None:
            self.folder.remove()
        gui = self.server.gui
        self.folder = gui.add_folder("Parameters")
        self._handles = {}
        cs = self.session.controls()
        self._names = tuple(c.name for c in cs)
        with self._quiet(), self.folder:
            for c in cs:
                self._handles[c.name] = self._add(c)

    def _add(self, c: Control):
        gui = self.server.gui
        if c.kind == CHOICE:
            h = gui.add_dropdown(c.label, tuple(c.choices), initial_value=c.value, hint=c.name)
        else:
            h = gui.add_slider(c.label, min=c.low, max=c.high, step=1, initial_value=c.value, hint=c.name)
        h.on_update(lambda e, name=c.name: self._changed(name, e.target.value))
        return h

    def _sync_values(self) -> None:
        cs = self.session.controls()
        if tuple(c.name for c in cs) != self._names:
            self._rebuild_controls()
            return
        with self._quiet():
            self._put_values(cs)

    def _set(self, name: str, value, t0: float) -> None:
        control = next((c for c in self.session.controls() if c.name == name), None)
        ok = self.session.set({name: page_value(control, value)})  # NaN is left for the control's check
        self._sync_values()
        self._draw(t0 if ok else None)

    def _redraw(self) -> None:
        self._draw()

    def _show(self) -> None:
        self._draw()

    def frame(self) -> None:
        """Point the view at the render (2D: the image plane, straight on; 3D: the shape's bounding box, or
        the whole canvas when it is empty) for new pages, "Reset View" and the pages open now."""
        s = self.session
        if s.dim == 2:
            half = PLANE_SIZE / 2
            pose = frame_box((-half, -half, 0.0), (half, half, 0.0), direction=(0, 0, -1), up=(0, -1, 0))
        else:
            filled = np.argwhere(np.asarray(s.canvas)) if s.canvas is not None else np.zeros((0, 3))
            if len(filled):  # voxel i spans [i - 0.5, i + 0.5]
                low, high = filled.min(0) - 0.5, filled.max(0) + 0.5
            else:
                low, high = np.full(3, -0.5), np.full(3, 63.5)
            pose = frame_box((low - VOXEL_CENTRE) / VOXEL_HALF, (high - VOXEL_CENTRE) / VOXEL_HALF,
                             direction=VIEW_DIRECTION_3D, up=(0, 0, 1))
        show_pose(self.server, pose)
        self.state["camera"] = pose

    def _draw(self, t0: float | None = None) -> None:
        s = self.session
        if s.canvas is not None:
            if s.dim == 2:
                self.image.image = self._picture()
            else:
                v, f = voxels_to_mesh(s.canvas)
                if len(f):
                    self.server.scene.add_mesh_simple("/shape", (v - VOXEL_CENTRE) / VOXEL_HALF, f,
                                                      color=(90, 160, 230), flat_shading=True)
                else:
                    self.server.scene.remove_by_name("/shape")
            if s.program is not None and self.text_box.value != s.text:
                self.text_box.value = s.text
        self.error_md.content = "" if s.error is None else f"**Error:** `{s.error}`"
        if t0 is not None:
            self.state["update_ms"] = 1000 * (time.perf_counter() - t0)
        filled = 0 if s.canvas is None else int(np.asarray(s.canvas).sum())
        self.status.content = f"{filled} filled {'pixels' if s.dim == 2 else 'voxels'}"
        self.state.update(version=self.state["version"] + 1, text=s.text,
                          canvas=None if s.canvas is None else np.asarray(s.canvas).copy(),
                          error=None if s.error is None else str(s.error))
