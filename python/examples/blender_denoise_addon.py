"""A sketch of a Blender add-on that denoises the render result with gsid (not run in CI).

Install: `pip install ./python` into Blender's Python (e.g.
`<blender>/<version>/python/bin/python3.11 -m pip install ./python`), then Edit > Preferences >
Add-ons > Install... this file. Enable the Denoising Data passes (View Layer Properties > Passes >
Data > Denoising Data) so Blender writes `Denoising Albedo` and `Denoising Normal`, render, and run
Image > "Denoise with gsid" in the Image Editor showing the Render Result. Esc cancels it.

What it shows: the passes found by name, `gsid.denoise` on a worker thread (it releases the GIL,
so the UI stays live), progress in Blender's status bar, Esc cancelling through a CancelToken, and
the result written to a new image, "gsid denoised".
"""

bl_info = {
    "name": "gsid denoiser (sketch)",
    "blender": (3, 6, 0),
    "category": "Render",
    "description": "Denoise the render result's passes with gsid",
}

import threading

import bpy
import numpy as np

import gsid

def render_passes(scene):
    """The render result's buffers, as `gsid denoise` maps a Blender multilayer EXR's passes.

    Blender's Python cannot read a Render Result's passes directly: it is saved as a multilayer
    EXR (beside the .blend) and read back by gsid, which finds Combined, Denoising Albedo,
    Denoising Normal and Depth by their names.
    """
    path = bpy.path.abspath("//gsid_render_result.exr")
    image = bpy.data.images["Render Result"]
    settings = scene.render.image_settings
    old = settings.file_format
    settings.file_format = "OPEN_EXR_MULTILAYER"
    try:
        image.save_render(path, scene=scene)
    finally:
        settings.file_format = old
    return gsid.read_render(path)


class GSID_OT_denoise(bpy.types.Operator):
    """Denoise the render result with gsid"""

    bl_idname = "image.gsid_denoise"
    bl_label = "Denoise with gsid"

    pipeline: bpy.props.EnumProperty(
        name="Pipeline",
        items=[(n, n, "") for n in ("full", "balanced", "fast")],
        default="full",
    )

    def invoke(self, context, event):
        buffers = render_passes(context.scene)
        self.shape = buffers["color"].shape
        self.token = gsid.CancelToken()
        self.state = {"fraction": 0.0, "stage": "", "result": None, "error": None}
        args = [buffers.get(k) for k in ("color", "albedo", "normal", "depth")]

        def progress(fraction, stage):
            self.state["fraction"], self.state["stage"] = fraction, stage

        def run():
            try:
                self.state["result"] = gsid.denoise(
                    *args, pipeline=self.pipeline, progress=progress, cancel=self.token
                )
            except gsid.Error as e:  # gsid.Cancelled included
                self.state["error"] = str(e)

        # The run releases the GIL, so Blender's UI stays responsive while it goes on.
        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        self.timer = context.window_manager.event_timer_add(0.1, window=context.window)
        context.window_manager.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def modal(self, context, event):
        if event.type == "ESC":
            self.token.cancel()
        if event.type != "TIMER":
            return {"PASS_UI"}
        if self.thread.is_alive():
            context.workspace.status_text_set(
                f"gsid: {self.state['stage']} {100 * self.state['fraction']:.0f} % (Esc cancels)"
            )
            return {"RUNNING_MODAL"}
        context.window_manager.event_timer_remove(self.timer)
        context.workspace.status_text_set(None)
        if self.state["error"]:
            self.report({"WARNING"}, f"gsid: {self.state['error']}")
            return {"CANCELLED"}
        h, w, _ = self.shape
        out = bpy.data.images.get("gsid denoised") or bpy.data.images.new(
            "gsid denoised", w, h, alpha=True, float_buffer=True
        )
        rgba = np.ones((h, w, 4), np.float32)
        rgba[..., :3] = self.state["result"]
        # Blender's pixels start at the bottom row.
        out.pixels.foreach_set(rgba[::-1].ravel())
        out.update()
        self.report({"INFO"}, "gsid: denoised into image 'gsid denoised'")
        return {"FINISHED"}


def menu(self, context):
    self.layout.operator(GSID_OT_denoise.bl_idname)


def register():
    bpy.utils.register_class(GSID_OT_denoise)
    bpy.types.IMAGE_MT_image.append(menu)


def unregister():
    bpy.types.IMAGE_MT_image.remove(menu)
    bpy.utils.unregister_class(GSID_OT_denoise)
