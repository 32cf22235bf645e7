"""Running the backend from the add-on: its command line and processes (``client``, ``warm_process``: no bpy), the
session's warm backend (``warm_session``), the add-on preferences that say where it runs (``preferences``), and a
run from Blender: one camera's (``camera_run``), every camera path's (``all_cameras``), the render answered without
it (``render_plan``). Its results are loaded into Blender by ``scene.results``."""
