"""End to end: a small BOP dataset, read back with a minimal reader written here from the BOP spec."""

import json
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
import trimesh
from plyfile import PlyData

from pegasus_gen.dataset.config import load_config
from pegasus_gen.dataset.generate import generate
from pegasus_gen.dataset.validate import validate
from pegasus_gen.errors import PegasusError


def config(library, out, *extra):
    return load_config(None, [f"output={out}", f"library={library.root}", "scenes=2", "frames_per_scene=2",
                              "camera.width=320", "camera.height=240", "device=cpu", "environments=[wooden_table]",
                              "objects=[{asset: 1, count: [1, 1]}, {asset: 7, count: [1, 1]},"
                              " {asset: 8, count: [0, 1]}]",
                              *extra])


def read_model_mm(path):
    ply = PlyData.read(str(path))
    vertices = np.stack([ply["vertex"][k] for k in "xyz"], 1).astype(np.float64)
    return vertices, np.stack(ply["face"]["vertex_indices"]).astype(np.int64)


def project_silhouette(vertices_mm, faces, R, t_mm, K, width, height):
    """Independent of pegasus_gen: pinhole projection of every triangle, filled one by one."""
    cam = vertices_mm @ R.T + t_mm
    uv = cam[:, :2] / cam[:, 2:3] * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    mask = np.zeros((height, width), np.uint8)
    for tri in faces:
        cv2.fillConvexPoly(mask, np.round(uv[tri] * 16).astype(np.int32), 255, cv2.LINE_8, shift=4)
    return mask > 0, cam


def test_dataset_reads_back_and_models_cover_their_masks(library, tmp_path):
    out = generate(config(library, tmp_path / "ds"))
    camera = json.loads((out / "camera.json").read_text())
    assert camera["depth_scale"] == 0.1 and camera["width"] == 320
    info = json.loads((out / "models" / "models_info.json").read_text())
    assert set(info) >= {"1", "7"}
    scenes = sorted(p for p in (out / "train_pbr").iterdir())
    assert [p.name for p in scenes] == ["000000", "000001"]
    checked = 0
    for scene in scenes:
        gt = json.loads((scene / "scene_gt.json").read_text())
        cams = json.loads((scene / "scene_camera.json").read_text())
        infos = json.loads((scene / "scene_gt_info.json").read_text())
        assert sorted(gt) == sorted(cams) == sorted(infos) == ["0", "1"]
        for im_id, entries in gt.items():
            K = np.array(cams[im_id]["cam_K"]).reshape(3, 3)
            depth = cv2.imread(str(scene / "depth" / f"{int(im_id):06d}.png"), cv2.IMREAD_UNCHANGED)
            assert depth.dtype == np.uint16
            depth_mm = depth * cams[im_id]["depth_scale"]
            for gt_idx, (entry, gi) in enumerate(zip(entries, infos[im_id])):
                R = np.array(entry["cam_R_m2c"]).reshape(3, 3)
                t = np.array(entry["cam_t_m2c"])
                assert np.allclose(R @ R.T, np.eye(3), atol=1e-6) and 100 < t[2] < 3000  # mm
                vertices, faces = read_model_mm(out / "models" / f"obj_{entry['obj_id']:06d}.ply")
                sil, cam_pts = project_silhouette(vertices, faces, R, t, K, 320, 240)
                mask = cv2.imread(str(scene / "mask" / f"{int(im_id):06d}_{gt_idx:06d}.png"), 0) > 0
                visib = cv2.imread(str(scene / "mask_visib" / f"{int(im_id):06d}_{gt_idx:06d}.png"), 0) > 0
                iou = (sil & mask).sum() / max((sil | mask).sum(), 1)
                if mask.sum() >= 1500:  # small or cut-off silhouettes are mostly boundary (splats add ~0.5 px)
                    assert iou >= 0.9, f"{scene.name}/{im_id}/{gt_idx}: IoU {iou:.3f}"
                    checked += 1
                assert visib.sum() == gi["px_count_visib"] and not (visib & ~mask).any()
                if gi["px_count_visib"] > 100:  # depth at visible pixels lies within the posed model's depth range
                    d = depth_mm[visib]
                    inside = (d >= cam_pts[:, 2].min() - 5) & (d <= cam_pts[:, 2].max() + 5)
                    assert inside.mean() > 0.95
    assert checked >= 4


