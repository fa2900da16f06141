"""Imports: a tilted, scaled environment scan comes out level at z = 0; objects land in their object frame."""

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from pegasus_gen.assets.collision import MeshParams
from pegasus_gen.assets.importers import import_mesh, import_splat
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.errors import PegasusError
from pegasus_gen.splats.cloud import concatenate
from pegasus_gen.splats.from_mesh import DEFAULT_SPACING, SILHOUETTE_INSET, mesh_to_splats
from pegasus_gen.splats.ply import write_ply
from pegasus_gen.splats.procedural import plane, wood_texture


def test_tilted_scaled_environment_is_levelled(tmp_path):
    rng = np.random.default_rng(0)
    table = plane(0.8, 0.6, 20000, wood_texture, rng, sh_degree=1)
    clutter = mesh_to_splats(trimesh.creation.box((0.1, 0.1, 0.1)), rng, spacing=0.01)
    clutter = clutter.transformed(trimesh.transformations.translation_matrix([0.2, 0.1, 0.05]))
    scene = concatenate([table, clutter])
    tilt = np.eye(4)
    tilt[:3, :3] = Rotation.from_euler("xyz", [25, -40, 70], degrees=True).as_matrix()
    tilt[:3, 3] = [3.0, -1.0, 2.0]
    scan = scene.transformed(tilt, scale=2.5)  # a scan in arbitrary units and pose
    write_ply(tmp_path / "scan.ply", scan)
    env = import_splat(tmp_path / "scan.ply", "room", "environment", AssetLibrary(tmp_path / "lib"), scale=0.4)
    z = env.splats.means[:, 2]
    on_table = np.abs(z) < 0.003
    assert on_table.mean() > 0.8  # the table is level at z = 0 ...
    assert (z[~on_table] > 0).mean() > 0.95  # ... with the clutter above it (z up)
    normal = np.linalg.svd(env.splats.means[on_table] - env.splats.means[on_table].mean(0), full_matrices=False)[2][2]
    assert np.degrees(np.arccos(abs(normal[2]))) < 1.0
    region = env.manifest.drop_region  # the table's long side along x, in metres (scale applied)
    assert -0.4 < region.x_min < region.x_max < 0.4 and -0.3 < region.y_min < region.y_max < 0.3
    assert np.isclose(region.x_max - region.x_min, 0.8 * 0.96 * 0.8, rtol=0.05)
    assert np.isclose(region.y_max - region.y_min, 0.6 * 0.96 * 0.8, rtol=0.05)
    assert env.mesh.bounds[0, 2] > -0.005 and len(env.mesh.faces) > 0


def test_object_mesh_import_centres_the_bounding_box_and_applies_the_transform(tmp_path):
    mesh = trimesh.creation.cylinder(40, 100, sections=48)  # millimetres, axis along y in the file (y up)
    mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    mesh.apply_translation([500, 200, 50])
    mesh.export(tmp_path / "cup.stl")
    y_up_to_z_up = trimesh.transformations.rotation_matrix(-np.pi / 2, [1, 0, 0])
    asset = import_mesh(tmp_path / "cup.stl", "cup", "object", AssetLibrary(tmp_path / "lib"), obj_id=3, scale=0.001,
                        transform=y_up_to_z_up)
    assert np.allclose(asset.mesh.bounds, [[-0.04, -0.04, -0.05], [0.04, 0.04, 0.05]], atol=1e-3)
    assert np.allclose(asset.splats.means.mean(0), 0, atol=0.003)
    assert asset.manifest.obj_id == 3 and AssetLibrary(tmp_path / "lib").get(3).name == "cup"


def test_a_fine_imported_model_collides_as_a_closed_decimated_copy_and_stays_the_surface(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=5, radius=50.0)  # 20,480 triangles, mm
    sphere.export(tmp_path / "ball.ply")
    asset = import_mesh(tmp_path / "ball.ply", "ball", "object", AssetLibrary(tmp_path / "lib"), obj_id=4, scale=0.001)
    assert len(sphere.faces) > 10 * MeshParams().max_triangles
    assert 0.3 * MeshParams().max_triangles <= len(asset.mesh.faces) <= MeshParams().max_triangles
    assert asset.mesh.is_watertight and abs(asset.mesh.volume / sphere.volume * 1e9 - 1) < 0.02
    assert len(asset.surface.faces) >= len(sphere.faces)  # the labels' model keeps every triangle
    assert np.allclose(asset.surface.vertices.mean(0), 0, atol=1e-3)


def test_an_objects_splats_sit_inside_its_surface_an_environments_on_it(tmp_path):
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=40.0)  # mm
    sphere.export(tmp_path / "ball.ply")
    sphere.invert()  # wound inside out: its face normals point in
    sphere.export(tmp_path / "inverted.ply")
    lib = AssetLibrary(tmp_path / "lib")
    ball = import_mesh(tmp_path / "ball.ply", "ball", "object", lib, obj_id=4, scale=0.001)
    inverted = import_mesh(tmp_path / "inverted.ply", "inverted", "object", lib, obj_id=5, scale=0.001)
    room = import_mesh(tmp_path / "ball.ply", "room", "environment", lib, scale=0.001)
    depth_in = [0.04 - np.linalg.norm(a.splats.means - a.mesh.centroid, axis=1) for a in (ball, inverted, room)]
    for inside in depth_in[:2]:
        assert np.median(inside) == pytest.approx(SILHOUETTE_INSET * DEFAULT_SPACING, abs=1e-4)
    assert abs(np.median(depth_in[2])) < 1e-4  # (the faceted sphere lies up to 0.05 mm inside the round one)


def test_object_splat_import_builds_a_collision_mesh(tmp_path):
    cloud = mesh_to_splats(trimesh.creation.box((0.1, 0.06, 0.04)), np.random.default_rng(1), spacing=0.002)
    write_ply(tmp_path / "box.ply", cloud.transformed(trimesh.transformations.translation_matrix([1, 2, 3])))
    asset = import_splat(tmp_path / "box.ply", "box", "object", AssetLibrary(tmp_path / "lib"), obj_id=5)
    assert asset.mesh.is_watertight and abs(asset.mesh.volume / (0.1 * 0.06 * 0.04) - 1) < 0.1
    assert np.allclose(asset.mesh.bounds.mean(0), 0, atol=1e-6)
    assert asset.manifest.geometry["alpha"] > 0


def test_object_without_obj_id_and_bad_scale_are_refused(tmp_path):
    write_ply(tmp_path / "b.ply", mesh_to_splats(trimesh.creation.box((0.1, 0.1, 0.1)), np.random.default_rng(0)))
    lib = AssetLibrary(tmp_path / "lib")
    with pytest.raises(PegasusError, match="obj-id"):
        import_splat(tmp_path / "b.ply", "b", "object", lib)
    with pytest.raises(PegasusError, match="scale"):
        import_splat(tmp_path / "b.ply", "b", "object", lib, obj_id=1, scale=0)
    with pytest.raises(PegasusError, match="rigid"):
        import_splat(tmp_path / "b.ply", "b", "object", lib, obj_id=1, transform=np.diag([2.0, 1, 1, 1]))
    assert not (tmp_path / "lib" / "b").exists()
