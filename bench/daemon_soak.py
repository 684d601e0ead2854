#!/usr/bin/env python3
"""Soak and load runs of the daemon as a process: N actors at a rate for a duration,
fed by `mocap-sim replay` over tcp loopback with medium corruption: by default each actor
on its own endless walk through a motion graph over the built-in humanoid's motions
(`--graph humanoid`: new motion throughout, no loop boundary), or with `--source loop`
the humanoid's 60 s mixed take looped as before.
Samples the daemon's CPU and resident memory every few seconds from /proc, reads its
/metrics at the end, and checks that frames in = frames out + counted drops.

    bench/daemon_soak.py --subjects 4 --rate 240 --seconds 600        # the 10-minute soak
    bench/daemon_soak.py --load --rate 240 --seconds 60               # N = 1..12: latency, CPU, memory
    bench/daemon_soak.py --subjects 8 --rate 240 --seconds 3600 --sample-s 60 --interval-s 60 \
        --report bench/results_soak_8x240_3600s.json --plot bench/results_soak_8x240_3600s.svg
                                                                       # the 1-hour soak, per minute
    bench/daemon_soak.py --subjects 4 --seconds 60 --curve             # with CURVE on every socket

Prints a table per run and writes JSON with --report.
"""
import argparse
import json
import math
import os
import subprocess
import sys
import threading
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "tests", "runtime"))
from daemon_harness import Daemon, add_run_arguments, http_get  # noqa: E402

try:  # only for --viewers / --stalled-viewers (Debian: chromium, python3-websocket)
    import socket

    import websocket
    from browser import Browser
except ImportError:
    websocket = Browser = None

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")
PAGE = os.sysconf("SC_PAGE_SIZE")


def proc_sample(pid):
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    cpu_s = (int(fields[11]) + int(fields[12])) / CLOCK_TICKS  # utime + stime
    with open(f"/proc/{pid}/statm") as f:
        rss = int(f.read().split()[1]) * PAGE
    return cpu_s, rss


def metric_sum(text, name):
    total = 0.0
    for line in text.splitlines():
        if line.startswith(name + "{") or line.startswith(name + " "):
            total += float(line.rsplit(" ", 1)[1])
    return total


