"""One Nimbus job driven from Blender.

gRPC calls block, and bpy may only be touched from the main thread, so a
worker thread submits, watches and fetches and puts events on a queue; the
main thread drains it in pump() (from a bpy.app.timers timer, or directly in
a script or test) and updates the scene.
"""

import os
import queue
import tempfile
import threading
from pathlib import Path

import bpy

from . import importer, vendor

nimbus = vendor.nimbus()

_active = None          # the JobSession being shown, if any
_local_server = None    # a nimbusd started by the add-on
RECENT_EVENTS = 5       # event-log lines the panel shows


class JobSession:
    def __init__(self, address, spec_path, out_dir, preview_resolution=64,
                 preview_interval=1.0, priority=None):
        self.address = address
        self.spec_path = spec_path
        self.out_dir = Path(out_dir)
        self.preview_resolution = preview_resolution
        self.preview_interval = preview_interval
        self.priority = priority
        self.events = queue.Queue()
        self.job_id = ""
        self.job_name = ""
        self.object_name = ""
        self.result_path = None
        self.previews_loaded = 0
        self.preview_dones = []
        self.shown_files = []   # the object's file after each load, in order
        self.shown_events = []  # the job's LogEvents as the panel got them, in order
        self.error = None
        self.finished = False
        self._client = None
        self._thread = threading.Thread(target=self._run, name="nimbus-job", daemon=True)

    def start(self):
        self._thread.start()
        return self

    # --- worker thread: no bpy here ------------------------------------------

    def _run(self):
        try:
            self._client = nimbus.Client(self.address)
            job = self._client.submit(self.spec_path, priority=self.priority)
            self.events.put(("submitted", job))
            previews_dir = self.out_dir / "previews" / job.id
            final = job
            for ev in self._client.watch(job, previews_dir=previews_dir,
                                         preview_resolution=self.preview_resolution,
                                         preview_interval=self.preview_interval,
                                         events=True):
                final = ev.job
                self.events.put(("update", ev.job, ev.preview, ev.events))
            nimbus.raise_for_job(final)
            path = self.out_dir / (final.result.file_name or f"{final.name}.vdb")
            self._client.fetch(final, path)
            self.events.put(("result", final, path))
        except Exception as e:  # everything ends up in the panel, not a traceback
            self.events.put(("error", e))
        finally:
            self.events.put(("end",))

    def cancel(self):
        """Asks the server to cancel; the watch then ends with CANCELLED."""
        if not self.job_id or self._client is None:
            return
        client, job_id = self._client, self.job_id
        threading.Thread(target=lambda: _ignore_errors(client.cancel, job_id),
                         daemon=True).start()

    # --- main thread -----------------------------------------------------------

    def pump(self, scene):
        """Applies queued events to the scene; returns True once the job is over."""
        props = scene.nimbus
        while True:
            try:
                ev = self.events.get_nowait()
            except queue.Empty:
                return self.finished
            kind = ev[0]
            if kind == "submitted":
                job = ev[1]
                self.job_id, self.job_name = job.id, job.name
                props.job_id = job.id
                props.status = f"{job.id} queued"
            elif kind == "update":
                job, preview = ev[1], ev[2]
                self._note_events(props, ev[3])
                p = job.progress
                phase = _phase_word(nimbus.pb2.ProgressPhase.Name(p.phase))
                props.progress = 100.0 * p.done / p.total if p.total else 0.0
                props.status = (f"{nimbus.state_name(job.state).lower()} {phase} "
                                f"{p.done}/{p.total} {p.unit}".strip())
                if preview is not None and preview.path is not None:
                    self._show(scene, preview.path, final=False)
                    self.previews_loaded += 1
                    self.preview_dones.append(preview.done)
            elif kind == "result":
                job, path = ev[1], ev[2]
                self.result_path = path
                self._show(scene, path, final=True)
                props.progress = 100.0
                props.status = f"{job.id} done: {path.name}"
            elif kind == "error":
                self.error = ev[1]
                props.status = f"error: {ev[1]}"
            elif kind == "end":
                self.finished = True
                _redraw()
                return True
            _redraw()

    def _note_events(self, props, events):
        """Keeps the job's newest event-log lines in the panel: the kind (a
        phase event with its phase), then the worker it names."""
        if not events:
            return
        self.shown_events.extend(events)
        props.recent_events = "\n".join(
            " ".join(w for w in (e.kind, _phase_word(e.fields.get("phase", "")), e.worker) if w)
            for e in self.shown_events[-RECENT_EVENTS:])

    def _show(self, scene, path, final):
        if not self.object_name:
            obj = importer.ensure_volume_object(self.job_name or "nimbus", scene.collection)
            self.object_name = obj.name
        obj = bpy.data.objects[self.object_name]
        grid = "density"
        importer.load_into(obj, path, final=final, grid_name=grid)
        self.shown_files.append(obj.data.filepath)
        scene.nimbus.object_name = obj.name


def _phase_word(phase):
    """"iterating" for PROGRESS_PHASE_ITERATING."""
    return phase.replace("PROGRESS_PHASE_", "").lower()


def _ignore_errors(fn, *args):
    try:
        fn(*args)
    except Exception:
        pass  # the watch reports how the job ended


def _redraw():
    wm = getattr(bpy.context, "window_manager", None)
    for window in (wm.windows if wm else []):
        for area in window.screen.areas:
            area.tag_redraw()


def output_dir(props):
    """The add-on's output folder: the panel's, relative to the .blend file,
    or a temporary folder while the file is unsaved."""
    d = props.output_dir
    if d.startswith("//") and not bpy.data.filepath:
        return Path(tempfile.gettempdir()) / "nimbus-blender" / d[2:]
    return Path(bpy.path.abspath(d))


def start(scene):
    """Starts a job from the scene's panel settings; returns the session."""
    global _active
    props = scene.nimbus
    spec = bpy.path.abspath(props.spec_path)
    if not spec or not os.path.isfile(spec):
        raise FileNotFoundError(f"spec file not found: '{props.spec_path}'")
    if _active is not None and not _active.finished:
        raise RuntimeError(f"job {_active.job_id or '(submitting)'} is still running")
    _active = JobSession(props.server, spec, output_dir(props), props.preview_resolution,
                         props.preview_interval, props.priority).start()
    props.status = "submitting"
    props.progress = 0.0
    props.recent_events = ""
    return _active


def active():
    return _active


def pump_active(scene):
    """Pumps the active session; True when there is none or it is over."""
    return True if _active is None else _active.pump(scene)


def timer():
    """bpy.app.timers callback: keeps pumping while a job runs."""
    if pump_active(bpy.context.scene):
        return None
    return 0.2


def start_local_server(binary=None):
    """Starts (or returns the running) nimbusd on 127.0.0.1 with a free port."""
    global _local_server
    if _local_server is not None and _local_server.proc is not None \
            and _local_server.proc.poll() is None:
        return _local_server
    from nimbus.testing import LocalServer
    data_dir = Path(tempfile.gettempdir()) / "nimbus-blender" / "nimbusd-data"
    _local_server = LocalServer(binary=binary or None, data_dir=data_dir).start()
    return _local_server


def stop_local_server():
    global _local_server
    if _local_server is not None:
        _local_server.stop()
        _local_server = None
