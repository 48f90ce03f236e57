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


@pytest.fixture
def tiny_vae_config(tmp_path):
    """``make(name, model, best) -> path``: ``configs/shapeassembly/<name>.yaml`` shrunk to a 2-step CPU run in
    ``tmp_path`` (2 training and 2 validation shapes, checkpoints in ``tmp_path/ckpt``), its model's init
    arguments updated with ``model`` and its best-checkpoint callback's with ``best``."""
    from pathlib import Path

    import yaml

    root = Path(__file__).resolve().parents[3]

    def make(name: str, model: dict, best: dict) -> Path:
        config = yaml.safe_load((root / "configs" / "shapeassembly" / f"{name}.yaml").read_text())
        config["model"]["init_args"].update(model)
        config["data"]["init_args"].update(val_count=2, max_train_shapes=2)  # an epoch of 2 steps
        config["trainer"].update(max_steps=2, accelerator="cpu", devices=1, enable_progress_bar=False,
                                 enable_model_summary=False, num_sanity_val_steps=0, default_root_dir=str(tmp_path))
        config["trainer"]["logger"]["init_args"]["save_dir"] = str(tmp_path)
        for cb in config["trainer"]["callbacks"]:
            cb["init_args"]["dirpath"] = str(tmp_path / "ckpt")
            if cb["init_args"].get("monitor") == "val/fscore":
                cb["init_args"].update(best)
        path = tmp_path / "tiny.yaml"
        path.write_text(yaml.safe_dump(config))
        return path

    return make
