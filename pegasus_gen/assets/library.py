"""Assets: a photometric entity (splats) and a geometric entity (collision mesh + URDF) in one frame.

An asset is a directory::

    NAME/asset.json      manifest (AssetManifest)
    NAME/splats.ply      3DGS splats in the asset frame (object frame / world frame of an environment)
    NAME/collision.obj   collision mesh in the same frame (metres)
    NAME/surface.ply     objects: the detailed surface with vertex colours (metres; the BOP model)
    NAME/model.urdf      URDF whose link frame is the asset frame; inertial origin = true centre of mass

A library is a directory of assets, looked up by name or obj_id. Its default location is
``$PEGASUS_ASSETS`` or ``~/.cache/pegasus/assets``.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Literal, Optional
from xml.sax.saxutils import quoteattr

import numpy as np
import trimesh
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from pegasus_gen.assets.collision import convex_decomposition, is_concave
from pegasus_gen.assets.names import ASSET_NAME_PATTERN, check_asset_name
from pegasus_gen.errors import PegasusError
from pegasus_gen.io.files import give_default_mode
from pegasus_gen.splats.cloud import SplatCloud
from pegasus_gen.splats.ply import read_ply, write_ply

MANIFEST = "asset.json"
SPLATS = "splats.ply"
COLLISION = "collision.obj"
CONVEX_PARTS = "collision_convex.obj"  # concave objects: V-HACD parts used by the URDF's collision
URDF = "model.urdf"
SURFACE = "surface.ply"


class ContinuousSymmetry(BaseModel):
    """Rotation symmetry about ``axis`` through ``offset`` (metres), as BOP's symmetries_continuous."""

    model_config = ConfigDict(extra="forbid")
    axis: tuple[float, float, float]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


class DropRegion(BaseModel):
    """Axis-aligned rectangle on the support surface where objects may be dropped (metres, world)."""

    model_config = ConfigDict(extra="forbid")
    x_min: float
    x_max: float
    y_min: float
    y_max: float

    @model_validator(mode="after")
    def _ordered(self):
        if not (self.x_min < self.x_max and self.y_min < self.y_max):
            raise ValueError("needs x_min < x_max and y_min < y_max")
        return self


class AssetManifest(BaseModel):
    """Everything about an asset except its arrays. Units: metres, kilograms, radians."""

    model_config = ConfigDict(extra="forbid")
    name: str = Field(pattern=ASSET_NAME_PATTERN)
    kind: Literal["object", "environment"]
    obj_id: Optional[int] = Field(default=None, ge=1)
    units: Literal["m"] = "m"
    mass: float = Field(default=0.2, gt=0)
    friction: float = Field(default=0.8, ge=0)
    restitution: float = Field(default=0.05, ge=0, le=1)
    # resistance to rolling and spinning in place (PyBullet contact coefficients); without it a cup
    # lying on its side rolls forever
    rolling_friction: float = Field(default=0.002, ge=0)
    spinning_friction: float = Field(default=0.002, ge=0)
    # BOP form: 4x4 row-major transforms (translation in metres here, mm in a written BOP dataset)
    symmetries_discrete: list[tuple[float, ...]] = Field(default_factory=list)
    symmetries_continuous: list[ContinuousSymmetry] = Field(default_factory=list)
    support_height: float = 0.0  # environments: height of the support plane (z up)
    drop_region: Optional[DropRegion] = None  # environments
    capture_poses: list[tuple[float, ...]] = Field(default_factory=list)  # T_world_cam, 16 floats each
    geometry: dict = Field(default_factory=dict)  # parameters the collision mesh was made with

    @model_validator(mode="after")
    def _kind_fields(self):
        if self.kind == "object" and self.obj_id is None:
            raise ValueError("an object needs obj_id (an integer >= 1)")
        if self.kind == "environment" and self.drop_region is None:
            raise ValueError("an environment needs drop_region")
        for i, sym in enumerate(self.symmetries_discrete):
            if len(sym) != 16:
                raise ValueError(f"symmetries_discrete[{i}] must have 16 numbers (4x4 row-major)")
        for i, pose in enumerate(self.capture_poses):
            if len(pose) != 16:
                raise ValueError(f"capture_poses[{i}] must have 16 numbers (4x4 row-major)")
        return self


@dataclass
class Asset:
    """A loaded asset: manifest, splats, collision mesh and (objects) surface model, all in the asset frame."""

    path: Path
    manifest: AssetManifest
    splats: SplatCloud
    mesh: trimesh.Trimesh
    surface: trimesh.Trimesh | None = None  # objects: fine mesh with vertex colours (assets.surface)

    @property
    def name(self) -> str:
        return self.manifest.name

    @property
    def urdf_path(self) -> Path:
        return self.path / URDF


def _describe(error: ValidationError) -> str:
    first = error.errors()[0]
    where = ".".join(str(p) for p in first["loc"]) or "(top level)"
    return f"field {where}: {first['msg']}"


