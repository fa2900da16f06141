"""BOP pieces: units, model PLY layout, evaluation models, models_info, gt_info, test targets and the BOP19
results file as bop_toolkit defines them."""

import json

import numpy as np
import open3d as o3d
import pytest
import trimesh
from plyfile import PlyData

from pegasus_gen.assets.library import ContinuousSymmetry
from pegasus_gen.dataset.models import (
    EVAL_SPACING,
    cached_eval_model,
    eval_model,
    model_extent,
    model_ply_bytes,
    models_info_entry,
    write_model_ply,
)
from pegasus_gen.errors import PegasusError
from pegasus_gen.formats.bop import (
    CanvasWindow,
    camera_entry,
    depth_to_png_values,
    gt_info_entry,
    pose_entry,
    read_bop_results,
    read_targets_bop19,
    targets_bop19,
    write_bop_results,
)
from pegasus_gen.render.raycast import MeshRaycaster


def test_pose_and_camera_entries_are_in_millimetres_row_major():
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.1, -0.2, 0.75]
    e = pose_entry(T, 3)
    assert e["obj_id"] == 3 and e["cam_R_m2c"] == [0, -1, 0, 1, 0, 0, 0, 0, 1]
    assert np.allclose(e["cam_t_m2c"], [100, -200, 750])
    K = np.array([[600.0, 0, 319.5], [0, 610.0, 239.5], [0, 0, 1]])
    c = camera_entry(K, T, 0.1)
    assert c["cam_K"] == K.ravel().tolist() and c["depth_scale"] == 0.1
    assert np.allclose(c["cam_t_w2c"], [100, -200, 750])


def test_depth_png_values_follow_depth_scale():
    values = depth_to_png_values(np.array([[0.0, 1.2345, 10.0]]), 0.1)
    assert values.dtype == np.uint16 and values.tolist() == [[0, 12345, 65535]]  # 10 m clips


def test_model_ply_is_mm_with_normals_colours_and_vertex_indices(tmp_path):
    mesh = trimesh.creation.box((0.1, 0.06, 0.04))
    colours = np.random.default_rng(0).integers(0, 256, (len(mesh.vertices), 3))
    mesh.visual.vertex_colors = np.concatenate([colours, np.full((len(colours), 1), 255)], 1)
    path = write_model_ply(tmp_path / "obj_000001.ply", mesh)
    ply = PlyData.read(str(path))
    assert [p.name for p in ply["vertex"].properties] == ["x", "y", "z", "nx", "ny", "nz", "red", "green", "blue"]
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "property float x" in header and "property list uchar int vertex_indices" in header
    v = np.stack([ply["vertex"][k] for k in "xyz"], 1)
    assert np.allclose(np.ptp(v, 0), [100, 60, 40], atol=1e-3)
    assert np.array_equal(np.stack([ply["vertex"][k] for k in ("red", "green", "blue")], 1), colours)
    normals = np.stack([ply["vertex"][k] for k in ("nx", "ny", "nz")], 1)
    assert np.allclose(np.linalg.norm(normals, axis=1), 1, atol=1e-5) and (np.sum(normals * v, 1) > 0).all()
    faces = np.stack(ply["face"]["vertex_indices"])
    assert faces.shape == (len(mesh.faces), 3) and np.array_equal(faces, mesh.faces)


def test_eval_model_resamples_the_surface_evenly_and_stays_closed():
    """A box of 12 triangles and a finely tessellated ring both come out closed, with vertices on the
    surface about EVAL_SPACING apart, and the same volume."""
    for mesh in (trimesh.creation.box((0.12, 0.05, 0.03)), trimesh.creation.annulus(0.02, 0.035, 0.03, sections=200)):
        resampled = eval_model(mesh)
        assert resampled.is_watertight and resampled.volume > 0  # closed, outward faces
        assert abs(resampled.volume / mesh.volume - 1) < 0.02
        distance = MeshRaycaster(mesh).scene.compute_distance(
            o3d.core.Tensor(np.asarray(resampled.vertices, np.float32))).numpy()
        assert np.median(distance) < 0.1 * EVAL_SPACING and distance.max() < 0.5 * EVAL_SPACING
        edges = resampled.edges_unique_length
        assert 0.6 * EVAL_SPACING < np.median(edges) < 1.2 * EVAL_SPACING and edges.max() < 2 * EVAL_SPACING


