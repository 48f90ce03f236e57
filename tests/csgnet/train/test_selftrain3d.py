"""3D self-training: labels ranked by IoU, relabelling, a tiny fit with checkpoint and resume, bad inputs."""
from pathlib import Path

import lightning as L
import numpy as np
import pytest
import torch

import csgnet
from csgnet.score import program_scores
from csgnet.train.checkpoint import AtomicCheckpointIO
from csgnet.train.labels import PseudoLabels
from csgnet.train.selftrain import SelfTrainDataModule, SelfTrainModule
from csgnet.train.targets import TargetDataModule, load_targets
from csgnet.vocab import vocabulary

ROOT = Path(__file__).resolve().parents[3]
TINY3 = {"hidden": 32, "channels": [2, 2, 2, 2], "embed": 8, "dropout": 0.0, "enc_dropout": 0.0}
SHAPES3 = ["sp(32,32,32,16)", "cu(32,32,32,24)", "cy(32,32,32,12,20)"]
STOP3 = vocabulary(3).stop


def _volumes():
    return csgnet.render(SHAPES3, 3)


def _module(**kw):
    args = dict(dim=3, size="lite", model=TINY3, beam_width=3, beam_batch=2, log_images=0)
    return SelfTrainModule(**{**args, **kw})


def test_3d_labels_are_ranked_by_iou_and_replaced_only_by_a_better_one():
    labels = PseudoLabels(3, 4, dim=3)
    assert labels.metric == "iou" and labels.higher_better and labels.worst == float("-inf")
    assert len(labels.labelled()) == 0 and labels.mean_score() == float("-inf")
    toks = torch.tensor([[5, 6, 7, STOP3], [8, STOP3, STOP3, STOP3]])
    got = labels.offer(torch.tensor([0, 2]), toks, torch.tensor([3, 1]), [0.5, float("nan")])
    assert got.tolist() == [True, False] and labels.labelled().tolist() == [0]
    # a lower or equal IoU is kept; a higher one replaces; non-finite scores never
    assert labels.offer(torch.tensor([0]), toks[1:], torch.tensor([1]), [0.4]).tolist() == [False]
    assert labels.offer(torch.tensor([0]), toks[1:], torch.tensor([1]), [0.5]).tolist() == [False]
    assert labels.offer(torch.tensor([0]), toks[1:], torch.tensor([1]), [float("inf")]).tolist() == [False]
    assert labels.tokens[0].tolist() == [5, 6, 7, STOP3] and labels.score[0] == 0.5
    assert labels.offer(torch.tensor([0]), toks[1:], torch.tensor([1]), [0.75]).tolist() == [True]
    assert labels.tokens[0].tolist() == [8, STOP3, STOP3, STOP3] and labels.lengths[0] == 1
    assert labels.score[0] == 0.75 and labels.mean_score() == 0.75
    # the table's round trip, and a 2D table refused
    state = labels.state_dict()
    other = PseudoLabels(3, 4, dim=3)
    other.load_state_dict(state)
    assert torch.equal(other.tokens, labels.tokens) and torch.equal(other.score, labels.score)
    assert other.metric == "iou" and torch.equal(other.lengths, labels.lengths)
    with pytest.raises(ValueError, match="ranked by 'iou', this run's by 'chamfer'"):
        PseudoLabels(3, 4, dim=2).load_state_dict(state)
    with pytest.raises(ValueError, match="unknown label score"):
        PseudoLabels(3, 4, dim=3, metric="accuracy")


def test_a_2d_table_saved_with_chamfer_scores_loads():
    old = {"tokens": torch.full((2, 3), vocabulary(2).stop), "lengths": torch.tensor([0, 1]),
           "chamfer": torch.tensor([float("inf"), 1.5], dtype=torch.float64), "rounds": 2, "last_epoch": 3}
    labels = PseudoLabels(2, 3)
    labels.load_state_dict(old)
    assert labels.metric == "chamfer" and labels.score.tolist() == [float("inf"), 1.5] and labels.rounds == 2
    assert labels.labelled().tolist() == [1]


