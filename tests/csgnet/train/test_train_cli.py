"""``train.py``: one LightningCLI runs every family's config (fit, resume, validate, TensorBoard)."""
from pathlib import Path

import pytest
import yaml

TINY = {"hidden": 16, "channels": [2, 2, 2], "embed": 8, "dropout": 0.0, "enc_dropout": 0.0}


def _config(tmp_path: Path) -> Path:
    config = {
        "seed_everything": 0,
        "model": {"class_path": "csgnet.train.supervised.CSGNetModule",
                  "init_args": {"dim": 2, "stack": False, "model": TINY, "log_images": 4}},
        "data": {"class_path": "csgnet.train.supervised.CSGDataModule",
                 "init_args": {"dim": 2, "data_dir": None, "lengths": [3, 5], "batch_size": 4,
                               "steps_per_epoch": 2, "val_per_length": 2}},
        "trainer": {
            "max_steps": 2, "accelerator": "cpu", "devices": 1, "enable_progress_bar": False,
            "enable_model_summary": False, "num_sanity_val_steps": 0, "default_root_dir": str(tmp_path),
            "logger": {"class_path": "lightning.pytorch.loggers.TensorBoardLogger",
                       "init_args": {"save_dir": str(tmp_path), "name": "tb"}},
            "plugins": [{"class_path": "csgnet.train.checkpoint.AtomicCheckpointIO"}],
            "callbacks": [{"class_path": "lightning.pytorch.callbacks.ModelCheckpoint",
                           "init_args": {"dirpath": str(tmp_path / "ckpt"), "save_last": True}}]},
    }
    path = tmp_path / "tiny.yaml"
    path.write_text(yaml.safe_dump(config))
    return path


def test_fit_resume_and_validate_through_the_one_cli(tmp_path, train_main, monkeypatch):
    config = _config(tmp_path)
    cli = train_main(["fit", "--config", str(config)])
    assert cli.trainer.global_step == 2 and (tmp_path / "ckpt" / "last.ckpt").is_file()
    assert "val/chamfer" in cli.trainer.callback_metrics
    assert list((tmp_path / "tb").glob("version_0/events.out.tfevents.*"))
    assert (tmp_path / "tb" / "version_0" / "config.yaml").is_file()  # the resolved config beside the logs
    before = (tmp_path / "ckpt" / "last.ckpt").read_bytes()
    with pytest.raises(SystemExit, match="holds the checkpoints of an earlier run"):  # a new run never overwrites
        train_main(["fit", "--config", str(config)])
    assert (tmp_path / "ckpt" / "last.ckpt").read_bytes() == before
    resumed = train_main(["fit", "--config", str(config), "--trainer.max_steps", "3", "--ckpt_path", "last"])
    assert resumed.trainer.global_step == 3
    # the resumed run logs on in the same TensorBoard folder: one curve, not one folder per resumption
    assert sorted(p.name for p in (tmp_path / "tb").iterdir()) == ["version_0"]
    assert len(list((tmp_path / "tb").glob("version_0/events.out.tfevents.*"))) == 2
    work = tmp_path / "work"
    work.mkdir()
    (work / "config.yaml").write_text("a user's file\n")
    monkeypatch.chdir(work)  # without a logger there is no run folder: nothing is written in the working folder
    val = train_main(["validate", "--config", str(config), "--trainer.logger", "false",
                      "--ckpt_path", str(tmp_path / "ckpt" / "last.ckpt")])
    assert "val/iou" in val.trainer.callback_metrics
    assert [p.name for p in work.iterdir()] == ["config.yaml"] and (work / "config.yaml").read_text() == "a user's file\n"
    # --ckpt_path last where the folder's last.ckpt is gone (a link lost in a copy): stop, never start over
    (tmp_path / "ckpt" / "last.ckpt").unlink()
    with pytest.raises(SystemExit, match=r"--ckpt_path last: .*ckpt holds checkpoints .* but no readable last\.ckpt"):
        train_main(["fit", "--config", str(config), "--trainer.max_steps", "4", "--ckpt_path", "last"])


def test_the_configs_last_checkpoint_is_the_last_epoch_even_without_improvement(tmp_path, train_main):
    # the checkpoint callbacks of a shipped config, pointed at tmp_path; with lr 0 the validation chamfer
    # never improves after the first epoch, so only the second callback keeps last.ckpt current
    root = Path(__file__).resolve().parents[3]
    shipped = yaml.safe_load((root / "configs" / "csgnet" / "csgnet2d_small.yaml").read_text())
    callbacks = [c for c in shipped["trainer"]["callbacks"] if c["class_path"].endswith("ModelCheckpoint")]
    assert len(callbacks) == 2
    for c in callbacks:
        c["init_args"]["dirpath"] = str(tmp_path / "ckpt")
    config = yaml.safe_load(_config(tmp_path).read_text())
    config["trainer"].update(callbacks=callbacks, max_steps=-1, max_epochs=3, logger=False)
    config["model"]["init_args"]["lr"] = 0.0
    path = tmp_path / "no_improvement.yaml"
    path.write_text(yaml.safe_dump(config))
    train_main(["fit", "--config", str(path)])
    import torch

    best = sorted(p.name for p in (tmp_path / "ckpt").glob("best-*.ckpt"))
    assert best == ["best-epoch=000.ckpt"]
    last = torch.load(tmp_path / "ckpt" / "last.ckpt", map_location="cpu", weights_only=False)
    assert last["epoch"] == 2


def test_a_run_that_fails_at_start_says_why_in_one_line_and_leaves_no_folder(tmp_path, train_main):
    config = _config(tmp_path)
    missing = tmp_path / "no_data"
    with pytest.raises(SystemExit, match=r"^error: no 2D dataset under .*no_data.*csgnet generate"):
        train_main(["fit", "--config", str(config), "--data.init_args.data_dir", str(missing),
                    "--trainer.logger.init_args.save_dir", str(tmp_path / "logs")])
    assert not (tmp_path / "logs").exists()
