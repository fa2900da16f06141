"""Distractors: procedural clutter that falls, shows and hides targets, and is never labelled."""

import json

import cv2
import numpy as np
from test_generate import config

from pegasus_gen.dataset.config import DistractorConfig
from pegasus_gen.dataset.distractors import PALETTE_SPLATS, make_distractor, object_palette
from pegasus_gen.dataset.generate import generate
from pegasus_gen.dataset.scene import camera_matrix, load_assets, plan_scene
from pegasus_gen.dataset.validate import validate
from pegasus_gen.splats import sh
from pegasus_gen.splats.surface_splats import surface_splats


def test_distractors_are_closed_convex_solids_of_the_asked_size():
    cfg = DistractorConfig(count=(1, 1), size=(0.05, 0.08))
    rng = np.random.default_rng(0)
    for k in range(12):
        d = make_distractor(cfg, rng, k)
        assert d.surface.is_watertight and d.surface.is_convex
        assert 0.05 * 0.3 - 1e-9 <= np.ptp(d.surface.vertices, axis=0).max() <= 0.08 + 1e-9
        assert d.mass > 0 and len(d.splats) >= 200
        mesh = d.surface  # convex: a point's distance outside the face planes is 0 exactly on the surface
        planes = np.einsum("fk,fk->f", mesh.face_normals, mesh.triangles[:, 0])
        outside = (d.splats.means @ mesh.face_normals.T - planes).max(axis=1)
        assert np.abs(outside).max() < 1e-3  # the splats lie on the surface
        assert np.ptp(d.splats.sh[:, 0], axis=0).max() > 0.5  # textured: more than one colour


def test_a_distractor_is_dropped_rendered_and_never_annotated(library, tmp_path):
    cfg = config(library, tmp_path / "ds", "scenes=2", "frames_per_scene=2", "distractors.count=[3, 3]",
                 "distractors.size=[0.06, 0.1]")
    out = generate(cfg)
    assert validate(out).ok
    assets = load_assets(cfg)
    K = camera_matrix(cfg)
    seen = 0
    for scene_id in range(2):
        plan = plan_scene(scene_id, cfg, assets)  # deterministic: the plan the dataset was made from
        kept = sorted(plan.drop.poses)
        targets, clutter = plan.labelled(kept), [i for i in kept if i >= plan.targets]
        assert plan.targets == len(plan.objects) - 3 and clutter
        scene = out / "train_pbr" / f"{scene_id:06d}"
        gt = json.loads((scene / "scene_gt.json").read_text())
        cameras = json.loads((scene / "scene_camera.json").read_text())
        coco = json.loads((scene / "scene_gt_coco.json").read_text())
        models = {int(k) for k in json.loads((out / "models" / "models_info.json").read_text())}
        assert len(coco["annotations"]) <= sum(len(v) for v in gt.values())  # COCO: the visible ones
        assert {a["category_id"] for a in coco["annotations"]} <= models
        for im_id, instances in gt.items():
            assert [g["obj_id"] for g in instances] == [plan.objects[i].manifest.obj_id for i in targets]
            assert {g["obj_id"] for g in instances} <= models
            cam = cameras[im_id]
            T_cam_world = np.eye(4)
            T_cam_world[:3, :3] = np.reshape(cam["cam_R_w2c"], (3, 3))
            T_cam_world[:3, 3] = np.array(cam["cam_t_w2c"]) / 1000
            for g, i in zip(instances, targets):  # each annotation is a target's pose, none a distractor's
                np.testing.assert_allclose(np.array(g["cam_t_m2c"]) / 1000,
                                           (T_cam_world @ plan.drop.poses[i])[:3, 3], atol=1e-6)
            depth = cv2.imread(str(scene / "depth" / f"{int(im_id):06d}.png"), cv2.IMREAD_UNCHANGED) * 1e-4
            for i in clutter:  # the distractor is in the render: the depth at its centre is its surface's
                p = (T_cam_world @ plan.drop.poses[i])[:3, 3]
                u, v = (K @ (p / p[2]))[:2].round().astype(int)
                if 0 <= u < depth.shape[1] and 0 <= v < depth.shape[0] and depth[v, u] > 0:
                    extent = np.ptp(plan.objects[i].surface.vertices, axis=0).max()
                    seen += abs(depth[v, u] - p[2]) < extent
    assert seen >= 3


def test_object_coloured_distractors_wear_the_palette_and_change_nothing_when_off():
    palette = np.array([[0.9, 0.8, 0.1], [0.7, 0.1, 0.1]])
    painted = [make_distractor(DistractorConfig(object_colours=1.0), np.random.default_rng(s), 0, palette)
               for s in range(8)]
    for d in painted:  # every splat in one of the palette's colours (base colour, SH DC)
        rgb = 0.5 + sh.C0 * d.splats.sh[:, 0].astype(np.float64)
        assert np.abs(rgb[:, None, :] - palette[None]).max(axis=2).min(axis=1).max() < 1e-4
    assert any(np.ptp(d.splats.sh[:, 0], axis=0).max() < 1e-6 for d in painted)  # one colour: plain
    off = make_distractor(DistractorConfig(), np.random.default_rng(3), 0, palette)
    plain = make_distractor(DistractorConfig(), np.random.default_rng(3), 0)
    assert np.array_equal(off.splats.sh, plain.splats.sh) and np.array_equal(off.splats.means, plain.splats.means)


def test_object_palette_holds_each_clouds_base_colours():
    rng = np.random.default_rng(0)
    clouds = []  # surface splats of two known colours
    for colour in ([0.9, 0.1, 0.1], [0.1, 0.2, 0.9]):
        points = rng.uniform(-0.05, 0.05, (500, 3))
        normals = points / np.linalg.norm(points, axis=1, keepdims=True)
        clouds.append(surface_splats(points, normals, np.tile(colour, (500, 1)), 0.004, rng))
    palette = object_palette(clouds, rng)
    assert palette.shape == (2 * PALETTE_SPLATS, 3)
    assert np.allclose(palette[:PALETTE_SPLATS], [0.9, 0.1, 0.1], atol=1e-4)
    assert np.allclose(palette[PALETTE_SPLATS:], [0.1, 0.2, 0.9], atol=1e-4)
