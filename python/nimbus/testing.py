"""Starts a real nimbusd on loopback for tests and the Blender add-on's
"start a local server" button.

    with LocalServer() as srv:
        client = nimbus.Client(srv.address)
"""

import os
import shutil
import subprocess
import tempfile
import time
import unittest
from pathlib import Path

_REPO = Path(__file__).resolve().parent.parent.parent


def find_nimbusd():
    """$NIMBUSD, else nimbusd on PATH, else the repository's build/bin."""
    if os.environ.get("NIMBUSD"):
        return os.environ["NIMBUSD"]
    on_path = shutil.which("nimbusd")
    if on_path:
        return on_path
    p = _REPO / "build" / "bin" / "nimbusd"
    if p.is_file():
        return str(p)
    raise FileNotFoundError("no nimbusd: set NIMBUSD to the binary, put it on PATH, "
                            f"or build it into {_REPO / 'build' / 'bin'}")


class LocalServer:
    """A nimbusd on 127.0.0.1, on a port it picks itself (port 0), with its
    own data dir (a temporary one unless given). stop() ends it; start()
    after stop() starts it again on the same port and data dir (a restart
    its clients reconnect to)."""

    def __init__(self, binary=None, data_dir=None, extra_args=(), start_timeout=30.0,
                 log_path=None):
        self.binary = binary or find_nimbusd()
        self._own_dir = data_dir is None
        self.data_dir = Path(data_dir or tempfile.mkdtemp(prefix="nimbusd-"))
        self.extra_args = list(extra_args)
        self.start_timeout = start_timeout
        self.log_path = Path(log_path) if log_path else self.data_dir / "nimbusd.log"
        self.proc = None
        self.port = None

    @property
    def address(self):
        return f"127.0.0.1:{self.port}"

    def start(self):
        self.data_dir.mkdir(parents=True, exist_ok=True)
        port_file = self.data_dir / "port"
        port_file.unlink(missing_ok=True)
        self._log = open(self.log_path, "ab")
        self.proc = subprocess.Popen(
            [self.binary, "--listen", f"127.0.0.1:{self.port or 0}",
             "--port-file", str(port_file),
             "--data-dir", str(self.data_dir), *self.extra_args],
            stdout=self._log, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + self.start_timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"nimbusd exited with {self.proc.returncode} before "
                                   f"listening; log: {self.log_path}\n{self.log_tail()}")
            text = port_file.read_text().strip() if port_file.exists() else ""
            if text.isdigit():
                self.port = int(text)
                return self
            time.sleep(0.05)
        self.stop()
        raise TimeoutError(f"nimbusd wrote no port file within {self.start_timeout} s; "
                           f"log: {self.log_path}")

    def log_tail(self, n=2000):
        try:
            return self.log_path.read_bytes()[-n:].decode("utf-8", "replace")
        except OSError:
            return ""

    def stop(self):
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None
        if getattr(self, "_log", None):
            self._log.close()
            self._log = None

    def cleanup(self):
        """Stops the server and removes a data dir it made itself."""
        self.stop()
        if self._own_dir:
            shutil.rmtree(self.data_dir, ignore_errors=True)

    def __enter__(self):
        return self.start()

    def __exit__(self, *exc):
        self.cleanup()


class ServerTestCase(unittest.TestCase):
    """A test case class whose tests share one LocalServer (cls.server) and
    a Client of it (cls.client), started before the first test and stopped
    after the last."""

    @classmethod
    def setUpClass(cls):
        from .client import Client
        cls.server = LocalServer().start()
        cls.client = Client(cls.server.address)

    @classmethod
    def tearDownClass(cls):
        cls.client.close()
        cls.server.cleanup()
