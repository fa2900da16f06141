"""BOP pieces: units, model PLY layout, models_info and gt_info as bop_toolkit defines them."""

import numpy as np
import trimesh
from plyfile import PlyData

from pegasus_gen.assets.library import ContinuousSymmetry
from pegasus_gen.dataset.bop import (
    camera_entry,
    depth_to_png_values,
    gt_info_entry,
    models_info_entry,
    pose_entry,
    write_model_ply,
)


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


def test_model_ply_is_mm_with_vertex_indices(tmp_path):
    mesh = trimesh.creation.box((0.1, 0.06, 0.04))
    path = write_model_ply(tmp_path / "obj_000001.ply", mesh)
    ply = PlyData.read(str(path))
    assert [p.name for p in ply["vertex"].properties][:3] == ["x", "y", "z"]
    header = path.read_bytes().split(b"end_header")[0].decode()
    assert "property float x" in header and "property list uchar int vertex_indices" in header
    v = np.stack([ply["vertex"][k] for k in "xyz"], 1)
    assert np.allclose(np.ptp(v, 0), [100, 60, 40], atol=1e-3)
    faces = np.stack(ply["face"]["vertex_indices"])
    assert faces.shape == (len(mesh.faces), 3) and np.array_equal(faces, mesh.faces)


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
    info, mask, visible = gt_info_entry(canvas, scene, K)
    assert info["px_count_all"] == 400 and mask.sum() == 300
    assert info["bbox_obj"] == [-5, 10, 20, 20]
    assert info["px_count_valid"] == 300 - 25
    assert info["px_count_visib"] == 300 - 150 and np.isclose(info["visib_fract"], 150 / 400)
    assert info["bbox_visib"] == [0, 20, 15, 10]
    occluded = gt_info_entry(canvas, np.full((H, W), 0.5), K)[0]
    assert occluded["px_count_visib"] == 0 and occluded["bbox_visib"] == [-1, -1, -1, -1]
