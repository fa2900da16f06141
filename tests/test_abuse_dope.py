"""DOPE's commands given bad input (issue 31, "Nothing lost, nothing wedged"): one clear line and exit code 2,
no traceback; NaN never trains or exports silently; sizes are checked against memory before anything is
allocated; a failed training run leaves nothing it made."""

import json
import shutil
import zlib
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
import torch
import trimesh

import dope_training.train
from dope_training.export import check_parity, export_checkpoint
from dope_training.model import build_model
from dope_training.train import TrainConfig, train
from pegasus_gen.cli.main import main


def tiny_bop(root: Path, t_mm=(0.0, 0.0, 300.0), K=(100.0, 0, 31.5, 0, 100.0, 31.5, 0, 0, 1)) -> Path:
    """A BOP dataset of 2 random 64 x 64 images, each showing a 4 cm cube (obj_id 1, "cube") at ``t_mm``
    seen with ``K`` (px)."""
    (root / "models").mkdir(parents=True)
    (root / "models" / "models_info.json").write_text(json.dumps({"1": {
        "min_x": -20, "min_y": -20, "min_z": -20, "size_x": 40, "size_y": 40, "size_z": 40, "diameter": 69.3,
        "name": "cube"}}))
    trimesh.creation.box(extents=(40, 40, 40)).export(root / "models" / "obj_000001.ply")
    scene = root / "train_pbr" / "000000"
    (scene / "rgb").mkdir(parents=True)
    rng = np.random.default_rng(0)
    for im_id in range(2):
        cv2.imwrite(str(scene / "rgb" / f"{im_id:06d}.png"), rng.integers(0, 256, (64, 64, 3), dtype=np.uint8))
    pose = [{"cam_R_m2c": np.eye(3).ravel().tolist(), "cam_t_m2c": list(t_mm), "obj_id": 1}]
    (scene / "scene_gt.json").write_text(json.dumps({str(i): pose for i in range(2)}))
    (scene / "scene_camera.json").write_text(json.dumps({str(i): {"cam_K": list(K), "depth_scale": 1.0}
                                                         for i in range(2)}))
    return root


TRAIN = ["--object", "cube", "--size", "32", "--batch-size", "2", "--epochs", "1", "--loader-workers", "0",
         "--device", "cpu", "--no-augment"]


def small(data: Path, out: Path, **kw) -> TrainConfig:
    return TrainConfig(**{**dict(data=[str(data)], object="cube", out=str(out), size=32, batch_size=2, epochs=1,
                                 augment=False, loader_workers=0, device="cpu"), **kw})


@pytest.fixture(scope="module")
def dataset(tmp_path_factory) -> Path:
    return tiny_bop(tmp_path_factory.mktemp("abuse") / "ds")


@pytest.fixture(scope="module")
def run(dataset, tmp_path_factory) -> Path:
    """A one-step training run of the light network on ``dataset`` (its folder)."""
    return train(small(dataset, tmp_path_factory.mktemp("abuse") / "run"))


@pytest.fixture(scope="module")
def exported(run, tmp_path_factory) -> Path:
    return export_checkpoint(run / "last.pt", tmp_path_factory.mktemp("abuse") / "model.onnx")[0]


