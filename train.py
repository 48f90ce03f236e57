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
import lightning as L
from lightning.pytorch.cli import LightningCLI


def main(args=None, run: bool = True) -> LightningCLI:
    """Run the CLI on ``args`` (default: ``sys.argv``); ``run=False`` only parses and builds the config's
    model, data module and trainer (``args`` then takes no subcommand)."""
    return LightningCLI(L.LightningModule, L.LightningDataModule, subclass_mode_model=True,
                        subclass_mode_data=True, save_config_kwargs={"overwrite": True}, args=args, run=run)


if __name__ == "__main__":
    main()
