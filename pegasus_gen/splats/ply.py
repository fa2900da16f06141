"""Read and write the standard INRIA 3DGS PLY (binary little/big endian, ASCII on read).

Vertex properties, all float32, in this order (written exactly so, read in any order):
``x y z nx ny nz f_dc_0..2 f_rest_0..f_rest_{3K'-1} opacity scale_0..2 rot_0..3`` with
K' = (degree+1)^2 - 1 and ``f_rest`` channel-major (``f_rest[c*K' + k]`` = coefficient k+1 of channel c).
Unknown extra properties are ignored, except an integer ``label`` which becomes the instance label.
Every problem raises :class:`SplatFileError` naming the file and what is wrong.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np

from pegasus_gen.errors import SplatFileError
from pegasus_gen.io.files import write_atomic
from pegasus_gen.splats import sh as shlib
from pegasus_gen.splats.cloud import SplatCloud

_PLY_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}
_FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": "ascii"}
_REQUIRED = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity",
             "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
_HEADER_LIMIT = 1 << 20
MAX_COORDINATE = 1e6  # a position or scale (file units, meant as metres) beyond this is refused as absurd


def _parse_header(path: Path, data: bytes):
    """Returns (format, elements, header_length); elements = [(name, count, [(prop, type|None)])]."""
    if not data.startswith(b"ply") or data[3:4] not in (b"\n", b"\r"):
        raise SplatFileError(path, "not a PLY file (it does not start with the 'ply' magic line)")
    end = data.find(b"end_header", 0, _HEADER_LIMIT)
    if end < 0:
        raise SplatFileError(path, "PLY header has no 'end_header' line")
    newline = data.find(b"\n", end)
    if newline < 0:
        raise SplatFileError(path, "PLY header is truncated after 'end_header'")
    try:
        lines = data[:end].decode("ascii").splitlines()[1:]
    except UnicodeDecodeError:
        raise SplatFileError(path, "PLY header is not ASCII text") from None
    fmt = None
    elements: list = []
    for lineno, line in enumerate(lines, start=2):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise SplatFileError(path, f"header line {lineno}: unsupported format {line.strip()!r}")
            fmt = _FORMATS[words[1]]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise SplatFileError(path, f"header line {lineno}: malformed element line {line.strip()!r}")
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property":
            if not elements:
                raise SplatFileError(path, f"header line {lineno}: property before any element")
            if len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1][2].append((words[2], _PLY_TYPES[words[1]]))
            elif len(words) == 5 and words[1] == "list":
                elements[-1][2].append((words[4], None))
            else:
                raise SplatFileError(path, f"header line {lineno}: malformed property line {line.strip()!r}")
        else:
            raise SplatFileError(path, f"header line {lineno}: unexpected {words[0]!r}")
    if fmt is None:
        raise SplatFileError(path, "PLY header has no 'format' line")
    _check_counts(path, fmt, elements, len(data) - newline - 1)
    return fmt, elements, newline + 1


def _check_counts(path: Path, fmt, elements, data_bytes: int) -> None:
    """Refuse element counts the data (``data_bytes`` after the header) cannot hold, before anything is
    allocated: a binary row takes its properties' bytes (a list at least its count), an ASCII row at least
    one character and one separator per property."""
    for name, count, props in elements:
        if fmt == "ascii":
            row = 2 * len(props)
        else:
            row = sum(np.dtype(t).itemsize if t is not None else 1 for _, t in props)
        if count * row > data_bytes:
            raise SplatFileError(path, f"data is truncated: element {name!r} declares {count:,} rows, which need "
                                       f"at least {count * row:,} bytes; the file holds {data_bytes:,} after "
                                       "its header")
        data_bytes -= count * row


def _read_vertex_table(path: Path, data: bytes, fmt, elements, offset: int) -> np.ndarray:
    """The vertex element as a structured array with the file's property names."""
    for name, count, props in elements:
        if name == "vertex":
            break
        # An element before the vertices must be skipped.
        if fmt == "ascii":
            for _ in range(count):
                offset = data.find(b"\n", offset) + 1
                if offset == 0:
                    raise SplatFileError(path, f"data is truncated inside element {name!r}")
        elif any(t is None for _, t in props):
            raise SplatFileError(path, f"element {name!r} with list properties before 'vertex' is not supported")
        else:
            offset += count * sum(np.dtype(t).itemsize for _, t in props)
    else:
        raise SplatFileError(path, "PLY file has no 'vertex' element")
    _, count, props = elements[[e[0] for e in elements].index("vertex")]
    if any(t is None for _, t in props):
        bad = [p for p, t in props if t is None]
        raise SplatFileError(path, f"vertex list properties {bad} are not supported in a splat file")
    names = [p for p, _ in props]
    if len(set(names)) != len(names):
        raise SplatFileError(path, "vertex element has duplicate property names")
    if fmt == "ascii":
        dtype = np.dtype([(p, t) for p, t in props])
        lines = data[offset:].split(b"\n", count)
        if len(lines) < count or (count and len(lines) == count and not lines[-1].strip()):
            raise SplatFileError(path, f"data is truncated: expected {count} vertex lines")
        table = np.empty(count, dtype=dtype)
        for i in range(count):
            values = lines[i].split()
            if len(values) != len(props):
                raise SplatFileError(path, f"vertex line {i}: expected {len(props)} values, found {len(values)}")
            try:
                table[i] = tuple(float(v) if np.dtype(t).kind == "f" else int(v) for v, (_, t) in zip(values, props))
            except ValueError:
                raise SplatFileError(path, f"vertex line {i}: not a number in {lines[i][:80]!r}") from None
            except OverflowError:
                raise SplatFileError(path, f"vertex line {i}: a value out of its property's range in "
                                           f"{lines[i][:80]!r}") from None
        return table
    dtype = np.dtype([(p, fmt + t) for p, t in props])  # the data's size is checked by _check_counts
    return np.frombuffer(data, dtype=dtype, count=count, offset=offset)


