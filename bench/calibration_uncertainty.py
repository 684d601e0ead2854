#!/usr/bin/env python3
"""How far `mocapd calibrate`'s per-joint uncertainty can be trusted.

Synthesizes Plug-in Gait takes of the built-in humanoid (several motions and seeds, with
marker noise and soft-tissue wobble), calibrates each from its markers alone, and compares
each limb bone's error against the true skeleton with the uncertainty the report gives
for it. An honest one-sigma uncertainty puts the median |error| / uncertainty near 0.67
and about 5 % of bones past 2.

usage: bench/calibration_uncertainty.py [--build build/release] [--seeds 4] [--work DIR]
"""
import argparse
import json
import math
import os
import re
import subprocess
import tempfile

# The calibrated subject's role names and the humanoid's joint names: the bone ending at
# each (its offset in its parent) is compared.
LIMBS = {"shin_l": "LeftLeg", "shin_r": "RightLeg", "foot_l": "LeftFoot", "foot_r": "RightFoot",
         "forearm_l": "LeftForeArm", "forearm_r": "RightForeArm", "hand_l": "LeftHand",
         "hand_r": "RightHand"}
MOTIONS = (("mixed", 6), ("rom", 10), ("walk", 8))


def truth_bone_mm(subject_toml):
    """Joint name -> length of its offset (mm), read from a subject file's [[joint]] tables."""
    bones, name = {}, None
    with open(subject_toml) as f:
        for line in f:
            m = re.match(r'name = "(.*)"', line)
            if m:
                name = m.group(1)
            m = re.match(r"offset = \[(.*)\]", line)
            if m and name:
                bones[name] = 1000 * math.sqrt(sum(float(x) ** 2 for x in m.group(1).split(",")))
                name = None
    return bones


def quantile(values, q):
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--build", default="build/release")
    p.add_argument("--seeds", type=int, default=4)
    p.add_argument("--work", default="")
    a = p.parse_args()
    sim = os.path.join(a.build, "sim", "mocap-sim")
    mocapd = os.path.join(a.build, "runtime", "mocapd")
    work = a.work or tempfile.mkdtemp(prefix="calibration_uncertainty_")
    print(f"{'motion':8} {'bones':>5} {'error mm p50':>12} {'p90':>6} {'max':>6} "
          f"{'|err|/unc p50':>13} {'p90':>6} {'>2':>5}")
    for motion, seconds in MOTIONS:
        errors, ratios = [], []
        for seed in range(1, a.seeds + 1):
            take = os.path.join(work, f"{motion}_{seed}.c3d")
            truth = os.path.join(work, "truth.toml")
            report = os.path.join(work, f"{motion}_{seed}.json")
            subprocess.run([sim, "synth", "--humanoid", motion, "--seconds", str(seconds),
                            "--rate", "120", "--marker-set", "plug-in-gait-full", "--noise-mm",
                            "1", "--soft-tissue-mm", "5", "--seed", str(seed), "--out", take,
                            "--subject-out", truth], check=True, stdout=subprocess.DEVNULL)
            subprocess.run([mocapd, "calibrate", "--markers", take, "--out",
                            os.path.join(work, f"{motion}_{seed}.toml"), "--report", report],
                           check=True, stdout=subprocess.DEVNULL)
            bones = truth_bone_mm(truth)
            with open(report) as f:
                for joint in json.load(f)["joints"]:
                    if joint["joint"] in LIMBS and joint.get("uncertainty_mm"):
                        error = abs(joint["bone_length_mm"] - bones[LIMBS[joint["joint"]]])
                        errors.append(error)
                        ratios.append(error / joint["uncertainty_mm"])
        past_two = 100.0 * sum(r > 2 for r in ratios) / len(ratios)
        print(f"{motion:8} {len(errors):5d} {quantile(errors, .5):12.1f} "
              f"{quantile(errors, .9):6.1f} {max(errors):6.1f} {quantile(ratios, .5):13.2f} "
              f"{quantile(ratios, .9):6.2f} {past_two:4.0f}%")


if __name__ == "__main__":
    main()
