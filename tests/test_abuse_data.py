"""Issue 31, data side: nothing lost, nothing wedged. A lock never follows a symlink nor outlives its run, a
refused run leaves nothing behind, a scan deletes nothing it did not make, a partial dataset does not
validate, and every bad number ends with one clear line and exit code 2 before anything is written."""

import json
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from conftest import one_line_error
from pydantic import BaseModel
from test_dataset_abuse import args

from pegasus_gen.cli.main import main
from pegasus_gen.dataset.config import GenerateConfig, load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.lock import LOCK_FILE, FolderLock


def files(root):
    """{relative path: bytes} of every file (symlinks as their target's name) under ``root``."""
    return {p.relative_to(root).as_posix(): (str(p.readlink()) if p.is_symlink() else p.read_bytes())
            for p in sorted(Path(root).rglob("*")) if p.is_file() or p.is_symlink()}


# --- C1: the lock ---------------------------------------------------------------------------------------------

def test_a_lock_that_is_a_symlink_is_refused_and_its_target_is_untouched(library, tmp_path, capsys):
    target = tmp_path / "f"
    target.write_text("data\n")
    out = tmp_path / "d"
    out.mkdir()
    (out / LOCK_FILE).symlink_to(target)
    with pytest.raises(PegasusError, match=r"d/\.lock is a symbolic link"):
        with FolderLock(out, "a test"):
            pass
    (out / "y").write_text("x\n")
    before = files(out)
    assert main(["generate", *args(library.root, out)]) == 2
    assert "not empty" in one_line_error(capsys)
    assert main(["generate", *args(library.root, out), "--resume"]) == 2  # with --resume: past the first check
    one_line_error(capsys)
    assert target.read_text() == "data\n" and files(out) == before


def test_a_refused_generate_leaves_nothing_behind(library, tmp_path, capsys):
    out = tmp_path / "d"
    out.mkdir()
    (out / "y").write_text("x\n")
    assert main(["generate", *args(library.root, out)]) == 2
    assert "not empty" in one_line_error(capsys)
    assert files(out) == {"y": b"x\n"}


def test_the_lock_is_gone_after_a_run_and_the_folders_it_made_after_a_failed_one(library, tmp_path):
    out = generate(load_config(None, args(library.root, tmp_path / "ds")))
    assert not (out / LOCK_FILE).exists()
    with pytest.raises(RuntimeError):
        with FolderLock(tmp_path / "new" / "run", "a test"):
            raise RuntimeError("the run failed before writing anything")
    assert not (tmp_path / "new").exists()


def test_a_stale_lock_of_a_killed_run_is_taken_over_and_removed(tmp_path):
    (tmp_path / LOCK_FILE).write_text("pegasus generate (pid 999999)")  # no process holds it
    with FolderLock(tmp_path, "a test"):
        assert (tmp_path / LOCK_FILE).read_text() == f"a test (pid {os.getpid()})"
    assert list(tmp_path.iterdir()) == []


def test_a_failed_train_leaves_no_folder_and_never_follows_a_symlinked_lock(tmp_path, capsys):
    target = tmp_path / "f"
    target.write_text("data\n")
    out = tmp_path / "d"
    out.mkdir()
    (out / LOCK_FILE).symlink_to(target)
    (out / "y").write_text("x\n")
    assert main(["train", "--data", str(tmp_path / "missing"), "--object", "cup", "--out", str(out)]) == 2
    assert "symbolic link" in one_line_error(capsys)
    assert target.read_text() == "data\n"
    assert main(["train", "--data", str(tmp_path / "missing"), "--object", "cup", "--out",
                 str(tmp_path / "new" / "run")]) == 2
    one_line_error(capsys)
    assert not (tmp_path / "new").exists()


# --- C2: a scan keeps what it did not make ----------------------------------------------------------------

def test_a_scan_refuses_a_work_folder_holding_an_sfm_folder_it_did_not_make(tmp_path, capsys):
    import cv2

    from pegasus_gen.scan.sfm import reconstruct

    photos = tmp_path / "imgs"
    photos.mkdir()
    rng = np.random.default_rng(0)
    for i in range(3):
        cv2.imwrite(str(photos / f"{i}.png"), rng.integers(0, 256, (60, 80, 3), dtype=np.uint8))
    work = tmp_path / "W"
    (work / "sfm").mkdir(parents=True)
    (work / "sfm" / "precious.txt").write_text("notes")
    assert main(["scan", str(photos), "--kind", "object", "--obj-id", "30", "--name", "x", "--scale", "1",
                 "--library", str(tmp_path / "lib"), "--work", str(work)]) == 2
    assert "W already holds sfm" in one_line_error(capsys)
    with pytest.raises(PegasusError, match="not an empty folder"):
        reconstruct(photos, work / "sfm")
    assert files(work) == {"sfm/precious.txt": b"notes"}


