"""Asset directories and libraries: save/load, URDF inertial from the mesh, clear errors."""

import json
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import trimesh

from pegasus_gen.assets.library import AssetLibrary, AssetManifest, load_asset, save_asset
from pegasus_gen.assets.surface import mesh_surface
from pegasus_gen.errors import PegasusError
from pegasus_gen.splats.from_mesh import mesh_to_splats


def off_centre_object():
    """A 15 x 10 x 10 cm box whose centre (= centre of mass) sits at x = 2 cm in the asset frame."""
    mesh = trimesh.creation.box((0.15, 0.1, 0.1))
    mesh.apply_translation([0.02, 0, 0])
    return mesh


def make_object(tmp_path, name="cup", obj_id=1, mesh=None):
    mesh = mesh if mesh is not None else off_centre_object()
    manifest = AssetManifest(name=name, kind="object", obj_id=obj_id, mass=0.3,
                             symmetries_continuous=[{"axis": [0, 0, 1]}])
    splats = mesh_to_splats(mesh, np.random.default_rng(0), spacing=0.01)
    return save_asset(tmp_path / name, manifest, splats, mesh, mesh_surface(mesh, max_edge=0.02))


def test_save_and_load_round_trip(tmp_path):
    asset = make_object(tmp_path)
    again = load_asset(tmp_path / "cup")
    assert again.manifest == asset.manifest
    assert np.array_equal(again.splats.means, asset.splats.means)
    assert np.isclose(again.mesh.volume, 0.15 * 0.1 * 0.1)
    assert np.allclose(again.surface.vertices, asset.surface.vertices, atol=1e-7)
    assert np.array_equal(again.surface.faces, asset.surface.faces)
    assert np.array_equal(again.surface.visual.vertex_colors, asset.surface.visual.vertex_colors)


def test_an_object_needs_its_surface_model(tmp_path):
    mesh = off_centre_object()
    manifest = AssetManifest(name="cup", kind="object", obj_id=1)
    splats = mesh_to_splats(mesh, np.random.default_rng(0), spacing=0.01)
    with pytest.raises(PegasusError, match="needs a surface model"):
        save_asset(tmp_path / "cup", manifest, splats, mesh)
    assert not (tmp_path / "cup").exists()
    make_object(tmp_path)
    (tmp_path / "cup" / "surface.ply").unlink()
    with pytest.raises(PegasusError, match="surface.ply: missing .*import or build it again"):
        load_asset(tmp_path / "cup")


def test_urdf_inertial_is_the_true_centre_of_mass(tmp_path):
    asset = make_object(tmp_path)
    link = ET.parse(asset.urdf_path).getroot().find("link")
    origin = [float(v) for v in link.find("inertial/origin").get("xyz").split()]
    assert np.allclose(origin, [0.02, 0, 0], atol=1e-9)
    assert float(link.find("inertial/mass").get("value")) == pytest.approx(0.3)
    ixx = float(link.find("inertial/inertia").get("ixx"))
    assert ixx == pytest.approx(0.3 * (0.1**2 + 0.1**2) / 12, rel=1e-6)  # solid box about its COM
    assert link.find("collision/geometry/mesh").get("filename") == "collision.obj"


def test_pybullet_loads_the_urdf_with_its_centre_of_mass(tmp_path):
    import pybullet as pb

    asset = make_object(tmp_path)
    client = pb.connect(pb.DIRECT)
    try:
        body = pb.loadURDF(str(asset.urdf_path), physicsClientId=client)
        info = pb.getDynamicsInfo(body, -1, physicsClientId=client)
        assert info[0] == pytest.approx(0.3)
        assert np.allclose(info[3], [0.02, 0, 0], atol=1e-6)  # local inertial position
    finally:
        pb.disconnect(client)


