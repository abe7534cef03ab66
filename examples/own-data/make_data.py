"""Write recordings.csv: twelve pick-and-lift trials of a lab gripper robot, logged at 50 Hz.

Columns: trial, t (seconds), ee_z (end-effector height, m), gripper_mm (finger opening),
wrist_force (N), phase (approach, grasp, lift, release). Stands in for a team's own robot logs.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import numpy as np

PHASES = ("approach", "grasp", "lift", "release")
RATE_HZ = 50


def trial(rng: np.random.Generator) -> list[tuple[float, float, float, str]]:
    """One trial as (ee_z, gripper_mm, wrist_force, phase) rows."""
    steps = {phase: int(rng.integers(low, high)) for phase, (low, high) in
             zip(PHASES, ((30, 50), (12, 20), (25, 40), (10, 18)))}
    top, bottom, mass_force = rng.uniform(0.25, 0.32), rng.uniform(0.04, 0.06), rng.uniform(3.0, 6.0)
    plan = {
        "approach": (np.linspace(top, bottom, steps["approach"]), np.full(steps["approach"], 80.0),
                     np.zeros(steps["approach"])),
        "grasp": (np.full(steps["grasp"], bottom), np.linspace(80.0, 32.0, steps["grasp"]),
                  np.linspace(0.0, 0.5, steps["grasp"])),
        "lift": (np.linspace(bottom, top, steps["lift"]), np.full(steps["lift"], 32.0),
                 np.full(steps["lift"], mass_force)),
        "release": (np.full(steps["release"], top), np.linspace(32.0, 80.0, steps["release"]),
                    np.linspace(mass_force, 0.0, steps["release"])),
    }
    rows = []
    for phase in PHASES:
        z, grip, force = plan[phase]
        z = z + rng.normal(0.0, 0.004, z.size)  # sensor noise comparable to the motion per frame
        grip = grip + rng.normal(0.0, 2.0, grip.size)
        force = force + rng.normal(0.0, 0.8, force.size)
        rows += [(float(a), float(b), float(c), phase) for a, b, c in zip(z, grip, force)]
    return rows


def main(path: Path = Path("recordings.csv"), trials: int = 12, seed: int = 7) -> Path:
    rng = np.random.default_rng(seed)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(["trial", "t", "ee_z", "gripper_mm", "wrist_force", "phase"])
        for number in range(trials):
            for step, (z, grip, force, phase) in enumerate(trial(rng)):
                writer.writerow([number, f"{step / RATE_HZ:.2f}", f"{z:.4f}", f"{grip:.2f}", f"{force:.3f}", phase])
    return path


if __name__ == "__main__":
    print(f"wrote {main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path('recordings.csv'))}")
