"""Every training config logs its curve within the first 10 steps and writes no ``hp_metric = -1`` placeholder."""
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
CONFIGS = sorted(p for p in (ROOT / "configs").rglob("*.yaml")
                 if "trainer" in (yaml.safe_load(p.read_text()) or {}))


def test_the_training_configs_are_found():
    assert {p.parent.name for p in CONFIGS} == {"csgnet", "pointcloud", "shapeassembly"} and len(CONFIGS) >= 30


@pytest.mark.parametrize("path", CONFIGS, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_config_logs_early_without_placeholder(path):
    trainer = yaml.safe_load(path.read_text())["trainer"]
    assert trainer["log_every_n_steps"] <= 10
    logger = trainer["logger"]
    assert logger["class_path"] == "lightning.pytorch.loggers.TensorBoardLogger"
    assert logger["init_args"]["default_hp_metric"] is False


def test_logger_as_configured_writes_no_hp_metric(tmp_path):
    from lightning.pytorch.loggers import TensorBoardLogger
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    args = dict(yaml.safe_load(CONFIGS[0].read_text())["trainer"]["logger"]["init_args"], save_dir=str(tmp_path))
    logger = TensorBoardLogger(**args)
    logger.log_hyperparams({"lr": 0.001})
    logger.log_metrics({"train/loss": 1.5}, step=0)
    logger.finalize("success")
    acc = EventAccumulator(logger.log_dir)
    acc.Reload()
    assert acc.Tags()["scalars"] == ["train/loss"]
