"""REINFORCE fine-tuning entry point: LightningCLI over the REINFORCE module and the target-image data.

    python train_rl.py fit --config configs/csgnet/rl_csgnet2d_small.yaml
    python train_rl.py fit --config configs/csgnet/rl_csgnet2d_small.yaml --ckpt_path last          # resume
    python train_rl.py fit --config configs/csgnet/rl_csgnetstack2d_paper.yaml --model.init runs/x/best.ckpt
    python train_rl.py fit --config configs/csgnet/rl_csgnet2d_small.yaml --data.source cad --data.path cad.h5

A separate entry from ``train.py`` (supervised training): the two have different modules and data, and
each config file names only its own. Everything else lives in :mod:`csgnet.train.reinforce`.
"""
from lightning.pytorch.cli import LightningCLI

from csgnet.train.reinforce import ReinforceModule, TargetDataModule


def main(args=None):
    return LightningCLI(ReinforceModule, TargetDataModule, save_config_kwargs={"overwrite": True}, args=args)


if __name__ == "__main__":
    main()
