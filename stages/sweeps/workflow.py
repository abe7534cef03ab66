"""The sweep's Snakemake workflow: a Snakefile whose rules are the stage commands, and the configs it reads.

Per config and seed, a workdir ``runs/CONFIG/seed-N`` links the dataset's shared inputs (as `make reproduce`
does), then ``mlnseq train``, ``conflate --decode all`` and ``eval --method all`` run in it as shell commands,
so that Snakemake's own bookkeeping (file times, the rules' parameters and code) decides what is missing or
stale, and its executors run the same rules on this machine or on a cluster.
"""

from __future__ import annotations

import json
import shlex
from pathlib import Path
from typing import Any

from mlnseq.catalog import artifacts
from mlnseq.sweeps.grid import Sweep, flags

SNAKEFILE = "Snakefile"
CONFIG_FILE = "sweep.json"
RUNS = "runs"
SHARED_INPUTS = (artifacts.FRAMES, artifacts.PREDICATES, artifacts.WEIGHTS, artifacts.FOLD_WEIGHTS)
# Resources a cluster schedules each rule with; a profile's set-resources / set-threads override them.
RESOURCES = {"train": {"mem_mb": 2000, "runtime": 60}, "conflate": {"mem_mb": 4000, "runtime": 30},
             "eval": {"mem_mb": 2000, "runtime": 10}}

TEMPLATE = '''\
# Written by `mlnseq sweep {sweep_file}`: the stage commands per config and seed. Edit the sweep file and run
# `mlnseq sweep` again rather than this file, which it rewrites.
import re

configfile: "{config_file}"

CONFIGS = config["configs"]
WORKDIR = "{runs}/{{config}}/seed-{{seed}}"
IN_SHELL = "{runs}/{{wildcards.config}}/seed-{{wildcards.seed}}"  # in a shell command, {{config}} is the config dict

wildcard_constraints:
    config="|".join(re.escape(name) for name in CONFIGS),
    seed=r"\\d+",

localrules: all, link

rule all:
    input: expand(WORKDIR + "/{metrics}", config=list(CONFIGS), seed=config["seeds"])

rule link:
    input: [config["shared"] + "/" + name for name in config["inputs"]]
    output: touch(WORKDIR + "/.inputs-linked")
    params: names=" ".join(config["inputs"]), shared=config["shared_quoted"]
    shell: "for name in {{params.names}}; do ln -sfn {{params.shared}}/$name $(dirname {{output}})/$name; done"

rule train:
    input: WORKDIR + "/.inputs-linked"
    output: WORKDIR + "/models/{{network}}.pt"
    params: flags=lambda w: CONFIGS[w.config]["train"] + " --seed " + w.seed, mlnseq=config["mlnseq"]
    log: WORKDIR + "/logs/train-{{network}}.log"
    threads: 1
    resources: {train}
    shell: "{{params.mlnseq}} train {{params.flags}} --workdir " + IN_SHELL + " > {{log}} 2>&1"

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
    return TEMPLATE.format(sweep_file=sweep_file.name, config_file=CONFIG_FILE, runs=RUNS,
                           metrics=artifacts.METRICS, predictions=artifacts.PREDICTIONS, **resources)


def workflow_config(sweep: Sweep, mlnseq: str) -> dict[str, Any]:
    """What the Snakefile reads: the command, the shared inputs, the seeds and each config's flags."""
    shared = str(sweep.workdir.resolve())
    return {
        "mlnseq": shlex.quote(mlnseq),
        "shared": shared,
        "shared_quoted": shlex.quote(shared),
        "inputs": list(SHARED_INPUTS),
        "seeds": list(sweep.seeds),
        "configs": {c.name: {"network": c.options["train"].method,
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
