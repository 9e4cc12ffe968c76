#!/usr/bin/python3
"""Watches a Nimbus job and prints its event log as it grows, with each
change of state: who claimed it, lost leases, requeues, retries, its end.

    PYTHONPATH=python python/examples/watch_events.py 127.0.0.1:50051 examples/tree.json
    PYTHONPATH=python python/examples/watch_events.py 127.0.0.1:50051 j-0123abcd

A spec file is submitted first; anything else is taken as a job id. Exits 0
when the job succeeded, 1 when it did not, 2 when a call failed.
"""

import argparse
import os
import sys

import nimbus


def watch(address, job_arg):
    with nimbus.Client(address) as client:
        job = client.submit(job_arg) if os.path.isfile(job_arg) else client.get(job_arg)
        print(f"watching {job.id} ({job.name})")
        state, last_seq = None, 0
        for ev in client.watch(job, events=True):
            for e in ev.events:
                print(e)  # seq, UTC time, kind, fields: as `nimbus events` prints them
                last_seq = e.seq
            if ev.state != state:
                state = ev.state
                print(f"      state {state}")
        # An event written after the end (a later "pinned") is not on the
        # watch; read whatever came after the last one shown.
        for e in client.events(job, after_seq=last_seq):
            print(e)
        return 0 if state == "SUCCEEDED" else 1


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("address", help="host:port of a nimbusd")
    ap.add_argument("job", help="a spec file to submit, or the id of a job to watch")
    args = ap.parse_args()
    try:
        return watch(args.address, args.job)
    except nimbus.NimbusError as e:
        print(f"watch_events: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
