"""The job event log through the Python client: Client.events (GetJobEvents)
and watch(events=True) against a real nimbusd, including a watch that
rides out a server restart.

Run: /usr/bin/python3 -m unittest discover -s python/tests (with NIMBUSD set,
or nimbusd in build/bin); ctest runs it as part of python_client.
"""

import json
import os
import subprocess
import sys
import tempfile
import unittest
from datetime import datetime, timezone
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent.parent
sys.path.insert(0, str(REPO / "python"))

import nimbus  # noqa: E402
from nimbus.testing import LocalServer, ServerTestCase  # noqa: E402

# Far more points than any machine grows before the test cancels the job.
LONG = 20_000_000_000


def tree(iterations):
    """examples/tree.json on a small grid, computed afresh (no cache hit)."""
    spec = json.loads((REPO / "examples" / "tree.json").read_text())
    spec["grid"]["resolution"] = [8, 64, 60]
    spec["chaos_game"]["iterations"] = str(iterations)
    spec["no_cache"] = True
    return spec


def logged(watch_events):
    """Every LogEvent the WatchEvents carried, in the order yielded."""
    return [e for ev in watch_events for e in ev.events]


def watch_and_cancel(client, job, until, on_event=None):
    """Watches `job` with its events and cancels it once until(log so far,
    WatchEvent) holds; returns the WatchEvents. The job is long, so it is
    still running whenever the condition comes true."""
    out, cancelled = [], False
    for ev in client.watch(job, events=True):
        out.append(ev)
        if on_event is not None:
            on_event(ev)
        if not cancelled and until(logged(out), ev):
            client.cancel(job)
            cancelled = True
    return out


class EventLogTest(ServerTestCase):
    def test_watch_yields_the_log_get_job_events_reads_and_ends_cancelled(self):
        job = self.client.submit(tree(LONG))
        running = []

        def note_running(ev):
            if ev.state == "RUNNING" and ev.job.worker:
                running.append(ev.job.worker)

        def iterating(log, ev):
            # The phase event may ride on a message whose job is still the
            # QUEUED snapshot, so wait for RUNNING too.
            return running and any(
                e.kind == "phase" and e.fields.get("phase") == "PROGRESS_PHASE_ITERATING"
                for e in log)

        events = watch_and_cancel(self.client, job, iterating, note_running)
        self.assertEqual(events[-1].state, "CANCELLED")
        watched = logged(events)
        # Read independently once the job has ended: the same events, each
        # once, in order.
        self.assertEqual(watched, self.client.events(job))
        self.assertEqual([e.seq for e in watched], list(range(1, len(watched) + 1)))
        kinds = [e.kind for e in watched]
        self.assertEqual(kinds[0], "submitted")
        self.assertEqual(kinds.count("claimed"), 1, kinds)
        self.assertLess(kinds.index("claimed"), kinds.index("cancel_requested"))
        # The end the worker recorded rides on the watch's last message.
        self.assertEqual([e.kind for e in events[-1].events][-1:], ["cancelled"])
        self.assertEqual(kinds[-1], "cancelled")
        claimed = watched[kinds.index("claimed")]
        self.assertEqual(claimed.fields["attempt"], "1")
        # The worker the claim names is the one the RUNNING job showed.
        self.assertTrue(running)
        self.assertEqual(claimed.worker, running[0])
        self.assertEqual(watched[-1].worker, running[0])
        self.assertEqual(watched[-1].fields["code"], "CANCELLED")
        times = [e.time for e in watched]
        self.assertEqual(times, sorted(times))
        self.assertTrue(all(t.tzinfo is timezone.utc for t in times))

    def test_watch_starts_after_events_after_seq(self):
        job = self.client.submit(tree(4_000_000))
        final = self.client.wait(job)
        self.assertEqual(nimbus.state_name(final.state), "SUCCEEDED")
        full = self.client.events(job)
        kinds = [e.kind for e in full]
        self.assertEqual((kinds[0], kinds[-1]), ("submitted", "succeeded"))
        self.assertGreaterEqual(len(full), 4)  # submitted, claimed, a phase, succeeded
        for after in (0, 1, len(full) - 1, len(full)):
            with self.subTest(after=after):
                watched = logged(self.client.watch(job, events=True, events_after_seq=after))
                self.assertEqual(watched, full[after:])
                self.assertEqual(self.client.events(job, after_seq=after), full[after:])
        # Without events=True no event is sent.
        self.assertEqual(logged(self.client.watch(job)), [])

    def test_render_passes_the_log_to_on_event(self):
        seen = []
        with tempfile.TemporaryDirectory() as tmp:
            result = self.client.render(tree(4_000_000), Path(tmp) / "tree.vdb", events=True,
                                        on_event=seen.append)
            self.assertTrue((Path(tmp) / "tree.vdb").is_file())
        watched = logged(seen)
        self.assertEqual(watched, self.client.events(result.job))
        self.assertEqual((watched[0].kind, watched[-1].kind), ("submitted", "succeeded"))
        # Without events=True, on_event sees no log.
        seen.clear()
        with tempfile.TemporaryDirectory() as tmp:
            self.client.render(tree(4_000_000), Path(tmp) / "tree.vdb", on_event=seen.append)
        self.assertTrue(seen)
        self.assertEqual(logged(seen), [])

    def test_the_example_prints_the_log(self):
        job = self.client.submit(tree(4_000_000))
        self.client.wait(job)
        env = dict(os.environ, PYTHONPATH=str(REPO / "python"))
        r = subprocess.run([sys.executable, str(REPO / "python" / "examples" / "watch_events.py"),
                            self.server.address, job.id],
                           env=env, capture_output=True, text=True, timeout=120)
        self.assertEqual(r.returncode, 0, r.stderr)
        lines = [line for line in r.stdout.splitlines() if not line.lstrip().startswith(
            ("watching", "state"))]
        self.assertEqual(lines, [str(e) for e in self.client.events(job)])


