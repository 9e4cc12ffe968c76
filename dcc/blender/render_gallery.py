"""Renders a Nimbus spec to a PNG with Blender, headless, through the same
client and importer the add-on uses:

    blender -b --factory-startup --python dcc/blender/render_gallery.py -- \\
        --spec examples/fern_volume.json --resolution 256 --iterations 60000000 \\
        --out docs/gallery/fern_volume.png --frame 0.85

Starts its own nimbusd ($NIMBUSD, PATH, or build/bin) unless --server is
given. Cycles on the CPU, small and few samples: a gallery thumbnail, not a
beauty render.
"""

import argparse
import math
import shutil
import sys
import tempfile
from pathlib import Path

import bpy
from mathutils import Vector

REPO = Path(__file__).resolve().parent.parent.parent
sys.path.insert(0, str(REPO / "python"))
sys.path.insert(0, str(REPO / "dcc" / "blender"))

import nimbus  # noqa: E402
from nimbus.testing import LocalServer  # noqa: E402
from nimbus_blender import importer  # noqa: E402


def parse_args():
    argv = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    ap = argparse.ArgumentParser(prog="render_gallery.py")
    ap.add_argument("--spec", required=True)
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--server", help="host:port of a running nimbusd")
    ap.add_argument("--resolution", type=int, help="override the grid: largest axis, voxels")
    ap.add_argument("--iterations", type=int, help="override the chaos game's iterations")
    ap.add_argument("--density", type=float, help="override the density multiplier")
    ap.add_argument("--size", type=int, default=480, help="image width and height, pixels")
    ap.add_argument("--samples", type=int, default=48)
    ap.add_argument("--frame", type=float, default=0.75,
                    help="camera distance as a multiple of the bounding sphere's fit; "
                         "below 1 crops the sparse outskirts a chaos game leaves")
    ap.add_argument("--view", default="1,-1.3,0.5",
                    help="direction from the object to the camera, Blender world space")
    return ap.parse_args(argv)


def scaled_spec(path, resolution, iterations):
    spec, base = nimbus.load_spec(path)
    if resolution:
        r = list(spec.grid.resolution) or [resolution]
        if len(r) == 3:
            s = resolution / max(r)
            r = [max(1, round(v * s)) for v in r]
        else:
            r = [resolution]
        spec.grid.ClearField("resolution")
        spec.grid.resolution.extend(r)
    if iterations and spec.WhichOneof("generator") == "chaos_game":
        spec.chaos_game.iterations = iterations
    return spec, base


def setup_scene(obj, args):
    scene = bpy.context.scene
    bpy.context.view_layer.update()
    pts = [obj.matrix_world @ Vector(c) for c in obj.bound_box]
    lo = Vector([min(p[i] for p in pts) for i in range(3)])
    hi = Vector([max(p[i] for p in pts) for i in range(3)])
    center, radius = (lo + hi) / 2, (hi - lo).length / 2

    cam_data = bpy.data.cameras.new("camera")
    cam_data.lens = 50
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    view = Vector([float(v) for v in args.view.split(",")]).normalized()
    fov = 2 * math.atan(cam_data.sensor_width / (2 * cam_data.lens))
    cam.location = center + view * (radius * args.frame / math.tan(fov / 2))
    cam.rotation_euler = (center - cam.location).to_track_quat("-Z", "Y").to_euler()
    scene.camera = cam

    sun_data = bpy.data.lights.new("sun", "SUN")
    sun_data.energy = 4.0
    sun = bpy.data.objects.new("sun", sun_data)
    sun.rotation_euler = (math.radians(40), math.radians(-20), math.radians(30))
    scene.collection.objects.link(sun)

    world = bpy.data.worlds.new("world")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (0.02, 0.025, 0.035, 1)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world

    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = args.samples
    scene.cycles.use_denoising = False
    scene.render.resolution_x = scene.render.resolution_y = args.size
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.render.image_settings.file_format = "PNG"
    scene.view_settings.view_transform = "Standard"


def main():
    args = parse_args()
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    spec, base = scaled_spec(args.spec, args.resolution, args.iterations)
    tmp = Path(tempfile.mkdtemp(prefix="nimbus-gallery-"))
    vdb = tmp / f"{spec.name or 'nimbus'}.vdb"
    server = None if args.server else LocalServer().start()
    try:
        with nimbus.Client(args.server or server.address) as c:
            r = c.render(spec, vdb, base_dir=base)
            print(f"rendered {r.job.id} -> {vdb} ({vdb.stat().st_size} bytes)")
    finally:
        if server:
            server.cleanup()
    obj = importer.import_vdb(str(vdb))
    if args.density:
        pv = next(n for n in obj.data.materials[0].node_tree.nodes
                  if n.bl_idname == "ShaderNodeVolumePrincipled")
        pv.inputs["Density"].default_value = args.density
    setup_scene(obj, args)
    out = Path(args.out).resolve()
    out.parent.mkdir(parents=True, exist_ok=True)
    bpy.context.scene.render.filepath = str(out)
    bpy.ops.render.render(write_still=True)
    shutil.rmtree(tmp, ignore_errors=True)
    print(f"wrote {out}")


main()
