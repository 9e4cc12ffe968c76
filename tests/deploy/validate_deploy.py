"""Checks deploy/: every Kubernetes manifest parses as YAML and holds what
deploy/README.md promises (probes on grpc.health.v1, the database URL from
a Secret, a shared results volume, a dev PostgreSQL StatefulSet), and the
Containerfile is multi-stage on Debian bookworm with a non-root user.

    /usr/bin/python3 tests/deploy/validate_deploy.py deploy
"""
import pathlib
import sys
import unittest

import yaml

DEPLOY = pathlib.Path(sys.argv.pop(1) if len(sys.argv) > 1 else "deploy")


def documents():
    docs = {}
    for path in sorted((DEPLOY / "k8s").glob("*.yaml")):
        for doc in yaml.safe_load_all(path.read_text()):
            if doc and doc["kind"] != "Kustomization":
                docs[(doc["kind"], doc["metadata"]["name"])] = doc
    return docs


class Manifests(unittest.TestCase):
    docs = documents()

    def get(self, kind, name):
        self.assertIn((kind, name), self.docs, f"no {kind} {name} in deploy/k8s")
        return self.docs[(kind, name)]

    def test_every_document_has_api_version_kind_and_name(self):
        self.assertGreaterEqual(len(self.docs), 8)
        for (kind, name), doc in self.docs.items():
            self.assertIn("apiVersion", doc, name)

    def test_nimbusd_deployment(self):
        dep = self.get("Deployment", "nimbusd")
        self.assertEqual(dep["spec"]["replicas"], 3)
        pod = dep["spec"]["template"]["spec"]
        self.assertTrue(pod["securityContext"]["runAsNonRoot"])
        self.assertGreaterEqual(pod["terminationGracePeriodSeconds"], 15)
        (c,) = pod["containers"]
        self.assertEqual(c["readinessProbe"]["grpc"],
                         {"port": 50051, "service": "nimbus.v1.NimbusService"})
        self.assertEqual(c["livenessProbe"]["grpc"]["port"], 50051)
        env = {e["name"]: e for e in c["env"]}
        self.assertEqual(env["NIMBUS_STORE_URL"]["valueFrom"]["secretKeyRef"]["name"],
                         "nimbus-db")
        self.assertIn("--results-dir=/results", c["args"])
        self.assertIn("--replica-id=$(POD_NAME)", c["args"])
        mounts = {m["name"]: m["mountPath"] for m in c["volumeMounts"]}
        self.assertEqual(mounts["results"], "/results")
        vols = {v["name"]: v for v in pod["volumes"]}
        claim = vols["results"]["persistentVolumeClaim"]["claimName"]
        pvc = self.get("PersistentVolumeClaim", claim)
        self.assertEqual(pvc["spec"]["accessModes"], ["ReadWriteMany"])
        self.assertEqual(dep["spec"]["selector"]["matchLabels"],
                         dep["spec"]["template"]["metadata"]["labels"])

    def test_service_reaches_the_pods(self):
        svc = self.get("Service", "nimbusd")
        dep = self.get("Deployment", "nimbusd")
        self.assertEqual(svc["spec"]["selector"],
                         dep["spec"]["template"]["metadata"]["labels"])
        self.assertEqual(svc["spec"]["ports"][0]["port"], 50051)

    def test_secrets_and_dev_database(self):
        self.assertIn("url", self.get("Secret", "nimbus-db")["stringData"])
        self.assertIn("tokens", self.get("Secret", "nimbus-tokens")["stringData"])
        sts = self.get("StatefulSet", "nimbus-postgres")
        self.assertEqual(sts["spec"]["replicas"], 1)
        self.assertEqual(self.get("Service", "nimbus-postgres")["spec"]["ports"][0]["port"], 5432)
        text = (DEPLOY / "k8s" / "postgres-dev.yaml").read_text()
        self.assertIn("managed", text)

    def test_kustomization_lists_existing_files(self):
        kust = yaml.safe_load((DEPLOY / "k8s" / "kustomization.yaml").read_text())
        for res in kust["resources"]:
            self.assertTrue((DEPLOY / "k8s" / res).is_file(), res)


class Containerfile(unittest.TestCase):
    def test_multi_stage_debian_non_root(self):
        lines = [l.strip() for l in (DEPLOY / "Containerfile").read_text().splitlines()]
        froms = [l for l in lines if l.startswith("FROM ")]
        self.assertGreaterEqual(len(froms), 2)
        for f in froms:
            self.assertIn("debian:bookworm", f)
        self.assertTrue(any(l.startswith("COPY --from=build") for l in lines))
        users = [l for l in lines if l.startswith("USER ")]
        self.assertTrue(users and not users[-1].split()[1].startswith(("root", "0")))

    def test_smoke_script_is_executable_and_skips_cleanly(self):
        script = DEPLOY / "smoke_test.sh"
        self.assertTrue(script.stat().st_mode & 0o111)
        self.assertIn("SKIPPED", script.read_text())


if __name__ == "__main__":
    unittest.main(verbosity=2)
