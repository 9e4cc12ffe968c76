"""Checks deploy/: every Kubernetes manifest parses as YAML and holds what
deploy/README.md promises (probes on grpc.health.v1, the database URL from
a Secret, a shared results volume, a dev PostgreSQL StatefulSet), the
Containerfile is multi-stage on Debian bookworm with a non-root user, and
the manifests run the images as deploy/compose.sh (the tested containers)
does: the same users, volumes, read-only root and health service.

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


def instructions(path):
    """The Containerfile's instructions, continuation lines joined."""
    text = path.read_text().replace("\\\n", " ")
    return [l.strip() for l in text.splitlines() if l.strip() and not l.strip().startswith("#")]


def last_user(path):
    users = [l.split()[1] for l in instructions(path) if l.startswith("USER ")]
    return int(users[-1].split(":")[0])


class Containerfile(unittest.TestCase):
    def test_multi_stage_debian_non_root(self):
        lines = instructions(DEPLOY / "Containerfile")
        self.assertIn("ARG BASE=docker.io/library/debian:bookworm", lines)
        froms = [l for l in lines if l.startswith("FROM ")]
        self.assertGreaterEqual(len(froms), 2)
        for f in froms:
            self.assertEqual(f.split()[1], "${BASE}", f)
        self.assertTrue(any(l.startswith("COPY --from=build") for l in lines))
        self.assertNotEqual(last_user(DEPLOY / "Containerfile"), 0)

    def test_container_scripts_are_executable_and_never_skip(self):
        for name in ("build_image.sh", "compose.sh", "test_containers.sh"):
            script = DEPLOY / name
            self.assertTrue(script.stat().st_mode & 0o111, name)
        self.assertNotIn("SKIPPED", (DEPLOY / "test_containers.sh").read_text().replace(
            "never reports SKIPPED", ""))


class ManifestsMatchTheTestedContainers(unittest.TestCase):
    docs = documents()
    compose = (DEPLOY / "compose.sh").read_text()

    def pod(self, kind, name):
        return self.docs[(kind, name)]["spec"]["template"]["spec"]

    def test_nimbusd_user_volumes_and_read_only_root(self):
        pod = self.pod("Deployment", "nimbusd")
        self.assertEqual(pod["securityContext"]["runAsUser"], last_user(DEPLOY / "Containerfile"))
        (c,) = pod["containers"]
        self.assertTrue(c["securityContext"]["readOnlyRootFilesystem"])
        mounts = sorted(m["mountPath"] for m in c["volumeMounts"])
        self.assertEqual(mounts, ["/results", "/tmp", "/var/lib/nimbus"])
        volume_line = [l for l in instructions(DEPLOY / "Containerfile") if l.startswith("VOLUME")]
        for path in ("/results", "/var/lib/nimbus"):
            self.assertIn(f'"{path}"', volume_line[0])
            self.assertIn(f':{path}"', self.compose)
        self.assertIn("--tmpfs /tmp:", self.compose)
        self.assertIn("--read-only", self.compose)
        for arg in ("--data-dir=/var/lib/nimbus", "--results-dir=/results"):
            self.assertIn(arg, c["args"])
            self.assertIn(arg.replace("=", " "), self.compose)

    def test_same_health_service_and_store_variable(self):
        (c,) = self.pod("Deployment", "nimbusd")["containers"]
        service = c["readinessProbe"]["grpc"]["service"]
        self.assertIn(f"health_service={service}", self.compose)
        self.assertIn("NIMBUS_STORE_URL=", self.compose)
        self.assertIn("NIMBUS_STORE_URL", {e["name"] for e in c["env"]})

    def test_dev_postgres_runs_the_image_of_deploy_postgres(self):
        pod = self.pod("StatefulSet", "nimbus-postgres")
        self.assertEqual(pod["securityContext"]["runAsUser"],
                         last_user(DEPLOY / "postgres" / "Containerfile"))
        (c,) = pod["containers"]
        self.assertTrue(c["image"].startswith("nimbus-postgres:"))
        env = {e["name"] for e in c["env"]}
        self.assertLessEqual({"NIMBUS_DB_PASSWORD", "NIMBUS_DB_LISTEN"}, env)
        entrypoint = (DEPLOY / "postgres" / "entrypoint.sh").read_text()
        for name in env:
            self.assertIn(f"${name}", entrypoint.replace("{", "").replace("}", ""))


if __name__ == "__main__":
    unittest.main(verbosity=2)
