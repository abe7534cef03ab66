"""A Rerun recording (``.rrd``) of predictions beside their signals: per episode the features as scalar
series, the true (when known) and predicted class index, and every class's probability, on the recording's
own timeline (``time``, seconds) and by frame (``frame``). Needs rerun-sdk."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import polars as pl

from mlnseq.catalog import artifacts


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
