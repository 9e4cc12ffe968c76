"""Opens VDB files with pyopenvdb and checks them against a manifest.

Run by tests/core/pyopenvdb_interop_test.cc with Debian's /usr/bin/python3,
whose pyopenvdb wraps only float, bool and Vec3f grids and refuses a whole
file when any grid has another type. The manifest (JSON) lists, per file,
the grids with their type, class, active voxel count,
metadata and some voxel values. Prints one line per problem and exits 1 if
there is any.
"""
import json
import math
import os
import sys

import pyopenvdb as vdb


def close(a, b):
    if isinstance(b, list):
        return len(a) == len(b) and all(close(x, y) for x, y in zip(a, b))
    if isinstance(b, float) or isinstance(a, float):
        return math.isclose(a, b, rel_tol=1e-6, abs_tol=1e-7)
    return a == b


def check_metadata_only(path, want, problems):
    try:
        metas = vdb.readAllGridMetadata(path)
    except Exception as e:  # pyopenvdb raises plain RuntimeError/KeyError
        problems.append(f"{path}: readAllGridMetadata: {e}")
        return
    # pyopenvdb lists grids in its own order, not the file's.
    names = sorted(m.name for m in metas)
    if names != sorted(g["name"] for g in want):
        problems.append(f"{path}: grids {names}, want {sorted(g['name'] for g in want)}")
        return
    by_name = {m.name: m for m in metas}
    for g in want:
        m = by_name[g["name"]]
        if type(m).__name__ != g["type"]:
            problems.append(f"{path}:{g['name']}: type {type(m).__name__}, want {g['type']}")
        if m.gridClass != g["class"]:
            problems.append(f"{path}:{g['name']}: class {m.gridClass!r}, want {g['class']!r}")
        count = m.metadata.get("file_voxel_count")
        if count != g["active"]:
            problems.append(f"{path}:{g['name']}: file_voxel_count {count}, want {g['active']}")


def check_grid(path, grid, g, problems):
    where = f"{path}:{g['name']}"
    if grid.activeVoxelCount() != g["active"]:
        problems.append(f"{where}: {grid.activeVoxelCount()} active voxels, want {g['active']}")
    for key, value in g.get("meta", {}).items():
        if key not in grid:
            problems.append(f"{where}: no metadata {key}")
        elif not close(list(grid[key]) if isinstance(value, list) else grid[key], value):
            problems.append(f"{where}: metadata {key} = {grid[key]!r}, want {value!r}")
    accessor = grid.getConstAccessor()
    for x, y, z, value in g.get("values", []):
        got = accessor.getValue((x, y, z))
        got = list(got) if isinstance(value, list) else got
        if not close(got, value):
            problems.append(f"{where}: value at ({x},{y},{z}) = {got!r}, want {value!r}")
        if not accessor.isValueOn((x, y, z)):
            problems.append(f"{where}: voxel ({x},{y},{z}) is not active")


def check_file(path, want, problems):
    check_metadata_only(path, want, problems)
    try:
        grids, _ = vdb.readAll(path)
    except Exception as e:
        problems.append(f"{path}: readAll: {e}")
        return
    by_name = {grid.name: grid for grid in grids}
    for g in want:
        if g["name"] not in by_name:
            problems.append(f"{path}: readAll has no grid {g['name']}")
            continue
        check_grid(path, by_name[g["name"]], g, problems)
        # One grid by name too, as Blender-style importers do.
        single = vdb.read(path, g["name"])
        if single.activeVoxelCount() != g["active"]:
            problems.append(f"{path}:{g['name']}: read() gives another voxel count")


def main():
    with open(sys.argv[1]) as f:
        manifest = json.load(f)
    base = os.path.dirname(os.path.abspath(sys.argv[1]))
    problems = []
    for entry in manifest["files"]:
        check_file(os.path.join(base, entry["file"]), entry["grids"], problems)
    for p in problems:
        print(p)
    print(f"checked {len(manifest['files'])} files, {len(problems)} problems")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
