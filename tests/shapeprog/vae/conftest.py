"""Programs shared by the VAE tests."""
import pytest

TWO_LEVELS = """Assembly Program_0 {
\tbbox = Cuboid(1.2, 1.0, 0.8, True)
\tProgram_1 = Cuboid(0.3, 0.6, 0.7, False)
\tcube1 = Cuboid(1.2, 0.1, 0.8, True)
\tattach(Program_1, bbox, 0.5, 0.0, 0.5, 0.2, 0.0, 0.5)
\tsqueeze(cube1, bbox, Program_1, top, 0.5, 0.25)
\treflect(Program_1, X)
}
Assembly Program_1 {
\tbbox = Cuboid(0.3, 0.6, 0.7, True)
\tcube0 = Cuboid(0.05, 0.6, 0.05, False)
\tattach(cube0, bbox, 0.5, 0.0, 0.5, 0.5, 0.0, 0.1)
\ttranslate(cube0, Z, 2, 0.8)
}
"""


@pytest.fixture
def two_levels() -> str:
    """A two-block program with every statement kind: a sub-program, squeeze, reflect and translate."""
    return TWO_LEVELS