def test_library_lookup_by_name_and_obj_id(tmp_path):
    make_object(tmp_path, "cup", 1)
    make_object(tmp_path, "bowl", 7)
    lib = AssetLibrary(tmp_path)
    assert lib.names() == ["bowl", "cup"]
    assert lib.get("bowl").manifest.obj_id == 7
    assert lib.get(1).name == "cup" and lib.get("7").name == "bowl"
    with pytest.raises(PegasusError, match="no asset 'plate'.*bowl, cup"):
        lib.get("plate")


def test_default_library_location_is_configurable(tmp_path, monkeypatch):
    monkeypatch.setenv("PEGASUS_ASSETS", str(tmp_path / "lib"))
    assert AssetLibrary().root == tmp_path / "lib"


@pytest.mark.parametrize("change,field", [
    ({"kind": "thing"}, "kind"),
    ({"obj_id": 0}, "obj_id"),
    ({"mass": -1}, "mass"),
    ({"colour": "red"}, "colour"),
    ({"symmetries_discrete": [[1, 0, 0]]}, "symmetries_discrete"),
])
def test_broken_manifest_names_the_file_and_field(tmp_path, change, field):
    make_object(tmp_path)
    path = tmp_path / "cup" / "asset.json"
    data = json.loads(path.read_text())
    data.update(change)
    path.write_text(json.dumps(data))
    with pytest.raises(PegasusError, match=rf"asset.json: .*{field}"):
        load_asset(tmp_path / "cup")


def test_unparsable_manifest_and_missing_files(tmp_path):
    make_object(tmp_path)
    (tmp_path / "cup" / "model.urdf").unlink()
    with pytest.raises(PegasusError, match="model.urdf: missing"):
        load_asset(tmp_path / "cup")
    (tmp_path / "cup" / "asset.json").write_text("{not json")
    with pytest.raises(PegasusError, match="asset.json: not a readable JSON"):
        load_asset(tmp_path / "cup")
    with pytest.raises(PegasusError, match="not an asset directory"):
        load_asset(tmp_path / "nothing")


def test_open_mesh_is_refused_and_nothing_is_written(tmp_path):
    mesh = trimesh.creation.box((0.1, 0.1, 0.1))
    mesh.update_faces(np.arange(len(mesh.faces)) != 0)  # punch a hole
    with pytest.raises(PegasusError, match="not closed"):
        make_object(tmp_path, mesh=mesh)
    assert list(tmp_path.iterdir()) == []


def test_environment_needs_a_drop_region():
    with pytest.raises(ValueError, match="drop_region"):
        AssetManifest(name="table", kind="environment")
    env = AssetManifest(name="table", kind="environment", drop_region={"x_min": -0.3, "x_max": 0.3,
                                                                      "y_min": -0.2, "y_max": 0.2})
    assert env.obj_id is None


def bowl_mesh():
    profile = np.array([[0.0, 0.0], [0.05, 0.0], [0.07, 0.05], [0.06, 0.05], [0.042, 0.012], [0.0, 0.012]])
    return trimesh.creation.revolve(profile, sections=48)


def test_concave_object_collides_by_its_convex_parts(tmp_path):
    """A ball dropped into a bowl asset ends up inside it, not on a convex hull lid."""
    import pybullet as pb

    box = make_object(tmp_path, "box", 1)
    assert not (box.path / "collision_convex.obj").exists()
    bowl = make_object(tmp_path, "bowl", 2, mesh=bowl_mesh())
    assert (bowl.path / "collision_convex.obj").exists()
    client = pb.connect(pb.DIRECT)
    try:
        pb.setGravity(0, 0, -9.81, physicsClientId=client)
        pb.loadURDF(str(bowl.urdf_path), useFixedBase=True, physicsClientId=client)
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=0.01, physicsClientId=client)
        ball = pb.createMultiBody(0.01, shape, basePosition=[0, 0, 0.1], physicsClientId=client)
        for _ in range(480):
            pb.stepSimulation(physicsClientId=client)
        z = pb.getBasePositionAndOrientation(ball, physicsClientId=client)[0][2]
        assert z < 0.035, f"ball rests at z={z:.3f}: the bowl's inside is not empty for collision"
    finally:
        pb.disconnect(client)