def test_relabel_keeps_the_best_beam_by_iou_and_never_a_worse_one():
    L.seed_everything(0, verbose=False)
    m = _module()
    vols = torch.from_numpy(_volumes())
    labels = PseudoLabels(len(vols), 8, dim=3)
    stats = m.relabel(vols, labels)
    assert set(stats) == {"replaced", "labelled", "iou"}
    have = labels.labelled()
    assert stats["labelled"] == len(have) / 3 and stats["replaced"] == stats["labelled"]
    assert len(have)
    for i in have.tolist():  # each score is its label's IoU against its own target
        text = vocabulary(3).text(labels.tokens[i, :labels.lengths[i]].tolist())
        assert labels.score[i].item() == pytest.approx(program_scores([text], vols[i])[0][0], abs=1e-12)
    before = labels.score.clone()
    m.relabel(vols, labels)  # the same model decodes the same beams: nothing is better
    assert torch.equal(labels.score, before)
    with pytest.raises(ValueError, match=r"relabels \(N, 64, 64, 64\) targets, got \(3, 64, 64, 32\)"):
        m.relabel(vols[..., :32], labels)


class _Labels(L.Callback):
    """The label table when training starts and at each batch (after that epoch's relabelling)."""

    def __init__(self):
        self.start, self.tables = None, []

    def on_train_start(self, trainer, pl_module):
        self.start = trainer.datamodule.labels.state_dict()

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx):
        self.tables.append(trainer.datamodule.labels.state_dict())


def _trainer(tmp_path, epochs, callbacks=()):
    from lightning.pytorch.callbacks import ModelCheckpoint

    return L.Trainer(max_epochs=epochs, accelerator="cpu", devices=1, logger=False, enable_progress_bar=False,
                     enable_model_summary=False, default_root_dir=tmp_path, plugins=[AtomicCheckpointIO()],
                     callbacks=[ModelCheckpoint(dirpath=tmp_path / "ckpt", save_last=True), *callbacks],
                     num_sanity_val_steps=0, log_every_n_steps=1)


def _data():
    return SelfTrainDataModule.from_arrays(_volumes(), dim=3, batch_size=4, steps_per_epoch=1, synthetic_fraction=0.5,
                                           lengths=[3], max_len=3)


def test_a_tiny_3d_fit_of_two_steps_relabels_checkpoints_and_resumes(tmp_path):
    from csgnet.inference import load_model

    L.seed_everything(0, verbose=False)
    m, dm, seen = _module(round_epochs=1, max_len=3), _data(), _Labels()
    t = _trainer(tmp_path, 2, [seen])
    t.fit(m, dm)
    assert t.global_step == 2 and dm.labels.rounds == 2 and len(seen.tables) == 2
    for key in ("val/iou", "val/valid", "val/length", "train/loss", "train/pseudo", "round/iou", "round/labelled"):
        assert key in t.callback_metrics, key
    old, new = seen.tables
    assert new["metric"] == "iou" and (new["score"] >= old["score"]).all()  # labels never get worse
    same = new["score"] == old["score"]
    assert torch.equal(new["tokens"][same], old["tokens"][same])
    saved = dm.labels.state_dict()
    assert torch.isfinite(saved["score"]).any()
    ckpt = tmp_path / "ckpt" / "last.ckpt"
    assert load_model(ckpt).config == m.config and m.config.dim == 3  # a self-training checkpoint is a model file
    # resume: the label table comes back from the checkpoint as it was saved, and epoch 2 relabels
    seen2 = _Labels()
    m2, dm2 = _module(round_epochs=1, max_len=3), _data()
    t2 = _trainer(tmp_path, 3, [seen2])
    t2.fit(m2, dm2, ckpt_path=str(ckpt))
    assert seen2.start["rounds"] == 2 and seen2.start["metric"] == "iou"
    assert all(torch.equal(seen2.start[k], saved[k]) for k in ("tokens", "lengths", "score"))
    assert t2.global_step == 3 and dm2.labels.rounds == 3 and (dm2.labels.score >= saved["score"]).all()