def test_evaluation_models_are_cached_by_surface_content_and_recomputed_when_unreadable(tmp_path):
    box, ring = trimesh.creation.box((0.12, 0.05, 0.03)), trimesh.creation.annulus(0.02, 0.035, 0.03, sections=64)
    for name, mesh in (("box", box), ("ring", ring)):
        write_model_ply(tmp_path / f"{name}.ply", mesh)
    cache = tmp_path / "cache"
    data, extent, extent_eval = cached_eval_model(tmp_path / "box.ply", box, cache)
    assert data == model_ply_bytes(eval_model(box))  # what eval_model gives, in the models_eval layout
    assert extent == model_extent(box) and extent_eval == model_extent(eval_model(box))
    (entry,) = cache.iterdir()
    (entry / "eval.ply").write_bytes(b"kept")  # a second call reads the cache instead of resampling
    assert cached_eval_model(tmp_path / "box.ply", box, cache)[0] == b"kept"
    assert cached_eval_model(tmp_path / "ring.ply", ring, cache)[0] == model_ply_bytes(eval_model(ring))
    assert len(list(cache.iterdir())) == 2  # another surface file, another entry
    (entry / "info.json").write_text("{not json")
    assert cached_eval_model(tmp_path / "box.ply", box, cache)[0] == data  # unreadable: recomputed, rewritten
    blocked = tmp_path / "blocked"
    blocked.write_text("a file where the cache folder should be")
    assert cached_eval_model(tmp_path / "box.ply", box, blocked)[0] == data  # cannot be written: still right


def test_models_info_diameter_is_the_largest_vertex_distance():
    mesh = trimesh.creation.cylinder(0.04, 0.1, sections=32)
    info = models_info_entry(mesh, symmetries_continuous=[ContinuousSymmetry(axis=(0, 0, 1))])
    v = mesh.vertices * 1000
    brute = max(np.linalg.norm(a - b) for a in v for b in v)
    assert np.isclose(info["diameter"], brute)
    assert np.isclose(info["size_z"], 100) and np.isclose(info["min_z"], -50)
    assert info["symmetries_continuous"] == [{"axis": [0.0, 0.0, 1.0], "offset": [0.0, 0.0, 0.0]}]


def test_gt_info_counts_outside_pixels_and_occlusion():
    H, W = 40, 60
    K = np.array([[50.0, 0, 29.5], [0, 50.0, 19.5], [0, 0, 1]])
    canvas = np.zeros((3 * H, 3 * W))
    canvas[H + 10:H + 30, W - 5:W + 15] = 1.0  # a 20 x 20 px object, 5 columns left of the image
    scene = np.full((H, W), 2.0)
    scene[10:20, 0:15] = 0.5  # an occluder in front of its top half
    scene[25:30, 10:15] = 0.0  # no scene depth here: counts as visible, not valid
    info, mask, visible = gt_info_entry(CanvasWindow(canvas), scene, K)
    assert info["px_count_all"] == 400 and mask.sum() == 300
    assert info["bbox_obj"] == [-5, 10, 20, 20]
    assert info["px_count_valid"] == 300 - 25
    assert info["px_count_visib"] == 300 - 150 and np.isclose(info["visib_fract"], 150 / 400)
    assert info["bbox_visib"] == [0, 20, 15, 10]
    occluded = gt_info_entry(CanvasWindow(canvas), np.full((H, W), 0.5), K)[0]
    assert occluded["px_count_visib"] == 0 and occluded["bbox_visib"] == [-1, -1, -1, -1]


