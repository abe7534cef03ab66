"""The sweep's Snakemake workflow: a Snakefile whose rules are the stage commands, and the configs it reads.

Per config and seed, a workdir ``runs/CONFIG/seed-N`` links the dataset's shared inputs (as `make reproduce`
does; the train rule's command makes the links), then ``mlnseq train``, ``conflate --decode all`` and ``eval
--method all`` run in it as shell commands, so that Snakemake's own bookkeeping (file times, the rules'
parameters and code) decides what is missing or stale, and its executors run the same rules on this machine or
on a cluster. Every rule is a ``shell:`` command: Snakemake 9's local executor runs a ``run:`` block in a new
Snakemake process that parses the workflow again (about 1 s of CPU and 2-3 s of wall per job).
"""

from __future__ import annotations

import json
import re
import shlex
from pathlib import Path
from typing import Any

from mlnseq.catalog import artifacts
from mlnseq.sweeps.grid import Sweep, flags

SNAKEFILE = "Snakefile"
FORMULAS_DIR = "formulas"  # OUT/formulas/SPEC: a grid formulas file's weights
CONFIG_FILE = "sweep.json"
RUNS = "runs"
SHARED_INPUTS = (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS, artifacts.FOLD_WEIGHTS)
# Resources a cluster schedules each rule with; a profile's set-resources / set-threads override them.
RESOURCES = {"train": {"mem_mb": 2000, "runtime": 60}, "conflate": {"mem_mb": 4000, "runtime": 30},
             "eval": {"mem_mb": 2000, "runtime": 10}}

TEMPLATE = '''\
# Written by `mlnseq sweep {sweep_file}`: the stage commands per config and seed. Edit the sweep file and run
# `mlnseq sweep` again rather than this file, which it rewrites. Every rule is a shell command: Snakemake runs
# those itself, where a `run:` block would cost a second Snakemake process (it parses this file again) per job.
import os
import re
import shlex

configfile: "{config_file}"

CONFIGS = config["configs"]
WORKDIR = "{runs}/{{config}}/seed-{{seed}}"
IN_SHELL = "{runs}/{{wildcards.config}}/seed-{{wildcards.seed}}"  # in a shell command, {{config}} is the config dict

wildcard_constraints:
    config="|".join(re.escape(name) for name in CONFIGS),
    seed=r"\\d+",

localrules: all

rule all:
    input: expand(WORKDIR + "/{metrics}", config=list(CONFIGS), seed=config["seeds"])

def shared_inputs(wildcards):
    return list(CONFIGS[wildcards.config]["sources"].values())

def links(wildcards):
    """The shell commands that link a config's workdir to its inputs (again on a rerun: ln -sfn replaces them)."""
    folder = f"{runs}/{{wildcards.config}}/seed-{{wildcards.seed}}"
    return " && ".join(f"ln -sfn {{shlex.quote(os.path.abspath(source))}} {{shlex.quote(os.path.join(folder, name))}}"
                       for name, source in CONFIGS[wildcards.config]["sources"].items())

# A formulas file of the grid: the dataset's frames and predicates linked, `formulas --spec`, then its weights and
# each fold's, learned with the dataset's folds.
rule formulas:
    input: lambda w: config["specs"][w.spec]
    output: "{formulas}/{{spec}}/formulas.mln"
    params: spec=lambda w: config["specs_quoted"][w.spec], mlnseq=config["mlnseq"], dir="{formulas}/{{spec}}",
            shared=config["shared_quoted"]
    log: "{formulas}/{{spec}}/logs/formulas.log"
    shell: "ln -sfn {{params.shared}}/{frames} {{params.dir}}/{frames} && "
           "ln -sfn {{params.shared}}/{predicates} {{params.dir}}/{predicates} && "
           "{{params.mlnseq}} formulas --spec {{params.spec}} --workdir {{params.dir}} > {{log}} 2>&1"

rule learn_weights:
    input: "{formulas}/{{spec}}/formulas.mln"
    output: "{formulas}/{{spec}}/{weights}", "{formulas}/{{spec}}/{fold_weights}"
    params: mlnseq=config["mlnseq"], folds=config["folds"], dir="{formulas}/{{spec}}"
    log: "{formulas}/{{spec}}/logs/learn-weights.log"
    threads: 1
    resources: mem_mb=2000, runtime=30
    shell: "{{params.mlnseq}} learn-weights {{input}} --folds {{params.folds}} --workdir {{params.dir}} > {{log}} 2>&1"

# The config's workdir linked to the dataset's inputs (or its formulas' weights), then the networks trained in it.
rule train:
    input: shared_inputs
    output: WORKDIR + "/models/{{network}}.pt"
    params: links=links, flags=lambda w: CONFIGS[w.config]["train"] + " --seed " + w.seed, mlnseq=config["mlnseq"]
    log: WORKDIR + "/logs/train-{{network}}.log"
    threads: 1
    resources: {train}
    shell: "{{params.links}} && {{params.mlnseq}} train {{params.flags}} --workdir " + IN_SHELL + " > {{log}} 2>&1"

rule conflate:
    input: lambda w: f"{runs}/{{w.config}}/seed-{{w.seed}}/models/{{CONFIGS[w.config]['network']}}.pt"
    output: WORKDIR + "/{predictions}"
    params: flags=lambda w: CONFIGS[w.config]["conflate"], mlnseq=config["mlnseq"]
    log: WORKDIR + "/logs/conflate.log"
    threads: 1
    resources: {conflate}
    shell: "{{params.mlnseq}} conflate --decode all {{params.flags}} --workdir " + IN_SHELL + " > {{log}} 2>&1"

rule eval:
    input: WORKDIR + "/{predictions}"
    output: WORKDIR + "/{metrics}"
    params: mlnseq=config["mlnseq"]
    log: WORKDIR + "/logs/eval.log"
    threads: 1
    resources: {eval}
    shell: "{{params.mlnseq}} eval --method all --workdir " + IN_SHELL + " > {{log}} 2>&1"
'''


