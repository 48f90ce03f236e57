"""Gymnasium environments over the CSG and ShapeAssembly renderers (registrations only)."""
