#!/usr/bin/env python3
"""Straggler experiment: how long a job takes with one fast worker and one 4x slower one.

The slow worker is the same program stopped 75 % of the time (SIGSTOP / SIGCONT, a
quarter of each --cycle-ms running), so it renders at a quarter of the fast one's speed;
a long cycle also leaves its leased units standing still for seconds at a time. The
ideal farm finishes in 0.8x the fast worker's time alone (it does 4/5 of the work); a
farm that waits for the slow worker's last units takes longer. Prints medians of
alternated runs and the ratio to the ideal.

    cargo build --release
    python3 bench/stragglers.py [--runs 3] [--width 256] [--spp 256] [--cycle-ms 2000]
"""
import argparse
import os
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
BIN = os.path.join(ROOT, "target", "release")
SCENE = os.path.join(ROOT, "scenes", "cornell-box", "scene.toml")


def free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def throttle(proc, stop, cycle_s):
    """Keeps `proc` stopped 75 % of the time until `stop` is set."""
    run_s, pause_s = 0.25 * cycle_s, 0.75 * cycle_s
    while not stop.is_set():
        try:
            os.kill(proc.pid, signal.SIGSTOP)
            time.sleep(pause_s)
            os.kill(proc.pid, signal.SIGCONT)
            time.sleep(run_s)
        except ProcessLookupError:
            return
    try:
        os.kill(proc.pid, signal.SIGCONT)
    except ProcessLookupError:
        pass


def one_job(args, slow):
    """Seconds for one job on a fresh farm: a fast worker, and a throttled one if `slow`."""
    tmp = tempfile.mkdtemp(prefix="tilefarm-stragglers-")
    addr = f"127.0.0.1:{free_port()}"
    procs = []
    stop = threading.Event()
    try:
        serve = subprocess.Popen(
            [os.path.join(BIN, "coordinator"), "serve", "--listen", addr, "--store", os.path.join(tmp, "store")],
            stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        procs.append(serve)
        serve.stdout.readline()  # "listening on ..."
        def worker(name):
            p = subprocess.Popen(
                [os.path.join(BIN, "worker"), "--coordinator", addr, "--threads", "1",
                 "--cache", os.path.join(tmp, name)],
                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, stdin=subprocess.DEVNULL)
            procs.append(p)
            return p
        worker("fast")
        if slow:
            slow_worker = worker("slow")
            threading.Thread(target=throttle, args=(slow_worker, stop, args.cycle_ms / 1000), daemon=True).start()
        time.sleep(0.5)  # both registered
        out = os.path.join(tmp, "out.exr")
        start = time.monotonic()
        subprocess.run(
            [os.path.join(BIN, "coordinator"), "submit", SCENE, "--coordinator", addr, "--wait", "-q",
             "--width", str(args.width), "--spp", str(args.spp), "-o", out],
            check=True, stdout=subprocess.DEVNULL, timeout=600)
        return time.monotonic() - start
    finally:
        stop.set()
        for p in procs:
            try:
                os.kill(p.pid, signal.SIGCONT)
            except ProcessLookupError:
                pass
            p.kill()
            p.wait()
        subprocess.run(["rm", "-rf", tmp])


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3, help="alternated runs of each setup")
    ap.add_argument("--width", type=int, default=256)
    ap.add_argument("--spp", type=int, default=256)
    ap.add_argument("--cycle-ms", type=int, default=2000, help="the slow worker's run + stop cycle")
    args = ap.parse_args()
    alone, both = [], []
    for r in range(args.runs):
        alone.append(one_job(args, slow=False))
        both.append(one_job(args, slow=True))
        print(f"run {r + 1}: fast alone {alone[-1]:.2f} s, fast + slow {both[-1]:.2f} s", flush=True)
    a, b = statistics.median(alone), statistics.median(both)
    ideal = 0.8 * a
    print(f"median: fast alone {a:.2f} s; fast + slow {b:.2f} s = {b / a:.2f}x alone; "
          f"ideal {ideal:.2f} s; ratio to ideal {b / ideal:.2f} (goal <= 1.10)")


if __name__ == "__main__":
    sys.exit(main())
