"""Surface models (the BOP models): where the splats are, coloured as the splats look, fine and closed."""

import numpy as np
import trimesh
from PIL import Image
from scipy.spatial import cKDTree

from pegasus_gen.assets.demo_library import CUPS, frustum_surface
from pegasus_gen.assets.importers import import_cloud, import_mesh
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.assets.surface import MAX_EDGE, mesh_surface
from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.raycast import MeshRaycaster
from pegasus_gen.render.renderer import render
from pegasus_gen.splats.from_mesh import mesh_to_splats


def surface_colour_image(surface, K, T_cam_obj, width, height):
    """[H, W, 3] colour of the surface's nearest vertex at each ray's hit, and the hit mask [H, W]."""
    depth = MeshRaycaster(surface).depth(K, T_cam_obj, width, height)
    u, v = np.meshgrid(np.arange(width), np.arange(height))
    points = np.stack([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], -1).reshape(-1, 3)
    _, nearest = cKDTree(surface.vertices).query((points - T_cam_obj[:3, 3]) @ T_cam_obj[:3, :3])
    colours = np.asarray(surface.visual.vertex_colors)[nearest, :3].reshape(height, width, 3) / 255.0
    return colours, depth > 0


def test_demo_surfaces_are_the_solids_the_splats_cover_coloured_like_their_render(library):
    K = intrinsics_from_fov(320, 240, 40)
    for name in ("noodle_cup_red", "snack_box", "drink_can"):
        asset = library.get(name)
        surface = asset.surface
        assert surface.is_watertight and np.allclose(surface.bounds, asset.mesh.bounds, atol=1e-3)
        spacing = np.linalg.norm(surface.vertices[surface.edges_unique[:, 0]]
                                 - surface.vertices[surface.edges_unique[:, 1]], axis=1)
        assert np.median(spacing) <= MAX_EDGE
        for eye in ([0.0, -0.4, 0.25], [0.3, 0.2, -0.2]):
            T = look_at(eye, [0, 0, 0])
            colours, hit = surface_colour_image(surface, K, T, 320, 240)
            rgb = render(asset.splats, K, T, 320, 240, device="cpu").rgb
            inside = hit & (np.abs(np.diff(hit.astype(int), axis=0, prepend=0)) == 0)
            error = np.abs(colours - rgb)[inside].mean(axis=1)
            assert inside.sum() > 2000 and np.median(error) < 0.08, (name, np.median(error))


def test_the_red_cup_surface_lies_on_its_frustum():
    _, _, (rb, rt, h), *_ = CUPS[0]
    surface = frustum_surface(rb, rt, h, lambda p: np.zeros((len(p), 3)))
    x, y, z = surface.vertices.T
    r = np.hypot(x, y)
    side = (np.abs(z) < h / 2 - 1e-9)
    assert np.abs(r[side] - (rb + (rt - rb) * (z[side] + h / 2) / h)).max() < 1e-4
    assert (r[z >= h / 2 - 1e-9] <= rt + 1e-9).all() and (r[z <= -h / 2 + 1e-9] <= rb + 1e-9).all()
    assert surface.is_watertight and abs(surface.volume / (np.pi * h / 3 * (rb**2 + rb * rt + rt**2)) - 1) < 0.002


def test_an_imported_textured_mesh_keeps_its_texture_per_vertex(tmp_path):
    box = trimesh.creation.box((0.1, 0.06, 0.04))
    uv = np.stack([box.vertices[:, 0] / 0.1 + 0.5, np.full(len(box.vertices), 0.5)], 1)
    image = Image.fromarray(np.array([[[220, 20, 20], [20, 20, 220]]], np.uint8))  # left red, right blue
    box.visual = trimesh.visual.TextureVisuals(uv=uv, image=image)
    box.export(tmp_path / "box.obj")
    asset = import_mesh(tmp_path / "box.obj", "box", "object", AssetLibrary(tmp_path / "lib"), obj_id=3)
    x = asset.surface.vertices[:, 0]
    colours = np.asarray(asset.surface.visual.vertex_colors)[:, :3].astype(int)
    assert len(asset.surface.vertices) > 1000  # subdivided: the texture is carried per vertex
    assert (colours[x < -0.01, 0] > 150).all() and (colours[x < -0.01, 2] < 80).all()
    assert (colours[x > 0.01, 2] > 150).all() and (colours[x > 0.01, 0] < 80).all()


def test_a_splat_object_gets_a_surface_on_its_splats_coloured_by_them(tmp_path):
    mesh = trimesh.creation.cylinder(radius=0.03, height=0.08, sections=64)
    mesh.visual.vertex_colors = np.tile([40, 160, 60, 255], (len(mesh.vertices), 1))
    cloud = mesh_to_splats(mesh, np.random.default_rng(0), spacing=0.002)
    asset = import_cloud(cloud, "green", "object", AssetLibrary(tmp_path / "lib"), obj_id=4)
    distance, _ = cKDTree(asset.splats.means).query(asset.surface.vertices)
    assert np.median(distance) < 0.002 and asset.surface.is_watertight
    colours = np.asarray(asset.surface.visual.vertex_colors)[:, :3].astype(int)
    assert np.abs(np.median(colours, axis=0) - [40, 160, 60]).max() < 15


def test_a_zero_area_face_of_an_imported_mesh_takes_its_corners_mean_colour():
    vertices = np.array([[0, 0, 0], [0.01, 0, 0], [0, 0.01, 0], [0.02, 0.02, 0], [0.02, 0.02, 0]], float)
    faces = np.array([[0, 1, 2], [1, 3, 4]])  # the second face has two equal corners: no area
    colours = np.array([[255, 0, 0, 255], [255, 0, 0, 255], [255, 0, 0, 255], [0, 0, 255, 255], [0, 0, 255, 255]])
    mesh = trimesh.Trimesh(vertices, faces, vertex_colors=colours, process=False)
    fine = mesh_surface(mesh)
    rgb = np.asarray(fine.visual.vertex_colors)[:, :3].astype(float)
    assert np.isfinite(rgb).all() and (rgb.sum(axis=1) > 0).all()  # no vertex left black by NaN weights
    # every vertex's colour lies between the corner colours it was made from: red and blue, never anything else
    assert (rgb[:, 1] == 0).all()
