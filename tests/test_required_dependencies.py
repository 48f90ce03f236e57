"""Required dependencies are imported by the tests, never skipped: a broken install fails the suite."""
from pathlib import Path

TESTS = Path(__file__).resolve().parent


def test_no_test_skips_on_a_missing_import():
    calls = "importor" + "skip("  # spelled apart so that this file does not list itself
    found = [f"{p.relative_to(TESTS)}:{n}" for p in sorted(TESTS.rglob("*.py"))
             for n, line in enumerate(p.read_text().splitlines(), 1) if calls in line]
    assert found == []


def test_the_required_dependencies_import():
    import egglog  # noqa: F401
    import h5py  # noqa: F401
    import msgspec  # noqa: F401
    import playwright.sync_api  # noqa: F401  (drives the real-browser editor test)
    import pybullet  # noqa: F401
    import skimage.draw  # noqa: F401
    import trimesh  # noqa: F401
    import viser  # noqa: F401
    import websockets  # noqa: F401
    import zstandard  # noqa: F401