def read_manifest(path: Path) -> AssetManifest:
    """Parse and validate an asset.json; errors name the file and the field."""
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise PegasusError(f"{path}: missing asset manifest") from None
    except (OSError, json.JSONDecodeError) as exc:
        raise PegasusError(f"{path}: not a readable JSON manifest ({exc})") from None
    try:
        return AssetManifest.model_validate(data)
    except ValidationError as exc:
        raise PegasusError(f"{path}: {_describe(exc)}") from None


def load_asset(path: str | os.PathLike) -> Asset:
    """Load and validate the asset directory ``path``."""
    path = Path(path)
    if not path.is_dir():
        raise PegasusError(f"{path}: not an asset directory")
    manifest = read_manifest(path / MANIFEST)
    for name in (SPLATS, COLLISION, URDF):
        if not (path / name).is_file():
            raise PegasusError(f"{path / name}: missing (every asset needs {SPLATS}, {COLLISION} and {URDF})")
    splats = read_ply(path / SPLATS)
    try:
        mesh = trimesh.load(path / COLLISION, force="mesh", process=False)
    except Exception as exc:
        raise PegasusError(f"{path / COLLISION}: cannot read mesh ({exc})") from None
    if len(mesh.faces) == 0:
        raise PegasusError(f"{path / COLLISION}: the collision mesh has no triangles")
    surface = None
    if manifest.kind == "object":
        if not (path / SURFACE).is_file():
            raise PegasusError(f"{path / SURFACE}: missing (an object made by an older version: import or build "
                               "it again)")
        try:
            surface = trimesh.load(path / SURFACE, force="mesh", process=False)
        except Exception as exc:
            raise PegasusError(f"{path / SURFACE}: cannot read mesh ({exc})") from None
    return Asset(path, manifest, splats, mesh, surface)


def mass_properties(mesh: trimesh.Trimesh, mass: float) -> tuple[np.ndarray, np.ndarray]:
    """(centre of mass [3] m, inertia [3, 3] kg m^2 about the COM, asset axes) of a closed mesh of ``mass``."""
    if not mesh.is_watertight or mesh.volume <= 0:
        raise PegasusError("the collision mesh is not closed (watertight, outward normals): "
                           "its volume, centre of mass and inertia are undefined")
    return np.asarray(mesh.center_mass), np.asarray(mesh.moment_inertia) * (mass / mesh.volume)


def urdf_text(manifest: AssetManifest, mesh: trimesh.Trimesh, collision_file: str = COLLISION) -> str:
    """URDF of one link in the asset frame; objects get mass, COM origin and inertia from the mesh.

    The visual geometry is the collision mesh; the collision geometry is ``collision_file`` (convex
    parts for concave objects). Environments are static and collide as a concave triangle mesh.
    """
    name = quoteattr(manifest.name)
    visual = f'<geometry><mesh filename="{COLLISION}" scale="1 1 1"/></geometry>'
    collision = f'<geometry><mesh filename="{collision_file}" scale="1 1 1"/></geometry>'
    concave = ' concave="yes"' if manifest.kind == "environment" else ""
    if manifest.kind == "object":
        com, inertia = mass_properties(mesh, manifest.mass)
        inertial = (
            f'    <inertial>\n      <origin xyz="{com[0]:.9g} {com[1]:.9g} {com[2]:.9g}" rpy="0 0 0"/>\n'
            f'      <mass value="{manifest.mass:.9g}"/>\n'
            f'      <inertia ixx="{inertia[0, 0]:.9g}" ixy="{inertia[0, 1]:.9g}" ixz="{inertia[0, 2]:.9g}" '
            f'iyy="{inertia[1, 1]:.9g}" iyz="{inertia[1, 2]:.9g}" izz="{inertia[2, 2]:.9g}"/>\n    </inertial>\n')
    else:  # static environment
        inertial = ('    <inertial>\n      <origin xyz="0 0 0" rpy="0 0 0"/>\n      <mass value="0"/>\n'
                    '      <inertia ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/>\n    </inertial>\n')
    return (f'<?xml version="1.0"?>\n<robot name={name}>\n  <link name={name}>\n'
            f'    <contact>\n      <lateral_friction value="{manifest.friction:.9g}"/>\n'
            f'      <rolling_friction value="{manifest.rolling_friction:.9g}"/>\n'
            f'      <spinning_friction value="{manifest.spinning_friction:.9g}"/>\n'
            f'      <restitution value="{manifest.restitution:.9g}"/>\n    </contact>\n'
            f'{inertial}'
            f'    <visual>\n      <origin xyz="0 0 0" rpy="0 0 0"/>\n      {visual}\n    </visual>\n'
            f'    <collision{concave}>\n      <origin xyz="0 0 0" rpy="0 0 0"/>\n      {collision}\n    </collision>\n'
            f'  </link>\n</robot>\n')


