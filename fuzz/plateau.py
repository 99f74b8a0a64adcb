#!/usr/bin/env python3
"""Run one libFuzzer binary until its coverage plateaus, and say how flat it was.

A plateau here is: no new edge (`cov`) for `--quiet-min` minutes of wall time, after at
least `--min-min` minutes. The run also stops at `--max-min`, plateau or not; the summary
says which. The rule is fixed before the run, not fitted to it.

    python3 plateau.py target/x86_64-unknown-linux-gnu/release/scene_file corpus/scene_file \
        --log /tmp/scene_file.log -- -dict=dicts/toml.dict

Prints one JSON line: executions, exec/s, final cov/ft, cov at half and three quarters of
the wall time, when the last new edge came, and whether it stopped on a plateau.
Everything after `--` goes to libFuzzer unchanged (a dictionary, `-rss_limit_mb`, ...).
"""

import argparse
import json
import re
import signal
import subprocess
import sys
import threading
import time

STAT = re.compile(r"^#(\d+)\s+(\w+)\s+cov: (\d+) ft: (\d+)(?:.*?exec/s: (\d+))?")
FINAL = re.compile(r"^stat::(\w+):\s+(\d+)")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("binary")
    ap.add_argument("corpus")
    ap.add_argument("--min-min", type=float, default=15.0)
    ap.add_argument("--quiet-min", type=float, default=10.0)
    ap.add_argument("--max-min", type=float, default=60.0)
    ap.add_argument("--log", required=True)
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1:] if "--" in argv else []
    a = ap.parse_args(argv[:argv.index("--")] if "--" in argv else argv)

    cmd = [a.binary, a.corpus, "-print_final_stats=1", "-rss_limit_mb=2048"]
    cmd += extra
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL,
                            text=True, errors="replace")
    samples = []  # (seconds, execs, cov, ft)
    final = {}
    state = {"last_new_cov_s": 0.0, "start_cov": None}
    lock = threading.Lock()

    def read(log):
        for line in proc.stderr:
            now = time.monotonic() - t0
            log.write(f"{now:9.1f} {line}")
            m = STAT.match(line)
            f = FINAL.match(line)
            with lock:
                if m:
                    execs, kind, cov, ft = int(m[1]), m[2], int(m[3]), int(m[4])
                    if kind in ("INITED", "DONE") and state["start_cov"] is None:
                        state["start_cov"] = cov
                    if samples and cov > samples[-1][2]:
                        state["last_new_cov_s"] = now
                    samples.append((now, execs, cov, ft))
                if f:
                    final[f[1]] = int(f[2])

    stop_reason = "exited"
    with open(a.log, "w") as log:
        log.write(" ".join(cmd) + "\n")
        reader = threading.Thread(target=read, args=(log,))
        reader.start()
        # libFuzzer prints only at new coverage and at powers of two, so the clock is
        # watched here rather than on each line.
        while proc.poll() is None:
            time.sleep(5)
            now = time.monotonic() - t0
            with lock:
                quiet = now - state["last_new_cov_s"]
            if now >= a.min_min * 60 and quiet >= a.quiet_min * 60:
                stop_reason = "plateau"
            elif now >= a.max_min * 60:
                stop_reason = "max_time"
            else:
                continue
            proc.send_signal(signal.SIGINT)
            break
        reader.join()
    last_new_cov_s = state["last_new_cov_s"]
    start_cov = state["start_cov"]
    proc.wait()
    wall = time.monotonic() - t0

    def cov_at(frac):
        t = wall * frac
        before = [s for s in samples if s[0] <= t]
        return before[-1][2] if before else None

    end = samples[-1] if samples else (wall, 0, 0, 0)
    out = {
        "target": a.binary.rsplit("/", 1)[-1],
        "stop": stop_reason,
        "wall_s": round(wall),
        "execs": final.get("number_of_executed_units", end[1]),
        "exec_per_s": round(final.get("number_of_executed_units", end[1]) / max(wall, 1e-9)),
        "cov_start": start_cov,
        "cov_half": cov_at(0.5),
        "cov_three_quarters": cov_at(0.75),
        "cov": end[2],
        "ft": end[3],
        "last_new_cov_s": round(last_new_cov_s),
        "quiet_s": round(wall - last_new_cov_s),
        "new_units": final.get("new_units_added"),
        "peak_rss_mb": final.get("peak_rss_mb"),
        "exit_code": proc.returncode,
    }
    print(json.dumps(out))
    return 0 if proc.returncode in (0, -signal.SIGINT, 130, 72) else 1


if __name__ == "__main__":
    sys.exit(main())
