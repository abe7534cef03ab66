"""A robot's control loop that recognises its own activity live with an exported mlnseq model.

    python robot_loop.py MODEL.mlnseq RECORDING.csv

The robot's sensor is played back here from a recording (one row per frame, a column per feature);
on a robot, `read_sensor` would read the arms' kinematics instead. Each frame goes through
`Recognizer.step` as it arrives; the loop reports each change of activity and what it spent per frame.
"""

from __future__ import annotations

import csv
import sys
import time
from collections.abc import Iterator

from stages.recognizer import Recognizer


def read_sensor(path: str) -> Iterator[dict[str, float]]:
    """Frames as the robot would produce them: feature name -> value."""
    with open(path, newline="") as handle:
        for row in csv.DictReader(handle):
            yield {name: float(value) for name, value in row.items()}


def main(model_path: str, recording: str) -> None:
    recognizer = Recognizer.load(model_path)  # once, at start-up
    current, spent, frames = None, 0.0, 0
    for frame in read_sensor(recording):
        started = time.perf_counter()
        prediction = recognizer.step(frame)  # keys the model does not use (a timestamp, a label) are ignored
        spent += time.perf_counter() - started
        frames += 1
        if prediction.name != current:
            current = prediction.name
            print(f"frame {prediction.frame}: {current} ({prediction.probabilities[prediction.label]:.0%})")
    # between two episodes (a new trial), call recognizer.reset()
    print(f"{frames} frames, {1000 * spent / max(frames, 1):.3f} ms per frame in the recogniser")


if __name__ == "__main__":
    main(*sys.argv[1:3])
