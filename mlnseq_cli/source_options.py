"""The options that say how a recording is read and decoded, one set for every command that reads one as the model's
were read (predict, explain, review; ``reads_recordings`` adds them to a command): a line of one pasted into another
reads and decides the same frames."""

from __future__ import annotations

import inspect
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, Optional, TypeVar

import typer

from mlnseq.recognition.reading import ReadOptions
from mlnseq.sources import labels_option

Command = TypeVar("Command", bound=Callable[..., None])

Decode = Annotated[Optional[str], typer.Option(help="A decoder, with @LAG for smooth and lagviterbi (e.g. smooth-legal@5), or the model's method with it as names are printed (conflation+viterbi) \\[default: the model's]; viterbi or posterior decodes a filter model offline.")]
Env = Annotated[Optional[str], typer.Option(help="table, rosbag, lerobot, hdf5 or jigsaws \\[default: as the model's recordings were read].")]
LabelColumn = Annotated[Optional[str], typer.Option(help="The label column; named, the recordings must have it \\[default: the model's, used if present]; predict scores labelled recordings (metrics printed and stored).")]
EpisodeColumn = Annotated[Optional[str], typer.Option(help="The episode column \\[default: the model's; else 'episode' if present, else one episode per file]; \"\" reads a recording without the model's episode column.")]
TimeColumn = Annotated[Optional[str], typer.Option(help="The time/frame column \\[default: the model's; else 'frame' if present, else file order]; \"\" reads a recording without the model's time column.")]
LabelsFile = Annotated[Optional[Path], typer.Option("--labels", help="True labels as intervals (episode, start, end, label), to score the predictions; lerobot: subtask reads the dataset's own subtask annotations.", dir_okay=False)]
LabelsUnit = Annotated[Optional[str], typer.Option(help="--labels' unit: seconds or frames \\[default: as the file's unit column says; else the model's].")]
Topics = Annotated[Optional[str], typer.Option(help="rosbag: topics, comma-separated \\[default: the model's].")]
Rate = Annotated[Optional[float], typer.Option(help="rosbag: the clock in Hz \\[default: the model's].")]
LabelTopic = Annotated[Optional[str], typer.Option(help="rosbag: a std_msgs/String topic of true phases \\[default: the model's].")]
MaxHold = Annotated[Optional[float], typer.Option(help="rosbag: the longest a frame holds a topic's or joint's last value, in seconds (inf: no bound); past it the frame is dropped \\[default: the model's].")]


def read_options(
    decode: Decode = None,
    env: Env = None,
    label_column: LabelColumn = None,
    episode_column: EpisodeColumn = None,
    time_column: TimeColumn = None,
    labels: LabelsFile = None,
    labels_unit: LabelsUnit = None,
    topics: Topics = None,
    rate: Rate = None,
    label_topic: LabelTopic = None,
    max_hold: MaxHold = None,
) -> ReadOptions:
    """The reading flags as the library's options (the source's given ones override the model's)."""
    return ReadOptions(decode=decode, env=env, label_column=label_column, episode_column=episode_column,
                       time_column=time_column,
                       overrides=overrides(labels, labels_unit, topics, rate, label_topic, max_hold))


def reads_recordings(command: Command) -> Command:
    """``command``, whose ``**reading`` takes the reading flags, with them after its own parameters, for typer."""
    own = [p for p in inspect.signature(command, eval_str=True).parameters.values() if p.kind is not p.VAR_KEYWORD]
    flags = list(inspect.signature(read_options, eval_str=True).parameters.values())
    command.__signature__ = inspect.Signature(own + flags)  # type: ignore[attr-defined]
    return command


def overrides(labels: Optional[Path], labels_unit: Optional[str], topics: Optional[str], rate: Optional[float],
              label_topic: Optional[str], max_hold: Optional[float]) -> dict[str, Any]:
    """The SourceOptions fields given (the rest: the model's)."""
    given = dict(**labels_option(labels), labels_unit=labels_unit, topics=names(topics), rate=rate,
                 label_topic=label_topic, max_hold=max_hold)
    return {k: v for k, v in given.items() if v not in (None, ())}


def names(text: Optional[str]) -> tuple[str, ...]:
    """A comma list as a tuple of names."""
    return tuple(name.strip() for name in text.split(",") if name.strip()) if text else ()
