"""The errors a stage raises on purpose; the CLI turns each into one line on stderr and an exit code."""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


class MlnseqError(Exception):
    """A run that could not complete (exit 1)."""

    exit_code = 1


class BadInput(MlnseqError):
    """Bad usage or bad input: a file, line or option the user must fix (exit 2)."""

    exit_code = 2


class MissingArtifact(BadInput):
    """An input artifact is absent: says which stage writes it."""


class StaleArtifact(BadInput):
    """An input artifact no longer matches the inputs it was made from: says which stage to rerun."""


class MissingExtra(BadInput):
    """An optional library is not installed: says which extra of mlnseq installs it."""


# The optional libraries by import name: (what needs it, the package, the extra that installs it). The base
# install (numpy, polars, pyarrow, typer, rich) recognises with a model file: info, predict, stream.
EXTRAS = {
    "torch": ("training", "torch", "train"),
    "scipy": ("training", "scipy", "train"),
    "mujoco": ("simulating Fetch", "mujoco", "sim"),
    "gymnasium": ("simulating Fetch", "gymnasium-robotics", "sim"),
    "gymnasium_robotics": ("simulating Fetch", "gymnasium-robotics", "sim"),
    "matplotlib": ("the report's figures", "matplotlib", "report"),
    "rosbags": ("reading this format", "rosbags", "recordings"),
    "h5py": ("reading this format", "h5py", "recordings"),
    "rerun": ("writing a Rerun recording", "rerun-sdk", "recordings"),
}
WHEEL = "mlnseq-{version}-py3-none-any.whl"  # what `make dist` builds: mlnseq is on no package index


def install_hint(extra: str) -> str:
    """How to add an extra where mlnseq came from: its checkout, or the wheel `make dist` built."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        wheel = WHEEL.format(version=version("mlnseq"))
    except PackageNotFoundError:
        wheel = WHEEL.format(version="VERSION")
    return f"pip install '.[{extra}]' in mlnseq's checkout, or pip install '{wheel}[{extra}]' beside the wheel"


def missing_extra(error: ImportError) -> MissingExtra | None:
    """The one-line refusal for an optional library that could not be imported, or None for any other module."""
    name = (error.name or "").split(".")[0]
    if name not in EXTRAS:
        return None
    purpose, package, extra = EXTRAS[name]
    return MissingExtra(f"{purpose} needs {package}, which is not installed: {install_hint(extra)}")


def check_choice(option: str, value: Any, allowed: Iterable[Any], more: str = "") -> None:
    """Refuse a value of ``--option`` that is not one of ``allowed``: "unknown --option 'x': choose one of a, b"
    (then ``more``, the other forms the option takes, if any)."""
    allowed = tuple(allowed)
    if value not in allowed:
        raise BadInput(f"unknown --{option} {value!r}: choose one of {', '.join(map(str, allowed))}"
                       + (f", {more}" if more else ""))
