"""Nimbus in Houdini: render a spec on a nimbusd and load the result.

Needs the `nimbus` Python package (python/, see docs/dcc.md) importable by
Houdini's Python 3 with grpcio and protobuf. Untested here: no Houdini on
the build machines (docs/dcc.md says so too).

Python SOP (Type Properties > Code): add string parameters `spec` (a spec
file), `server` (host:port) and `output` (a .vdb path), then:

    import nimbus_houdini
    nimbus_houdini.cook_python_sop(hou.pwd())

Shelf tool (Script):

    import nimbus_houdini
    nimbus_houdini.shelf_tool()
"""

import hashlib
import os
from pathlib import Path

import hou  # noqa: F401  (provided by Houdini)
import nimbus


def _for_houdini(spec_path):
    """The spec as a JobSpec, written Y-up (Houdini's convention, Nimbus's
    default), whatever up axis the file asked for."""
    spec, base_dir = nimbus.load_spec(spec_path)
    spec.output.up_axis = nimbus.spec_pb2.UP_AXIS_Y
    return spec, base_dir


def render(spec_path, server, output, previews_dir=None, on_event=None):
    """Renders `spec_path` on `server` into `output` unless `output` already
    holds the result of this very spec (its sha256 sits beside it), so a
    re-cook does not render again. Returns the result's path."""
    spec, base_dir = _for_houdini(spec_path)
    key = hashlib.sha256(spec.SerializeToString(deterministic=True)).hexdigest()
    output = Path(output)
    stamp = output.with_suffix(output.suffix + ".spec-sha256")
    if output.is_file() and stamp.is_file() and stamp.read_text().strip() == key:
        return output
    output.parent.mkdir(parents=True, exist_ok=True)
    with nimbus.Client(server) as client:
        result = client.render(spec, output, previews_dir=previews_dir, base_dir=base_dir,
                               on_event=on_event)
    stamp.write_text(key + "\n")
    return result.path


def cook_python_sop(node):
    """Body of a Python SOP: render (or reuse) and load the VDB's grids as
    VDB primitives. Grid metadata (nimbus_suggested_density, ...) arrives as
    primitive attributes, as with a File SOP."""
    spec = node.evalParm("spec")
    server = node.evalParm("server") or "127.0.0.1:50051"
    output = node.evalParm("output") or os.path.join(
        hou.getenv("HIP", "."), "nimbus", Path(spec).stem + ".vdb")
    try:
        path = render(spec, server, output)
    except nimbus.NimbusError as e:
        where = f" ({e.field})" if e.field else ""
        raise hou.NodeError(f"Nimbus: {e.details}{where}")
    # Houdini's geometry readers open .vdb files as VDB primitives.
    node.geometry().loadFromFile(str(path))


def shelf_tool():
    """Asks for a spec and a server, renders with a progress window, and
    adds /obj/NAME with a File SOP reading the result."""
    spec = hou.ui.selectFile(title="Nimbus spec", pattern="*.json *.txtpb")
    if not spec:
        return
    spec = hou.expandString(spec)
    ok, server = hou.ui.readInput("nimbusd address", initial_contents="127.0.0.1:50051",
                                  buttons=("Render", "Cancel"))
    if ok != 0:
        return
    name = Path(spec).stem
    output = os.path.join(hou.getenv("HIP", "."), "nimbus", name + ".vdb")
    with hou.InterruptableOperation("Nimbus render", open_interrupt_dialog=True) as op:
        def on_event(ev):
            p = ev.job.progress
            if p.total:
                op.updateProgress(min(1.0, p.done / p.total))
        path = render(spec, server, output, on_event=on_event)
    geo = hou.node("/obj").createNode("geo", name)
    file_sop = geo.createNode("file", "nimbus_vdb")
    file_sop.parm("file").set(str(path))
    file_sop.setDisplayFlag(True)
    file_sop.setRenderFlag(True)
    geo.layoutChildren()
    return geo