# --- H1: a partial dataset ------------------------------------------------------------------------------------

def test_a_dataset_missing_scenes_does_not_validate(library, tmp_path, capsys):
    out = generate(load_config(None, args(library.root, tmp_path / "ds", "scenes=2")))
    shutil.rmtree(out / "train_pbr" / "000001")  # as a run killed after its first scene leaves it
    capsys.readouterr()
    assert main(["validate", str(out)]) == 1
    assert "train_pbr: 1 of the 2 scenes in pegasus_config.yaml are missing (000001); finish the dataset with " \
           "pegasus generate --resume" in capsys.readouterr().out


# --- H3 and the config's numbers ------------------------------------------------------------------------------

@pytest.mark.parametrize("override, key", [
    ("depth_scale=1e-6", "depth_scale"),
    ("seed=-1", "seed"),
    ("camera.cx=.nan", "camera.cx"),
    ("camera.fx=.inf", "camera.fx"),
    ("camera.cx=100000", "camera"),
    ("trajectory.jitter=.inf", "trajectory.jitter"),
])
def test_a_bad_number_in_the_config_is_one_line_and_nothing_is_written(library, tmp_path, capsys, override, key):
    out = tmp_path / "ds"
    assert main(["generate", *args(library.root, out), override]) == 2
    assert f"config key {key}" in one_line_error(capsys)
    assert not out.exists()


def float_keys(model, prefix=""):
    """Dotted keys of every float field (or tuple of floats) of a config model, nested models walked."""
    for name, field in type(model).model_fields.items():
        value = getattr(model, name)
        if isinstance(value, BaseModel):
            yield from float_keys(value, f"{prefix}{name}.")
        elif "float" in str(field.annotation):
            yield f"{prefix}{name}", value


@pytest.mark.parametrize("bad", [".nan", ".inf", "-.inf"])
def test_every_float_of_the_config_must_be_finite(bad):
    keys = dict(float_keys(GenerateConfig()))
    assert {"fps", "depth_scale", "camera.fx", "camera.cx", "trajectory.jitter", "trajectory.distance",
            "shadows.light_direction", "appearance.exposure_ev"} <= set(keys)
    for key, default in keys.items():
        width = len(default) if isinstance(default, tuple) else 3 if key == "shadows.light_direction" else 0
        value = f"[{', '.join([bad] * width)}]" if width else bad
        with pytest.raises(PegasusError, match=f"config key {key}"):
            load_config(None, [f"{key}={value}"])


def test_depth_scale_must_store_the_scene_depth():
    load_config(None, ["depth_scale=0.1"])  # BOP PBR's: 6.5 m
    with pytest.raises(PegasusError, match="depth_scale: .*uint16"):
        load_config(None, ["depth_scale=0.01"])  # 0.65 m: the trajectory reaches 0.8 m
    load_config(None, ["depth_scale=0.01", "trajectory.distance=[0.2, 0.3]"])


# --- Low rows ---------------------------------------------------------------------------------------------

def test_validate_refuses_a_negative_max_images(library, tmp_path, capsys):
    out = generate(load_config(None, args(library.root, tmp_path / "ds")))
    capsys.readouterr()
    assert main(["validate", str(out), "--max-images", "-1"]) == 2
    assert "--max-images" in one_line_error(capsys)


def test_asset_lookups_follow_the_name_rule(library, tmp_path, capsys):
    elsewhere = tmp_path / "other" / "x"
    shutil.copytree(library.get(1).path, elsewhere)
    manifest = json.loads((elsewhere / "asset.json").read_text())
    (elsewhere / "asset.json").write_text(json.dumps({**manifest, "name": "x"}))
    lookup = os.path.relpath(elsewhere, library.root)  # ../test_.../other/x
    assert (library.root / lookup / "asset.json").is_file()  # the path reaches the asset outside the library
    out = tmp_path / "ds"
    assert main(["generate", *args(library.root, out), f"objects=[{{asset: '{lookup}'}}]"]) == 2
    assert "asset name" in one_line_error(capsys)
    assert main(["assets", "--library", str(library.root), "show", lookup, "--out", str(tmp_path / "pv")]) == 2
    assert "asset name" in one_line_error(capsys)
    assert not out.exists() and not (tmp_path / "pv").exists()


def test_a_generate_whose_frames_do_not_fit_in_memory_is_refused_before_anything(library, tmp_path, capsys,
                                                                                   monkeypatch):
    from pegasus_gen.render import renderer

    monkeypatch.setattr(renderer, "memory_available", lambda: 10**9)  # 1 GB left: a 4096 x 4096 frame needs 1.3
    out = tmp_path / "big"
    assert main(["generate", *args(library.root, out, "camera.width=4096", "camera.height=4096")]) == 2
    assert "a 4096 x 4096 image needs about 1.3 GB of memory" in one_line_error(capsys)
    assert not out.exists()
