"""Labels as time intervals: ``episode,start,end,label`` rows (CSV or TSV), or a folder of JIGSAWS-style
``start end label`` files named by episode, applied to recordings; and one click per phase: ``episode,frame,label``
(or ``time``) rows, each saying "this frame is in this phase", each boundary put halfway between two clicks when read
(``mlnseq.labelling.clicks`` learns where it falls). A file may mix both, episode by episode. An episode of
``--source`` that the file does not name keeps its own labels where they are read (collect), else is read unlabelled.

Units: ``frames`` counts a frame's position in its episode from 0, an interval holding ``start`` to ``end``
inclusive (the JIGSAWS convention); ``seconds`` is the recording's time, an interval holding
``start <= t < end`` (so one interval may end where the next starts). Frames outside every interval are
dropped, or given the class ``unlabelled``.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog.errors import BadInput
from mlnseq.sources.recording import Recording
from mlnseq.timeline.sequences import runs

COLUMNS = ("episode", "start", "end", "label")
POINT_COLUMNS = {"frame": "frames", "time": "seconds"}  # a click's column, and its unit unless --labels-unit says
UNIT_COLUMN = "unit"  # optional: a row's own unit (frames or seconds), so that the file says it (review writes it)
UNITS = ("frames", "seconds")


@dataclass(frozen=True)
class Interval:
    start: float
    end: float
    label: str | int
    where: str  # file and line, for messages
    unit: str | None = None  # its own: a click's column's, the file's unit column's or --labels-unit; None: default
    click: bool = False  # a click (start == end): one frame said to be in this phase

    def covers(self, key: np.ndarray, unit: str) -> np.ndarray:
        """bool [len(key)]: the frames (positions or times ``key`` in ``unit``) this interval holds: frames
        inclusive, seconds ``start <= t < end``."""
        return (key >= self.start) & ((key <= self.end) if unit == "frames" else (key < self.end))


def read(path: Path, unit: str | None = None) -> dict[str, list[Interval]]:
    """The intervals and clicks of ``path`` by episode id (as text), in start order; overlaps, reversed ends and two
    labels at one click refused. ``unit``: --labels-unit as given (None: a click's column names its unit)."""
    path = Path(path)
    if path.is_dir():
        files = sorted(p for p in path.iterdir() if p.suffix.lower() == ".txt")
        if not files:
            raise BadInput(f"--labels {path} holds no .txt file of start end label lines")
        return {p.stem: in_order(transcription(p)) for p in files}
    if not path.is_file():
        raise BadInput(f"--labels {path} not found")
    try:
        separator = "\t" if path.suffix.lower() == ".tsv" or "\t" in path.open(encoding="utf-8").readline() else ","
        table = pl.read_csv(path, separator=separator, infer_schema_length=10_000,
                            schema_overrides={"episode": pl.String})  # ids as written: 001 is not 1
    except Exception as error:  # polars raises many types for unreadable files
        raise BadInput(f"{path}: cannot read it as intervals ({str(error).strip().splitlines()[0][:120]})") from error
    if table.height == 0:
        raise BadInput(f"{path} holds no interval or click, only {'its header' if table.width else 'nothing'}; give "
                       f"{','.join(COLUMNS)} rows, or episode,frame,label clicks")
    point = next((c for c in POINT_COLUMNS if c in table.columns), None)
    spans = [c for c in ("start", "end") if c in table.columns]
    missing = [c for c in COLUMNS if c not in table.columns and (point is None or c not in ("start", "end"))]
    if missing:
        raise BadInput(f"{path}: no column {', '.join(map(repr, missing))}; intervals need {','.join(COLUMNS)}, "
                       "one click per phase episode,frame,label (or time)")
    for name in [*spans, *([point] if point else [])]:
        values = table[name].cast(pl.Float64, strict=False)
        bad = (values.is_null() & table[name].is_not_null()) | ~values.is_finite().fill_null(True)
        if point is None:
            bad = bad | values.is_null()
        if bad.any():
            row = int(bad.arg_true()[0])
            raise BadInput(f"{path}:{row + 2}: {name} {table[name][row]!r} is not a number")
        table = table.with_columns(values.alias(name))
    if table["label"].is_null().any():
        raise BadInput(f"{path}:{int(table['label'].is_null().arg_true()[0]) + 2}: empty label")
    by_episode: dict[str, list[Interval]] = {}
    for line, row in enumerate(table.iter_rows(named=True), start=2):
        by_episode.setdefault(str(row["episode"]), []).append(_row(row, point, spans, unit, f"{path}:{line}"))
    return {episode: in_order(found) for episode, found in by_episode.items()}


def _unit(row: dict, given: str | None, where: str) -> str | None:
    """A row's own unit, from the file's unit column (checked against --labels-unit, ``given``), else ``given``."""
    said = row.get(UNIT_COLUMN)
    if said is None or str(said).strip() == "":
        return given
    said = str(said).strip()
    if said not in UNITS:
        raise BadInput(f"{where}: unit {said!r}; a row's unit is frames or seconds")
    if given is not None and given != said:
        raise BadInput(f"{where}: the file says its unit is {said}, --labels-unit says {given}; leave --labels-unit "
                       "out (the file says its own)")
    return said


def _row(row: dict, point: str | None, spans: list[str], unit: str | None, where: str) -> Interval:
    """One line as an interval (start and end given) or a click (its point column given, start and end empty)."""
    own = _unit(row, unit, where)
    if spans and any(row[c] is not None for c in spans):
        empty = [c for c in ("start", "end") if row.get(c) is None]
        if empty:
            raise BadInput(f"{where}: {empty[0]} is empty; give start and end (an interval) or only "
                           f"{point or 'frame'} (a click)")
        return Interval(row["start"], row["end"], row["label"], where, own)
    if point is None or row[point] is None:
        raise BadInput(f"{where}: neither start,end nor {point or 'frame'} given; an interval needs start and end, "
                       "a click its frame")
    return Interval(row[point], row[point], row["label"], where, own or POINT_COLUMNS[point], click=True)


def transcription(path: Path, first_frame: int = 0) -> list[Interval]:
    """A JIGSAWS-style file: ``start end label`` per line, whitespace-separated, frames numbered from
    ``first_frame`` (JIGSAWS: 1)."""
    found = []
    try:
        lines = Path(path).read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as error:
        raise BadInput(f"cannot read {path}: {error}") from error
    for number, line in enumerate(lines, start=1):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 3:
            raise BadInput(f"{path}:{number}: expected start end label, found {len(fields)} fields")
        try:
            start, end = int(fields[0]) - first_frame, int(fields[1]) - first_frame
        except ValueError:
            raise BadInput(f"{path}:{number}: start and end must be frame numbers, got {line.strip()[:40]!r}") from None
        found.append(Interval(start, end, fields[2], f"{path}:{number}"))
    if not found:
        raise BadInput(f"{path} holds no interval")
    return found


def in_order(found: list[Interval]) -> list[Interval]:
    """An episode's intervals in time order, or its clicks (``clicks_in_order``); a reversed interval, clicks beside
    intervals, two units in one episode and overlapping intervals refused."""
    for interval in found:
        if interval.end < interval.start:
            raise BadInput(f"{interval.where}: ends ({interval.end:g}) before it starts ({interval.start:g})")
    clicks = [i for i in found if i.click]
    if clicks and len(clicks) < len(found):
        raise BadInput(f"{clicks[0].where}: a click in an episode that has intervals too; give an episode "
                       "intervals or clicks, not both")
    other = next((i for i in found if i.unit != found[0].unit), None)
    if other is not None:
        raise BadInput(f"{other.where}: in {other.unit or 'the default unit'}, unlike {found[0].where} "
                       f"({found[0].unit or 'the default unit'}); give an episode's rows one unit")
    if clicks:
        return clicks_in_order(clicks)
    by_start = sorted(found, key=lambda i: i.start)
    for before, after in zip(by_start, by_start[1:]):
        if after.start < before.end:
            raise BadInput(f"{after.where}: overlaps the interval of {before.where}; intervals may touch, not overlap")
    return by_start


# ---- clicks: one label per phase, each boundary halfway until labelling/clicks.py learns it ---------------

def clicks_in_order(found: list[Interval]) -> list[Interval]:
    """An episode's clicks in time order, a repeated one once; two labels at one frame refused."""
    ordered = sorted(found, key=lambda i: i.start)
    kept = ordered[:1]
    for click in ordered[1:]:
        before = kept[-1]
        if click.start == before.start:
            if click.label != before.label:
                raise BadInput(f"{click.where}: a second label at {click.unit} {click.start:g} ({click.label!r}; "
                               f"{before.where} says {before.label!r}); give one label a frame")
            continue
        kept.append(click)
    return kept


def positions(key: np.ndarray, found: list[Interval], what: str) -> np.ndarray:
    """Each click's frame in its episode (``key``: positions 0, 1, ... or the frames' times); outside refused."""
    unit = found[0].unit
    if unit == "frames":
        last = key[-1]
        at = [int(c.start) if c.start == int(c.start) else -1 for c in found]
    else:
        last = key[-1] + (np.median(np.diff(key)) if len(key) > 1 else 0.0)
        at = [int(np.searchsorted(key, c.start, side="right")) - 1 for c in found]
    for click, index in zip(found, at):
        if not (key[0] <= click.start <= last + 1e-9) or not 0 <= index < len(key):
            raise BadInput(f"{click.where}: click at {click.start:g} falls outside {what} ({key[0]:g}..{last:g} "
                           f"{unit})")
    for (a, click_a), (b, click_b) in zip(zip(at, found), zip(at[1:], found[1:])):
        if a == b and click_a.label != click_b.label:
            raise BadInput(f"{click_b.where}: a second label at the frame of {click_a.where} ({click_b.label!r}, "
                           f"{click_a.label!r}); give one label a frame")
    return np.asarray(at, dtype=np.int64)


def halfway(n: int, at: np.ndarray, labels: list) -> np.ndarray:
    """The n frames' labels from clicks at frames ``at`` (ascending) of ``labels``: each boundary halfway."""
    cuts = (at[:-1] + at[1:] + 1) // 2
    return np.asarray(labels, dtype=object)[np.searchsorted(cuts, np.arange(n), side="right")]


def _label_from_clicks(key: np.ndarray, found: list, rows: np.ndarray, labels: np.ndarray, keep: np.ndarray,
                  clicked: np.ndarray, what: str) -> None:
    """Label an episode's ``rows`` from its clicks (``found``, in order), each boundary halfway, marking the clicked
    rows."""
    at = positions(key, found, what)
    labels[rows] = halfway(len(rows), at, [c.label for c in found])
    keep[rows] = True
    clicked[rows[at]] = True


def check_classes(intervals: dict[str, list[Interval]], others: set[str], classes: tuple[str, ...] = ()) -> None:
    """A class of the labels file that one of its episodes alone uses, that no other labels (``others``: the
    recordings' own) use and that --classes (``classes``) does not name is refused: a typo, or a phase nothing else
    shows. Where there is nothing to compare with (one episode, no other labels) or --classes names the classes
    (then checked against them), nothing is refused."""
    if classes or (len(intervals) < 2 and not others):
        return
    episodes_of: dict[str, set[str]] = {}
    for episode, found in intervals.items():
        for interval in found:
            episodes_of.setdefault(str(interval.label), set()).add(episode)
    for episode, found in intervals.items():
        for interval in found:
            name = str(interval.label)
            if episodes_of[name] == {episode} and name not in others:
                theirs = sorted(others | {c for c, e in episodes_of.items() if e != {episode}})
                what = "is clicked in" if interval.click else "labels"
                raise BadInput(f"{interval.where}: class {interval.label!r} {what} episode {episode!r} only, no other "
                               f"labels have it (theirs: {', '.join(theirs[:8])}{', ...' if len(theirs) > 8 else ''}); "
                               "correct it, label another episode with it, or name every class with --classes")


def apply(recordings: list[Recording], intervals: dict[str, list[Interval]], unit: str,
          unlabelled: str | None = None, classes: tuple[str, ...] = ()) -> list[Recording]:
    """Each recording labelled from its episode's intervals (frames outside every interval dropped or labelled
    ``unlabelled``) or clicks (each boundary halfway); the episodes the labels do not name keep the recording's
    own labels, if read, else read unlabelled, a recording of their own. Every interval's episode needs a
    recording."""
    own = {str(v) for r in recordings if r.label is not None for v in r.label.unique().drop_nulls().to_list()}
    check_classes(intervals, own | ({unlabelled} if unlabelled is not None else set()), classes)
    seen: set[str] = set()
    found_parts = []
    for recording in recordings:
        episodes = recording.episode.cast(pl.String).to_numpy()
        keep, named, clicked = (np.zeros(len(episodes), dtype=bool) for _ in range(3))
        labels = np.full(len(episodes), unlabelled, dtype=object)
        for episode in dict.fromkeys(episodes.tolist()):
            name = episode if episode in intervals else _as_written(episode, intervals, recording.episode)
            if name is None:
                continue
            rows, found = np.flatnonzero(episodes == episode), intervals[name]
            what = f"{recording.path} episode {episode!r}"
            seen.add(name)
            named[rows] = True
            own_unit = found[0].unit or unit
            key = np.arange(len(rows), dtype=np.float64) if own_unit == "frames" else recording.time.to_numpy()[rows]
            if found[0].click:
                _label_from_clicks(key, found, rows, labels, keep, clicked, what)
            else:
                _label_from_intervals(key, found, own_unit, rows, labels, keep, what)
        if named.any() and not keep[named].any():
            raise BadInput(f"{recording.path}: no frame falls in an interval of --labels")
        if unlabelled is not None:
            keep |= named
        keep &= named
        if keep.any():
            values = labels[keep].tolist()
            label_series = (pl.Series("label", values, dtype=pl.Int64) if all(isinstance(v, int) for v in values)
                            else pl.Series("label", [str(v) for v in values], dtype=pl.String))
            found_parts.append(_part(recording, keep, label_series, {
                "labels_file": True, **({"clicks": np.flatnonzero(clicked[keep]).tolist()} if clicked.any() else {})}))
        if not named.all():  # the episodes the labels do not name: their own labels where they have them
            own = None if recording.label is None else recording.label.filter(pl.Series(~named))
            found_parts.append(_part(recording, ~named, own, {}))
    if not seen:
        ids = list(dict.fromkeys(str(e) for r in recordings for e in r.episode.unique(maintain_order=True).to_list()))
        first = next(iter(intervals.values()))[0].where.rsplit(":", 1)[0]
        raise BadInput(f"--labels {first} names no recording of --source (its episodes: {_some(list(intervals))}; "
                       f"the recordings': {_some(ids)}); name the episodes as --source's recordings are named")
    unused = [e for e in intervals if e not in seen]
    if unused:
        raise BadInput(f"{intervals[unused[0]][0].where}: episode {unused[0]!r} is in no recording")
    return found_parts


def _some(names: list[str]) -> str:
    return ", ".join(names[:5]) + (", ..." if len(names) > 5 else "")


def _part(recording: Recording, mask: np.ndarray, label: pl.Series | None, resolved: dict) -> Recording:
    """The rows of ``recording`` in ``mask``, with ``label`` (None: unlabelled)."""
    rows = pl.Series(mask)
    return dataclasses.replace(
        recording, features=recording.features.filter(rows), episode=recording.episode.filter(rows),
        time=recording.time.filter(rows), label=label,
        split=None if recording.split is None else recording.split.filter(rows),
        row=(recording.row if recording.row is not None else pl.int_range(len(mask), eager=True)).filter(rows),
        resolved={**recording.resolved, **resolved})


def _as_written(episode: str, intervals: dict[str, list[Interval]], ids: pl.Series) -> str | None:
    """An episode id a table column holds as a number (1) matches ``001`` in --labels, if only one id does."""
    if not ids.dtype.is_integer():
        return None
    same = [key for key in intervals if key.strip().lstrip("+-").isdigit() and int(key) == int(episode)]
    return same[0] if len(same) == 1 else None


def _label_from_intervals(key: np.ndarray, found: list[Interval], unit: str, rows: np.ndarray, labels: np.ndarray,
                   keep: np.ndarray, what: str) -> None:
    last = key[-1] if unit == "frames" else key[-1] + (np.median(np.diff(key)) if len(key) > 1 else 0.0)
    for interval in found:
        inside = interval.covers(key, unit)
        if interval.start < key[0] or interval.end > last + 1e-9 or not inside.any():
            raise BadInput(f"{interval.where}: interval {interval.start:g}..{interval.end:g} falls outside {what} "
                           f"({key[0]:g}..{last:g} {unit})")
        if keep[rows[inside]].any():
            raise BadInput(f"{interval.where}: overlaps the interval before it in {what}")
        labels[rows[inside]] = interval.label
        keep[rows[inside]] = True


def segments(episodes: list, positions: np.ndarray, times: np.ndarray, classes: list[str], unit: str) -> pl.DataFrame:
    """The runs of one class per episode as ``episode,start,end,label`` in ``unit``, the form ``read`` takes
    back: frames inclusive, seconds from a run's first frame to the next run's (the last run: one median
    step past its last frame)."""
    rows: dict[str, list] = {"episode": [], "start": [], "end": [], "label": []}
    ids = np.asarray(episodes, dtype=object)
    labels = np.asarray(classes, dtype=object)
    for run in runs(ids, labels):
        a, b = run.start, run.stop
        rows["episode"].append(str(ids[a]))
        rows["label"].append(labels[a])
        if unit == "frames":
            rows["start"].append(int(positions[a]))
            rows["end"].append(int(positions[b - 1]))
        else:
            episode_times = times[ids == ids[a]]
            step = float(np.median(np.diff(episode_times))) if len(episode_times) > 1 else 0.0
            rows["start"].append(float(times[a]))
            rows["end"].append(float(times[b]) if b < len(ids) and ids[b] == ids[a] else float(times[b - 1]) + step)
    return pl.DataFrame(rows)
