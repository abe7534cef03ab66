"""A robot's control loop that recognises its own activity live with an exported mlnseq model.

    python robot_loop.py MODEL.mlnseq RECORDING.csv [EPISODE_COLUMN]

The robot's sensor is played back here from a recording (one row per frame, a column per feature; other
columns, such as a label or a timestamp, are ignored); on a robot, `read_sensor` would read the arms'
kinematics instead. Each frame goes through the recogniser's `step` as it arrives; a new value in the episode
column (default `episode`, if the recording has one) is a new trial, and the loop calls `reset()` there.
The loop reports each change of activity and what it spent per frame.
"""

from __future__ import annotations

import csv
import sys
import time
from collections.abc import Iterator, Sequence

import mlnseq


def read_sensor(path: str, features: Sequence[str], episode_column: str) -> Iterator[tuple[str | None, dict[str, float]]]:
    """Frames as the robot would produce them: (its episode, or None without that column; feature name -> value)."""
    with open(path, newline="") as handle:
        reader = csv.DictReader(handle)
        missing = [name for name in features if name not in (reader.fieldnames or [])]
        if missing:
            sys.exit(f"{path}: no column {', '.join(missing)}; the model reads {', '.join(features)}")
        for number, row in enumerate(reader, start=2):
            try:
                yield row.get(episode_column), {name: float(row[name]) for name in features}
            except ValueError as error:
                sys.exit(f"{path}:{number}: {error}")


def main(model_path: str, recording: str, episode_column: str = "episode") -> None:
    recognizer = mlnseq.load(model_path)  # once, at start-up
    episode, current, spent, frames = object(), None, 0.0, 0
    for frame_episode, frame in read_sensor(recording, recognizer.features, episode_column):
        if frame_episode != episode:  # a new trial: the next frame starts a new episode
            if frames:
                recognizer.reset()
            episode, current = frame_episode, None
            if frame_episode is not None:
                print(f"episode {frame_episode}")
        started = time.perf_counter()
        prediction = recognizer.step(frame)
        spent += time.perf_counter() - started
        frames += 1
        if prediction.name != current:
            current = prediction.name
            print(f"frame {prediction.frame}: {current} ({prediction.probabilities[prediction.label]:.0%})")
    print(f"{frames} frames, {1000 * spent / max(frames, 1):.3f} ms per frame in the recogniser")


if __name__ == "__main__":
    main(*sys.argv[1:4])
