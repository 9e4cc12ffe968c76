"""The nimbus Python client against a real nimbusd on loopback.

Run: /usr/bin/python3 -m unittest discover -s python/tests (with NIMBUSD set,
or nimbusd in build/bin); ctest runs it as python_client.
"""

import hashlib
import json
import shutil
import sys
import tempfile
import time
import unittest
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent.parent
sys.path.insert(0, str(REPO / "python"))

import grpc  # noqa: E402

import nimbus  # noqa: E402
from nimbus.testing import LocalServer, ServerTestCase  # noqa: E402

EXAMPLES = REPO / "examples"


def small_tree(resolution=(8, 64, 60), iterations=4_000_000):
    """examples/tree.json with a small grid and budget: runs in well under a second."""
    spec = json.loads((EXAMPLES / "tree.json").read_text())
    spec["grid"]["resolution"] = list(resolution)
    spec["chaos_game"]["iterations"] = str(iterations)
    return spec


def sha256(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


class ClientTest(ServerTestCase):
    def setUp(self):
        self.tmp = Path(tempfile.mkdtemp(prefix="nimbus-pytest-"))
        self.addCleanup(shutil.rmtree, self.tmp, True)

    def test_submit_get_list_and_wait(self):
        job = self.client.submit(small_tree())
        self.assertTrue(job.id)
        self.assertEqual(job.name, "tree")
        self.assertEqual(self.client.get(job.id).id, job.id)
        self.assertIn(job.id, [j.id for j in self.client.list()])
        final = self.client.wait(job)
        self.assertEqual(nimbus.state_name(final.state), "SUCCEEDED")
        self.assertIn(job.id, [j.id for j in self.client.list(state="SUCCEEDED")])
        self.assertEqual(final.result.file_name, "tree.vdb")
        self.assertEqual(len(final.result.sha256), 64)

    def test_text_format_spec_file(self):
        spec, _ = nimbus.load_spec(EXAMPLES / "sierpinski_tetrahedron.txtpb")
        spec.grid.ClearField("resolution")
        spec.grid.resolution.append(32)
        spec.chaos_game.iterations = 200_000
        out = self.tmp / "tet.vdb"
        r = self.client.render(spec, out)
        self.assertEqual(r.sha256, sha256(out))
        info = nimbus.vdb.read_info(out)
        self.assertEqual(info.grids[0].metadata["nimbus_resolution"], (32, 32, 32))
        self.assertEqual(info.grids[0].name, "density")
        self.assertEqual(info.grids[0].metadata["class"], "fog volume")

    def test_vdb_metadata_reader_agrees_with_pyopenvdb(self):
        try:
            import pyopenvdb
        except ImportError:
            self.skipTest("pyopenvdb (python3-openvdb) is not installed")
        out = self.tmp / "tree.vdb"
        self.client.render(small_tree(), out)
        grids, _ = pyopenvdb.readAll(str(out))
        info = nimbus.vdb.read_info(out)
        self.assertEqual([g.name for g in info.grids], [g.name for g in grids])
        ours = info.grids[0].metadata
        theirs = grids[0].metadata
        self.assertGreater(len(theirs), 10)
        for key, value in theirs.items():
            got = ours[key]
            if isinstance(value, float):
                self.assertAlmostEqual(got, value, msg=key)
            elif isinstance(value, (tuple, list)):
                for a, b in zip(got, value):
                    self.assertAlmostEqual(a, b, msg=key)
            else:
                self.assertEqual(got, value, key)

    def watch_until_previews(self, job, previews_dir, count, pause=0.0):
        """Watches a long job and cancels it once `count` previews are in:
        on a fast machine or a loaded one, the watcher sees that many
        previews before the job could end by itself. Returns the events."""
        import time
        events, seen = [], 0
        for ev in self.client.watch(job, previews_dir=previews_dir, preview_interval=0.05):
            events.append(ev)
            if ev.preview is not None:
                seen += 1
                if seen == count:
                    self.client.cancel(job)
                time.sleep(pause)
        return events

    def test_watch_saves_dense_previews_with_their_progress(self):
        total = 20_000_000_000
        job = self.client.submit(small_tree(iterations=total))
        previews_dir = self.tmp / "previews"
        events = self.watch_until_previews(job, previews_dir, 3)
        self.assertEqual(events[-1].state, "CANCELLED")
        previews = [e.preview for e in events if e.preview is not None]
        self.assertGreaterEqual(len(previews), 3)
        # Files are numbered 1..n in the order received; sequence numbers
        # only increase but may skip (the hub sends the newest one).
        self.assertEqual([p.index for p in previews], list(range(1, len(previews) + 1)))
        seqs = [p.sequence for p in previews]
        self.assertEqual(seqs, sorted(set(seqs)))
        names = sorted(f.name for f in previews_dir.glob("*.vdb"))
        self.assertEqual(names, [f"tree.preview.{i:04d}.vdb" for i in range(1, len(previews) + 1)])
        manifest = json.loads((previews_dir / "tree.previews.json").read_text())
        self.assertEqual(manifest["job_id"], job.id)
        self.assertEqual([m["done"] for m in manifest["previews"]], [p.done for p in previews])
        dones = [p.done for p in previews]
        self.assertEqual(dones, sorted(dones))
        self.assertTrue(all(0 < d < total for d in dones), dones)
        for p in previews:
            self.assertEqual(p.path.read_bytes(), p.vdb)
            self.assertEqual(p.vdb[:8], (0x56444220).to_bytes(8, "little"))  # VDB magic
            # The file itself says which preview of the wire it is.
            meta = nimbus.vdb.read_info(p.path).grids[0].metadata
            self.assertEqual(meta["nimbus_preview_sequence"], p.sequence)
            self.assertEqual(meta["nimbus_preview_done"], p.done)
        self.assertEqual(list(previews_dir.glob("*.tmp")), [])

        # Re-attaching to the ended job into the same folder ends at once
        # and leaves the saved previews as they were.
        again = list(self.client.watch(job, previews_dir=previews_dir))
        self.assertEqual(again[-1].state, "CANCELLED")
        for p in previews:
            self.assertEqual(p.path.read_bytes(), p.vdb)

    def test_slow_watcher_still_gets_dense_files(self):
        """A watcher that reads slowly: the hub may skip sequence numbers
        (whether it does depends on how much gRPC buffers, so the skipping
        itself is covered by PreviewSaverTest); the files stay 0001..n and
        each names the sequence it shows."""
        job = self.client.submit(small_tree(resolution=(16, 128, 120), iterations=20_000_000_000))
        previews_dir = self.tmp / "slow"
        events = self.watch_until_previews(job, previews_dir, 3, pause=0.25)
        previews = [e.preview for e in events if e.preview is not None]
        self.assertEqual(events[-1].state, "CANCELLED")
        self.assertGreaterEqual(len(previews), 3)
        names = sorted(f.name for f in previews_dir.glob("*.vdb"))
        self.assertEqual(names, [f"tree.preview.{i:04d}.vdb" for i in range(1, len(previews) + 1)])
        seqs = [nimbus.vdb.read_info(p.path).grids[0].metadata["nimbus_preview_sequence"]
                for p in previews]
        self.assertEqual(seqs, [p.sequence for p in previews])
        self.assertEqual(seqs, sorted(set(seqs)))
        print(f"slow watcher: {len(seqs)} files for sequences up to {seqs[-1]}", file=sys.stderr)

    def test_up_axis_half_float_and_suggested_density_metadata(self):
        spec = small_tree()
        spec["output"] = {"up_axis": "UP_AXIS_Z", "half_float": True}
        out = self.tmp / "tree_z.vdb"
        self.client.render(spec, out)
        g = nimbus.vdb.read_info(out).grids[0]
        self.assertTrue(g.half_float)
        self.assertEqual(g.metadata["nimbus_up_axis"], "Z")
        self.assertEqual(g.metadata["nimbus_downsample_factor"], 1)
        d = g.metadata["nimbus_suggested_density"]
        self.assertTrue(1.0 <= d <= 1000.0, d)

    def test_fetch_resumes_a_truncated_file_and_checks_sha256(self):
        final = self.client.wait(self.client.submit(small_tree(resolution=(16, 128, 120))))
        out = self.tmp / "tree.vdb"
        first = self.client.fetch(final, out)
        whole = out.read_bytes()
        self.assertEqual(first.resumed_from, 0)
        self.assertEqual(first.received, len(whole))
        self.assertEqual(first.sha256, final.result.sha256)
        self.assertEqual(sha256(out), final.result.sha256)
        self.assertGreater(len(whole), 1000)

        # A truncated download resumes from where it stopped.
        half = len(whole) // 2
        out.write_bytes(whole[:half])
        again = self.client.fetch(final.id, out)
        self.assertEqual(again.resumed_from, half)
        self.assertEqual(again.received, len(whole) - half)
        self.assertEqual(out.read_bytes(), whole)
        self.assertFalse(Path(str(out) + ".part").exists())

        # So does an interrupted one left in OUT.part.
        Path(str(out) + ".part").write_bytes(whole[:100])
        out.unlink()
        self.assertEqual(self.client.fetch(final, out).resumed_from, 100)
        self.assertEqual(out.read_bytes(), whole)

        # A partial file that is not a prefix of the result fails the sha256
        # check and is downloaded again from the start.
        out.write_bytes(b"x" * half)
        fixed = self.client.fetch(final, out)
        self.assertEqual(fixed.resumed_from, 0)
        self.assertEqual(out.read_bytes(), whole)

    def test_fetch_before_the_job_succeeded_is_failed_precondition(self):
        job = self.client.submit(small_tree(resolution=(32, 256, 240), iterations=4_000_000_000))
        try:
            with self.assertRaises(nimbus.NimbusError) as cm:
                self.client.fetch(job, self.tmp / "early.vdb")
            self.assertEqual(cm.exception.code, grpc.StatusCode.FAILED_PRECONDITION)
        finally:
            cancelled = self.client.cancel(job)
        final = self.client.wait(cancelled)
        self.assertEqual(nimbus.state_name(final.state), "CANCELLED")
        with self.assertRaises(nimbus.JobFailedError) as cm:
            nimbus.raise_for_job(final)
        self.assertEqual(cm.exception.code, grpc.StatusCode.CANCELLED)

    def test_poke_a_running_jelly_job(self):
        spec = json.loads((EXAMPLES / "jelly_sierpinski.json").read_text())
        spec["grid"]["resolution"] = [32]
        spec["jelly"].update(frames=2000, depth=8)
        job = self.client.submit(spec)
        try:
            for _ in range(600):
                if nimbus.state_name(self.client.get(job).state) == "RUNNING":
                    break
                time.sleep(0.05)
            resp = self.client.poke(job, 0, impulse=(2, 0, 0))
            self.assertGreater(resp.poke_id, 0)
            self.assertLess(resp.earliest_frame, 2000)
            with self.assertRaises(nimbus.NimbusError) as cm:
                self.client.poke(job, 4, drag_target=(0, 1, 0))
            self.assertEqual(cm.exception.code, grpc.StatusCode.INVALID_ARGUMENT)
            self.assertIn("push.body", str(cm.exception))
        finally:
            final = self.client.wait(self.client.cancel(job))
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.poke(final, 0, impulse=(1, 0, 0))
        self.assertEqual(cm.exception.code, grpc.StatusCode.FAILED_PRECONDITION)

    def test_mesh_assets_are_uploaded_and_pinned(self):
        spec = json.loads((EXAMPLES / "cow_cloud.json").read_text())
        spec["grid"]["resolution"] = [40]
        spec["set_ifs"]["random"]["iterations"] = "6"
        spec["set_ifs"]["random"]["warmup"] = 2
        spec_path = self.tmp / "cow_small.json"
        spec_path.write_text(json.dumps(spec))
        # Relative mesh paths resolve against the spec's folder, so point
        # this copy's base at examples/.
        job = self.client.submit(spec_path, base_dir=EXAMPLES)
        cow_sha = sha256(EXAMPLES / "meshes" / "cow.obj")
        stored = self.client.get(job).spec
        assets = []
        nimbus.for_each_asset(stored, lambda f, a: assets.append((f, a)))
        self.assertEqual([f for f, _ in assets],
                         ["set_ifs.maps[0].condensation.mesh.asset",
                          "set_ifs.maps[1].condensation.random_balls.inside.mesh.asset"])
        for _, a in assets:
            self.assertEqual(a.WhichOneof("source"), "sha256")
            self.assertEqual(a.sha256, cow_sha)
            self.assertEqual(a.label, "cow.obj")
        final = self.client.wait(job)
        self.assertEqual(nimbus.state_name(final.state), "SUCCEEDED", final.status.message)
        out = self.tmp / "cow.vdb"
        self.client.fetch(final, out)
        info = nimbus.vdb.read_info(out)
        self.assertEqual(info.grids[0].metadata["nimbus_resolution"][0], 40)

    def test_shaped_field_mesh_is_uploaded(self):
        spec = json.loads((EXAMPLES / "cumulus.json").read_text())
        spec["grid"]["resolution"] = [32]
        spec_path = self.tmp / "cumulus_small.json"
        spec_path.write_text(json.dumps(spec))
        job = self.client.submit(spec_path, base_dir=EXAMPLES)
        assets = []
        nimbus.for_each_asset(self.client.get(job).spec, lambda f, a: assets.append((f, a)))
        self.assertEqual([f for f, _ in assets], ["fractal_field.shape.source.mesh.asset"])
        self.assertEqual(assets[0][1].sha256, sha256(EXAMPLES / "meshes" / "suzanne.obj"))
        final = self.client.wait(job)
        self.assertEqual(nimbus.state_name(final.state), "SUCCEEDED", final.status.message)

    def test_missing_asset_names_its_field(self):
        spec = json.loads((EXAMPLES / "cow_cloud.json").read_text())
        spec["set_ifs"]["maps"][1]["condensation"]["random_balls"]["inside"]["mesh"]["asset"][
            "path"] = "meshes/no_such_mesh.obj"
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.submit(spec, base_dir=EXAMPLES)
        self.assertEqual(cm.exception.code, grpc.StatusCode.NOT_FOUND)
        self.assertEqual(cm.exception.field,
                         "set_ifs.maps[1].condensation.random_balls.inside.mesh.asset.path")
        self.assertIn("no_such_mesh.obj", cm.exception.details)

    def test_invalid_spec_error_carries_code_and_field_path(self):
        spec = small_tree()
        spec["grid"]["resolution"] = [8, 0, 60]
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.submit(spec)
        e = cm.exception
        self.assertEqual(e.code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertEqual(e.field, "grid.resolution[1]")
        self.assertIn("must be positive", e.details)

    def test_priority_is_kept_checked_and_retry_links_the_original(self):
        job = self.client.submit(small_tree(iterations=2_000_000_000), priority=80)
        self.assertEqual(job.priority, 80)
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.submit(small_tree(), priority=101)
        self.assertEqual(cm.exception.code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertIn("priority", cm.exception.details)
        cancelled = self.client.wait(self.client.cancel(job))
        self.assertEqual(nimbus.state_name(cancelled.state), "CANCELLED")
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.set_priority(job, 10)
        self.assertEqual(cm.exception.code, grpc.StatusCode.FAILED_PRECONDITION)
        again = self.client.retry(job)
        self.assertNotEqual(again.id, job.id)
        self.assertEqual(again.retried_from, job.id)
        self.assertEqual(again.priority, 80)
        self.client.wait(self.client.cancel(again))
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.retry(self.client.submit(small_tree(), priority=0))
        self.assertEqual(cm.exception.code, grpc.StatusCode.FAILED_PRECONDITION)

    def test_event_log_and_worker_registry(self):
        spec = small_tree()
        spec["no_cache"] = True  # a run of its own, not a copy of an earlier one
        job = self.client.submit(spec, priority=60)
        self.client.wait(job)
        events = self.client.events(job)
        kinds = [e.kind for e in events]
        self.assertEqual(kinds[0], "submitted")
        self.assertEqual(events[0].fields["priority"], "60")
        self.assertIn("claimed", kinds)
        self.assertEqual(kinds[-1], "succeeded")
        self.assertEqual(events[-1].fields["sha256"], self.client.get(job).result.sha256)
        self.assertEqual([e.seq for e in events], list(range(1, len(events) + 1)))
        workers = self.client.workers()
        self.assertEqual(len(workers), 1)
        self.assertFalse(workers[0].lost)
        self.assertGreaterEqual(workers[0].worker_slots, 1)

    def test_unknown_job_is_not_found(self):
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.get("j-does-not-exist")
        self.assertEqual(cm.exception.code, grpc.StatusCode.NOT_FOUND)
        self.assertIsNone(cm.exception.field)

    def test_unparseable_spec_is_invalid_argument_before_any_call(self):
        bad = self.tmp / "bad.json"
        bad.write_text('{"grid": {"resolutoin": [8]}}')
        with self.assertRaises(nimbus.NimbusError) as cm:
            self.client.submit(bad)
        self.assertEqual(cm.exception.code, grpc.StatusCode.INVALID_ARGUMENT)
        self.assertIn("resolutoin", cm.exception.details)


class PreviewSaverTest(unittest.TestCase):
    """The dense numbering on its own, with the sequence numbers a slow
    watcher sees (the hub skips to the newest; a re-attach repeats it)."""

    def test_dense_names_whatever_the_sequence(self):
        tmp = Path(tempfile.mkdtemp(prefix="nimbus-saver-"))
        self.addCleanup(shutil.rmtree, tmp, True)
        job = nimbus.pb2.Job(id="j-1", name="tree")
        saver = nimbus.PreviewSaver(tmp, "j-1")
        got = []
        for seq in [3, 5, 5, 9, 4, 12]:
            p = nimbus.pb2.Preview(sequence=seq, done=seq * 10, vdb=b"vdb%d" % seq)
            got.append(saver.add(job, p))
        saved = [g for g in got if g is not None]
        self.assertEqual([g.sequence for g in saved], [3, 5, 9, 12])
        self.assertEqual([g.index for g in saved], [1, 2, 3, 4])
        self.assertEqual(sorted(f.name for f in tmp.glob("*.vdb")),
                         [f"tree.preview.{i:04d}.vdb" for i in range(1, 5)])
        self.assertEqual((tmp / "tree.preview.0003.vdb").read_bytes(), b"vdb9")
        manifest = json.loads((tmp / "tree.previews.json").read_text())
        self.assertEqual([m["sequence"] for m in manifest["previews"]], [3, 5, 9, 12])
        # A second watch of the same job continues the numbering.
        again = nimbus.PreviewSaver(tmp, "j-1").add(job, nimbus.pb2.Preview(sequence=13))
        self.assertEqual(again.path.name, "tree.preview.0005.vdb")

    def test_preview_pictures_are_saved_beside_their_grids(self):
        tmp = Path(tempfile.mkdtemp(prefix="nimbus-saver-"))
        self.addCleanup(shutil.rmtree, tmp, True)
        job = nimbus.pb2.Job(id="j-2", name="arcs")
        saver = nimbus.PreviewSaver(tmp, "j-2")
        first = saver.add(job, nimbus.pb2.Preview(sequence=1, vdb=b"v1", png=b"\x89PNG1"))
        second = saver.add(job, nimbus.pb2.Preview(sequence=2, vdb=b"v2"))
        self.assertEqual(first.png_path.name, "arcs.preview.0001.png")
        self.assertEqual(first.png_path.read_bytes(), b"\x89PNG1")
        self.assertIsNone(second.png_path)  # a volume preview has no picture
        manifest = json.loads((tmp / "arcs.previews.json").read_text())
        self.assertEqual(manifest["previews"][0]["png"], "arcs.preview.0001.png")
        self.assertNotIn("png", manifest["previews"][1])


class FieldPathTest(unittest.TestCase):
    def test_parse(self):
        p = nimbus.parse_field_path
        self.assertEqual(p("grid.resolution[1]: must be positive, got 0"), "grid.resolution[1]")
        self.assertEqual(p("chaos_game.ifs.maps[2].steps[0].rotate.axis: must be non-zero"),
                         "chaos_game.ifs.maps[2].steps[0].rotate.axis")
        self.assertIsNone(p("server busy, retry later"))
        self.assertIsNone(p("no job j-1"))


class UnreachableServerTest(unittest.TestCase):
    def test_unavailable(self):
        with LocalServer() as srv:
            address = srv.address
        c = nimbus.Client(address, reconnect_timeout=0.5)
        c.timeout = 1.0
        with self.assertRaises(nimbus.NimbusError) as cm:
            c.get("j-x")
        self.assertIn(cm.exception.code, (grpc.StatusCode.UNAVAILABLE,
                                          grpc.StatusCode.DEADLINE_EXCEEDED))


if __name__ == "__main__":
    unittest.main()
