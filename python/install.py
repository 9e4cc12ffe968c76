#!/usr/bin/python3
"""Installs the nimbus Python package with its generated gRPC stubs.

    /usr/bin/python3 python/install.py                 # into the user site dir
    /usr/bin/python3 python/install.py --target DIR    # into DIR (then PYTHONPATH=DIR)

Copies python/nimbus/, a copy of proto/nimbus/v1/*.proto (so the package can
regenerate its stubs) and the stubs protoc generates from them into
TARGET/nimbus/. Needs only Debian packages: python3-grpcio, python3-protobuf,
protobuf-compiler and protobuf-compiler-grpc (scripts/install_deps.sh).
The CMake target nimbus_python runs it with --target build/python.
"""

import argparse
import shutil
import site
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "nimbus"))
import _stubs  # noqa: E402  (the stub generator, without importing grpc)


def install(target, proto_dir=None):
    target = Path(target)
    src = HERE / "nimbus"
    dest = target / "nimbus"
    root = Path(proto_dir) if proto_dir else HERE.parent / "proto"
    with tempfile.TemporaryDirectory() as tmp:
        # Generate first: a failure leaves the old install untouched.
        _stubs.generate(Path(tmp) / "gen", root)
        staged = Path(tmp) / "nimbus"
        shutil.copytree(src, staged, ignore=shutil.ignore_patterns("__pycache__", "*.pyc"))
        shutil.copytree(Path(tmp) / "gen" / "nimbus" / "v1", staged / "v1")
        (staged / "proto" / "nimbus" / "v1").mkdir(parents=True)
        for f in _stubs.PROTO_FILES:
            shutil.copy2(root / "nimbus" / "v1" / f, staged / "proto" / "nimbus" / "v1" / f)
        target.mkdir(parents=True, exist_ok=True)
        if dest.exists():
            shutil.rmtree(dest)
        shutil.move(str(staged), str(dest))
    return dest


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--target", help="install into this folder (default: the user site dir, "
                    f"{site.getusersitepackages()})")
    ap.add_argument("--proto-dir", help="folder holding nimbus/v1/*.proto "
                    "(default: the repository's proto/)")
    args = ap.parse_args()
    try:
        dest = install(args.target or site.getusersitepackages(), args.proto_dir)
    except (_stubs.StubError, OSError) as e:
        sys.exit(f"install.py: {e}")
    print(f"installed the nimbus package in {dest}")


if __name__ == "__main__":
    main()
