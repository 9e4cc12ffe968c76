#!/usr/bin/env python3
"""The cost of watching a running job through the HTTP port: a chaos-game
job's rate (points/s) alone, then with 50 open event streams (previews at
64 voxels every second, as 50 open console pages ask) and a /metrics scrape
every second, alternating so that drift from other load shows.

Usage: bench/http_observers_bench.py build/bin/nimbusd [SECONDS_PER_WINDOW]
Prints one line per window and the overhead: 1 - rate(observed)/rate(alone).
"""
import json, os, subprocess, sys, tempfile, threading, time, urllib.request

NIMBUSD = sys.argv[1]
WINDOW = float(sys.argv[2]) if len(sys.argv) > 2 else 20.0
SRC = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def get(url):
    with urllib.request.urlopen(url, timeout=30) as r:
        return r.read()


def post(url, body):
    req = urllib.request.Request(url, data=json.dumps(body).encode(),
                                 headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(req, timeout=30) as r:
        return json.load(r)


def done(base, job):
    return int(json.loads(get(f"{base}/api/v1/jobs/{job}"))["job"]["progress"]["done"])


def cpu_seconds(pid):
    fields = open(f"/proc/{pid}/stat").read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def rate(base, job, seconds, pid):
    # Progress is stored at each heartbeat: wait for a change at each end.
    d0 = done(base, job)
    while (d1 := done(base, job)) == d0:
        time.sleep(0.02)
    t1 = time.monotonic()
    c1 = cpu_seconds(pid)
    time.sleep(seconds)
    cpu = cpu_seconds(pid) - c1
    d2 = done(base, job)
    while (d3 := done(base, job)) == d2:
        time.sleep(0.02)
    wall = time.monotonic() - t1
    return (d3 - d1) / wall, cpu / wall


def observe(base, job, stop):
    def stream():
        with urllib.request.urlopen(
                f"{base}/api/v1/jobs/{job}/stream?preview_resolution=64&preview_interval=1",
                timeout=600) as r:
            while not stop.is_set():
                line = r.readline()
                if not line:
                    return
                if line.startswith(b"event: preview"):
                    pass

    def scrape():
        while not stop.wait(1.0):
            get(f"{base}/metrics")

    threads = [threading.Thread(target=stream, daemon=True) for _ in range(50)]
    threads.append(threading.Thread(target=scrape, daemon=True))
    for t in threads:
        t.start()
    return threads


def main():
    d = tempfile.mkdtemp()
    proc = subprocess.Popen([NIMBUSD, "--listen", "127.0.0.1:0", "--port-file", f"{d}/port",
                             "--http", "127.0.0.1:0", "--http-port-file", f"{d}/http_port",
                             "--data-dir", f"{d}/data", "--workers", "1", "--threads-per-job", "1",
                             "--heartbeat-ms", "500", "--min-free-disk-mib", "0",
                             "--log-level", "warn"])
    try:
        while not os.path.exists(f"{d}/port"):
            time.sleep(0.05)
        base = "http://127.0.0.1:" + open(f"{d}/http_port").read().strip()
        spec = json.load(open(f"{SRC}/examples/sierpinski_tetrahedron.json"))
        spec["grid"]["resolution"] = [128]
        spec["chaos_game"]["iterations"] = str(2 ** 39)
        job = post(f"{base}/api/v1/jobs", {"spec": spec})["job"]["id"]
        while done(base, job) == 0:
            time.sleep(0.1)
        alone, watched, cpu_alone, cpu_watched = [], [], [], []
        for _ in range(2):
            r, c = rate(base, job, WINDOW, proc.pid)
            alone.append(r)
            cpu_alone.append(c)
            print(f"alone:    {r:.4g} points/s, nimbusd {c:.3f} CPUs", flush=True)
            stop = threading.Event()
            observe(base, job, stop)
            time.sleep(2)
            r, c = rate(base, job, WINDOW, proc.pid)
            watched.append(r)
            cpu_watched.append(c)
            print(f"observed: {r:.4g} points/s, nimbusd {c:.3f} CPUs (50 streams + 1 scrape/s)",
                  flush=True)
            stop.set()
            time.sleep(2)
        a, w = sum(alone) / len(alone), sum(watched) / len(watched)
        ca, cw = sum(cpu_alone) / 2, sum(cpu_watched) / 2
        print(f"http_observers: rate change {100 * (1 - w / a):.2f} % "
              f"(alone {a:.4g}, observed {w:.4g} points/s, one job thread); "
              f"observer CPU {100 * (cw / w - ca / a) * a / ca:.2f} % of the job's CPU per point")
        post(f"{base}/api/v1/jobs/{job}/cancel", {})
    finally:
        proc.terminate()
        proc.wait()


main()
