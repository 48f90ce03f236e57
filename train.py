"""Training entry point: LightningCLI over the CSGNet modules.

    python train.py fit --config configs/csgnet/csgnetstack2d_small.yaml
    python train.py fit --config configs/csgnet/csgnetstack2d_small.yaml --ckpt_path last   # resume
    python train.py fit --config configs/csgnet/csgnet2d_paper.yaml --trainer.devices 4 --trainer.strategy ddp

Everything else (models, data, losses) lives in the library (:mod:`csgnet.train.supervised`).
"""
from lightning.pytorch.cli import LightningCLI

from csgnet.train.supervised import CSGDataModule, CSGNetModule


def main(args=None):
    return LightningCLI(CSGNetModule, CSGDataModule, save_config_kwargs={"overwrite": True}, args=args)


if __name__ == "__main__":
    main()
