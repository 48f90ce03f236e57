"""Training entry point: one LightningCLI for every model family.

Each config names its LightningModule and LightningDataModule (``model.class_path``, ``data.class_path``
with their ``init_args``), so a new family adds a module and a YAML file and leaves this script alone:

    python train.py fit --config configs/csgnet/csgnetstack2d_small.yaml                   # supervised CSGNet
    python train.py fit --config configs/csgnet/csgnetstack2d_small.yaml --ckpt_path last   # resume
    python train.py fit --config configs/csgnet/csgnet2d_paper.yaml --trainer.devices 4 --trainer.strategy ddp
    python train.py fit --config configs/csgnet/rl_csgnet2d_small.yaml                      # REINFORCE
    python train.py fit --config configs/csgnet/rl_csgnet2d_small.yaml --model.init runs/x/best.ckpt
    python train.py validate --config configs/csgnet/rl_csgnet2d_small.yaml --trainer.logger false

The modules, data and losses live in the library (:mod:`csgnet.train`); ``configs/README.md`` lists the
configs.
"""
import shutil
from pathlib import Path

import lightning as L
from lightning.pytorch.cli import LightningCLI, SaveConfigCallback
from lightning.pytorch.loggers import TensorBoardLogger


class SaveConfig(SaveConfigCallback):
    """Saves the run's config in its TensorBoard folder; a run without a logger has no run folder, and its
    config is not written (Lightning would write ``config.yaml`` into the working folder, over any file of
    that name)."""

    def setup(self, trainer, pl_module, stage: str) -> None:
        if trainer.logger is None:
            return
        super().setup(trainer, pl_module, stage)


class CLI(LightningCLI):
    """The LightningCLI that never lets a new run overwrite an earlier run's checkpoints."""

    def before_fit(self) -> None:
        """A ``fit`` without ``--ckpt_path`` into a checkpoint folder that already holds checkpoints stops
        before training: resume that run (``--ckpt_path last``) or move its folder away. ``--ckpt_path last``
        into such a folder without a readable ``last*.ckpt`` (a link lost in a copy, a kill while it was
        replaced) stops too: Lightning would start from scratch beside them."""
        ckpt = self.config[self.subcommand].get("ckpt_path")
        for folder in self._used_checkpoint_folders():
            if ckpt is None:
                raise SystemExit(f"error: {folder} holds the checkpoints of an earlier run; resume it with "
                                 "--ckpt_path last, or move that folder away to start a new run")
            if ckpt == "last" and not any(p.is_file() for p in folder.glob("last*.ckpt")):  # is_file follows links
                names = ", ".join(sorted(p.name for p in folder.glob("*.ckpt"))[:5])
                raise SystemExit(f"error: --ckpt_path last: {folder} holds checkpoints ({names}) but no readable "
                                 "last.ckpt; resume from one of them with --ckpt_path <file>")
        if ckpt == "last":
            self._continue_log_version()

    def _continue_log_version(self) -> None:
        """A resumed run logs into its latest TensorBoard version folder, so that its curve stays in one
        folder (Lightning would start ``version_N+1``)."""
        logger = self.trainer.logger
        if not isinstance(logger, TensorBoardLogger) or getattr(logger, "_version", None) is not None:
            return
        root = Path(logger.root_dir)
        versions = [int(p.name[8:]) for p in root.glob("version_*") if p.is_dir() and p.name[8:].isdigit()]
        if versions:
            logger._version = max(versions)

    def _run_subcommand(self, subcommand: str) -> None:
        """Run it; a run that fails before its first step (a missing dataset, a bad value) stops with one
        line naming the problem and leaves no empty TensorBoard folder behind."""
        logger = self.trainer.logger
        root = Path(logger.root_dir) if isinstance(logger, TensorBoardLogger) else None
        before = set(root.glob("version_*")) if root is not None and root.is_dir() else set()
        made = [] if root is None else [p for p in (root, root.parent) if not p.exists()]  # folders this run creates
        try:
            super()._run_subcommand(subcommand)
        except (FileNotFoundError, ValueError) as e:
            if self.trainer.global_step:
                raise
            if root is not None:
                for folder in set(root.glob("version_*")) - before:
                    shutil.rmtree(folder, ignore_errors=True)
                for folder in made:
                    if folder.is_dir() and not any(folder.iterdir()):
                        folder.rmdir()
            raise SystemExit(f"error: {e}") from None

    def _used_checkpoint_folders(self) -> list[Path]:
        """The checkpoint callbacks' folders that already hold checkpoints."""
        folders = [Path(cb.dirpath) for cb in self.trainer.checkpoint_callbacks if getattr(cb, "dirpath", None)]
        return [f for f in folders if f.is_dir() and any(f.glob("*.ckpt"))]


def main(args=None, run: bool = True) -> LightningCLI:
    """Run the CLI on ``args`` (default: ``sys.argv``); ``run=False`` only parses and builds the config's
    model, data module and trainer (``args`` then takes no subcommand)."""
    return CLI(L.LightningModule, L.LightningDataModule, subclass_mode_model=True,
               subclass_mode_data=True, save_config_callback=SaveConfig, save_config_kwargs={"overwrite": True},
               args=args, run=run)


if __name__ == "__main__":
    main()
