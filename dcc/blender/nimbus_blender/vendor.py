"""Finds the nimbus Python package for the add-on.

Order: the copy bundled into the add-on by dcc/blender/build_addon.py
(`_vendor/`), the folder named in the add-on preferences or $NIMBUS_PYTHON,
then the repository's python/ when the add-on runs from a source checkout.
Blender on Debian uses the system Python 3.11, so grpc and protobuf come
from python3-grpcio and python3-protobuf.
"""

import os
import sys
from pathlib import Path

_HERE = Path(__file__).resolve().parent


def candidates():
    out = [_HERE / "_vendor"]
    if os.environ.get("NIMBUS_PYTHON"):
        out.append(Path(os.environ["NIMBUS_PYTHON"]))
    out.append(_HERE.parent.parent.parent / "python")
    return out


def nimbus():
    try:
        import nimbus as mod  # already importable (installed, or added before)
        return mod
    except ImportError:
        pass
    for c in candidates():
        if (c / "nimbus" / "__init__.py").is_file():
            sys.path.insert(0, str(c))
            import nimbus as mod
            return mod
    raise ImportError("the nimbus Python package was not found in any of: " +
                      ", ".join(str(c) for c in candidates()) +
                      "; install the add-on zip made by dcc/blender/build_addon.py, "
                      "or set NIMBUS_PYTHON to the repository's python/ folder")
