#!/usr/bin/env python3
"""Fan-out through a two-relay tree (issue 18, BENCHMARKS.md).

For each subscriber count K: two clustered moq-relay processes sharing one
certificate (relay b dials relay a), `psao serve --publish` on the default
scene publishing to relay a (the origin), and one `psao view --subscribe
... --subscribers K` process whose subscribers start half on each relay.
It measures, over the load process's run, the CPU of the origin, of each
relay and of the subscribers' process (from /proc), the broadcast's bit
rate at the origin (its status lines), and what `psao view` reports: how
many are in sync at the end, join times, bytes per subscriber. With
--direct it also runs a direct session (`psao serve` and `psao view
--connect`) for the join time and bytes of one direct client, side by side
with one subscriber through the relays.

Usage: scripts/relay-bench.py [--psao target/release/psao] [--relay moq-relay]
       [--counts 1,10,100,200] [--seconds 20] [--direct] [--group-seconds T]
"""

import argparse
import os
import re
import shutil
import socket
import subprocess
import sys
import tempfile
import time

TICK = os.sysconf("SC_CLK_TCK")


def cpu_seconds(pid):
    with open(f"/proc/{pid}/stat") as f:
        rest = f.read().rsplit(")", 1)[1].split()
    return (int(rest[11]) + int(rest[12])) / TICK


