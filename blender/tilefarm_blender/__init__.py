"""tilefarm for Blender: export the scene as a tilefarm scene folder (File > Export >
tilefarm scene), or render it on a tilefarm farm (Render > Render on tilefarm), with
the farm's progress in the status bar and the finished EXR opened in an Image Editor.
The farm's address, token and `coordinator` executable are the add-on's preferences."""

import os
import tempfile
import time

import bpy
from bpy.props import StringProperty

from . import export, farm


# The preferences' defaults: the environment's, as the coordinator's own commands read it.
DEFAULT_EXE = os.environ.get("TILEFARM_COORDINATOR_EXE", "coordinator")
DEFAULT_URL = os.environ.get("TILEFARM_COORDINATOR", "http://127.0.0.1:7878")


class TilefarmPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    coordinator: StringProperty(
        name="coordinator executable", subtype="FILE_PATH", default=DEFAULT_EXE,
        description="tilefarm's `coordinator` program (on PATH, or its full path)")
    url: StringProperty(name="farm", default=DEFAULT_URL,
                        description="the farm's address, as `coordinator submit --coordinator` takes it")
    token: StringProperty(name="token", subtype="PASSWORD", default="",
                          description="your access token on the farm (empty on a farm without users)")

    def draw(self, context):
        for prop in ("coordinator", "url", "token"):
            self.layout.prop(self, prop)


def preferences(context):
    addon = context.preferences.addons.get(__package__)
    if addon is not None:
        return addon.preferences
    # Not installed as an add-on (a script registered the classes): the defaults.
    token = os.environ.get("TILEFARM_TOKEN", "")
    return type("Defaults", (), {"coordinator": DEFAULT_EXE, "url": DEFAULT_URL, "token": token})


def _warn_once(op, report):
    summary = report.summary()
    if summary:
        op.report({"WARNING"}, summary)


class TILEFARM_OT_export(bpy.types.Operator):
    """Write the scene as a tilefarm scene folder (scene.toml, OBJs, materials, textures)"""

    bl_idname = "tilefarm.export_scene"
    bl_label = "Export tilefarm scene"
    bl_options = {"REGISTER"}

    directory: StringProperty(subtype="DIR_PATH")

    def execute(self, context):
        if not self.directory:
            self.report({"ERROR"}, "choose a folder")
            return {"CANCELLED"}
        try:
            report = export.export_scene(bpy.path.abspath(self.directory), context.scene)
        except (ValueError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        _warn_once(self, report)
        self.report({"INFO"}, f"tilefarm: {report.triangles} triangles written in {report.seconds:.1f} s")
        return {"FINISHED"}

    def invoke(self, context, event):
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}


class TILEFARM_OT_render(bpy.types.Operator):
    """Export the scene and render it on the tilefarm farm of the add-on's preferences"""

    bl_idname = "tilefarm.render"
    bl_label = "Render on tilefarm"

    output: StringProperty(name="output", subtype="FILE_PATH", default="",
                           description="where the EXR goes (default: beside the exported scene)")

    _timer = None
    _job = None

    def start(self, context):
        folder = tempfile.mkdtemp(prefix="tilefarm-")
        report = export.export_scene(folder, context.scene)
        _warn_once(self, report)
        prefs = preferences(context)
        output = bpy.path.abspath(self.output) if self.output else os.path.join(folder, "render.exr")
        name = bpy.path.display_name_from_filepath(bpy.data.filepath) or context.scene.name
        return farm.Submission(bpy.path.abspath(prefs.coordinator), prefs.url, prefs.token,
                               os.path.join(folder, "scene.toml"), output, name)

    def finish(self, context, job, code):
        if code != 0:
            self.report({"ERROR"}, "tilefarm: " + job.error())
            return {"CANCELLED"}
        image = bpy.data.images.load(job.output, check_existing=False)
        for area in getattr(context.screen, "areas", []):
            if area.type == "IMAGE_EDITOR":
                area.spaces.active.image = image
                break
        self.report({"INFO"}, f"tilefarm: rendered {job.output}")
        return {"FINISHED"}

    def execute(self, context):
        # Without a window (blender -b, or PyPI's bpy): submit and wait here.
        try:
            job = self.start(context)
        except (ValueError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        return self.finish(context, job, job.wait())

    def invoke(self, context, event):
        try:
            self._job = self.start(context)
        except (ValueError, OSError) as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        self._started = time.monotonic()
        self._timer = context.window_manager.event_timer_add(0.5, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self._job.cancel()
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        code = self._job.poll()
        if code is None:
            elapsed = time.monotonic() - self._started
            context.workspace.status_text_set(self._job.status_text(elapsed))
            return {"RUNNING_MODAL"}
        context.window_manager.event_timer_remove(self._timer)
        context.workspace.status_text_set(None)
        return self.finish(context, self._job, code)


def _export_menu(self, context):
    self.layout.operator(TILEFARM_OT_export.bl_idname, text="tilefarm scene (folder)")


def _render_menu(self, context):
    self.layout.operator(TILEFARM_OT_render.bl_idname, icon="RENDER_STILL")


CLASSES = (TilefarmPreferences, TILEFARM_OT_export, TILEFARM_OT_render)


def register():
    for c in CLASSES:
        bpy.utils.register_class(c)
    bpy.types.TOPBAR_MT_file_export.append(_export_menu)
    bpy.types.TOPBAR_MT_render.append(_render_menu)


def unregister():
    bpy.types.TOPBAR_MT_render.remove(_render_menu)
    bpy.types.TOPBAR_MT_file_export.remove(_export_menu)
    for c in reversed(CLASSES):
        bpy.utils.unregister_class(c)
