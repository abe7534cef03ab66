"""A Rerun recording (``.rrd``) of predictions beside their signals: per episode the features as scalar
series, the true (when known) and predicted class index, and every class's probability, on the recording's
own timeline (``time``, seconds), by frame (``frame``) and, for messages (a bag: predict's ``stamp``), on their
clock (``stamp``, a wall-clock timeline); and the predicted (and true) segments as time ranges,
Rerun's state lanes (the segments ``--write-lerobot`` writes back). Needs rerun-sdk."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts
from mlnseq.timeline.sequences import run_starts


def _send_segments(recording, entity: str, names: np.ndarray, times: np.ndarray, frames: np.ndarray) -> None:
    """An episode's runs of one class as time ranges (Rerun's state lanes): each class from its run's first frame,
    and no state from one step past the last frame."""
    import rerun as rr

    labels = np.asarray(names, dtype=object)
    starts = run_starts(labels)
    step = float(np.median(np.diff(times))) if len(times) > 1 else 0.0
    index = [rr.TimeColumn("time", duration=np.r_[times[starts], times[-1] + step]),
             rr.TimeColumn("frame", sequence=np.r_[frames[starts], frames[-1] + 1])]
    recording.send_columns(entity, indexes=index,
                           columns=rr.StateChange.columns(state=[*map(str, labels[starts]), ""]))  # "": a reset


def write(path: Path, episodes: list, frames: pl.DataFrame, times: np.ndarray, predictions: pl.DataFrame,
          features: list[str], classes: list[str], why: list[tuple] | None = None) -> Path:
    """``frames`` and ``predictions`` row by row (the same order); ``episodes`` the user's id per row; ``why``:
    (episode, time, frame, text) of each segment's first frame, logged as text (`predict --explain`)."""
    try:
        import rerun as rr
    except ImportError as error:
        from mlnseq.sources import missing_extra

        raise missing_extra("rerun-sdk", error) from error
    ids = np.asarray([str(e) for e in episodes], dtype=object)
    with artifacts.atomic_path(Path(path)) as tmp, open(tmp, "wb") as handle:
        recording = rr.RecordingStream("mlnseq")
        stream = recording.binary_stream()  # written here, so that a full disk is an OSError, not a Rust log line
        for episode in dict.fromkeys(ids.tolist()):
            rows = np.flatnonzero(ids == episode)
            index = [rr.TimeColumn("time", duration=times[rows]),
                     rr.TimeColumn("frame", sequence=frames["frame"].to_numpy()[rows])]
            if "stamp" in predictions.columns:  # the messages' clock: seconds since the epoch
                index.append(rr.TimeColumn("stamp", timestamp=predictions["stamp"].to_numpy()[rows]))
            part = rr.escape_entity_path_part
            base = f"episode/{part(episode)}"
            series = {f"features/{part(name)}": frames[name].to_numpy()[rows] for name in features}
            series["class/predicted"] = np.asarray(predictions["class"].replace_strict(
                classes, list(range(len(classes))), return_dtype=pl.Int64).to_numpy()[rows], dtype=np.float64)
            if "label" in predictions.columns:
                series["class/true"] = frames["label"].to_numpy()[rows].astype(np.float64)
            series.update({f"probability/{part(name)}": predictions[f"p_{name}"].to_numpy()[rows].astype(np.float64)
                           for name in classes})
            for entity, values in series.items():
                recording.send_columns(f"{base}/{entity}", indexes=index,
                                       columns=rr.Scalars.columns(scalars=np.asarray(values, dtype=np.float64)))
            true = (np.asarray(classes, dtype=object)[frames["label"].to_numpy()[rows]]
                    if "label" in predictions.columns else None)
            for lane, names in (("predicted", predictions["class"].to_numpy()[rows]), ("true", true)):
                if names is not None:
                    _send_segments(recording, f"{base}/segments/{lane}", names, times[rows],
                                   frames["frame"].to_numpy()[rows])
            logged = [entry for entry in why or () if str(entry[0]) == episode]
            if logged:
                recording.send_columns(f"{base}/why", indexes=[
                    rr.TimeColumn("time", duration=[entry[1] for entry in logged]),
                    rr.TimeColumn("frame", sequence=[entry[2] for entry in logged])],
                    columns=rr.TextLog.columns(text=[entry[3] for entry in logged]))
        recording.flush()
        handle.write(stream.read() or b"")  # at once: reading it in parts breaks the file's checksums (rerun 0.41)
        recording.disconnect()
        handle.write(stream.read() or b"")
    return Path(path)
