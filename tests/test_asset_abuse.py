"""Asset commands under abuse: names that are paths, bad numbers, broken files and runaway sizes end with one
clear line and exit code 2, before any work, and nothing in or around the library is touched."""

import numpy as np
import pytest
import trimesh

from pegasus_gen.assets.importers import import_mesh
from pegasus_gen.assets.library import AssetLibrary
from pegasus_gen.cli.main import main
from pegasus_gen.splats.ply import write_ply
from pegasus_gen.splats.procedural import plane, wood_texture


def snapshot(root):
    """{relative path: bytes} of every file under ``root``."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture
def workspace(tmp_path):
    """(box OBJ, library root holding one asset, the folder around the library with a sibling project)."""
    box = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(box)
    around = tmp_path / "around"
    (around / "sibling").mkdir(parents=True)
    (around / "sibling" / "keep.txt").write_text("a sibling project")
    library = AssetLibrary(around / "lib")
    import_mesh(box, "cube", "object", library, obj_id=7)
    (around / "lib" / "notes").mkdir()
    (around / "lib" / "notes" / "todo.txt").write_text("not an asset")
    return box, library.root, around


def run_import(capsys, box, library_root, *args):
    """Exit code and stderr lines of ``pegasus assets import-mesh``."""
    code = main(["assets", "--library", str(library_root), "import-mesh", str(box), *args])
    return code, capsys.readouterr().err.strip().splitlines()


@pytest.mark.parametrize("name", [".", "..", "../evil", "a/b", "", ".hidden", "-x", "/tmp/abs"])
def test_a_name_that_is_a_path_is_refused_and_nothing_is_deleted(workspace, capsys, name):
    box, library_root, around = workspace
    before = snapshot(around)
    code, err = run_import(capsys, box, library_root, f"--name={name}", "--kind", "object", "--obj-id", "9",
                           "--overwrite")
    assert code == 2 and len(err) == 1 and "asset name" in err[0]
    assert snapshot(around) == before


def test_overwrite_replaces_an_asset_never_another_folder(workspace, capsys):
    box, library_root, around = workspace
    before = snapshot(around)
    code, err = run_import(capsys, box, library_root, "--name", "notes", "--kind", "object", "--obj-id", "9",
                           "--overwrite")
    assert code == 2 and len(err) == 1 and "is not an asset" in err[0]
    assert snapshot(around) == before
    code, err = run_import(capsys, box, library_root, "--name", "cube", "--kind", "object", "--obj-id", "7",
                           "--overwrite", "--mass", "0.3")
    assert code == 0 and AssetLibrary(library_root).get("cube").manifest.mass == 0.3


@pytest.mark.parametrize("args, says", [
    (["--mass", "-1"], "mass"),
    (["--obj-id", "0"], "obj_id"),
    (["--scale", "inf"], "--scale"),
    (["--spacing", "0"], "--spacing"),
    (["--spacing", "nan"], "--spacing"),
    (["--spacing", "0.00001"], "use --spacing"),  # 7.5 million splats on a 5 cm box: refused before allocating
    (["--obj-id", "7", "--name", "other_cube"], "obj_id 7 is taken by asset 'cube'"),
])
def test_bad_numbers_and_duplicate_ids_are_one_line_and_touch_nothing(workspace, capsys, args, says):
    box, library_root, around = workspace
    before = snapshot(around)
    full = {"--name": "new", "--kind": "object", "--obj-id": "9"}
    for flag, value in zip(args[::2], args[1::2]):
        full[flag] = value
    code, err = run_import(capsys, box, library_root, *[x for kv in full.items() for x in kv])
    assert code == 2 and len(err) == 1 and says in err[0], err
    assert snapshot(around) == before


def test_a_mesh_with_a_nan_vertex_and_splats_without_orientation_are_refused(workspace, tmp_path, capsys):
    box, library_root, around = workspace
    before = snapshot(around)
    text = box.read_text().splitlines()
    first = next(i for i, line in enumerate(text) if line.startswith("v "))
    text[first] = "v nan 0.0 0.0"
    (tmp_path / "nan.obj").write_text("\n".join(text) + "\n")
    code, err = run_import(capsys, tmp_path / "nan.obj", library_root, "--name", "n", "--kind", "object",
                           "--obj-id", "9")
    assert code == 2 and len(err) == 1 and "NaN or infinite" in err[0]

    cloud = plane(0.2, 0.2, 2000, wood_texture, np.random.default_rng(0))
    quats = cloud.quats_wxyz.copy()
    quats[:5] = 0.0
    write_ply(tmp_path / "flat.ply", type(cloud)(cloud.means, quats, cloud.log_scales, cloud.opacity_logits,
                                                  cloud.sh, cloud.labels))
    code = main(["assets", "--library", str(library_root), "import-splat", str(tmp_path / "flat.ply"),
                 "--name", "flat", "--kind", "environment"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "5 splat(s) with a zero rotation quaternion" in err[0]
    assert snapshot(around) == before


def test_scan_checks_the_name_before_any_work(tmp_path, capsys):
    (tmp_path / "photos").mkdir()
    for name in ("..", "../x"):
        assert main(["scan", str(tmp_path / "photos"), "--kind", "environment", f"--name={name}",
                     "--library", str(tmp_path / "lib"), "--work", str(tmp_path / "work")]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and "name" in err[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["photos"]


def test_asset_folders_and_files_follow_the_umask(tmp_path):
    import os
    import stat

    from pegasus_gen.io.files import write_atomic

    box = tmp_path / "box.obj"
    trimesh.creation.box(extents=(0.05, 0.05, 0.05)).export(box)
    old = os.umask(0o027)
    try:
        asset = import_mesh(box, "cube", "object", AssetLibrary(tmp_path / "lib"), obj_id=3)
        written = write_atomic(tmp_path / "x.bin", lambda f: f.write(b"x"))
    finally:
        os.umask(old)
    assert stat.S_IMODE(asset.path.stat().st_mode) == 0o750
    assert {stat.S_IMODE(p.stat().st_mode) for p in asset.path.iterdir()} == {0o640}
    assert stat.S_IMODE(written.stat().st_mode) == 0o640