def refused(argv, capsys, *expected, alone: bool = True) -> str:
    """Run ``pegasus argv``: exit code 2 and its last stderr line the error naming ``expected`` (the only line
    unless a progress bar came first: ``alone`` False); returns that line."""
    assert main([str(a) for a in argv]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines and (len(lines) == 1 or not alone), lines
    assert lines[-1].startswith("pegasus: error: ") and all(e in lines[-1] for e in expected), lines[-1]
    assert "Traceback" not in "\n".join(lines) and "weights_only" not in lines[-1]
    return lines[-1]


# ---------------------------------------------------------------- H2: NaN in, NaN network out
def test_training_data_with_a_nan_pose_or_a_zero_K_is_refused_naming_the_frame(tmp_path, capsys):
    nan_pose = tiny_bop(tmp_path / "nan_pose", t_mm=(0.0, float("nan"), 300.0))
    zero_K = tiny_bop(tmp_path / "zero_K", K=(0.0,) * 9)
    refused(["train", "--data", nan_pose, "--out", tmp_path / "r1", *TRAIN], capsys, "image 0",
            "scene_gt.json", "finite")
    refused(["train", "--data", zero_K, "--out", tmp_path / "r2", *TRAIN], capsys, "image 0", "scene_camera.json")
    assert not (tmp_path / "r1").exists() and not (tmp_path / "r2").exists()  # the failed runs left nothing


def test_training_stops_when_the_loss_is_not_finite_keeping_only_whole_epochs(dataset, tmp_path, capsys,
                                                                              monkeypatch):
    # lr 1e30: the first step's update takes the weights to ~1e30, so the second step's loss overflows
    line = refused(["train", "--data", dataset, "--out", tmp_path / "fresh", *TRAIN, "--batch-size", "1",
                    "--lr", "1e30"], capsys, "training loss became", "step 2 (epoch 1)", alone=False)
    assert "nan" in line or "inf" in line
    assert not (tmp_path / "fresh").exists()  # failed before its first checkpoint: nothing left

    real_loss, losses = dope_training.train.dope_loss, []

    def nan_from_step_2(*args, **kwargs):
        losses.append(real_loss(*args, **kwargs))
        return losses[-1] * (float("nan") if len(losses) >= 2 else 1.0)

    monkeypatch.setattr(dope_training.train, "dope_loss", nan_from_step_2)
    refused(["train", "--data", dataset, "--out", tmp_path / "two", *TRAIN, "--epochs", "2"], capsys,
            "training loss became nan at step 2 (epoch 2)", alone=False)
    assert torch.load(tmp_path / "two" / "last.pt", weights_only=True)["epoch"] == 1  # epoch 1 kept, for --resume


def test_export_refuses_a_network_whose_outputs_are_not_finite(run, exported, tmp_path, capsys):
    state = torch.load(run / "last.pt", weights_only=True)
    next(iter(state["model"].values())).fill_(float("nan"))
    torch.save(state, tmp_path / "nan.pt")
    refused(["export", tmp_path / "nan.pt", "--out", tmp_path / "nan.onnx"], capsys, "not finite")
    assert list(tmp_path.iterdir()) == [tmp_path / "nan.pt"]  # nothing written
    model = build_model(state["model_config"])
    model.load_state_dict(state["model"])
    assert check_parity(model, exported, [(1, 32, 32)]) == np.inf  # NaN is no agreement


# ---------------------------------------------------------------- one line instead of a traceback
def test_outputs_of_the_wrong_kind_are_refused_before_any_work(run, dataset, exported, tmp_path, capsys):
    image = dataset / "train_pbr" / "000000" / "rgb" / "000000.png"
    (tmp_path / "file").write_text("mine")
    (tmp_path / "folder").mkdir()
    refused(["infer", "--model", exported, "--image", image, "--out", tmp_path / "file"], capsys, "--out", "a file")
    refused(["eval", "--model", exported, "--data", dataset, "--out", tmp_path / "file"], capsys, "--out", "a file")
    refused(["eval", "--model", exported, "--data", dataset, "--out", tmp_path / "file" / "sub"], capsys,
            "is a file, not a folder")
    refused(["eval", "--model", exported, "--data", dataset, "--out", tmp_path / "ev", "--bop-results",
             tmp_path / "folder"], capsys, "--bop-results", "a folder")
    refused(["export", run / "last.pt", "--out", tmp_path / "folder"], capsys, "--out", "a folder")
    assert (tmp_path / "file").read_text() == "mine" and not any((tmp_path / "folder").iterdir())
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "folder"]


def test_checkpoints_with_missing_or_unknown_keys_are_refused(run, dataset, tmp_path, capsys):
    image = dataset / "train_pbr" / "000000" / "rgb" / "000000.png"
    good = torch.load(run / "last.pt", weights_only=True)
    weights = good["model"]
    first = next(iter(weights))
    broken = {"missing": ({k: v for k, v in good.items() if k != "object"}, "missing keys: object"),
              "unknown": ({**good, "extra": 1}, "unknown keys: extra"),
              "weight_missing": ({**good, "model": {k: v for k, v in weights.items() if k != first}},
                                 "missing: " + first),
              "weight_unknown": ({**good, "model": {**weights, "stage9.weight": torch.zeros(1)}},
                                 "unknown: stage9"),
              "object": ({**good, "object": {**good["object"], "colour": "red"}}, "colour")}
    for name, (state, expected) in broken.items():
        torch.save(state, tmp_path / f"{name}.pt")
        refused(["infer", "--model", tmp_path / f"{name}.pt", "--image", image, "--out", tmp_path / "inf"], capsys,
                expected)
        refused(["export", tmp_path / f"{name}.pt"], capsys, expected)
        resumed = tmp_path / f"resume_{name}"
        shutil.copytree(run, resumed)
        shutil.copy(tmp_path / f"{name}.pt", resumed / "last.pt")
        refused(["train", "--data", dataset, "--out", resumed, *TRAIN, "--epochs", "2", "--resume"], capsys, expected)
    assert not list(tmp_path.glob("*.onnx")) and not (tmp_path / "inf").exists()


