#!/usr/bin/python3
"""ctest entry of the Blender add-on test: runs test_addon.py inside a
headless Blender with a throw-away user config, so installing the add-on
never touches the user's own Blender set-up. Exit 77 (ctest: skipped) when
blender is not installed."""

import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main():
    blender = os.environ.get("BLENDER") or shutil.which("blender")
    if not blender:
        print("SKIPPED: blender is not installed (apt-get install blender, "
              "or scripts/install_deps.sh)")
        return 77
    with tempfile.TemporaryDirectory(prefix="nimbus-blender-home-") as home:
        env = dict(os.environ)
        env["BLENDER_USER_SCRIPTS"] = str(Path(home) / "scripts")
        env["BLENDER_USER_CONFIG"] = str(Path(home) / "config")
        # The add-on's local nimbusd keeps its jobs under the temp folder:
        # a private one, so parallel runs (other checkouts, other builds'
        # job-store schemas) never share a database.
        env["TMPDIR"] = home
        # The add-on must find nimbus in its own bundle, not through the
        # caller's environment.
        env.pop("PYTHONPATH", None)
        env.pop("NIMBUS_PYTHON", None)
        cmd = [blender, "-b", "--factory-startup", "--python-exit-code", "1",
               "--python", str(HERE / "test_addon.py")]
        r = subprocess.run(cmd, env=env, timeout=900)
        return r.returncode


if __name__ == "__main__":
    sys.exit(main())
