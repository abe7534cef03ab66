"""Run the real mlnseq CLI with one hook, so the interruption tests can kill it at a known point.

    python tests/stall_driver.py MARKER WHERE ARGS...

WHERE is ``parquet-write`` or ``checkpoint-write`` (write a Parquet artifact's or a checkpoint's temporary
file, cut it to half its size, create MARKER and hang: killed mid-write), or ``running:MODULE:FUNCTION``
(create MARKER once FUNCTION has returned the first time and carry on: killed while it works).
"""

from __future__ import annotations

import importlib
import sys
import time
from pathlib import Path


def half_then_hang(real, marker: Path):
    def write(obj, target, *args, **kwargs):
        real(obj, target, *args, **kwargs)
        if hasattr(target, "flush"):  # an open file (torch.save in save_checkpoint)
            target.flush()
            target = target.name
        Path(target).write_bytes(Path(target).read_bytes()[: Path(target).stat().st_size // 2])
        marker.write_text("mid-write")
        while True:
            time.sleep(1)
    return write


def after_first_call(real, marker: Path):
    def call(*args, **kwargs):
        result = real(*args, **kwargs)
        if not marker.exists():
            marker.write_text("running")
        return result
    return call


def main() -> None:
    marker, where, *args = sys.argv[1:]
    marker = Path(marker)
    if where == "parquet-write":
        from mlnseq.catalog import artifacts

        artifacts.pq.write_table = half_then_hang(artifacts.pq.write_table, marker)
    elif where == "checkpoint-write":
        import torch

        torch.save = half_then_hang(torch.save, marker)
    else:
        _, module_name, function = where.split(":")
        module = importlib.import_module(module_name)
        setattr(module, function, after_first_call(getattr(module, function), marker))
    from mlnseq_cli.main import main as cli

    sys.argv = ["mlnseq", *args]
    cli()


if __name__ == "__main__":
    main()
