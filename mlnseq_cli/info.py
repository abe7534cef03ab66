"""`mlnseq info`: what a model file holds."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape
from rich.table import Table

from mlnseq_cli.console import console, counted, reported_errors
from stages import methods, model_file, networks, recognizer


def info(
    model: Annotated[Path, typer.Argument(help="A model file written by `mlnseq export`.", dir_okay=False)],
    as_json: Annotated[bool, typer.Option("--json", help="Print the manifest as JSON.")] = False,
) -> None:
    """Read MODEL (.mlnseq); print its method and decoding, classes, features, network, MLN formulas, notes, the mlnseq version that wrote it and the digests of the workdir files it came from."""
    with reported_errors():
        entries = model_file.read_model(model)
        manifest = recognizer.Recognizer(entries, str(model)).manifest  # loads, or says in one line why it cannot
    if as_json:
        print(json.dumps(manifest, indent=1, sort_keys=True))
        return
    table = Table(title=f"{model}", box=None, show_header=False)
    weight = manifest.get("network_weight")
    accuracy = manifest.get("validation_frame_accuracy")
    rows = [
        ("method", methods.decoded_name(manifest["method"], manifest["decode"])),
        ("network factor weight", "–" if weight is None else f"{weight:g}"
         + ("" if accuracy is None else f" (validation frame accuracy {accuracy:.1%})")),
        ("classes", ", ".join(manifest["classes"])),
        ("features", ", ".join(manifest["features"])),
        ("source", manifest.get("source", "")),
    ]
    chosen = manifest.get("chosen_by_cross_validation")
    if chosen:
        figures = chosen["figures"]
        rows.append(("chosen by", f"{chosen['folds']}-fold cross-validation among "
                                  f"{', '.join(sorted(chosen['candidates']))}: segment accuracy "
                                  f"{figures['segment_accuracy']:.1f} %, frame accuracy {figures['frame_accuracy']:.1f} %, "
                                  f"edit {figures['edit']:.1f}, F1@50 {figures['f1_50']:.1f}"))
    if manifest.get("network_weight_how") == "learned":
        rows[1] = ("network factor weight", f"{weight:g} (learned on out-of-fold predictions)")
    network = manifest.get("network")
    if network:
        model_config = network["model"]
        rows.append(("network", f"{network['name']}: {networks.describe(model_config)}, "
                                f"{network['mode']} mode, seed {network['seed']}, epoch {network['kept_epoch']}"
                                + (f", PriorLayer input {network['prior']}" if network.get("prior") else "")))
    if model_file.WEIGHTS in entries:
        rows.append(("MLN", f"{counted(len(manifest['predicates']), 'predicate column')}, mln-mode {manifest['mln_mode']}"))
    limits = model_file.member_limits(manifest, model)
    rows.append(("members", ", ".join(f"{name} {len(data):,} bytes (limit {limits[name]:,})" for name, data in entries.items())))
    rows += [("written by", f"mlnseq {manifest['mlnseq_version']}, {manifest['created']}, format {manifest['format']}"),
             ("inputs", ", ".join(f"{k} {v}" for k, v in manifest["inputs"].items()))]
    for name, value in rows:
        table.add_row(name, escape(value))
    console.print(table)
    for note in manifest.get("notes", []):
        console.print(f"[yellow]note[/]: {escape(note)}")
