"""Runs inside Blender (run_blender_test.py starts it):

    blender -b --factory-startup --python-exit-code 1 --python test_addon.py

Installs the add-on zip, enables it, starts a real nimbusd through the
add-on's operator, runs a small tree job through the panel's Submit
operator, and checks the object it made: previews streamed into it in
place, the result's grids, its world-space bounds and orientation (the
tree's trunk, +Y in Nimbus, along +Z in Blender) and its material. Then
imports a coloured result and checks the Cd wiring. Any failed check raises,
and --python-exit-code turns that into exit code 1.
"""

import json
import os
import shutil
import sys
import tempfile
import time
import traceback
from pathlib import Path

import bpy
from mathutils import Vector

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent.parent
TMP = Path(tempfile.mkdtemp(prefix="nimbus-blender-test-"))


def check(cond, what):
    if not cond:
        raise AssertionError(what)
    print(f"  ok: {what}")


def close(a, b, tol):
    return abs(a - b) <= tol


def world_bounds(obj):
    bpy.context.view_layer.update()
    pts = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
    return (Vector([min(p[i] for p in pts) for i in range(3)]),
            Vector([max(p[i] for p in pts) for i in range(3)]))


def install_addon():
    # Loaded by path: with dcc/blender on sys.path, Blender would enable the
    # source tree's nimbus_blender instead of the installed one.
    import importlib.util
    spec = importlib.util.spec_from_file_location("build_addon",
                                                  REPO / "dcc" / "blender" / "build_addon.py")
    build_addon = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(build_addon)
    zip_path = build_addon.build(TMP / "nimbus_blender.zip")
    bpy.ops.preferences.addon_install(filepath=str(zip_path))
    bpy.ops.preferences.addon_enable(module="nimbus_blender")
    import nimbus
    check("_vendor" in nimbus.__file__,
          f"the add-on uses its bundled nimbus package ({nimbus.__file__})")


def run_panel_job():
    scene = bpy.context.scene
    props = scene.nimbus
    prefs = bpy.context.preferences.addons["nimbus_blender"].preferences
    prefs.nimbusd_path = os.environ.get("NIMBUSD", "")
    check(bpy.ops.nimbus.start_server() == {"FINISHED"}, "Start local server")
    check(props.server.startswith("127.0.0.1:") and not props.server.endswith(":50051"),
          f"server address set to the started nimbusd ({props.server})")

    spec = json.loads((REPO / "examples" / "tree.json").read_text())
    spec["grid"]["resolution"] = [16, 128, 120]
    # Seconds long, so the loop below sees previews even on a loaded machine.
    spec["chaos_game"]["iterations"] = "300000000"
    spec_path = TMP / "tree_small.json"
    spec_path.write_text(json.dumps(spec))
    props.spec_path = str(spec_path)
    props.output_dir = str(TMP / "out")
    props.preview_resolution = 48
    props.preview_interval = 0.05

    from nimbus_blender import session
    # The panel's timer does not run while a background script does, so the
    # test pumps the session itself, as the timer would.
    seen_objects = set()
    check(bpy.ops.nimbus.submit() == {"FINISHED"}, "Submit")
    deadline = time.monotonic() + 300
    while not session.pump_active(scene):
        if props.object_name:
            obj = bpy.data.objects[props.object_name]
            seen_objects.add(obj.as_pointer())
        if time.monotonic() > deadline:
            raise AssertionError(f"job still running after 300 s: {props.status}")
        time.sleep(0.05)
    s = session.active()
    check(s.error is None, f"job ended without error ({s.error!r})")
    check(s.previews_loaded >= 1, f"previews streamed into the object ({s.previews_loaded})")
    check(s.preview_dones == sorted(s.preview_dones), "previews arrive in progress order")
    check(props.progress == 100.0, "progress shows 100 %")
    obj = bpy.data.objects[props.object_name]
    seen_objects.add(obj.as_pointer())
    check(len(seen_objects) == 1, "one object shows every preview and the result (in place)")
    check(len([o for o in bpy.data.objects if o.type == "VOLUME"]) == 1, "no extra volume objects")
    check(Path(obj.data.filepath) == s.result_path and s.result_path.is_file(),
          f"object shows the fetched result {s.result_path}")
    # One pump may apply every queued event at once, so the files the object
    # showed come from the session's own record, not from polling here.
    shown = s.shown_files
    check(any(".preview." in f for f in shown[:-1]) and shown[-1] == obj.data.filepath,
          f"object showed previews, then the result: {shown}")
    check_events(s, props)
    return obj


def check_events(s, props):
    """The panel got the job's event log as the server recorded it."""
    import nimbus
    kinds = [e.kind for e in s.shown_events]
    check(kinds[:2] == ["submitted", "claimed"], f"event log starts submitted, claimed: {kinds}")
    check(s.shown_events[1].worker != "", f"the claim names its worker ({s.shown_events[1]})")
    with nimbus.Client(props.server) as c:
        logged = [(e.seq, e.kind) for e in c.events(s.job_id)]
    check([(e.seq, e.kind) for e in s.shown_events] == logged,
          f"every event shown once, in order, as GetJobEvents lists them ({len(logged)})")
    lines = props.recent_events.splitlines()
    check(len(lines) == min(5, len(kinds)), f"the panel shows the newest events: {lines}")
    check(lines[-1] == f"succeeded {s.shown_events[1].worker}",
          "the last line is the end, by the worker that claimed the job")
    check(f"phase iterating {s.shown_events[1].worker}" in lines, "a phase line names its phase")


