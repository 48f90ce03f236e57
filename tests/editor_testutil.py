"""Shared programs for the editor tests."""

# one statement of every kind
EVERY = """bbox = Cuboid(1.0, 1.0, 1.0, True)
cube0 = Cuboid(0.2, 0.5, 0.2, False)
cube1 = Cuboid(0.8, 0.1, 0.8, True)
cube2 = Cuboid(0.1, 0.3, 0.1, True)
attach(cube1, bbox, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5)
squeeze(cube0, bbox, cube1, bot, 0.2, 0.3)
attach(cube2, cube1, 0.5, 0.0, 0.5, 0.1, 1.0, 0.1)
reflect(cube0, X)
translate(cube2, Z, 2, 0.5)
"""

MACROS = """def leg(s: float, b: bool, t: float):
    c = Cuboid(s, bb_y, s, b)
    squeeze(bbox, bbox, bot, 0.6 * s, t)
    reflect(X)

def four_legs(s: float, b: bool, t: float):
    c1 = leg(s, b, t)
    c2 = leg(0.95 * s, b, 1.0 - t)

bbox = Cuboid(1.2, 0.9, 1.0, True)
leg0, leg1 = four_legs(0.1, True, 0.2)
seat = Cuboid(1.2, 0.1, 1.0, True)
attach(leg0, 0.5, 0.0, 0.5, 0.5, 1.0, 0.5)
"""
