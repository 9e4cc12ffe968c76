"""Nimbus for Blender: grow fractal volumes on a nimbusd from a spec file,
watch their previews fill a volume object, and get the result with a ready
material. See docs/dcc.md."""

bl_info = {
    "name": "Nimbus fractal volumes",
    "author": "Nimbus",
    "version": (0, 1, 0),
    "blender": (3, 4, 0),
    "location": "3D Viewport > Sidebar (N) > Nimbus",
    "description": "Submit Nimbus specs to nimbusd, stream previews, import the VDB result",
    "category": "Import-Export",
}

import bpy  # noqa: E402
from bpy.props import FloatProperty, IntProperty, PointerProperty, StringProperty  # noqa: E402

from . import importer, session  # noqa: E402


class NimbusPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    nimbusd_path: StringProperty(
        name="nimbusd", subtype="FILE_PATH",
        description="nimbusd binary for 'Start local server' (empty: $NIMBUSD, PATH, "
                    "then the source tree's build/bin)")

    def draw(self, context):
        self.layout.prop(self, "nimbusd_path")


class NimbusSceneProps(bpy.types.PropertyGroup):
    spec_path: StringProperty(name="Spec", subtype="FILE_PATH",
                              description="Nimbus spec file (.json, .txtpb)")
    server: StringProperty(name="Server", default="127.0.0.1:50051",
                           description="host:port of a nimbusd")
    output_dir: StringProperty(name="Output", subtype="DIR_PATH", default="//nimbus/",
                               description="Folder for results and previews")
    preview_resolution: IntProperty(name="Preview voxels", default=64, min=0, max=512,
                                    description="Largest axis of preview grids; 0: none")
    preview_interval: FloatProperty(name="Preview every", default=1.0, min=0.05,
                                    unit="TIME_ABSOLUTE", description="Seconds between previews")
    priority: IntProperty(name="Priority", default=50, min=0, max=100,
                          description="Higher runs first; equal priorities share the farm fairly")
    status: StringProperty(name="Status", default="")
    progress: FloatProperty(name="Progress", subtype="PERCENTAGE", min=0, max=100)
    job_id: StringProperty(name="Job")
    recent_events: StringProperty(name="Events", default="",
                                  description="The job's newest event-log entries, one a line")
    object_name: StringProperty(name="Object")


class NIMBUS_OT_submit(bpy.types.Operator):
    """Submit the spec, stream its previews into a volume object, import the result"""
    bl_idname = "nimbus.submit"
    bl_label = "Submit"

    def execute(self, context):
        try:
            session.start(context.scene)
        except Exception as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        if not bpy.app.timers.is_registered(session.timer):
            bpy.app.timers.register(session.timer, first_interval=0.2)
        return {"FINISHED"}


class NIMBUS_OT_cancel(bpy.types.Operator):
    """Cancel the running job"""
    bl_idname = "nimbus.cancel"
    bl_label = "Cancel"

    @classmethod
    def poll(cls, context):
        s = session.active()
        return s is not None and not s.finished

    def execute(self, context):
        session.active().cancel()
        return {"FINISHED"}


class NIMBUS_OT_start_server(bpy.types.Operator):
    """Start a nimbusd on this machine (loopback, free port) and use it"""
    bl_idname = "nimbus.start_server"
    bl_label = "Start local server"

    def execute(self, context):
        prefs = context.preferences.addons[__package__].preferences
        try:
            srv = session.start_local_server(bpy.path.abspath(prefs.nimbusd_path) or None)
        except Exception as e:
            self.report({"ERROR"}, f"cannot start nimbusd: {e}")
            return {"CANCELLED"}
        context.scene.nimbus.server = srv.address
        self.report({"INFO"}, f"nimbusd listening on {srv.address}")
        return {"FINISHED"}


class NIMBUS_OT_stop_server(bpy.types.Operator):
    """Stop the nimbusd this add-on started"""
    bl_idname = "nimbus.stop_server"
    bl_label = "Stop local server"

    @classmethod
    def poll(cls, context):
        return session._local_server is not None

    def execute(self, context):
        session.stop_local_server()
        return {"FINISHED"}


class NIMBUS_OT_import_vdb(bpy.types.Operator):
    """Import a Nimbus .vdb result (Y-up to Z-up, Principled Volume material)"""
    bl_idname = "nimbus.import_vdb"
    bl_label = "Import Nimbus VDB"

    filepath: StringProperty(subtype="FILE_PATH")

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        try:
            importer.import_vdb(self.filepath)
        except Exception as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        return {"FINISHED"}


class NIMBUS_PT_panel(bpy.types.Panel):
    bl_label = "Nimbus"
    bl_space_type = "VIEW_3D"
    bl_region_type = "UI"
    bl_category = "Nimbus"

    def draw(self, context):
        props = context.scene.nimbus
        col = self.layout.column()
        col.prop(props, "spec_path")
        row = col.row(align=True)
        row.prop(props, "server")
        row.operator("nimbus.start_server", text="", icon="PLAY")
        col.prop(props, "output_dir")
        row = col.row(align=True)
        row.prop(props, "preview_resolution")
        row.prop(props, "preview_interval")
        col.prop(props, "priority")
        row = col.row(align=True)
        row.operator("nimbus.submit", icon="EXPORT")
        row.operator("nimbus.cancel", icon="CANCEL")
        if props.status:
            col.prop(props, "progress", slider=True)
            col.label(text=props.status)
        if props.recent_events:
            box = col.box()
            for line in props.recent_events.splitlines():
                box.label(text=line)
        col.operator("nimbus.import_vdb", icon="IMPORT")


CLASSES = (NimbusPreferences, NimbusSceneProps, NIMBUS_OT_submit, NIMBUS_OT_cancel,
           NIMBUS_OT_start_server, NIMBUS_OT_stop_server, NIMBUS_OT_import_vdb,
           NIMBUS_PT_panel)


def register():
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.Scene.nimbus = PointerProperty(type=NimbusSceneProps)


def unregister():
    if bpy.app.timers.is_registered(session.timer):
        bpy.app.timers.unregister(session.timer)
    session.stop_local_server()
    del bpy.types.Scene.nimbus
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