def run(args, subjects, seconds, work):
    names = [f"actor{k + 1}" for k in range(subjects)]
    daemon = Daemon(args.mocapd, os.path.join(ROOT, "config"), work, lookahead=args.lookahead, subjects=names, rate_hz=args.rate,
                    workers=args.workers, curve=args.curve)
    samples = []
    stop = threading.Event()

    def sampler():
        start = time.monotonic()
        while not stop.wait(args.sample_s):
            samples.append((time.monotonic() - start, *proc_sample(daemon.process.pid)))

    # Browsers on the live view, and stalled viewers: WebSockets that never read.
    browsers, stalled = [], []
    for _ in range(args.viewers):
        browsers.append(Browser())
        browsers[-1].open(f"http://127.0.0.1:{daemon.http_port}/")
    for _ in range(args.stalled_viewers):
        stalled.append(websocket.create_connection(f"ws://127.0.0.1:{daemon.http_port}/live",
                                                   sockopt=((socket.SOL_SOCKET, socket.SO_RCVBUF, 4096),)))
    # Readers: pages without a renderer, taking every message as it comes. What the live
    # view costs the daemon itself, without browsers' software WebGL sharing the cores.
    readers, reader_counts = [], []

    def read_all(ws, k):
        try:
            while True:
                ws.recv()
                reader_counts[k] += 1
        except Exception:  # closed at the end of the run
            pass

    for k in range(args.readers):
        ws = websocket.create_connection(f"ws://127.0.0.1:{daemon.http_port}/live")
        reader_counts.append(0)
        readers.append((ws, threading.Thread(target=read_all, args=(ws, k), daemon=True)))
        readers[-1][1].start()
    thread = threading.Thread(target=sampler)
    thread.start()
    take_seconds = min(seconds, 60.0)
    loops = max(1, round(seconds / take_seconds))
    report_path = os.path.join(work, "replay.json")
    if args.source == "loop":
        source = ["--humanoid", "mixed", "--seconds", str(take_seconds), "--loop", str(loops)]
    else:
        source = ["--graph", args.graph, "--seconds", str(seconds)]
    try:
        replay = subprocess.run([args.mocap_sim, "replay", *source, "--synth-rate", str(args.rate),
                                 "--subjects", str(subjects), "--corrupt", "medium", "--to", daemon.input,
                                 "--from", daemon.output, "--report", report_path, "--plot", os.path.join(work, "latency.svg"),
                                 "--latency-interval", str(args.interval_s), *daemon.replay_curve_args],
                                capture_output=True, text=True)
        stop.set()
        thread.join()
        if replay.returncode not in (0, 2):
            raise RuntimeError(replay.stdout + replay.stderr)
        time.sleep(0.2)  # the daemon's statistics snapshot is refreshed every 20 ms
        metrics = http_get(daemon.http_port, "/metrics")[1]
        views = [b.evaluate("({frames: mocapdView.framesReceived, fps: mocapdView.renderFps, first_ms: mocapdView.firstFrameMs})")
                 for b in browsers]
    finally:
        stop.set()
        for b in browsers:
            b.close()
        for w in stalled:
            w.close()
        for ws, _ in readers:
            ws.close()
        code = daemon.stop()
    with open(report_path) as f:
        r = json.load(f)
    received = metric_sum(metrics, "mocapd_messages_received_total")
    published = metric_sum(metrics, "mocapd_frames_published_total")
    dropped = metric_sum(metrics, "mocapd_frames_dropped_total")
    control = metric_sum(metrics, "mocapd_control_messages_total")
    pending = metric_sum(metrics, "mocapd_frames_pending")
    cpu = [(samples[i + 1][1] - samples[i][1]) / (samples[i + 1][0] - samples[i][0]) * 100 for i in range(len(samples) - 1)]
    rss_mb = [s[2] / 1e6 for s in samples]
    quarter = max(1, len(rss_mb) // 4)
    result = {
        "subjects": subjects, "rate_hz": args.rate, "seconds": seconds, "lookahead": args.lookahead,
        "source": "loop of the humanoid's mixed take" if args.source == "loop" else f"motion graph {args.graph}",
        "frames_sent": r["frames_sent"], "frames_received_by_replay": r["frames_received"], "frames_lost": r["frames_lost"],
        "daemon_messages_in": received, "daemon_frames_published": published, "daemon_dropped": dropped,
        "daemon_control_messages": control, "daemon_pending": pending,
        "balanced": received == published + dropped + pending + control, "daemon_exit_code": code,
        "processing_latency": r["processing_latency"], "end_to_end_latency": r["end_to_end_latency"],
        "accuracy": r.get("accuracy"),
        "daemon_cpu_percent_mean": sum(cpu) / len(cpu) if cpu else None,
        "daemon_rss_mb_first_quarter": sum(rss_mb[:quarter]) / quarter if rss_mb else None,
        "daemon_rss_mb_last_quarter": sum(rss_mb[-quarter:]) / quarter if rss_mb else None,
        "daemon_rss_mb_max": max(rss_mb) if rss_mb else None,
        "curve": args.curve,
        "live_view": {"browsers": args.viewers, "stalled_viewers": args.stalled_viewers, "pages": views,
                      "readers": args.readers, "reader_messages": reader_counts,
                      "messages_sent": metric_sum(metrics, "mocapd_live_messages_sent_total"),
                      "messages_skipped": metric_sum(metrics, "mocapd_live_messages_skipped_total"),
                      "closed_slow": metric_sum(metrics, "mocapd_live_viewers_closed_slow_total")},
        # Per interval of the replay's sending time: processing latency (the replay's
        # measure) and the daemon's resident memory sampled within it.
        "per_interval": [
            {"from_s": i["from_s"], "processing_latency": {k: v for k, v in i.items() if k != "from_s"},
             "daemon_rss_mb_max": max([m / 1e6 for t, _, m in samples if i["from_s"] <= t < i["from_s"] + args.interval_s] or [0])}
            for i in r.get("processing_latency_per_interval", [])],
    }
    p = r["processing_latency"]
    print(f"N={subjects} @ {args.rate:.0f} Hz, {seconds:.0f} s: sent {r['frames_sent']}, received {r['frames_received']}, lost {r['frames_lost']}; "
          f"daemon in {received:.0f} = published {published:.0f} + dropped {dropped:.0f} + pending {pending:.0f} + control {control:.0f} "
          f"({'balanced' if result['balanced'] else 'UNBALANCED'}), exit {code}; processing p50 {p['p50_ms']:.3f} p99 {p['p99_ms']:.3f} "
          f"p99.9 {p['p99.9_ms']:.3f} max {p['max_ms']:.3f} ms; CPU {result['daemon_cpu_percent_mean'] or 0:.0f} %; "
          f"RSS {result['daemon_rss_mb_first_quarter'] or 0:.1f} -> {result['daemon_rss_mb_last_quarter'] or 0:.1f} MB", flush=True)
    a = r.get("accuracy")
    if a:
        w = a.get("worst_frame", {})
        print(f"  joint error: mean {a['mean_joint_position_error_cm']:.3f} cm / {a['mean_joint_rotation_error_deg']:.2f} deg, "
              f"frame p99.9 {a.get('p999_frame_position_error_cm', 0):.2f} cm, worst frame {a['max_joint_position_error_cm']:.2f} cm "
              f"({w.get('subject', '?')} frame {w.get('frame_number', '?')}, {w.get('joint', '?')})", flush=True)
        tail = a.get("p999_tail", [])
        if tail:
            print("  frames over p99.9 by joint: " + ", ".join(
                f"{t['joint']} {t['frames']} ({t['episodes']} episode{'' if t['episodes'] == 1 else 's'}, worst {t['worst_cm']:.1f} cm at {t.get('worst_subject', '?')} frame {t.get('worst_frame_number', '?')})" for t in tail[:6]), flush=True)
    if args.viewers or args.stalled_viewers or args.readers:
        lv = result["live_view"]
        rates = ", ".join("%.1f fps" % p["fps"] for p in views if p)
        print(f"  live view: {args.viewers} browsers ({rates}), {args.readers} readers ({lv['reader_messages']} messages), "
              f"{args.stalled_viewers} stalled; {lv['messages_sent']:.0f} messages sent, {lv['messages_skipped']:.0f} skipped, "
              f"{lv['closed_slow']:.0f} stalled viewers closed", flush=True)
    if result["per_interval"]:
        worst = max(result["per_interval"], key=lambda i: i["processing_latency"]["p99_ms"])
        rss = [i["daemon_rss_mb_max"] for i in result["per_interval"] if i["daemon_rss_mb_max"] > 0]
        print(f"  per {args.interval_s:.0f} s: worst p99 {worst['processing_latency']['p99_ms']:.3f} ms (from {worst['from_s']:.0f} s), "
              f"RSS {min(rss) if rss else 0:.1f}..{max(rss) if rss else 0:.1f} MB", flush=True)
    return result


def plot_intervals(result, path, interval_s):
    """An SVG of processing p50/p99/p99.9 and RSS per interval: a long soak at a glance."""
    rows = result["per_interval"]
    if not rows:
        return
    w, h, left, right, top, bottom = 900, 420, 70, 70, 40, 50
    pw, ph = w - left - right, h - top - bottom
    t_max = rows[-1]["from_s"] + interval_s
    # A log axis: the median (tenths of a ms) and a rare stall (hundreds) both stay readable.
    lat_min = 0.1
    worst = max(r["processing_latency"]["p99.9_ms"] for r in rows)
    lat_max = 10 ** math.ceil(math.log10(max(2.0, worst * 1.1)))
    rss = [r["daemon_rss_mb_max"] for r in rows]
    rss_max = max(rss) * 1.3 if max(rss) > 0 else 1.0
    x = lambda t: left + pw * t / t_max
    y_lat = lambda v: top + ph * (1 - math.log10(min(max(v, lat_min), lat_max) / lat_min) / math.log10(lat_max / lat_min))
    y_rss = lambda v: top + ph * (1 - v / rss_max)
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-family="sans-serif" font-size="12">',
           f'<rect width="{w}" height="{h}" fill="white"/>',
           f'<text x="{w / 2}" y="20" text-anchor="middle" font-size="14">mocapd soak: {result["subjects"]} actors at {result["rate_hz"]:.0f} Hz, '
           f'{result["seconds"] / 60:.0f} min, {result["frames_sent"]} frames, {result["frames_lost"]} lost</text>',
           f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="#888"/>']
    ticks = [m * 10 ** e for e in range(-1, int(math.log10(lat_max)) + 1) for m in (1, 2, 5)]
    for v in [t for t in ticks if lat_min <= t <= lat_max]:
        out.append(f'<line x1="{left}" x2="{left + pw}" y1="{y_lat(v):.1f}" y2="{y_lat(v):.1f}" stroke="#eee"/>'
                   f'<text x="{left - 6}" y="{y_lat(v) + 4:.1f}" text-anchor="end">{v:g}</text>')
    if lat_max >= 2.0:
        out.append(f'<line x1="{left}" x2="{left + pw}" y1="{y_lat(2.0):.1f}" y2="{y_lat(2.0):.1f}" stroke="#c00" stroke-dasharray="6,4"/>'
                   f'<text x="{left + pw - 4}" y="{y_lat(2.0) - 4:.1f}" text-anchor="end" fill="#c00">2 ms bound</text>')
    for k in range(0, int(t_max / 60) + 1, max(1, int(t_max / 60 / 12))):
        out.append(f'<text x="{x(k * 60):.1f}" y="{top + ph + 16}" text-anchor="middle">{k}</text>')
    out.append(f'<text x="{left + pw / 2}" y="{h - 12}" text-anchor="middle">minutes</text>'
               f'<text x="16" y="{top + ph / 2}" transform="rotate(-90 16 {top + ph / 2})" text-anchor="middle">processing latency (ms, log scale)</text>'
               f'<text x="{w - 14}" y="{top + ph / 2}" transform="rotate(90 {w - 14} {top + ph / 2})" text-anchor="middle">daemon RSS (MB)</text>')
    for v in [rss_max * k / 4 for k in range(5)]:
        out.append(f'<text x="{left + pw + 6}" y="{y_rss(v) + 4:.1f}">{v:.0f}</text>')
    for key, colour in (("p50_ms", "#2a7"), ("p99_ms", "#27c"), ("p99.9_ms", "#c72")):
        pts = " ".join(f"{x(r['from_s'] + interval_s / 2):.1f},{y_lat(r['processing_latency'][key]):.1f}" for r in rows)
        out.append(f'<polyline points="{pts}" fill="none" stroke="{colour}" stroke-width="1.5"/>')
    pts = " ".join(f"{x(r['from_s'] + interval_s / 2):.1f},{y_rss(r['daemon_rss_mb_max']):.1f}" for r in rows if r["daemon_rss_mb_max"] > 0)
    out.append(f'<polyline points="{pts}" fill="none" stroke="#888" stroke-width="1.5" stroke-dasharray="3,3"/>')
    for k, (label, colour) in enumerate((("p50", "#2a7"), ("p99", "#27c"), ("p99.9", "#c72"), ("RSS", "#888"))):
        out.append(f'<line x1="{left + 10 + k * 80}" x2="{left + 30 + k * 80}" y1="{top + 12}" y2="{top + 12}" stroke="{colour}" stroke-width="2"/>'
                   f'<text x="{left + 34 + k * 80}" y="{top + 16}">{label}</text>')
    out.append("</svg>\n")
    with open(path, "w") as f:
        f.write("\n".join(out))


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    add_run_arguments(parser, ROOT, seconds=600.0)
    parser.add_argument("--lookahead", type=int, default=12)
    parser.add_argument("--workers", type=int, default=None, help="data-plane threads (default: the daemon's, one per core)")
    parser.add_argument("--sample-s", dest="sample_s", type=float, default=5.0)
    parser.add_argument("--load", action="store_true", help="run each N of --load-subjects and report the largest within bounds")
    parser.add_argument("--load-subjects", dest="load_subjects", default="1,2,4,6,8,10,12")
    parser.add_argument("--work", default=os.path.join(ROOT, "build", "soak"))
    parser.add_argument("--report", default="")
    parser.add_argument("--source", choices=("graph", "loop"), default="graph",
                        help="graph: each actor walks a motion graph (default); loop: the mixed take looped")
    parser.add_argument("--graph", default="humanoid",
                        help="with --source graph: a graph file from `mocap-sim graph build` (its subject must be the "
                             "daemon's) or 'humanoid'")
    parser.add_argument("--curve", action="store_true", help="CURVE on every socket (fresh keys from mocapd keygen)")
    parser.add_argument("--interval-s", dest="interval_s", type=float, default=60.0,
                        help="latency percentiles and RSS per this many seconds")
    parser.add_argument("--plot", default="", help="write the per-interval latency and RSS as SVG")
    parser.add_argument("--viewers", type=int, default=0, help="headless Chromium pages on the live view during the run")
    parser.add_argument("--readers", type=int, default=0,
                        help="WebSocket clients on the live view that read every message and render nothing")
    parser.add_argument("--stalled-viewers", dest="stalled_viewers", type=int, default=0,
                        help="live-view WebSockets that never read")
    args = parser.parse_args()
    results = []
    if args.load:
        for n in [int(x) for x in args.load_subjects.split(",")]:
            results.append(run(args, n, args.seconds, os.path.join(args.work, f"n{n}")))
        period_ms = 1e3 / args.rate
        for bound, name in ((1.0, "1 ms"), (period_ms, f"one frame period ({period_ms:.2f} ms)")):
            passing = [r["subjects"] for r in results
                       if r["processing_latency"]["p99_ms"] < bound and r["frames_lost"] == 0 and r["daemon_dropped"] == 0]
            print(f"largest N with p99 processing < {name} and no loss at {args.rate:.0f} Hz: {max(passing) if passing else 0}")
    else:
        results.append(run(args, args.subjects, args.seconds, args.work))
    if args.plot:
        plot_intervals(results[-1], args.plot, args.interval_s)
    if args.report:
        with open(args.report, "w") as f:
            json.dump(results, f, indent=2)
    return 0 if all(r["balanced"] and r["daemon_exit_code"] == 0 for r in results) else 1


if __name__ == "__main__":
    sys.exit(main())