def snakefile(sweep_file: Path) -> str:
    """The Snakefile's text (the same for every sweep: what varies is in the config file)."""
    resources = {rule: ", ".join(f"{k}={v}" for k, v in values.items()) for rule, values in RESOURCES.items()}
    return TEMPLATE.format(sweep_file=sweep_file.name, config_file=CONFIG_FILE, runs=RUNS, formulas=FORMULAS_DIR,
                           metrics=artifacts.METRICS, predictions=artifacts.PREDICTIONS, frames=artifacts.FRAMES,
                           predicates=artifacts.PREDICATES, weights=artifacts.WEIGHTS,
                           fold_weights=artifacts.FOLD_WEIGHTS, **resources)


def spec_names(sweep: Sweep) -> dict[Path, str]:
    """A folder name per formulas file of the grid: its stem, numbered where two stems are alike."""
    names: dict[Path, str] = {}
    for spec in dict.fromkeys(c.formulas for c in sweep.configs if c.formulas is not None):
        stem = re.sub(r"[^A-Za-z0-9.+-]+", "-", spec.stem)
        names[spec] = stem if stem not in names.values() else f"{stem}-{len(names) + 1}"
    return names


def sources(shared: str, spec: str | None) -> dict[str, str]:
    """Where a config's workdir links each input from: the dataset, or for the weights its formulas' folder."""
    linked = {name: f"{shared}/{name}" for name in SHARED_INPUTS}
    if spec is not None:
        for name in (artifacts.WEIGHTS, artifacts.FOLD_WEIGHTS):
            linked[name] = f"{FORMULAS_DIR}/{spec}/{name}"
    return linked


def workflow_config(sweep: Sweep, mlnseq: str) -> dict[str, Any]:
    """What the Snakefile reads: the command, the dataset, its folds, the formulas files, the seeds and each
    config's flags and inputs."""
    shared = str(sweep.workdir.resolve())
    specs = spec_names(sweep)
    folds = artifacts.read_metadata(sweep.workdir / artifacts.FOLD_WEIGHTS, "fold_weights")["folds"]["k"]
    return {
        "mlnseq": shlex.quote(mlnseq),
        "shared": shared,
        "shared_quoted": shlex.quote(shared),
        "folds": folds,
        "specs": {name: str(path) for path, name in specs.items()},
        "specs_quoted": {name: shlex.quote(str(path)) for path, name in specs.items()},
        "seeds": list(sweep.seeds),
        "configs": {c.name: {"network": c.options["train"].method,
                             "sources": sources(shared, specs.get(c.formulas)),
                             "train": shlex.join(flags("train", c.options["train"])),
                             "conflate": shlex.join(flags("conflate", c.options["conflate"]))}
                    for c in sweep.configs},
    }


def write(sweep: Sweep, out: Path, mlnseq: str) -> Path:
    """Write OUT/Snakefile and OUT/sweep.json atomically; return the Snakefile's path."""
    out.mkdir(parents=True, exist_ok=True)
    config = json.dumps(workflow_config(sweep, mlnseq), indent=1, sort_keys=True) + "\n"
    if not (out / CONFIG_FILE).exists() or (out / CONFIG_FILE).read_text() != config:  # unchanged: left alone
        artifacts.write_text(out / CONFIG_FILE, config)
    text = snakefile(sweep.path)
    if not (out / SNAKEFILE).exists() or (out / SNAKEFILE).read_text() != text:
        artifacts.write_text(out / SNAKEFILE, text)
    return out / SNAKEFILE


def run_dir(out: Path, config: str, seed: int) -> Path:
    return out / RUNS / config / f"seed-{seed}"
