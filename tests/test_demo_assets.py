"""The built-in demo library: contents, caching, and physics + rendering in the shared object frame."""

import numpy as np
import pybullet as pb
import pytest
from conftest import assert_covers_the_silhouette
from scipy.spatial import ConvexHull
from scipy.spatial.transform import Rotation

from pegasus_gen.assets.demo_library import build_demo_library
from pegasus_gen.geometry.cameras import intrinsics_from_fov, look_at
from pegasus_gen.render.renderer import render
from pegasus_gen.render.silhouette import mesh_silhouette


def test_contents(library):
    manifests = library.manifests()
    objects = [m for m in manifests if m.kind == "object"]
    envs = [m for m in manifests if m.kind == "environment"]
    assert len(objects) >= 8 and len(envs) >= 3
    assert sum(m.name.startswith("noodle_") for m in objects) >= 6
    assert sorted(m.obj_id for m in objects) == list(range(1, len(objects) + 1))
    for m in envs:
        n = len(library.get(m.name).splats)
        assert 200_000 <= n <= 600_000, (m.name, n)


def test_second_build_reuses_the_assets(library):
    stamps = {n: (library.root / n / "splats.ply").stat().st_mtime_ns for n in library.names()}
    build_demo_library(library)
    assert stamps == {n: (library.root / n / "splats.ply").stat().st_mtime_ns for n in library.names()}


def rest_pose(urdf: str, seed: int):
    """Drop the object from 15 cm with a random orientation onto a plane; returns
    (T_world_obj of the link frame, contact points [K, 3], COM [3]) at rest."""
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        plane = pb.createMultiBody(0, pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=client),
                                   physicsClientId=client)
        quat_xyzw = Rotation.random(random_state=seed).as_quat()
        body = pb.loadURDF(urdf, [0, 0, 0.15], quat_xyzw, physicsClientId=client)
        for step in range(240 * 6):
            pb.stepSimulation(physicsClientId=client)
            v, w = pb.getBaseVelocity(body, physicsClientId=client)
            if step > 120 and np.linalg.norm(v) < 1e-3 and np.linalg.norm(w) < 1e-2:
                break
        else:
            raise AssertionError("did not come to rest in 6 s")
        com, q = pb.getBasePositionAndOrientation(body, physicsClientId=client)
        local_com = pb.getDynamicsInfo(body, -1, physicsClientId=client)[3]
        contacts = np.array([c[5] for c in pb.getContactPoints(body, plane, physicsClientId=client)])
    finally:
        pb.disconnect(client)
    T_world_com = np.eye(4)
    T_world_com[:3, :3] = Rotation.from_quat(q).as_matrix()
    T_world_com[:3, 3] = com
    T_obj_com = np.eye(4)
    T_obj_com[:3, 3] = local_com
    return T_world_com @ np.linalg.inv(T_obj_com), contacts, np.asarray(com)


@pytest.mark.parametrize("obj_id", range(1, 9))
def test_dropped_object_rests_stably_and_its_splats_match_its_mesh(library, obj_id):
    asset = library.get(obj_id)
    T, contacts, com = rest_pose(str(asset.urdf_path), seed=obj_id)
    assert len(contacts) >= 3
    hull = ConvexHull(contacts[:, :2])  # the centre of mass lies over the support polygon
    assert np.all(hull.equations[:, :2] @ com[:2] + hull.equations[:, 2] <= 1e-4)
    lowest = (asset.mesh.vertices @ T[:3, :3].T + T[:3, 3])[:, 2].min()
    assert abs(lowest) < 0.003  # resting on the plane, not floating or sunk
    w, h = 320, 240
    K = intrinsics_from_fov(w, h, 40)
    target = T[:3, 3]
    for eye in ([0.35, -0.25, 0.3], [-0.3, 0.2, 0.4]):
        cam = look_at(target + eye, target)
        splat_mask = render(asset.splats.transformed(T), K, cam, w, h, device="cpu").alpha > 0.5
        mesh_mask = mesh_silhouette(asset.mesh.vertices @ T[:3, :3].T + T[:3, 3], asset.mesh.faces, K, cam, w, h)
        assert_covers_the_silhouette(splat_mask, mesh_mask, asset.name)
