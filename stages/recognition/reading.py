"""How new recordings are read for a model: as its own recordings were read (its manifest's ``reading``: env,
episode, time and label columns, the source's options such as topics and rate), options given overriding it.
`predict` and `explain` read them so."""

from __future__ import annotations

import dataclasses
from typing import Any

from mlnseq.sources import RECORDING_ENVS, SourceOptions
from mlnseq.sources.recording import Labels, TableColumns


def reading_of(model: Any, options: Any) -> tuple[str, TableColumns, SourceOptions, str]:
    """The env, columns and source options to read new recordings with: the model's (a Recognizer), overridden by
    ``options`` (its env, label_column, episode_column, time_column and overrides); and whether labels are required
    (a named label column) or optional."""
    kept = model.manifest.reading or {}
    env = options.env or (kept.get("env") if kept.get("env") in RECORDING_ENVS else "table")
    same = env == kept.get("env")
    pick = lambda given, key, default=None: (  # noqa: E731
        given if given is not None else (kept.get(key, default) if same else default))
    columns = TableColumns(label=pick(options.label_column, "label_column", "label"),
                           episode=pick(options.episode_column, "episode_column"),
                           time=pick(options.time_column, "time_column"),
                           features=tuple(model.features), classes=tuple(model.classes))
    names = {f.name for f in dataclasses.fields(SourceOptions)} - {"labels"}
    known = {k: (tuple(v) if isinstance(v, list) else v) for k, v in kept.items() if k in names} if same else {}
    if options.label_column is not None:  # a label column named: not the annotations the model's labels came from
        known.pop("annotations", None)
    recordings = SourceOptions(**{**known, **options.overrides})
    return env, columns, recordings, Labels.REQUIRED if options.label_column is not None else Labels.OPTIONAL