def rss_mb(pid):
    with open(f"/proc/{pid}/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    return 0.0


def free_port():
    while True:
        u = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        u.bind(("127.0.0.1", 0))
        port = u.getsockname()[1]
        t = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            t.bind(("127.0.0.1", port))
            return port
        except OSError:
            continue
        finally:
            u.close()
            t.close()


def wait_for(path, pattern, proc, seconds=120):
    until = time.time() + seconds
    while time.time() < until:
        text = open(path).read()
        m = re.search(pattern, text)
        if m:
            return m
        if proc.poll() is not None:
            sys.exit(f"{proc.args[0]} exited; its log {path}:\n{text[-3000:]}")
        time.sleep(0.2)
    sys.exit(f"timed out waiting for {pattern!r} in {path}")


def start_relay(relay, cert, key, log, peer=None, fp=None):
    port = free_port()
    args = [relay, "--listen", f"127.0.0.1:{port}", "--listen-tls-cert", cert,
            "--listen-tls-key", key, "--web-http-listen", f"127.0.0.1:{port}",
            "--auth-public", "**"]
    if peer:
        args += ["--cluster-connect", f"https://127.0.0.1:{peer}/", "--connect-tls-fingerprint", fp]
    p = subprocess.Popen(args, stdout=open(log, "w"), stderr=subprocess.STDOUT)
    for _ in range(200):
        try:
            s = socket.create_connection(("127.0.0.1", port), timeout=1)
            s.sendall(b"GET /certificate.sha256 HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            body = s.makefile("rb").read().decode().split("\r\n\r\n", 1)[1].strip()
            s.close()
            if len(body.replace(":", "")) == 64:
                return p, port, body.replace(":", "")
        except OSError:
            pass
        time.sleep(0.05)
    sys.exit(f"moq-relay did not come up; {log}")


def mean_relay_mbit(log):
    vals = [float(x) for x in re.findall(r"relay: up, ([0-9.]+) Mbit/s", open(log).read())]
    vals = vals[2:] or vals  # past the first seconds
    return sum(vals) / max(len(vals), 1)


def run_count(a, k, tmp, seconds):
    psao, relay = a.psao, a.relay
    cert, key = os.path.join(tmp, "cert", "cert.pem"), os.path.join(tmp, "cert", "key.pem")
    ra, pa, fp = start_relay(relay, cert, key, os.path.join(tmp, f"a{k}.log"))
    rb, pb, _ = start_relay(relay, cert, key, os.path.join(tmp, f"b{k}.log"), peer=pa, fp=fp)
    serve_log = os.path.join(tmp, f"serve{k}.log")
    origin = subprocess.Popen([psao, "serve", "--bind", f"127.0.0.1:{free_port()}",
                               "--publish", f"https://127.0.0.1:{pa}/", "--relay-fingerprint", fp,
                               "--group-seconds", str(a.group_seconds)],
                              stdout=open(serve_log, "w"), stderr=subprocess.STDOUT)
    try:
        wait_for(serve_log, r"publishing broadcast", origin, 300)
        time.sleep(2)
        view_log = os.path.join(tmp, f"view{k}.log")
        t0 = {p.pid: cpu_seconds(p.pid) for p in (origin, ra, rb)}
        rss0 = {p.pid: rss_mb(p.pid) for p in (origin, ra, rb)}
        w0 = time.time()
        serve_lines0 = len(open(serve_log).read().splitlines())
        view = subprocess.Popen([psao, "view", "--subscribe", f"https://127.0.0.1:{pa}/psao/default",
                                 "--subscribe", f"https://127.0.0.1:{pb}/psao/default",
                                 "--fingerprint", fp, "--subscribers", str(k), "--seconds", str(seconds)],
                                stdout=open(view_log, "w"), stderr=subprocess.STDOUT)
        load_cpu = 0.0
        while view.poll() is None:
            try:
                load_cpu = cpu_seconds(view.pid)
            except OSError:
                pass
            time.sleep(0.25)
        wall = time.time() - w0
        cpu = {p.pid: (cpu_seconds(p.pid) - t0[p.pid]) / wall * 100 for p in (origin, ra, rb)}
        rss = {p.pid: rss_mb(p.pid) - rss0[p.pid] for p in (origin, ra, rb)}
        text = open(view_log).read()
        if view.returncode != 0:
            sys.exit(f"psao view failed:\n{text[-3000:]}")
        lines = open(serve_log).read().splitlines()[serve_lines0:]
        fps = [float(m.group(1)) for m in (re.match(r"\s*([0-9.]+) fps", l) for l in lines) if m]
        mbit = [float(x) for x in re.findall(r"relay: up, ([0-9.]+) Mbit/s", "\n".join(lines))]
        insync = re.search(r"in sync\s+(\d+) of (\d+)", text)
        joined = re.search(r"joined\s+(\d+) of \d+: (.*) after", text)
        recv = re.search(r"received\s+.* per subscriber \(([0-9.]+) Mbit/s\)", text)
        row = {
            "K": k,
            "T s": a.group_seconds,
            "in sync": f"{insync.group(1)}/{insync.group(2)}" if insync else "?",
            "join": joined.group(2) if joined else "?",
            "Mbit/s per subscriber": recv.group(1) if recv else "?",
            "origin fps": f"{min(fps):.1f}-{max(fps):.1f}" if fps else "?",
            "origin CPU %": f"{cpu[origin.pid]:.0f}",
            "origin broadcast Mbit/s": f"{sum(mbit) / max(len(mbit), 1):.3f}",
            "origin RSS growth MB": f"{rss[origin.pid]:+.1f}",
            "relay a CPU %": f"{cpu[ra.pid]:.0f}",
            "relay b CPU %": f"{cpu[rb.pid]:.0f}",
            "subscribers' process CPU %": f"{load_cpu / wall * 100:.0f}",
        }
        return row
    finally:
        for p in (origin, rb, ra):
            p.terminate()
            p.wait()


def run_direct(a, tmp, seconds):
    serve_log = os.path.join(tmp, "direct-serve.log")
    port = free_port()
    origin = subprocess.Popen([a.psao, "serve", "--bind", f"127.0.0.1:{port}"],
                              stdout=open(serve_log, "w"), stderr=subprocess.STDOUT)
    try:
        fp = wait_for(serve_log, r"certificate SHA-256 ([0-9a-f]+)", origin, 300).group(1)
        time.sleep(2)
        out = subprocess.run([a.psao, "view", "--connect", f"127.0.0.1:{port}", "--fingerprint", fp,
                              "--seconds", str(seconds)], capture_output=True, text=True, check=True).stdout
        joined = re.search(r"joined\s+([0-9]+) ms", out)
        recv = re.search(r"received\s+.*\(([0-9.]+) Mbit/s\)", out)
        return {"K": "1 direct", "join": f"{joined.group(1)} ms" if joined else "?",
                "Mbit/s per subscriber": recv.group(1) if recv else "?"}
    finally:
        origin.terminate()
        origin.wait()


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--psao", default="target/release/psao")
    ap.add_argument("--relay", default=os.environ.get("PSAO_MOQ_RELAY") or shutil.which("moq-relay"))
    ap.add_argument("--counts", default="1,10,100,200")
    ap.add_argument("--seconds", type=int, default=20)
    ap.add_argument("--direct", action="store_true")
    ap.add_argument("--group-seconds", type=float, default=2.0,
                    help="the publisher's T (psao serve --group-seconds)")
    a = ap.parse_args()
    if not a.relay:
        sys.exit("no moq-relay: --relay PATH or PSAO_MOQ_RELAY")
    tmp = tempfile.mkdtemp(prefix="psao-relay-bench-")
    # The certificate alone in its directory: moq-relay reloads it at every
    # change in that directory (the logs beside it would make it loop).
    os.mkdir(os.path.join(tmp, "cert"))
    subprocess.run(["openssl", "req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
                    "-nodes", "-subj", "/CN=localhost", "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
                    "-days", "2", "-keyout", os.path.join(tmp, "cert", "key.pem"), "-out", os.path.join(tmp, "cert", "cert.pem")],
                   check=True, capture_output=True)
    rows = []
    if a.direct:
        rows.append(run_direct(a, tmp, a.seconds))
        print(rows[-1], flush=True)
    for k in [int(x) for x in a.counts.split(",")]:
        rows.append(run_count(a, k, tmp, a.seconds))
        print(rows[-1], flush=True)
    cols = list(rows[-1].keys())
    print()
    print("| " + " | ".join(cols) + " |")
    print("|" + "---|" * len(cols))
    for r in rows:
        print("| " + " | ".join(str(r.get(c, "")) for c in cols) + " |")
    print(f"\n(logs in {tmp})")


if __name__ == "__main__":
    main()