def test_bad_3d_inputs_raise_clear_errors(tmp_path):
    vols = _volumes()
    with pytest.raises(ValueError, match=r"3D target volumes must be \(N, 64, 64, 64\), got shape \(3, 64, 64, 32\)"):
        TargetDataModule.from_arrays(vols[..., :32], dim=3)
    with pytest.raises(ValueError, match=r"must be \(N, 64, 64, 64\), got shape \(2, 64, 64\)"):
        SelfTrainDataModule.from_arrays(np.ones((2, 64, 64), bool), dim=3)
    with pytest.raises(ValueError, match="empty target volume"):
        TargetDataModule.from_arrays(np.zeros((1, 64, 64, 64), bool), dim=3)
    with pytest.raises(ValueError, match="'silhouettes' holds 2D shapes; 3D targets come from volumes, npz, synthetic"):
        SelfTrainDataModule(source="silhouettes", dim=3)
    with pytest.raises(ValueError, match="dim must be 2"):
        TargetDataModule(dim=4)
    np.savez(tmp_path / "v.npz", train=vols[:, :32])
    with pytest.raises(ValueError, match=r"v.npz:train: 3D target volumes must be \(N, 64, 64, 64\)"):
        load_targets("npz", "train", tmp_path / "v.npz", dim=3)
    with pytest.raises(FileNotFoundError, match="python -m shapeprog assembly volumes --out"):
        load_targets("volumes", "train", tmp_path / "none.npz", dim=3)
    with pytest.raises(ValueError, match="dim=3 was asked for"):
        SelfTrainModule(init=str(ROOT / "csgnet" / "weights" / "csgnet2d.pt"), dim=3)
    # a 3D model on 2D targets stops at the first round, naming the fix
    m = _module()
    dm = SelfTrainDataModule.from_arrays(csgnet.render(["c(32,32,16)"]), batch_size=2, steps_per_epoch=1)
    trainer = L.Trainer(max_epochs=1, accelerator="cpu", logger=False, enable_progress_bar=False,
                        enable_model_summary=False, enable_checkpointing=False, limit_val_batches=0)
    with pytest.raises(ValueError, match="a 3D model cannot self-train on 2D targets: set data.dim to 3"):
        trainer.fit(m, dm)


def test_the_volume_source_reads_a_volume_file(tmp_path):
    from shapeio.volumes import VolumeSplit, pack_volumes, write_volumes

    vols = _volumes()
    ids = np.array(["chair/1", "table/2", "chair/3"])
    write_volumes(tmp_path / "v.npz", {"train": VolumeSplit(pack_volumes(vols), ids, 64),
                                       "val": VolumeSplit(pack_volumes(vols[:1]), ids[:1], 64)}, margin=4)
    assert np.array_equal(load_targets("volumes", "train", tmp_path / "v.npz", dim=3), vols)
    assert np.array_equal(load_targets("volumes", "train", tmp_path / "v.npz", dim=3, limit=2), vols[:2])
    dm = SelfTrainDataModule(path=str(tmp_path / "v.npz"), dim=3, train_size=2)
    assert dm.source == "volumes" and dm.max_len == 7 and dm.lengths == [3, 5, 7]
    dm.setup("fit")
    assert dm.train_images.shape == (2, 64, 64, 64) and torch.equal(dm.val_images, torch.from_numpy(vols[:1]))
    assert dm.labels.metric == "iou" and dm.labels.width == 8
    with pytest.raises(ValueError, match="not a volume set with a test split: missing test_ids, test_volumes"):
        load_targets("volumes", "test", tmp_path / "v.npz", dim=3)