class RestartTest(unittest.TestCase):
    def test_a_watch_resumes_after_a_restart_without_repeating_an_event(self):
        with LocalServer() as srv:
            client = nimbus.Client(srv.address, reconnect_timeout=60)
            self.addCleanup(client.close)
            job = client.submit(tree(LONG))
            restarted = []

            def restart_once_claimed(log, ev):
                claims = [e for e in log if e.kind == "claimed"]
                if claims and not restarted:
                    # The generator waits here while the server goes away and
                    # comes back on the same port; the job is queued again.
                    srv.stop()
                    srv.start()
                    restarted.append(True)
                return len(claims) >= 2

            events = watch_and_cancel(client, job, restart_once_claimed)
            self.assertEqual(events[-1].state, "CANCELLED")
            watched = logged(events)
            self.assertEqual(watched, client.events(job))
            seqs = [e.seq for e in watched]
            self.assertEqual(seqs, list(range(1, len(watched) + 1)))
            kinds = [e.kind for e in watched]
            claims = [e for e in watched if e.kind == "claimed"]
            self.assertEqual([c.fields["attempt"] for c in claims], ["1", "2"])
            # Between the claims, the first worker's hold ended: released on a
            # clean stop, lease_lost (reason=restart) after an unclean one.
            first, second = (i for i, k in enumerate(kinds) if k == "claimed")
            between = kinds[first + 1:second]
            self.assertTrue({"released", "lease_lost"} & set(between), kinds)
            self.assertEqual(kinds[-1], "cancelled")
            print("after a restart: " + " ".join(kinds), file=sys.stderr)


class LogEventTest(unittest.TestCase):
    def test_from_proto_and_the_cli_line(self):
        when = datetime(2026, 11, 29, 3, 4, 5, 250000, tzinfo=timezone.utc)
        pb = nimbus.pb2.JobEvent(seq=7, kind="claimed",
                                 fields={"worker": "r1/w0", "attempt": "2", "empty": ""})
        pb.time.FromDatetime(when)
        e = nimbus.LogEvent.from_proto(pb)
        self.assertEqual((e.seq, e.kind, e.time), (7, "claimed", when))
        self.assertEqual(e.worker, "r1/w0")
        self.assertEqual(e.detail, "attempt=2")
        self.assertEqual(str(e),
                         "    7 2026-11-29T03:04:05Z claimed          attempt=2 worker=r1/w0")
        bare = nimbus.LogEvent.from_proto(nimbus.pb2.JobEvent(seq=1, kind="submitted"))
        self.assertEqual((bare.worker, bare.detail), ("", ""))


if __name__ == "__main__":
    unittest.main()
