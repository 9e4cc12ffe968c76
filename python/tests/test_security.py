"""The Python client against a nimbusd with TLS (a CA made by the test with
the openssl tool) and bearer tokens.

Run: /usr/bin/python3 -m unittest discover -s python/tests; ctest runs it as
part of python_client.
"""

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
import unittest
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent.parent
sys.path.insert(0, str(REPO / "python"))

import grpc  # noqa: E402

import nimbus  # noqa: E402
from nimbus.testing import LocalServer  # noqa: E402

ALICE = "alice-token-0123456789abcdef"
BOB = "bob-token-0123456789abcdef00"


def openssl(folder, *args):
    subprocess.run(["/usr/bin/openssl", *args], cwd=folder, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def make_pki(folder):
    """A CA and a server certificate for 127.0.0.1, P-256 keys."""
    ec = ["-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes"]
    openssl(folder, "req", "-x509", *ec, "-days", "2", "-subj", "/CN=test-ca", "-keyout",
            "ca.key", "-out", "ca.pem", "-addext", "basicConstraints=critical,CA:TRUE",
            "-addext", "keyUsage=critical,keyCertSign,cRLSign")
    openssl(folder, "req", *ec, "-subj", "/CN=localhost", "-keyout", "server.key", "-out",
            "server.csr")
    (folder / "server.ext").write_text("subjectAltName=IP:127.0.0.1,DNS:localhost\n"
                                       "extendedKeyUsage=serverAuth\n")
    openssl(folder, "x509", "-req", "-in", "server.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
            "-CAcreateserial", "-days", "2", "-out", "server.pem", "-extfile", "server.ext")


def small_job():
    spec = json.loads((REPO / "examples" / "sierpinski_tetrahedron.json").read_text())
    spec["grid"]["resolution"] = [16]
    spec["chaos_game"]["iterations"] = "100000"
    return spec


@unittest.skipUnless(Path("/usr/bin/openssl").exists(), "needs the openssl tool")
class SecurityTest(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        cls.tmp = Path(tempfile.mkdtemp(prefix="nimbus-pysec-"))
        make_pki(cls.tmp)
        tokens = cls.tmp / "tokens"
        tokens.write_text(f"{ALICE} alice\n{BOB} bob\n")
        os.chmod(tokens, 0o600)
        cls.server = LocalServer(extra_args=[
            "--tls-cert", str(cls.tmp / "server.pem"), "--tls-key", str(cls.tmp / "server.key"),
            "--auth-tokens", str(tokens), "--min-free-disk-mib", "0"]).start()

    @classmethod
    def tearDownClass(cls):
        cls.server.cleanup()
        shutil.rmtree(cls.tmp, True)

    def client(self, token):
        return nimbus.Client(self.server.address, tls_ca=self.tmp / "ca.pem", token=token,
                             timeout=20)

    def test_token_and_tls_round_trip(self):
        with self.client(ALICE) as c:
            job = c.submit(small_job())
            self.assertEqual(job.owner, "alice")
            final = c.wait(job)
            self.assertEqual(nimbus.state_name(final.state), "SUCCEEDED")
            out = self.tmp / "alice.vdb"
            r = c.fetch(job, out)
            self.assertEqual(r.sha256, hashlib.sha256(out.read_bytes()).hexdigest())
            pinned = c.pin(job)
            self.assertTrue(pinned.pinned)
        # Another principal does not see it.
        with self.client(BOB) as c:
            with self.assertRaises(nimbus.NimbusError) as err:
                c.get(job.id)
            self.assertEqual(err.exception.code, grpc.StatusCode.NOT_FOUND)
            self.assertNotIn(job.id, [j.id for j in c.list()])

    def test_missing_or_wrong_token_is_unauthenticated(self):
        for token in ("", "not-a-token-of-this-server"):
            with self.client(token) as c:
                with self.assertRaises(nimbus.NimbusError) as err:
                    c.list()
                self.assertEqual(err.exception.code, grpc.StatusCode.UNAUTHENTICATED)

    def test_unreadable_ca_is_named(self):
        with self.assertRaises(nimbus.NimbusError) as err:
            nimbus.Client(self.server.address, tls_ca=self.tmp / "missing.pem")
        self.assertIn("missing.pem", str(err.exception))


if __name__ == "__main__":
    unittest.main()
