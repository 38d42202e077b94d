#!/usr/bin/env python3
"""What the dashboard costs and how fresh it is: a farm (serve --http, 2 local workers of
1 thread) renders a long Cornell box job while 0, 1 and 10 dashboard pages are open in
headless Chromium for SECONDS each; prints the coordinator's CPU (user + system, from
/proc) in each window and, with pages open, the latency from a batch merged to its
image shown (median and p99 over every update of every page).

    python3 bench/dashboard.py [--seconds 20]

Needs target/release/{coordinator,worker}, /usr/bin/chromium and tests/dashboard's
node_modules (npm ci there)."""
import argparse
import json
import os
import socket
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
BIN = ROOT / "target/release"


def cpu_seconds(pid):
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=20)
    args = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="tilefarm-dashboard-bench-"))
    http = f"127.0.0.1:{free_port()}"
    coord = subprocess.Popen([BIN / "coordinator", "serve", "--listen", "127.0.0.1:0", "--http", http,
                              "--store", tmp / "store"], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    procs = [coord]
    try:
        url = coord.stdout.readline().split()[-1]
        for i in range(2):
            procs.append(subprocess.Popen([BIN / "worker", "--coordinator", url, "--threads", "1", "--cache",
                                           tmp / f"cache{i}"], stderr=subprocess.DEVNULL))
        subprocess.run([BIN / "coordinator", "submit", ROOT / "scenes/cornell-box/scene.toml", "--coordinator", url,
                        "--width", "256", "--spp", "100000", "--batch-spp", "2", "--tile", "32"], check=True,
                       stdout=subprocess.DEVNULL)
        time.sleep(3)
        for n in [0, 1, 10]:
            before = cpu_seconds(coord.pid)
            t0 = time.monotonic()
            if n == 0:
                time.sleep(args.seconds)
                lat = []
            else:
                out = subprocess.run(["node", ROOT / "bench/dashboard_pages.mjs", f"http://{http}/", str(n),
                                      str(args.seconds)], check=True, capture_output=True, text=True).stdout
                lat = json.loads(out)["latencies_ms"]
            used = cpu_seconds(coord.pid) - before
            wall = time.monotonic() - t0
            line = f"{n:>2} pages: coordinator CPU {used:.2f} s in {wall:.1f} s ({100 * used / wall:.1f}% of a core)"
            if lat:
                lat.sort()
                p99 = lat[min(len(lat) - 1, int(0.99 * len(lat)))]
                line += f"; merge to image {statistics.median(lat):.0f} ms median, {p99:.0f} ms p99 ({len(lat)} updates)"
            print(line, flush=True)
    finally:
        for p in procs:
            p.kill()


if __name__ == "__main__":
    main()