@pytest.mark.parametrize("seed", range(6))
def test_gt_info_of_a_window_equals_that_of_the_whole_canvas(seed):
    """The object's window anywhere on the 3x canvas (inside the image, across its border, wholly outside it)
    gives what the whole canvas gives."""
    rng = np.random.default_rng(seed)
    H, W = 30, 40
    K = np.array([[40.0, 0, 19.5], [0, 41.0, 14.5], [0, 0, 1]])
    h, w = rng.integers(3, 40, 2)
    y0, x0 = rng.integers(0, 3 * H - h), rng.integers(0, 3 * W - w)
    if seed == 0:
        y0, x0 = H + 5, W - w // 2  # across the image's left border
    window = np.where(rng.random((h, w)) < 0.7, rng.uniform(0.4, 0.6, (h, w)), 0.0)
    canvas = np.zeros((3 * H, 3 * W))
    canvas[y0:y0 + h, x0:x0 + w] = window
    scene = np.where(rng.random((H, W)) < 0.1, 0.0, rng.uniform(0.3, 0.7, (H, W)))
    whole = gt_info_entry(CanvasWindow(canvas), scene, K)
    part = gt_info_entry(CanvasWindow(window, int(x0), int(y0)), scene, K)
    assert whole[0] == part[0]
    np.testing.assert_array_equal(whole[1], part[1])
    np.testing.assert_array_equal(whole[2], part[2])
    np.testing.assert_array_equal(CanvasWindow(window, int(x0), int(y0)).canvas(W, H), canvas)


def test_bop19_results_file_has_the_toolkits_layout_and_reads_back(tmp_path):
    rng = np.random.default_rng(3)
    rows = []
    for n in range(4):
        R = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        rows.append({"scene_id": n // 2, "im_id": 7 + n // 2, "obj_id": 1 + n % 2, "score": float(rng.uniform()),
                     "R": R.ravel().tolist(), "t": (rng.normal(size=3) * 300).tolist(), "time": 0.25 + n // 2})
    path = write_bop_results(tmp_path / "mine_lm-test.csv", rows)
    lines = path.read_text().splitlines()
    assert lines[0] == "scene_id,im_id,obj_id,score,R,t,time" and len(lines) == 5
    fields = lines[1].split(",")
    assert len(fields) == 7 and len(fields[4].split(" ")) == 9 and len(fields[5].split(" ")) == 3
    back = read_bop_results(path)
    for row, read in zip(rows, back):
        assert (read["scene_id"], read["im_id"], read["obj_id"]) == (row["scene_id"], row["im_id"], row["obj_id"])
        assert read["score"] == row["score"] and read["time"] == row["time"]
        assert np.array_equal(read["R"], np.reshape(row["R"], (3, 3))) and np.array_equal(read["t"], row["t"])
    (tmp_path / "bad.csv").write_text("scene,im\n1,2\n")
    with pytest.raises(PegasusError, match="not a BOP19 results file"):
        read_bop_results(tmp_path / "bad.csv")


def test_test_targets_count_the_instances_seen_at_least_ten_percent(tmp_path):
    visib = {0: {"0": [(1, 0.5), (1, 0.09), (2, 0.1)], "4": [(2, 0.0)]}, 3: {"1": [(1, 0.95), (1, 0.3), (3, 0.2)]}}
    for scene_id, frames in visib.items():
        scene = tmp_path / f"{scene_id:06d}"
        scene.mkdir()
        (scene / "scene_gt.json").write_text(json.dumps(
            {im: [{"obj_id": o, "cam_R_m2c": [1, 0, 0, 0, 1, 0, 0, 0, 1], "cam_t_m2c": [0, 0, 500]} for o, _ in inst]
             for im, inst in frames.items()}))
        (scene / "scene_gt_info.json").write_text(json.dumps(
            {im: [{"visib_fract": v} for _, v in inst] for im, inst in frames.items()}))
    expected = [(0, 0, 1, 1), (0, 0, 2, 1), (3, 1, 1, 2), (3, 1, 3, 1)]
    assert targets_bop19(tmp_path) == [dict(zip(("scene_id", "im_id", "obj_id", "inst_count"), e)) for e in expected]
    # read back from the dataset's root as evaluation does: keyed by (scene, image, object), None without the file
    listed, root = targets_bop19(tmp_path), tmp_path / "root"
    assert read_targets_bop19(root, "test") is None
    root.mkdir()
    (root / "test_targets_bop19.json").write_text(json.dumps(listed))
    assert read_targets_bop19(root, "test") == {e[:3]: e[3] for e in expected}
    (root / "test_targets_bop19.json").write_text(json.dumps({"scene_id": 0}))
    with pytest.raises(PegasusError, match="test_targets_bop19.json: not a list"):
        read_targets_bop19(root, "test")
