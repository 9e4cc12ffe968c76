"""Turns Nimbus VDB files into Blender volume objects.

Nimbus is Y-up by default (the tree grows along +Y); Blender is Z-up. A
Y-up file's object gets a +90 degree rotation about X, which takes +Y to +Z
and +Z to -Y, so the file's voxels stay untouched and re-exporting the
object's data gives the original file back. A file written with
`output.up_axis: UP_AXIS_Z` says so in its nimbus_up_axis metadata; its
grid transform already holds that rotation, so the object gets none.
"""

import math
import os

import bpy

from . import vendor

nimbus = vendor.nimbus()

# Principled Volume density used when the file suggests none. Nimbus fog
# volumes hold values in [0, 1]; at 1 a 2-unit fractal renders as a faint
# haze, 8 gives a readable cloud in a default-lit scene.
DEFAULT_DENSITY = 8.0
# Grid metadata (double) a result may carry to suggest the multiplier.
DENSITY_META_KEY = "nimbus_suggested_density"
Y_UP_TO_Z_UP = (math.radians(90.0), 0.0, 0.0)
# Grid metadata (string "y" or "z") naming the file's up axis. Files without
# it are Nimbus's native Y-up.
UP_AXIS_META_KEY = "nimbus_up_axis"


def read_metadata(path, grid_name):
    """The named grid's metadata merged over the file's, or {} when the file
    cannot be read (e.g. a half-written preview)."""
    try:
        info = nimbus.vdb.read_info(path)
    except (OSError, nimbus.vdb.VdbFormatError):
        return {}
    meta = dict(info.metadata)
    g = info.grid(grid_name) or next((g for g in info.grids if "float" in g.type), None)
    if g is not None:
        meta.update(g.metadata)
    return meta


def rotation_for(meta):
    """The object rotation that puts the file's up axis on Blender's +Z."""
    if str(meta.get(UP_AXIS_META_KEY, "y")).lower() == "z":
        return (0.0, 0.0, 0.0)  # already Z-up
    return Y_UP_TO_Z_UP


def suggested_density(meta):
    v = meta.get(DENSITY_META_KEY)
    return float(v) if isinstance(v, (int, float)) and v > 0 else DEFAULT_DENSITY


def build_material(name, density, density_grid="density", color_grid=None):
    """A Principled Volume material reading `density_grid`, scaled by
    `density`, coloured by `color_grid` through an Attribute node if given."""
    mat = bpy.data.materials.get(name) or bpy.data.materials.new(name)
    mat.use_nodes = True
    nt = mat.node_tree
    nt.nodes.clear()
    out = nt.nodes.new("ShaderNodeOutputMaterial")
    out.location = (300, 0)
    pv = nt.nodes.new("ShaderNodeVolumePrincipled")
    pv.location = (0, 0)
    nt.links.new(pv.outputs["Volume"], out.inputs["Volume"])
    pv.inputs["Density"].default_value = density
    pv.inputs["Density Attribute"].default_value = density_grid
    if color_grid:
        attr = nt.nodes.new("ShaderNodeAttribute")
        attr.location = (-300, 0)
        attr.attribute_name = color_grid
        nt.links.new(attr.outputs["Color"], pv.inputs["Color"])
    else:
        pv.inputs["Color"].default_value = (0.85, 0.85, 0.85, 1.0)
    return mat


def ensure_volume_object(name, collection=None):
    """The volume object called `name`, created (rotated Y-up to Z-up) if missing."""
    obj = bpy.data.objects.get(name)
    if obj is not None and obj.type == "VOLUME":
        return obj
    vol = bpy.data.volumes.new(name)
    obj = bpy.data.objects.new(name, vol)
    (collection or bpy.context.scene.collection).objects.link(obj)
    obj.rotation_euler = Y_UP_TO_Z_UP
    return obj


def load_into(obj, path, final, grid_name="density"):
    """Points the object's volume at `path` and (re)loads its grids, in
    place: the same object and data block show each preview, then the
    result. A final file also gets its material rebuilt from its metadata."""
    vol = obj.data
    vol.filepath = os.path.abspath(path)
    vol.grids.load()
    if vol.grids.error_message:
        raise RuntimeError(f"Blender cannot load {path}: {vol.grids.error_message}")
    names = [g.name for g in vol.grids]
    # Previews are complete files too (renamed into place) with the job's
    # up axis, so every file sets the rotation.
    meta = read_metadata(path, grid_name)
    obj.rotation_euler = rotation_for(meta)
    if final or not obj.data.materials:
        density_grid = grid_name if grid_name in names else (names[0] if names else grid_name)
        mat = build_material(f"{obj.name} volume", suggested_density(meta), density_grid,
                             "Cd" if "Cd" in names else None)
        if obj.data.materials:
            obj.data.materials[0] = mat
        else:
            obj.data.materials.append(mat)
    obj.update_tag()
    return names


def import_vdb(path, name=None, grid_name="density"):
    """Imports a Nimbus result as a new (or the same-named) volume object."""
    name = name or os.path.splitext(os.path.basename(path))[0]
    obj = ensure_volume_object(name)
    load_into(obj, path, final=True, grid_name=grid_name)
    return obj
