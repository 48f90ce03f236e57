"""Shipped ShapeMOD libraries (text files): see README.md."""