def test_a_checkpoint_refused_as_unsafe_says_so_in_our_words(tmp_path, capsys):
    class Payload:
        def __reduce__(self):
            return print, ("code ran",)

    torch.save({"format": 1, "payload": Payload()}, tmp_path / "crafted.pt")
    line = refused(["export", tmp_path / "crafted.pt"], capsys, "not a readable checkpoint", "could run code")
    assert "weights_only" not in line and "trusted" not in line  # not torch's advice to load it unsafely


def with_metadata(source: Path, path: Path, **changes) -> Path:
    """A copy of the ONNX file ``source`` at ``path`` with metadata keys changed."""
    graph = onnx.load(source)
    for prop in graph.metadata_props:
        prop.value = changes.get(prop.key, prop.value)
    onnx.save(graph, path)
    return path


def test_onnx_metadata_not_written_by_export_is_refused(exported, dataset, tmp_path, capsys):
    image = dataset / "train_pbr" / "000000" / "rgb" / "000000.png"
    meta = {p.key: p.value for p in onnx.load(exported).metadata_props}
    for name, changes, expected in (
            ("unknown", {"object": json.dumps({**json.loads(meta["object"]), "colour": "red"})}, "colour"),
            ("not_json", {"object": "{cube"}, "metadata object="),
            ("abc", {"input_short_side": "abc"}, "metadata input_short_side='abc'"),
            ("config", {"config": json.dumps({"variant": "light", "stages": "many"})}, "metadata config")):
        model = with_metadata(exported, tmp_path / f"{name}.onnx", **changes)
        refused(["infer", "--model", model, "--image", image, "--out", tmp_path / "inf"], capsys, str(model), expected)
    assert not (tmp_path / "inf").exists()


# ---------------------------------------------------------------- intrinsics
def test_intrinsics_must_describe_a_camera(exported, dataset, tmp_path, capsys):
    image = dataset / "train_pbr" / "000000" / "rgb" / "000000.png"
    for flags, expected in ((["--K", "0", "0", "0", "0"], "--K 0 0 0 0"),
                            (["--K", "nan", "100", "80", "60"], "--K nan"),
                            (["--K", "100", "100", "inf", "60"], "cx, cy finite"),
                            (["--fov", "0"], "--fov 0"), (["--fov", "500"], "(0, 180)"),
                            (["--fov", "nan"], "--fov nan")):
        refused(["infer", "--model", exported, "--image", image, "--out", tmp_path / "inf", *flags], capsys, expected)
    assert not (tmp_path / "inf").exists()


def test_a_mesh_to_refine_against_must_be_a_mesh(exported, dataset, tmp_path, capsys):
    image = dataset / "train_pbr" / "000000" / "rgb" / "000000.png"
    (tmp_path / "notes.ply").write_text("not a mesh")
    refused(["infer", "--model", exported, "--image", image, "--out", tmp_path / "inf", "--refine-rgb",
             tmp_path / "notes.ply"], capsys, "notes.ply")
    refused(["infer", "--model", exported, "--image", image, "--out", tmp_path / "inf", "--refine-rgb",
             tmp_path / "missing.obj"], capsys, "missing.obj")


# ---------------------------------------------------------------- memory
def huge_png(path: Path, width: int, height: int) -> Path:
    """A valid black 1-bit greyscale PNG of ``width`` x ``height`` px, written without holding its pixels
    (a few hundred kB)."""
    def chunk(kind: bytes, data: bytes) -> bytes:
        return len(data).to_bytes(4, "big") + kind + data + zlib.crc32(kind + data).to_bytes(4, "big")

    row, packer = bytes(1 + (width + 7) // 8), zlib.compressobj(9)
    pixels = b"".join(packer.compress(row) for _ in range(height)) + packer.flush()
    header = width.to_bytes(4, "big") + height.to_bytes(4, "big") + bytes([1, 0, 0, 0, 0])
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", pixels) + chunk(b"IEND", b""))
    return path


def test_sizes_are_checked_against_memory_before_anything_is_allocated(dataset, exported, tmp_path, capsys):
    refused(["train", "--data", dataset, "--out", tmp_path / "big", *TRAIN, "--size", "50000"], capsys,
            "training on 50000 px crops in batches of 2 needs about", "GiB of memory, more than")
    assert not (tmp_path / "big").exists()
    image = dataset / "train_pbr" / "000000" / "rgb" / "000000.png"
    wide = with_metadata(exported, tmp_path / "wide.onnx", input_short_side="1000000")
    refused(["infer", "--model", wide, "--image", image, "--out", tmp_path / "inf"], capsys,
            "a 64x64 px image scaled to a 1000000x1000000 px network input", "more than")
    huge = huge_png(tmp_path / "huge.png", 30000, 30000)
    refused(["infer", "--model", exported, "--image", huge, "--out", tmp_path / "inf"], capsys, "huge.png",
            "megapixels")
    assert not (tmp_path / "inf").exists()
