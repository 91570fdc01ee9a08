#!/usr/bin/env python3
"""The tables of scripts/benchmark from the YAML files of one run.

usage: benchmark_report.py OUT_DIR BAG
Reads OUT_DIR/sim_{30,60}.yaml (demo monitor), sim_{30,60}_probe.yaml,
replay_*.yaml and live_*.yaml (benchmark probe), benchmark_spot_detector.txt
and benchmark_pose_delta.txt; prints Markdown, ending with the line
`ratios: chain A % of the study's chain, tracked B x, full C x, pose texture D x, 120 Hz dropped E of F`.
"""
import os
import re
import sys

import rosbag
import yaml

NODELETS = ["camera_driver", "spot_detector", "spot_detector_baseline", "triangulator", "pose_delta"]


def load(path):
    try:
        with open(path) as f:
            return yaml.safe_load(f) or {}
    except OSError:
        return {}


def fmt(v, spec="%.2f"):
    return spec % v if isinstance(v, (int, float)) else "n/a"


def per_frame_ms(probe, frames):
    cpu = probe.get("manager_cpu_s")
    return 1e3 * cpu / frames if cpu is not None and frames else None


def manager_ms(probe):
    """The manager's CPU per frame published in the probe's CPU window (after the start-up)."""
    frames = probe.get("published_in_cpu_window")
    return per_frame_ms(probe, frames if frames is not None else probe.get("published"))


def nodelet_ms(probe, name):
    n = probe.get("nodelets", {}).get("/" + name) or probe.get("nodelets", {}).get(name)
    return n.get("ms_per_callback") if n else None


def latency_cells(p):
    med, p99 = p.get("latency_median_ms"), p.get("latency_p99_ms")
    ratio = p99 / med if med and p99 else None
    return "%s | %s | %s" % (fmt(med, "%.1f"), fmt(p99, "%.1f"), fmt(ratio))


def sim_table(out):
    print("## Simulator in the pipeline's manager\n")
    print("| rate | frames | dropped | latency median ms | p99 ms | p99/median | in the manager: median ms | p99 ms | "
          "p99/median | manager CPU ms/frame | SpotDetector | Triangulator | PoseDelta (callback CPU ms/frame) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for rate in (30, 60):
        mon, p = load(os.path.join(out, "sim_%d.yaml" % rate)), load(os.path.join(out, "sim_%d_probe.yaml" % rate))
        if not p:
            print("| %d Hz | run failed (see sim_%d.log) |" % (rate, rate))
            continue
        inside = load(os.path.join(out, "sim_%d_latency.yaml" % rate)) or {}
        print("| %d Hz | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            rate, p.get("frames"), p.get("dropped"), latency_cells(p), latency_cells(inside),
            fmt(manager_ms(p)), fmt(nodelet_ms(p, "spot_detector")),
            fmt(nodelet_ms(p, "triangulator")), fmt(nodelet_ms(p, "pose_delta"))))
        if mon:
            print("|  | demo monitor: %s published, %s dropped, recall %s, pose %s mm / %s deg RMS |%s" % (
                mon.get("frames_published"), mon.get("frames_dropped"), fmt(mon.get("recall"), "%.4f"),
                fmt(mon.get("translation_rms_mm"), "%.3f"), fmt(mon.get("rotation_rms_deg"), "%.4f"), " |" * 11))
    print("\nStages inside the manager (LatencyProbe: camera_info -> spots -> points -> pose_delta; median, p99 "
          "and the mean over the slowest 2 %% of frames, ms):\n")
    print("| rate | SpotDetector | Triangulator | PoseDelta |")
    print("|---|---|---|---|")
    for rate in (30, 60):
        inside = load(os.path.join(out, "sim_%d_latency.yaml" % rate)) or {}
        print("| %d Hz | %s |" % (rate, " | ".join(
            "%s / %s / %s" % (fmt(inside.get(st + "_median_ms")), fmt(inside.get(st + "_p99_ms")),
                              fmt(inside.get(st + "_in_slowest_ms")))
            for st in ("detector", "triangulator", "pose_delta"))))
    print("\nThe latency from the arrival of camera/camera_info to that of pose_delta: first as "
          "nodes/benchmark_probe.py sees it from its own process, then as the LatencyProbe nodelet times it inside "
          "the pipeline's manager (steady clock, a thread of its own). The manager's CPU includes the simulator's "
          "rendering (CameraDriver).\n")