def read_ply(path: str | os.PathLike):
    """Load a 3DGS PLY into a :class:`~pegasus_gen.splats.cloud.SplatCloud` (float32 arrays as stored)."""
    path = Path(path)
    try:
        if not stat.S_ISREG(path.stat().st_mode):
            raise SplatFileError(path, "not a regular file")
        data = path.read_bytes()
    except OSError as exc:
        raise SplatFileError(path, f"cannot read file ({exc.strerror or exc})") from None
    fmt, elements, offset = _parse_header(path, data)
    table = _read_vertex_table(path, data, fmt, elements, offset)
    names = set(table.dtype.names or ())
    missing = [p for p in _REQUIRED if p not in names]
    if missing:
        raise SplatFileError(path, f"missing vertex properties {missing} (not a 3D Gaussian splat file?)")
    n_rest = sum(1 for p in names if p.startswith("f_rest_"))
    if n_rest % 3 or (n_rest // 3 + 1) not in (1, 4, 9, 16):
        raise SplatFileError(path, f"{n_rest} f_rest properties: expected 0, 9, 24 or 45 (SH degree 0..3)")
    rest_names = [f"f_rest_{i}" for i in range(n_rest)]
    if any(p not in names for p in rest_names):
        raise SplatFileError(path, f"f_rest properties must be numbered f_rest_0..f_rest_{n_rest - 1}")
    for p in _REQUIRED + rest_names:
        column = table[p]
        if column.dtype.kind == "f" and not np.all(np.isfinite(column)):
            first = int(np.flatnonzero(~np.isfinite(column))[0])
            raise SplatFileError(path, f"non-finite value (NaN or inf) in property {p!r} of vertex {first}")

    too_far = {p: np.abs(table[p]) > MAX_COORDINATE for p in ("x", "y", "z")}
    too_large = {p: table[p] > np.log(MAX_COORDINATE) for p in ("scale_0", "scale_1", "scale_2")}
    for p, bad in {**too_far, **too_large}.items():
        if bad.any():
            i = int(np.flatnonzero(bad)[0])
            what = "a position" if p in too_far else f"a scale of exp({table[p][i]:g})"
            raise SplatFileError(path, f"vertex {i}: {p} = {table[p][i]:g} is {what} beyond {MAX_COORDINATE:g} m, "
                                       "not a splat of a real scene")
    has_labels = "label" in names and table["label"].dtype.kind in "iu"
    if has_labels and len(table) and table["label"].max() > np.iinfo(np.int32).max:  # a uint label
        raise SplatFileError(path, f"label {table['label'].max()} is beyond the 32-bit signed integer range")

    norms = np.sqrt(sum(table[p].astype(np.float64) ** 2 for p in ("rot_0", "rot_1", "rot_2", "rot_3")))
    if (norms < 1e-12).any():
        raise SplatFileError(path, f"{int((norms < 1e-12).sum())} splat(s) with a zero rotation quaternion "
                                   "(rot_0..rot_3 all 0): they have no orientation and would render as nothing")

    def cols(props):
        return np.stack([table[p].astype(np.float32) for p in props], axis=1) if props else \
            np.zeros((len(table), 0), np.float32)

    n = len(table)
    k_rest = n_rest // 3
    rest = cols(rest_names).reshape(n, 3, k_rest).transpose(0, 2, 1)
    sh = np.concatenate([cols(["f_dc_0", "f_dc_1", "f_dc_2"])[:, None, :], rest], axis=1)
    labels = table["label"].astype(np.int32) if has_labels else np.zeros(n, np.int32)
    return SplatCloud(
        means=cols(["x", "y", "z"]),
        quats_wxyz=cols(["rot_0", "rot_1", "rot_2", "rot_3"]),
        log_scales=cols(["scale_0", "scale_1", "scale_2"]),
        opacity_logits=table["opacity"].astype(np.float32),
        sh=sh,
        labels=labels,
    )


def vertex_property_names(sh_degree: int) -> list[str]:
    """The INRIA property order for ``sh_degree``."""
    n_rest = 3 * (shlib.num_coeffs(sh_degree) - 1)
    return (["x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"]
            + [f"f_rest_{i}" for i in range(n_rest)]
            + ["opacity", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"])


def write_ply(path: str | os.PathLike, cloud, include_labels: bool = False) -> Path:
    """Write ``cloud`` as binary little-endian INRIA 3DGS PLY (normals written as 0).

    With ``include_labels`` an extra trailing ``int label`` property is written (other tools ignore it).
    The file appears atomically (written to a temporary file, then renamed).
    """
    path = Path(path)
    names = vertex_property_names(cloud.sh_degree)
    fields = [(p, "<f4") for p in names] + ([("label", "<i4")] if include_labels else [])
    table = np.zeros(len(cloud), dtype=np.dtype(fields))
    table["x"], table["y"], table["z"] = cloud.means.T
    for c in range(3):
        table[f"f_dc_{c}"] = cloud.sh[:, 0, c]
    k_rest = cloud.sh.shape[1] - 1
    rest = cloud.sh[:, 1:, :].transpose(0, 2, 1).reshape(len(cloud), 3 * k_rest)
    for i in range(3 * k_rest):
        table[f"f_rest_{i}"] = rest[:, i]
    table["opacity"] = cloud.opacity_logits
    for i in range(3):
        table[f"scale_{i}"] = cloud.log_scales[:, i]
    for i in range(4):
        table[f"rot_{i}"] = cloud.quats_wxyz[:, i]
    if include_labels:
        table["label"] = cloud.labels
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(cloud)}"]
    header += [f"property {'int' if t == '<i4' else 'float'} {p}" for p, t in fields]
    header.append("end_header")

    def write(f):
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(table.tobytes())

    return write_atomic(path, write)
