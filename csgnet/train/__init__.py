"""Training of the CSGNet models with PyTorch Lightning: the only part of :mod:`csgnet` that imports it.

* :mod:`csgnet.train.supervised`: supervised training (``CSGNetModule``, ``CSGDataModule``);
* :mod:`csgnet.train.reinforce`: REINFORCE fine-tuning of 2D models on target images (``ReinforceModule``);
* :mod:`csgnet.train.selftrain`: self-training of 2D and 3D models on pseudo-labels (``SelfTrainModule``,
  ``SelfTrainDataModule``), whose label table and mixed batches are in :mod:`csgnet.train.labels`;
* :mod:`csgnet.train.targets`: targets without programs, 2D images or 3D volumes (``TargetDataModule``,
  ``load_targets``);
* :mod:`csgnet.train.streams`: batch streams split over ranks and DataLoader workers;
* :mod:`csgnet.train.logs`: validation values averaged over ranks, TensorBoard image grids;
* :mod:`csgnet.train.checkpoint`: ``AtomicCheckpointIO``, checkpoints written atomically.

The repository's ``train.py`` runs any of these modules from a config file. This package imports no
submodule itself, so ``import csgnet.train.<module>`` loads only what that module needs.
"""