def replay_tables(out, frames):
    r = {name: load(os.path.join(out, "replay_%s.yaml" % name)) for name in (
        "side_by_side", "pipeline", "pipeline_notex", "fast_only", "baseline_only", "pipeline_30hz",
        "pipeline_60hz")}
    print("## Bag replay (%d frames, 1024 x 1024 bgr8, 10 Hz)\n" % frames)
    base = manager_ms(r["baseline_only"])
    print("| manager | CPU ms/frame | of the baseline-only manager |")
    print("|---|---|---|")
    for name, what in (("pipeline", "pipeline (fast detector, Triangulator, PoseDelta with texture)"),
                       ("pipeline_notex", "pipeline, PoseDelta texture off"),
                       ("fast_only", "fast SpotDetector alone"),
                       ("baseline_only", "the study's chain (baseline SpotDetector) alone")):
        ms = manager_ms(r[name])
        print("| %s | %s | %s |" % (what, fmt(ms), fmt(100 * ms / base, "%.1f %%") if ms and base else "n/a"))
    s = r["side_by_side"]
    fast, study = nodelet_ms(s, "spot_detector"), nodelet_ms(s, "spot_detector_baseline")
    print("\nSame manager, same frames (the study's chain loaded beside the pipeline), callback CPU per frame:\n")
    print("| nodelet | ms/frame |")
    print("|---|---|")
    for name in NODELETS[1:]:
        print("| %s | %s |" % (name, fmt(nodelet_ms(s, name))))
    print("| manager total | %s |" % fmt(manager_ms(s)))
    if fast and study:
        print("\nRatio study's chain / fast SpotDetector on the same frames: %.1fx" % (study / fast))
    print("\nLatency from publication to pose_delta on the bag (pipeline):\n")
    print("| replay rate | frames | dropped | median ms | p99 ms | p99/median | in the manager: median ms | p99 ms | "
          "p99/median |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name, rate in (("pipeline", "10 Hz"), ("pipeline_30hz", "30 Hz"), ("pipeline_60hz", "60 Hz")):
        p = r[name]
        inside = load(os.path.join(out, "replay_%s_latency.yaml" % name)) or {}
        print("| %s | %s | %s | %s | %s |" % (rate, p.get("frames"), p.get("dropped"), latency_cells(p),
                                            latency_cells(inside)))


LIVE_RUNS = (("side_by_side", "whole chain + the study's chain, same frames, 30 Hz"),
             ("pipeline", "whole chain alone, 30 Hz"),
             ("baseline_only", "the study's chain alone, 30 Hz"),
             ("driver_only", "the driver alone, 30 Hz"),
             ("pipeline_120hz", "whole chain alone, 120 Hz"))


def chain_ms(p):
    parts = [nodelet_ms(p, n) for n in ("spot_detector", "triangulator", "pose_delta")]
    return sum(parts) if all(v is not None for v in parts) else None


def live_tables(out):
    r = {name: load(os.path.join(out, "live_%s.yaml" % name)) for name, _ in LIVE_RUNS}
    print("## Live: frames from inside the manager (launch/benchmark_live.launch)\n")
    print("The bag's frames played by the CameraDriver's images source (decoded beforehand, looped) in the "
          "pipeline's manager: no rosbag play, no TCP, no deserialisation. Callback CPU per frame (ms), the "
          "manager's CPU per published frame (the driver's copy into each message included), frames without "
          "pose_delta within 1 s (dropped), ticks the driver missed, latency camera_info -> pose_delta.\n")
    print("| run | frames | dropped | ticks missed | SpotDetector | Triangulator | PoseDelta | chain | study's chain | "
          "manager ms/frame | latency median ms | p99 ms | p99/median | in the manager: median | p99 | p99/median |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, what in LIVE_RUNS:
        p = r[name]
        if not p:
            print("| %s | run failed (live_%s.log) |" % (what, name))
            continue
        inside = load(os.path.join(out, "live_%s_latency.yaml" % name)) or {}
        print("| %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s | %s |" % (
            what, p.get("frames") if p.get("pose_deltas") else p.get("published_in_cpu_window"), p.get("dropped"), p.get("not_published"), fmt(nodelet_ms(p, "spot_detector")),
            fmt(nodelet_ms(p, "triangulator")), fmt(nodelet_ms(p, "pose_delta")), fmt(chain_ms(p)),
            fmt(nodelet_ms(p, "spot_detector_baseline")), fmt(manager_ms(p)),
            latency_cells(p), latency_cells(inside)))
    s = r["side_by_side"]
    chain, study = chain_ms(s), nodelet_ms(s, "spot_detector_baseline")
    if chain and study:
        print("\nCallbacks on the same frames: the whole chain %.2f ms, the study's chain %.2f ms: %.1f %%. The "
              "study's chain runs part of its OpenCV work on OpenCV's worker threads, which its callback's thread "
              "CPU does not count: the managers below count every thread." % (chain, study, 100 * chain / study))
    alone = [manager_ms(r[n]) for n in ("pipeline", "baseline_only", "driver_only")]
    net = None
    if all(alone):
        net = 100 * (alone[0] - alone[2]) / (alone[1] - alone[2])
        print("\nManagers alone: the whole chain's %.2f ms/frame, the study's chain's %.2f, the driver's alone %.2f; "
              "without the driver, the whole chain is %.1f %% of the study's chain." % (alone[0], alone[1], alone[2],
                                                                                       net))
        for n in ("pipeline", "baseline_only"):
            frames = r[n].get("published_in_cpu_window")
            busiest = r[n].get("busiest_threads_cpu_s")
            if frames and busiest:
                print("\nBusiest threads of the manager, %s (ms/frame): %s." % (
                    dict(LIVE_RUNS)[n], ", ".join("%.2f" % (1e3 * t / frames) for t in busiest)))
    return net, r["pipeline_120hz"]


def stage_ratios(out):
    """(tracked, full) from benchmark_spot_detector; (texture on ms, off ms,
    off valid, frames) of the rock where texture off is meant to be valid."""
    tracked = full = None
    try:
        with open(os.path.join(out, "benchmark_spot_detector.txt")) as f:
            m = re.search(r"ratio baseline/fast: ([0-9.]+)x full search, ([0-9.]+)x tracked", f.read())
            if m:
                full, tracked = float(m.group(1)), float(m.group(2))
    except OSError:
        pass
    pose = {}
    try:
        with open(os.path.join(out, "benchmark_pose_delta.txt")) as f:
            for line in f:
                # The yardstick: the rock where texture off is valid (denser beams, benchmark_pose_delta).
                m = re.match(r"rock [0-9.]+ m, 20x20 beams, texture (on|off)\s*:.*?([0-9.]+) ms CPU;.*? (\d+)/(\d+) "
                             r"valid", line)
                if m:
                    pose[m.group(1)] = (float(m.group(2)), int(m.group(3)), int(m.group(4)))
    except OSError:
        pass
    return tracked, full, pose


def pose_motion_table(out):
    """benchmark_pose_delta at 30 Hz with and without the motion filter's prediction."""
    rows = {}
    for px, what in (("default", "from the motion filter's prediction (default)"), ("0", "coarse track always")):
        try:
            with open(os.path.join(out, "benchmark_pose_delta_30hz_%s.txt" % px)) as f:
                for line in f:
                    m = re.match(r"(.+?)\s*: .*?([0-9.]+) ms CPU;.*? (\d+)/(\d+) valid,.*? (\d+) from the motion "
                                 r"filter(?:; error ([0-9.e-]+) mm / ([0-9.e-]+) deg RMS)?", line)
                    if m:
                        rows.setdefault(m.group(1).strip(), []).append((what, m.groups()[1:]))
        except OSError:
            pass
    if not rows:
        return
    print("\n## PoseDelta at 30 Hz: texture from the motion filter's prediction or the coarse track\n")
    print("`benchmark_pose_delta 60 <case> 0.0333 [0]` (one core; error against the simulator's motion):\n")
    print("| case | texture refined | ms CPU/frame | valid | from the filter | error mm RMS | deg RMS |")
    print("|---|---|---|---|---|---|---|")
    for case, runs in rows.items():
        for what, (ms, valid, frames, motion, err_mm, err_deg) in runs:
            print("| %s | %s | %s | %s/%s | %s | %s | %s |" % (case, what, ms, valid, frames, motion, err_mm or "n/a",
                                                             err_deg or "n/a"))


def ratios_line(out, chain_pct, run120):
    tracked, full, pose = stage_ratios(out)
    texture = None
    if "on" in pose and "off" in pose:
        texture = pose["on"][0] / pose["off"][0]
        if pose["off"][1] < pose["off"][2]:
            print("\nPoseDelta's texture ratio: texture off is valid in only %d of %d frames on the 20 x 20 beam "
                  "rock (benchmark_pose_delta)." % pose["off"][1:])
    dropped = ticks = None
    if run120:
        ticks = run120.get("ticks")
        dropped = (run120.get("dropped") or 0) + (run120.get("not_published") or 0)
    print("\nratios: chain %s %% of the study's chain, tracked %s x, full %s x, pose texture %s x, "
          "120 Hz dropped %s of %s" % (fmt(chain_pct, "%.1f"), fmt(tracked, "%.1f"), fmt(full, "%.1f"),
                                     fmt(texture, "%.2f"), dropped if dropped is not None else "n/a",
                                     ticks if ticks is not None else "n/a"))


def main():
    out, bag = sys.argv[1], sys.argv[2]
    with rosbag.Bag(bag) as b:
        frames = b.get_message_count(["camera/image_raw", "/camera/image_raw"])
    print("# scripts/benchmark\n")
    sim_table(out)
    replay_tables(out, frames)
    chain_pct, run120 = live_tables(out)
    pose_motion_table(out)
    ratios_line(out, chain_pct, run120)


if __name__ == "__main__":
    main()
