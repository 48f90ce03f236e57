"""Writes the example shapes shipped in this folder (deterministic; run from the repository root):

    python examples/make_examples.py

2D: drawings at sizes other than 64×64, with either polarity, which ``python -m csgnet parse`` binarises
and fits into 64×64. 3D: small meshes that ``parse`` voxelises to 64³.
"""
from pathlib import Path

import trimesh
from PIL import Image, ImageDraw

from shapeio import atomic_write

HERE = Path(__file__).parent


def house() -> Image.Image:  # dark shape on a light background, 256×256
    im = Image.new("L", (256, 256), 245)
    d = ImageDraw.Draw(im)
    d.rectangle([64, 120, 192, 224], fill=20)
    d.polygon([(48, 124), (128, 40), (208, 124)], fill=20)
    d.rectangle([112, 168, 144, 224], fill=245)  # the door
    return im


def ring() -> Image.Image:  # light shape on a dark background, 200×200
    im = Image.new("L", (200, 200), 0)
    d = ImageDraw.Draw(im)
    d.ellipse([30, 30, 170, 170], fill=255)
    d.ellipse([70, 70, 130, 130], fill=0)
    return im


def bolt() -> Image.Image:  # wide image (aspect kept when fitted), 320×200
    im = Image.new("L", (320, 200), 255)
    d = ImageDraw.Draw(im)
    d.rectangle([40, 60, 120, 140], fill=0)      # the head
    d.rectangle([120, 85, 280, 115], fill=0)     # the shaft
    return im


def table() -> trimesh.Trimesh:
    parts = [trimesh.creation.box([1.0, 0.6, 0.08], trimesh.transformations.translation_matrix([0, 0, 0.5]))]
    for x in (-0.42, 0.42):
        for y in (-0.22, 0.22):
            parts.append(trimesh.creation.box([0.08, 0.08, 0.5], trimesh.transformations.translation_matrix([x, y, 0.21])))
    return trimesh.util.concatenate(parts)


def snowman() -> trimesh.Trimesh:
    a = trimesh.creation.icosphere(subdivisions=3, radius=0.5)
    b = trimesh.creation.icosphere(subdivisions=3, radius=0.32)
    b.apply_translation([0, 0, 0.72])
    return trimesh.util.concatenate([a, b])


def main() -> None:
    atomic_write(HERE / "house.png", lambda f: house().save(f, format="PNG"))
    atomic_write(HERE / "ring.png", lambda f: ring().save(f, format="PNG"))
    atomic_write(HERE / "bolt.jpg", lambda f: bolt().convert("RGB").save(f, format="JPEG", quality=92))
    atomic_write(HERE / "table.obj", lambda f: table().export(f, file_type="obj"))
    atomic_write(HERE / "snowman.stl", lambda f: snowman().export(f, file_type="stl"))
    print("wrote", ", ".join(sorted(p.name for p in HERE.iterdir() if p.suffix != ".py")))


if __name__ == "__main__":
    main()
