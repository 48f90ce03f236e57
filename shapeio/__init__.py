"""The file formats shared by ``csgnet`` and ``shapeprog`` (which do not import each other).

One module per format family, NumPy-level (no torch needed); see ``docs/shapeio.md``:

* :mod:`shapeio.files`: :func:`atomic_write`, :func:`write_new`, :func:`refuse_overwrite`,
  :func:`remove_stale_temps`, :class:`InputError`.
* :mod:`shapeio.image`: the PNG writer, users' images as bool masks, folders of target images.
* :mod:`shapeio.mesh`: the mesh writer (OBJ, PLY, GLB) and users' meshes.
* :mod:`shapeio.points`: point clouds (binary PLY, OBJ ``v`` lines).
* :mod:`shapeio.silhouettes`: the silhouette set's ``.npz`` layout and version.

``import shapeio`` loads only :mod:`shapeio.files`; the format modules are imported by name.
"""

from .files import InputError, atomic_write, refuse_overwrite, remove_stale_temps, write_new

__all__ = ["InputError", "atomic_write", "refuse_overwrite", "remove_stale_temps", "write_new"]