def save_asset(path: str | os.PathLike, manifest: AssetManifest, splats: SplatCloud,
               mesh: trimesh.Trimesh, surface: trimesh.Trimesh | None = None, overwrite: bool = False) -> Asset:
    """Write an asset directory; it appears complete or not at all (built beside it, then renamed).

    An object needs its ``surface`` model (vertex-coloured mesh, same frame; environments have none).
    Concave objects also get their V-HACD convex parts, which the URDF uses for collision.
    """
    path = Path(path)
    if path.exists() and not overwrite:
        raise PegasusError(f"{path}: already exists (pass overwrite to replace it)")
    if path.exists() and not (path / MANIFEST).is_file():  # overwrite replaces an asset, never another folder
        raise PegasusError(f"{path}: exists and is not an asset (no {MANIFEST}); not replacing it")
    if manifest.kind == "object":
        mass_properties(mesh, manifest.mass)  # a closed mesh is needed: check before writing anything
        if surface is None or len(surface.faces) == 0:
            raise PegasusError(f"{manifest.name}: an object asset needs a surface model")
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(dir=path.parent, prefix=f".{path.name}."))
    try:
        give_default_mode(tmp, directory=True)
        (tmp / MANIFEST).write_text(manifest.model_dump_json(indent=2) + "\n")
        write_ply(tmp / SPLATS, splats)
        mesh.export(tmp / COLLISION)
        if surface is not None:
            surface.export(tmp / SURFACE)
        collision_file = COLLISION
        if manifest.kind == "object" and is_concave(mesh):
            convex_decomposition(mesh, tmp / CONVEX_PARTS)
            collision_file = CONVEX_PARTS
        (tmp / URDF).write_text(urdf_text(manifest, mesh, collision_file))
        if path.exists():
            shutil.rmtree(path)
        os.replace(tmp, path)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return load_asset(path)


def default_library_path() -> Path:
    """$PEGASUS_ASSETS, else ~/.cache/pegasus/assets."""
    env = os.environ.get("PEGASUS_ASSETS")
    return Path(env) if env else Path.home() / ".cache" / "pegasus" / "assets"


def check_new_asset(library: "AssetLibrary", name: str, kind: str, obj_id: int | None = None,
                    overwrite: bool = False, **fields) -> Path:
    """The folder for a new asset, after the checks that need none of its data (so an import or a scan
    refuses before its work): a valid name, manifest fields (``kind``, ``obj_id``, ``fields`` such as
    ``mass``) as the manifest takes them, no asset of that name unless ``overwrite``, no other object with that
    ``obj_id``."""
    path = library.asset_path(name)
    if kind == "object" and obj_id is None:
        raise PegasusError("an object needs an obj_id (--obj-id, an integer >= 1)")
    placeholder = DropRegion(x_min=0.0, x_max=1.0, y_min=0.0, y_max=1.0) if kind == "environment" else None
    try:
        AssetManifest(name=name, kind=kind, obj_id=obj_id, drop_region=placeholder, **fields)
    except ValidationError as exc:
        raise PegasusError(f"asset {name!r}: {_describe(exc)}") from None
    if path.exists() and not overwrite:
        raise PegasusError(f"{path}: already exists (pass --overwrite to replace it)")
    if kind == "object":
        other = next((m.name for m in library.manifests() if m.obj_id == obj_id and m.name != name), None)
        if other is not None:
            raise PegasusError(f"obj_id {obj_id} is taken by asset {other!r} in {library.root}; choose another")
    return path


class AssetLibrary:
    """The assets under one directory, by name or obj_id."""

    def __init__(self, root: str | os.PathLike | None = None):
        self.root = Path(root) if root is not None else default_library_path()

    def asset_path(self, name: str) -> Path:
        """The folder of the asset ``name`` in this library (the name checked: ``check_asset_name``)."""
        return self.root / check_asset_name(name)

    def names(self) -> list[str]:
        """Names of the asset directories (those holding an asset.json), sorted."""
        if not self.root.is_dir():
            return []
        return sorted(p.name for p in self.root.iterdir() if (p / MANIFEST).is_file())

    def manifests(self) -> list[AssetManifest]:
        return [read_manifest(self.root / name / MANIFEST) for name in self.names()]

    def get(self, key: str | int) -> Asset:
        """The asset named ``key`` (the name checked: ``check_asset_name``), or the object with obj_id ``key``
        (an int or a digit string)."""
        if isinstance(key, str) and (self.asset_path(key) / MANIFEST).is_file():
            return load_asset(self.root / key)
        if isinstance(key, int) or (isinstance(key, str) and key.isdigit()):
            for m in self.manifests():
                if m.obj_id == int(key):
                    return load_asset(self.root / m.name)
        known = ", ".join(self.names()) or "none"
        raise PegasusError(f"no asset {key!r} in library {self.root} (assets: {known})")