def dataset_files(root):
    """{relative path: bytes} of every file of a dataset."""
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_resume_after_kill_9_gives_the_same_dataset(library, tmp_path):
    """A real generator process killed with SIGKILL mid-run, then resumed, equals an uninterrupted run."""
    args = [f"output={tmp_path / 'killed'}", f"library={library.root}", "scenes=3", "frames_per_scene=2",
            "camera.width=160", "camera.height=120", "device=cpu", "environments=[wooden_table]",
            "objects=[{asset: 1, count: [1, 1]}, {asset: 7, count: [1, 1]}]"]
    proc = subprocess.Popen([sys.executable, "-m", "pegasus_gen.cli", "generate", *args],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    split = tmp_path / "killed" / "train_pbr"
    deadline = time.monotonic() + 120
    while not (split / "000000").is_dir() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.kill()  # SIGKILL: no cleanup runs
    proc.wait()
    assert (split / "000000").is_dir() and not (split / "000002").exists()  # killed mid-run
    assert any("scenes in pegasus_config.yaml are missing" in p for p in validate(tmp_path / "killed").problems)
    resumed = generate(load_config(None, args), resume=True)
    full = generate(load_config(None, [a.replace("killed", "full") for a in args]))
    assert not [p for p in split.iterdir() if p.name.startswith(".")]  # no debris left
    got, want = dataset_files(resumed), dataset_files(full)
    assert sorted(got) == sorted(want)
    assert [k for k in want if got[k] != want[k]] == []


def test_resume_refuses_another_config_and_plain_rerun_refuses_a_full_folder(library, tmp_path):
    out = generate(config(library, tmp_path / "ds", "scenes=1", "frames_per_scene=1"))
    before = dataset_files(out)
    with pytest.raises(PegasusError, match="not empty; pass --resume"):
        generate(config(library, out, "scenes=2", "frames_per_scene=1"))
    with pytest.raises(PegasusError, match="different config .*seed"):
        generate(config(library, out, "scenes=1", "frames_per_scene=1", "seed=5"), resume=True)
    assert dataset_files(out) == before
    generate(config(library, out, "scenes=1", "frames_per_scene=1", "workers=2"), resume=True)  # workers may differ
    assert dataset_files(out) == before


def test_workers_give_the_same_dataset_as_one_process(library, tmp_path):
    one = generate(config(library, tmp_path / "one", "scenes=2", "frames_per_scene=1"))
    two = generate(config(library, tmp_path / "two", "scenes=2", "frames_per_scene=1", "workers=2"))
    got, want = dataset_files(two), dataset_files(one)
    assert sorted(got) == sorted(want) and [k for k in want if got[k] != want[k]] == []


def test_missing_asset_leaves_the_output_untouched(library, tmp_path):
    cfg = load_config(None, [f"output={tmp_path / 'ds'}", f"library={library.root}", "objects=[{asset: 99}]"])
    with pytest.raises(PegasusError, match="no asset 99"):
        generate(cfg)
    assert not (tmp_path / "ds").exists()


def world_poses(scene_dir):
    """Per image: the list of T_world_obj (m) recovered from scene_gt and scene_camera."""
    gt = json.loads((scene_dir / "scene_gt.json").read_text())
    cams = json.loads((scene_dir / "scene_camera.json").read_text())
    out = {}
    for im_id, entries in gt.items():
        T_cw = np.eye(4)
        T_cw[:3, :3] = np.array(cams[im_id]["cam_R_w2c"]).reshape(3, 3)
        T_cw[:3, 3] = np.array(cams[im_id]["cam_t_w2c"]) / 1000
        poses = []
        for e in entries:
            T_co = np.eye(4)
            T_co[:3, :3] = np.array(e["cam_R_m2c"]).reshape(3, 3)
            T_co[:3, 3] = np.array(e["cam_t_m2c"]) / 1000
            poses.append(np.linalg.inv(T_cw) @ T_co)
        out[int(im_id)] = poses
    return out


def test_dynamic_scene_gt_follows_the_physics_of_each_frame(library, tmp_path):
    from pegasus_gen.dataset.scene import frame_poses, load_assets, plan_scene

    cfg = config(library, tmp_path / "dyn", "scenes=1", "frames_per_scene=6", "dynamic=true", "fps=20")
    out = generate(cfg)
    written = world_poses(out / "train_pbr" / "000000")
    plan = plan_scene(0, cfg, load_assets(cfg))
    for im_id, poses in written.items():
        expected = frame_poses(plan, im_id, dynamic=True)
        for got, want in zip(poses, [expected[i] for i in sorted(expected)]):
            assert np.allclose(got, want, atol=1e-6)
    assert np.linalg.norm(written[0][0][:3, 3] - written[5][0][:3, 3]) > 0.01  # they really move


def test_a_scene_whose_targets_all_fell_off_is_dropped_again_and_then_refused(library, tmp_path, monkeypatch):
    import dataclasses

    from pegasus_gen.dataset import scene

    cfg = config(library, tmp_path / "x", "scenes=1", "frames_per_scene=1")
    real_drop, calls = scene.drop_objects, []

    def drop(*args, **kwargs):  # the real drop; its first result as if every object had fallen off
        result = real_drop(*args, **kwargs)
        calls.append(result)
        return dataclasses.replace(result, poses={}, removed=sorted(result.poses)) if len(calls) == 1 else result

    monkeypatch.setattr(scene, "drop_objects", drop)
    plan = scene.plan_scene(0, cfg, scene.load_assets(cfg))
    assert len(calls) == 2 and plan.drop is calls[1] and plan.labelled(sorted(plan.drop.poses))
    assert not np.allclose(calls[0].poses[0], calls[1].poses[0])  # dropped again from new spawn poses
    monkeypatch.setattr(scene, "drop_objects", lambda *a, **k: dataclasses.replace(real_drop(*a, **k), poses={}))
    with pytest.raises(PegasusError, match=f"in {scene.DROP_ATTEMPTS} drops"):
        generate(config(library, tmp_path / "y", "scenes=1", "frames_per_scene=1"))


def test_static_scene_keeps_the_rest_poses_in_every_frame(library, tmp_path):
    out = generate(config(library, tmp_path / "static", "scenes=1", "frames_per_scene=3"))
    written = world_poses(out / "train_pbr" / "000000")
    for im_id in (1, 2):
        for a, b in zip(written[0], written[im_id]):
            assert np.allclose(a, b, atol=1e-6)


@pytest.mark.parametrize("offset", [[0.0, 0.0, 0.0], [0.35, 0.1, 0.0], [0.0, -0.3, 0.2]])
def test_windowed_object_canvas_equals_the_full_canvas(library, offset):
    from pegasus_gen.dataset.scene import object_depth_window
    from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
    from pegasus_gen.render.raycast import MeshRaycaster

    asset = library.get(7)
    T_world_obj = np.eye(4)
    T_world_obj[:3, 3] = np.array([0.0, 0.0, 0.03]) + offset  # in view, beside the image, above it
    W, H = 160, 120
    K = intrinsics_from_fov(W, H, 60)
    K_canvas = K.copy()
    K_canvas[:2, 2] += [W, H]
    T_cam_obj = look_at([0.0, -0.45, 0.35], [0, 0, 0]) @ T_world_obj
    model = MeshRaycaster(asset.surface)
    full = model.depth(K_canvas, T_cam_obj, 3 * W, 3 * H)
    assert (full > 0).sum() > 200
    hull = asset.surface.convex_hull.vertices  # what generate passes (Assets.hull)
    for points in (asset.surface.vertices, hull, trimesh.bounds.corners(asset.surface.bounds)):
        window = object_depth_window(model, points, T_cam_obj, K_canvas, W, H)
        np.testing.assert_allclose(window.canvas(W, H), full, atol=1e-6)
