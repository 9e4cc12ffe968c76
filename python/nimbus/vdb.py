"""Reads the grid names, types and metadata of a .vdb file in pure Python.

Blender's Python API shows a volume's grids but not their metadata, and
pyopenvdb is not always importable inside a DCC, so the add-on reads what it
needs (e.g. a suggested density multiplier) straight from the file's header.
Only the uncompressed parts of the format are read: the header, the grid
descriptors and each grid's metadata block, never the voxel trees. A VDB
stream (nimbusd's previews) has no offsets to skip a grid's voxels, so only
its first grid (the density) is listed.
"""

import struct
from dataclasses import dataclass, field
from typing import Dict, List

_MAGIC = 0x56444220
_FILE_VERSION_GRID_INSTANCING = 216   # descriptors name an instance parent
_FILE_VERSION_NODE_MASK_COMPRESSION = 222  # per-grid compression flags
_FILE_VERSION_SELECTIVE_COMPRESSION = 220
_FILE_VERSION_BOOST_UUID = 213
_FILE_VERSION_NO_GRIDMAP = 212  # has-grid-offsets flag present from here

_SCALARS = {"bool": "<?", "int32": "<i", "int64": "<q", "float": "<f", "double": "<d"}
_VECTORS = {"vec2i": "<2i", "vec2s": "<2f", "vec2d": "<2d",
            "vec3i": "<3i", "vec3s": "<3f", "vec3d": "<3d"}


class VdbFormatError(ValueError):
    """The file is not a VDB file this reader understands."""


@dataclass
class GridInfo:
    name: str
    type: str                 # e.g. "Tree_float_5_4_3", "Tree_vec3s_5_4_3"
    half_float: bool
    metadata: Dict[str, object] = field(default_factory=dict)


@dataclass
class VdbInfo:
    file_version: int
    metadata: Dict[str, object]
    grids: List[GridInfo]

    def grid(self, name):
        """The grid called `name`, or None."""
        return next((g for g in self.grids if g.name == name), None)


class _Reader:
    def __init__(self, f, path):
        self.f, self.path = f, path

    def read(self, n):
        b = self.f.read(n)
        if len(b) != n:
            raise VdbFormatError(f"{self.path}: truncated at byte {self.f.tell()}")
        return b

    def unpack(self, fmt):
        return struct.unpack(fmt, self.read(struct.calcsize(fmt)))

    def string(self):
        (n,) = self.unpack("<I")
        if n > 1 << 20:
            raise VdbFormatError(f"{self.path}: implausible string length {n} "
                                 f"at byte {self.f.tell() - 4}")
        return self.read(n).decode("utf-8", "replace")

    def meta_map(self):
        (count,) = self.unpack("<i")
        out = {}
        for _ in range(count):
            name, type_name = self.string(), self.string()
            (size,) = self.unpack("<I")
            raw = self.read(size)
            out[name] = _decode(type_name, raw)
        return out


def _decode(type_name, raw):
    try:
        if type_name == "string":
            return raw.decode("utf-8", "replace")
        if type_name in _SCALARS:
            return struct.unpack(_SCALARS[type_name], raw)[0]
        if type_name in _VECTORS:
            return tuple(struct.unpack(_VECTORS[type_name], raw))
    except struct.error:
        pass
    return raw  # a type this reader does not know: its bytes


def read_info(path):
    """The file metadata, and every grid's name, type and metadata."""
    with open(path, "rb") as f:
        r = _Reader(f, path)
        try:
            (magic,) = r.unpack("<q")
        except VdbFormatError:
            raise VdbFormatError(f"{path}: too short for a VDB file") from None
        if magic != _MAGIC:
            raise VdbFormatError(f"{path}: not a VDB file (magic {magic:#x})")
        (version,) = r.unpack("<I")
        if version < _FILE_VERSION_NO_GRIDMAP:
            raise VdbFormatError(f"{path}: VDB file version {version} is too old "
                                 f"(need >= {_FILE_VERSION_NO_GRIDMAP})")
        r.unpack("<II")                      # library major, minor
        (has_offsets,) = r.unpack("<?")
        if _FILE_VERSION_SELECTIVE_COMPRESSION <= version < _FILE_VERSION_NODE_MASK_COMPRESSION:
            r.read(1)                        # file-wide compression flag
        r.read(36 if version >= _FILE_VERSION_BOOST_UUID else 16)  # uuid
        file_meta = r.meta_map()
        (count,) = r.unpack("<i")
        grids = []
        for _ in range(count):
            name, gtype = r.string(), r.string()
            if version >= _FILE_VERSION_GRID_INSTANCING:
                r.string()                   # instance parent
            grid_pos, _block_pos, end_pos = r.unpack("<qqq")
            half = gtype.endswith("_HalfFloat")
            if half:
                gtype = gtype[: -len("_HalfFloat")]
            # Unique names carry a "\x1e<n>" suffix for duplicates.
            g = GridInfo(name=name.split("\x1e")[0], type=gtype, half_float=half)
            here = f.tell()
            if has_offsets:
                f.seek(grid_pos)
            if version >= _FILE_VERSION_NODE_MASK_COMPRESSION:
                r.unpack("<I")               # the grid's compression flags
            g.metadata = r.meta_map()
            grids.append(g)
            if not has_offsets:
                # A stream (a preview): the grid's voxels follow with no
                # offset to skip them, so only the first grid is listed.
                break
            f.seek(end_pos if end_pos > 0 else here)
        return VdbInfo(file_version=version, metadata=file_meta, grids=grids)
