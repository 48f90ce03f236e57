"""The one weights reader and writer, and every shipped weights file."""
import json
from pathlib import Path

import pytest
import torch

from shapeio.weights import (LEGACY_VERSION, check_weights, checkpoint_entry, load_payload, read_weights,
                             write_weights)

ROOT = Path(__file__).resolve().parents[2]


def test_round_trip_adds_family_and_version(tmp_path):
    path = write_weights(tmp_path / "sub" / "m.pt", "demo", 3, {"state_dict": {"w": torch.arange(3.0)}, "meta": {}})
    assert path == tmp_path / "sub" / "m.pt"
    payload = read_weights(path, "demo", 3)
    assert payload["format"] == "demo" and payload["version"] == 3
    assert torch.equal(payload["state_dict"]["w"], torch.arange(3.0))
    assert sorted(p.name for p in path.parent.iterdir()) == ["m.pt"]  # no temporary file left behind


def test_refusals_name_the_file(tmp_path):
    path = write_weights(tmp_path / "m.pt", "demo", 1, {"x": 1})
    with pytest.raises(ValueError, match=r"m\.pt: a 'demo' weights file, not a 'csgnet' one$"):
        read_weights(path, "csgnet", 1)
    with pytest.raises(ValueError, match=r"m\.pt: 'demo' weights file version 1; this version of the software reads "
                                         r"version 2$"):
        read_weights(path, "demo", 2)
    torch.save({"x": 1}, tmp_path / "bare.pt")
    with pytest.raises(ValueError, match=r"bare\.pt: not a 'demo' weights file \(no 'format' field; keys \['x'\]\)"):
        read_weights(tmp_path / "bare.pt", "demo", 1)
    torch.save([1, 2], tmp_path / "list.pt")
    with pytest.raises(ValueError, match=r"list\.pt: not a 'demo' weights file \(a list\)"):
        read_weights(tmp_path / "list.pt", "demo", 1)
    (tmp_path / "junk.pt").write_bytes(b"not a torch file")
    with pytest.raises(ValueError, match=r"junk\.pt: not a model file \(unreadable: \w+\)$"):
        load_payload(tmp_path / "junk.pt", "model file")
    with pytest.raises(FileNotFoundError, match=r"none\.pt: no such checkpoint$"):
        load_payload(tmp_path / "none.pt", missing="checkpoint")
    with pytest.raises(ValueError, match="fields must not hold"):
        write_weights(tmp_path / "bad.pt", "demo", 1, {"version": 2})


def test_a_legacy_layout_reads_as_version_0(tmp_path):
    torch.save({"config": {"k": 1}, "state_dict": {}}, tmp_path / "old.pt")
    payload = read_weights(tmp_path / "old.pt", "demo", 1, legacy=("config", "state_dict"))
    assert payload == {"config": {"k": 1}, "state_dict": {}, "format": "demo", "version": LEGACY_VERSION}
    with pytest.raises(ValueError, match="no 'format' field"):
        check_weights({"config": {}}, "p.pt", "demo", 1, legacy=("config", "state_dict"))


def test_every_shipped_weights_file_loads():
    """The files under csgnet/weights, shapeprog/weights, the ShapeCoder networks and runs_in_progress."""
    from csgnet.inference import load_model as load_csgnet
    from shapeprog.coder.infer import load_library as load_coder_library
    from shapeprog.coder.lang import LANG_3D, Library
    from shapeprog.coder.recnet import FORMAT as RECNET, VERSION as RECNET_VERSION, load_checkpoint
    from shapeprog.pointcloud.infer import load_model as load_cloud_model
    from shapeprog.vae.pointnet import PRETRAINED, load_classifier
    from shapeprog.vae.pretrained import load_model as load_vae

    loaded = []
    runs = ROOT / "runs_in_progress"
    for path in sorted((ROOT / "csgnet" / "weights").glob("*.pt")) + sorted(runs.glob("*csgnet*.pt")):
        assert not load_csgnet(path).training
        loaded.append(path.name)
    weights = ROOT / "shapeprog" / "weights"
    for path in sorted(weights.glob("vae_*.pt")) + sorted((ROOT / "runs_in_progress").glob("vae_*.pt")):
        assert load_vae(path).category in ("chair", "table", "storage")
        loaded.append(path.name)
    for path in sorted(weights.glob("pointcloud_*.pt")) + sorted((ROOT / "runs_in_progress").glob("pointcloud_*.pt")):
        assert load_cloud_model(path).category in ("chair", "table", "storage")
        loaded.append(path.name)
    model, classes, _ = load_classifier(PRETRAINED)
    assert classes == ("chair", "table", "storage")
    loaded.append(PRETRAINED.name)
    for path in sorted((ROOT / "shapeprog" / "data" / "coder_libraries").glob("*_recnet.pt")):
        load_checkpoint(path, load_coder_library(path.name[:-len("_recnet.pt")]))
        loaded.append(path.name)
    chain = ROOT / "runs_in_progress" / "shapecoder_chair_chain"
    library = Library.from_text(json.loads((chain / "state.json").read_text())["library"], LANG_3D)
    read_weights(chain / "recnet_round5.pt", RECNET, RECNET_VERSION)
    load_checkpoint(chain / "recnet_round5.pt", library)
    loaded.append("recnet_round5.pt")
    shipped = {p.name for d in (ROOT / "csgnet" / "weights", weights, ROOT / "runs_in_progress") for p in d.glob("*.pt")}
    assert shipped <= set(loaded)


def test_checkpoint_entry_is_checked():
    assert checkpoint_entry({"fam": {"format": 2, "x": 1}}, "fam", 2, "m") == {"format": 2, "x": 1}
    with pytest.raises(ValueError, match=r"^not a checkpoint of the module m \(no 'fam' entry\)$"):
        checkpoint_entry({}, "fam", 2, "the module m")
    with pytest.raises(ValueError, match=r"^the checkpoint has format 1; this version reads 2$"):
        checkpoint_entry({"fam": {"format": 1}}, "fam", 2, "m")
