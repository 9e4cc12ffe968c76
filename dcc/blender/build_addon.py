#!/usr/bin/python3
"""Builds nimbus_blender.zip, the Blender add-on with the nimbus package
(and its generated stubs) bundled, ready for Edit > Preferences > Add-ons >
Install, or `blender -b --python-expr` with bpy.ops.preferences.addon_install.

    /usr/bin/python3 dcc/blender/build_addon.py [-o nimbus_blender.zip]
"""

import argparse
import importlib.util
import sys
import tempfile
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent


def build(out):
    # Load python/install.py by path and restore sys.path afterwards, so a
    # caller inside Blender still imports nimbus from the installed add-on.
    saved = list(sys.path)
    try:
        spec = importlib.util.spec_from_file_location("nimbus_install",
                                                      REPO / "python" / "install.py")
        install = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(install)
    finally:
        sys.path[:] = saved
    out = Path(out)
    with tempfile.TemporaryDirectory() as tmp:
        vendor = Path(tmp) / "_vendor"
        install.install(vendor, REPO / "proto")
        with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as z:
            for f in sorted((HERE / "nimbus_blender").rglob("*.py")):
                z.write(f, Path("nimbus_blender") / f.relative_to(HERE / "nimbus_blender"))
            for f in sorted(vendor.rglob("*")):
                if f.is_file() and "__pycache__" not in f.parts:
                    z.write(f, Path("nimbus_blender") / "_vendor" / f.relative_to(vendor))
    return out


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("-o", "--output", default="nimbus_blender.zip")
    print(f"wrote {build(ap.parse_args().output)}")


if __name__ == "__main__":
    main()