def check_tree(obj):
    vol = obj.data
    names = [g.name for g in vol.grids]
    check("density" in names, f"grids present: {names}")
    check(vol.grids["density"].data_type == "FLOAT", "density is a float grid")

    # Y-up to Z-up: Nimbus +Y is Blender +Z. (matrix_world is refreshed by
    # a depsgraph update, which a background script must ask for.)
    bpy.context.view_layer.update()
    up = obj.matrix_world.to_3x3() @ Vector((0, 1, 0))
    check((up - Vector((0, 0, 1))).length < 1e-6, f"Nimbus +Y maps to Blender +Z ({up})")

    # The tree spans y in [-0.025, 1.825] (trunk at the bottom, from 0 up),
    # x in +-0.0325, z in +-0.867 in Nimbus. In Blender world space the
    # height must be along +Z starting at the ground, not hanging below it.
    lo, hi = world_bounds(obj)
    print(f"  world bounds {tuple(round(v, 3) for v in lo)} .. {tuple(round(v, 3) for v in hi)}")
    check(-0.05 <= lo.z <= 0.1, f"trunk base at the ground (min z {lo.z:.3f})")
    check(1.5 <= hi.z <= 1.86, f"crown at the top (max z {hi.z:.3f})")
    check(hi.x - lo.x < 0.1, f"thin along x, as Nimbus x ({hi.x - lo.x:.3f})")
    check(1.2 < hi.y - lo.y <= 1.75, f"wide along y, Nimbus z ({hi.y - lo.y:.3f})")
    check(hi.z - lo.z > hi.y - lo.y, "tallest along Blender z")

    mat = vol.materials[0]
    nodes = mat.node_tree.nodes
    pv = next(n for n in nodes if n.bl_idname == "ShaderNodeVolumePrincipled")
    out = next(n for n in nodes if n.bl_idname == "ShaderNodeOutputMaterial")
    check(any(l.from_node == pv and l.to_node == out and l.to_socket.name == "Volume"
              for l in mat.node_tree.links), "Principled Volume feeds the output's Volume")
    import nimbus
    suggested = nimbus.vdb.read_info(vol.filepath).grids[0].metadata["nimbus_suggested_density"]
    check(close(pv.inputs["Density"].default_value, suggested, 1e-3 * suggested),
          f"density multiplier from nimbus_suggested_density ({suggested:.2f})")
    check(pv.inputs["Density Attribute"].default_value == "density", "reads the density grid")
    check(not any(n.bl_idname == "ShaderNodeAttribute" for n in nodes),
          "no Cd attribute node for a file without Cd")


def check_z_up_import(address):
    """A result written Z-up (output.up_axis) imports without a rotation of
    its own, and its trunk still stands along Blender's +Z."""
    import nimbus
    spec = json.loads((REPO / "examples" / "tree.json").read_text())
    spec["grid"]["resolution"] = [8, 64, 60]
    spec["chaos_game"]["iterations"] = "4000000"
    spec["output"] = {"up_axis": "UP_AXIS_Z"}
    path = TMP / "tree_z.vdb"
    with nimbus.Client(address) as c:
        c.render(spec, path)
    from nimbus_blender import importer
    obj = importer.import_vdb(str(path), name="tree_z")
    check(tuple(obj.rotation_euler) == (0.0, 0.0, 0.0), "a Z-up file gets no extra rotation")
    lo, hi = world_bounds(obj)
    check(-0.05 <= lo.z <= 0.15 and 1.5 <= hi.z <= 1.9,
          f"Z-up trunk along +Z ({lo.z:.3f} .. {hi.z:.3f})")
    check(hi.z - lo.z > hi.y - lo.y, "tallest along Blender z")
    bpy.data.objects.remove(obj)


def check_color_import(address):
    """A coloured flame: the importer wires Cd through an Attribute node."""
    import nimbus
    spec = json.loads((REPO / "examples" / "flame_cloud.json").read_text())
    spec["grid"]["resolution"] = [48]
    spec["chaos_game"]["iterations"] = "2000000"
    spec["chaos_game"].pop("convergence", None)
    path = TMP / "flame.vdb"
    with nimbus.Client(address) as c:
        c.render(spec, path)
    from nimbus_blender import importer
    obj = importer.import_vdb(str(path))
    names = [g.name for g in obj.data.grids]
    check("Cd" in names, f"flame result has Cd ({names})")
    nt = obj.data.materials[0].node_tree
    attr = next(n for n in nt.nodes if n.bl_idname == "ShaderNodeAttribute")
    check(attr.attribute_name == "Cd", "Attribute node reads Cd")
    check(any(l.from_node == attr and l.to_socket.name == "Color" and
              l.to_node.bl_idname == "ShaderNodeVolumePrincipled" for l in nt.links),
          "Cd colours the Principled Volume")


def main():
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    install_addon()
    try:
        obj = run_panel_job()
        check_tree(obj)
        check_z_up_import(bpy.context.scene.nimbus.server)
        check_color_import(bpy.context.scene.nimbus.server)
    finally:
        bpy.ops.nimbus.stop_server()
        shutil.rmtree(TMP, ignore_errors=True)
    print("NIMBUS BLENDER TEST PASSED")


main()
