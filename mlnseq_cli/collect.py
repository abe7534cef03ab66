"""`mlnseq collect`: make or import a dataset's frames."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TimeElapsedColumn

from mlnseq_cli.console import DEFAULT, WorkdirOption, console, counted, reported_errors
from mlnseq import collect as stage
from mlnseq.sources import labels_option
from mlnseq.sources.holds import MAX_HOLD_S
from mlnseq.sources.splits import Holdout


def collect(
    env: Annotated[str, typer.Option(help="Data source: fetch (MuJoCo simulation), desk (real Taurus files), table (your own CSV/Parquet), or robot recordings as they are: rosbag, lerobot, hdf5, jigsaws (see docs/recordings.md).")] = "fetch",
    source: Annotated[Optional[Path], typer.Option(help="desk: folder of the DESK Taurus text files; table: a CSV/Parquet file or folder; rosbag: a .bag, a ROS 2 bag folder, a .mcap or a folder of them; lerobot: the dataset folder; hdf5: a robomimic-style file; jigsaws: a task folder.")] = None,
    channels: Annotated[str, typer.Option(help="desk: motion (3 channels, all frames) or kinematics (14 channels, training file only).")] = "motion",
    episodes: Annotated[int, typer.Option(help="fetch: number of 50-step demonstrations.")] = stage.CollectOptions.episodes,
    seed: Annotated[int, typer.Option(help="fetch: seed of resets and action noise.")] = 0,
    train_frames: Annotated[Optional[int], typer.Option(help="The first K frames form the training split \\[default: 126 fetch, 1405 desk].")] = None,
    goals: Annotated[bool, typer.Option(help="fetch: add the achieved and desired goal as features.")] = False,
    cache: Annotated[Optional[Path], typer.Option(help="fetch: folder keeping simulated episodes; a collection of the same episodes, seed and simulator reads them back instead of simulating.", file_okay=False)] = None,
    label_column: Annotated[str, typer.Option(help="table: the label column (class index or name).")] = "label",
    episode_column: Annotated[Optional[str], typer.Option(help="table: the episode column \\[default: 'episode' if present, else one episode per file].")] = None,
    time_column: Annotated[Optional[str], typer.Option(help="table: the time/frame column, rising within an episode \\[default: 'frame' if present, else file order].")] = None,
    classes: Annotated[Optional[str], typer.Option(help="Class names in label order, comma-separated (any source with named labels: a table's label column, a bag's label topic, --labels) \\[default: sorted by name, or a numeric label's own order].")] = None,
    features: Annotated[Optional[str], typer.Option(help="table: feature columns, comma-separated \\[default: every other numeric column]; hdf5: dataset paths in a demo (obs/joint_pos, actions); lerobot: info.json features or their elements (observation.state, action/gripper); language columns and columns mlnseq wrote never are.")] = None,
    labels: Annotated[Optional[Path], typer.Option(help="Labels in a CSV/TSV (every recording env): intervals (episode,start,end,label) or one click per phase (episode,frame,label or episode,time,label: the frames between clicks labelled by learning where each phase begins), episode by episode; the episodes it does not name keep their own labels or are read without; lerobot: subtask reads the dataset's own subtask annotations (episodes without any left out).", dir_okay=False)] = None,
    labels_unit: Annotated[Optional[str], typer.Option(help="--labels' start and end: seconds or frames \\[default: as the file's unit column says (`mlnseq review` writes one); else seconds for rosbag, frames otherwise].")] = None,
    unlabelled: Annotated[Optional[str], typer.Option(help="jigsaws, --labels: the class of frames outside every interval \\[default: such frames are dropped].")] = None,
    topics: Annotated[Optional[str], typer.Option(help="rosbag: topics to read, comma-separated \\[default: every topic with numeric fields].")] = None,
    rate: Annotated[Optional[float], typer.Option(help="rosbag: the frames' clock in Hz \\[default: the first topic's rate].")] = None,
    label_topic: Annotated[Optional[str], typer.Option(help="rosbag: a std_msgs/String topic of phase names, each holding until the next.")] = None,
    holdout: Annotated[Optional[str], typer.Option(help="Recordings without a split column: share (the first 70 % of the labelled recordings train, the rest test), unless-few (share from 5 labelled recordings on; fewer: all train) or none (all train) \\[default: share; fit: unless-few].", show_default=False)] = None,
    max_hold: Annotated[float, typer.Option(help="rosbag: the longest a frame holds a topic's or joint's last value, in seconds (inf: no bound); past it the value is missing and the frame dropped. Each topic or joint that stops early, starts late or goes silent is a note.")] = MAX_HOLD_S,
    workdir: WorkdirOption = DEFAULT,
) -> None:
    """Collect frames into WORKDIR/frames.parquet (episode, frame, label, split, then one column per feature)."""
    options = collect_options(env=env, source=source, channels=channels, episodes=episodes, seed=seed,
                              train_frames=train_frames, goals=goals, cache=cache, label_column=label_column,
                              episode_column=episode_column, time_column=time_column, classes=classes,
                              features=features, labels=labels, labels_unit=labels_unit, unlabelled=unlabelled,
                              topics=topics, rate=rate, label_topic=label_topic, max_hold=max_hold, holdout=holdout)
    with reported_errors():
        options.validate()
        with Progress(
            "[progress.description]{task.description}", BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            console=console, transient=True, disable=env != "fetch",
        ) as bar:
            task = bar.add_task(f"simulating {env}", total=None)
            path, collected = stage.run(
                workdir, options, progress=lambda done, total: bar.update(task, completed=done, total=total)
            )
    print_collected(path, collected)


def collect_options(*, label_column: str, episode_column: Optional[str], time_column: Optional[str],
                    classes: Optional[str], features: Optional[str], labels: Optional[Path], labels_unit: Optional[str],
                    unlabelled: Optional[str], topics: Optional[str], rate: Optional[float], label_topic: Optional[str],
                    max_hold: float = MAX_HOLD_S, holdout: Optional[str] = None, **rest) -> stage.CollectOptions:
    """The stage's options from the command's flags (also `mlnseq fit`'s source flags)."""
    return stage.CollectOptions(
        **rest, holdout=None if holdout is None else holdout_of(holdout),
        columns=stage.TableColumns(label=label_column, episode=episode_column, time=time_column,
                                   classes=_names(classes), features=_names(features)),
        recordings=stage.SourceOptions(**labels_option(labels), labels_unit=labels_unit, unlabelled=unlabelled,
                                       topics=_names(topics), rate=rate, label_topic=label_topic, max_hold=max_hold),
    )


def print_collected(path: Path, collected: stage.Collected) -> None:
    """collect's summary: the frames, episodes, split and features, the classes and notes."""
    frames = collected.frames
    split_sizes = dict(frames.group_by("split").len().iter_rows())
    console.print(
        f"[green]collect[/]: wrote {path} ({counted(frames.height, 'frame')}, "
        f"{counted(frames['episode'].n_unique(), 'episode')}, "
        f"{split_sizes.get('train', 0):,} train / {split_sizes.get('test', 0):,} test"
        f"{f' / {unlabelled:,} unlabelled' if (unlabelled := split_sizes.get('unlabelled', 0)) else ''}, "
        f"{counted(len(collected.meta['features']), 'feature')})"
    )
    console.print(collected.classes_line, markup=False, highlight=False)
    if collected.meta.get("clicks_filled"):
        from mlnseq.labelling.clicks import filled_said

        console.print(filled_said(collected.meta["clicks_filled"]), highlight=False)
    for note in collected.meta.get("notes", []):
        console.print(f"note: {note}")
    if "success_rate" in collected.meta:
        console.print(f"episodes that succeeded: {collected.meta['success_rate']:.1%}")


def holdout_of(text: str) -> Holdout:
    try:
        return Holdout(text)
    except ValueError:
        raise typer.BadParameter(f"{text!r}: choose {', '.join(h.value for h in Holdout)}",
                                 param_hint="--holdout") from None


def _names(text: Optional[str]) -> tuple[str, ...]:
    return tuple(name.strip() for name in text.split(",") if name.strip()) if text else ()
