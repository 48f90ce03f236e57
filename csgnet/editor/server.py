"""The CSG editor's browser page: a ``viser`` server over a :class:`~csgnet.editor.CSGEditSession`.

``viser`` (the ``editor`` extra) is imported when a :class:`CSGEditorApp` is made. The page's main view shows
the live render, framed by the camera when the page opens, after "Run text" and on reset (2D: the 64x64
canvas as an image plane facing the camera, upscaled; 3D: the voxel volume's marching-cubes mesh). The side
panel holds one slider per primitive parameter and a drop-down per primitive (by name) and operator, the
program text (editable, "Run text"), the last error, and undo / redo / reset / export buttons.
:attr:`CSGEditorApp.state` holds what the page shows.
"""
from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from shapeedit import check_port, frame_box, import_viser, show_pose, viser_server

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


class CSGEditorApp:
    """A running CSG editor page (see :class:`shapeprog.editor.server.EditorApp` for the ShapeAssembly one).

    Args:
        session: the program to edit.
        host, port: where to serve (``127.0.0.1``: this machine only).
        export_dir: the folder exports go to.
        source_text: the text as given (shown when it does not parse).
    """

    def __init__(self, session: CSGEditSession, host: str = "127.0.0.1", port: int = 8080, export_dir=".",
                 source_text: str | None = None):
        check_port(port)
        import_viser()
        self.export_dir = Path(export_dir)
        if not self.export_dir.is_dir():
            raise FileNotFoundError(f"{export_dir}: the export folder does not exist")
        self.session = session
        self.source_text = session.text if source_text is None else source_text
        self.lock = threading.RLock()
        self._syncing = False
        self._handles: dict = {}
        self._names: tuple = ()
        self.state: dict = {"version": 0}
        self.server = viser_server(host, port)
        if session.dim == 2:  # viser draws an image with its top row towards -y (OpenCV's camera frame)
            self.server.scene.set_up_direction("-y")
        gui = self.server.gui
        gui.add_markdown(f"**CSG program ({session.dim}D)**")
        self.status = gui.add_markdown("")
        self.error_md = gui.add_markdown("")
        self.image = None
        if session.dim == 2:
            self.image = self.server.scene.add_image("/render", self._picture(), PLANE_SIZE, PLANE_SIZE, format="png",
                                                     cast_shadow=False, receive_shadow=False)
        row = gui.add_button_group("Edit", ("Undo", "Redo", "Reset"))
        row.on_click(lambda e: {"Undo": self.undo, "Redo": self.redo, "Reset": self.reset}[e.target.value]())
        gui.add_button("Export text and render", hint=f"into {self.export_dir}").on_click(lambda _: self.export())
        self.text_box = gui.add_text("Program", self.source_text)
        gui.add_button("Run text").on_click(lambda _: self.run_text())
        self.folder = None
        with self.lock:
            self._rebuild()
            self._draw()
            self.frame()

    def _picture(self) -> np.ndarray:
        c = self.session.canvas
        if c is None:
            c = np.zeros((64, 64), bool)
        img = np.where(c, 0, 255).astype(np.uint8)
        img = np.repeat(np.repeat(img, IMAGE_SCALE, 0), IMAGE_SCALE, 1)
        return np.repeat(img[:, :, None], 3, 2)

    def _rebuild(self) -> None:
        if self.folder is not None:
            self.folder.remove()
        gui = self.server.gui
        self.folder = gui.add_folder("Parameters")
        self._handles = {}
        cs = self.session.controls()
        self._names = tuple(c.name for c in cs)
        self._syncing = True
        try:
            with self.folder:
                for c in cs:
                    self._handles[c.name] = self._add(c)
        finally:
            self._syncing = False

    def _add(self, c: Control):
        gui = self.server.gui
        if c.kind == CHOICE:
            h = gui.add_dropdown(c.label, tuple(c.choices), initial_value=c.value, hint=c.name)
        else:
            h = gui.add_slider(c.label, min=c.low, max=c.high, step=1, initial_value=c.value, hint=c.name)
        h.on_update(lambda e, name=c.name: self._changed(name, e.target.value))
        return h

    def _sync(self) -> None:
        cs = self.session.controls()
        if tuple(c.name for c in cs) != self._names:
            self._rebuild()
            return
        self._syncing = True
        try:
            for c in cs:
                if self._handles[c.name].value != c.value:
                    self._handles[c.name].value = c.value
        finally:
            self._syncing = False

    def _changed(self, name: str, value) -> None:
        if self._syncing:
            return
        with self.lock:
            t0 = time.perf_counter()
            control = next((c for c in self.session.controls() if c.name == name), None)
            ok = self.session.set({name: page_value(control, value)})  # NaN is left for the control's check
            self._sync()
            self._draw(t0 if ok else None)

    def _step(self, move) -> bool:
        with self.lock:
            done = move()
            self._sync()
            self._draw()
            return done

    def undo(self) -> bool:
        return self._step(self.session.undo)

    def redo(self) -> bool:
        return self._step(self.session.redo)

    def reset(self) -> bool:
        with self.lock:
            done = self._step(self.session.reset)
            self.frame()
            return done

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

    def export(self) -> list[Path]:
        with self.lock:
            try:
                paths = self.session.export(self.export_dir)
            except (OSError, ValueError) as e:
                self.session.error = e
                self._draw()
                return []
            self.status.content = "wrote " + ", ".join(f"`{p.name}`" for p in paths)
            self.state["exported"] = [str(p) for p in paths]
            return paths

    def run_text(self, text: str | None = None) -> bool:
        with self.lock:
            if text is not None:
                self.text_box.value = text
            ok = self.session.set_text(self.text_box.value)
            if ok:
                self._rebuild()
            self._draw()
            if ok:
                self.frame()
            return ok

    def _draw(self, t0: float | None = None) -> None:
        s = self.session
        if s.canvas is not None:
            if s.dim == 2:
                self.image.image = self._picture()
            else:
                from ..export import voxels_to_mesh

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

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    def handle(self, name: str):
        """The GUI handle of control ``name`` (setting its ``value`` acts as a change in the page)."""
        return self._handles[name]

    def stop(self) -> None:
        self.server.stop()
