"""Runs `make reproduce`'s stage commands in processes forked from one that has already imported torch and the
data libraries, so that each of its ~300 stage runs skips that start-up (about 4 s of CPU for a command that
runs a network, on this 2-core machine; the whole reproduction's start-up was more than its compute).

    python scripts/stage_server.py serve SOCKET          preload the libraries, then fork a child per request
    python scripts/stage_server.py run SOCKET MLNSEQ ARGS...
                                                         run `MLNSEQ ARGS...` there, or here when no server
                                                         listens on SOCKET

A child runs what `mlnseq ARGS...` runs, in the client's folder, with its environment and its standard
streams (passed over the socket); the client exits with the child's status. The server also imports the
reproduction's stages (the `mlnseq` package, not the command line's modules, whose console reads the child's
terminal): a child whose mlnseq sources changed since then drops those modules and imports them from disk, so an
edited stage runs as edited.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import os
import signal
import socket
import sys
import traceback
from pathlib import Path

# scipy.optimize, .sparse and .linalg: the MLN learners (learn-weights) and conflate's network-weight learning (cll)
PRELOAD = ("numpy", "polars", "pyarrow.parquet", "scipy.special", "scipy.optimize", "scipy.sparse", "scipy.linalg",
           "torch", "typer", "rich.console", "rich.progress", "rich.table")
# typer's option parsing, which imports pydantic at a command's first parse (about 0.2 s of every stage run);
# a module of typer's own, so it is skipped where this typer does not have it
OPTIONAL_PRELOAD = ("typer._adapters",)
# the stages `make reproduce` runs, with the libraries they import
OWN_PRELOAD = tuple(f"mlnseq.{stage}" for stage in ("collect", "binarize", "formulas", "learn_weights", "train",
                                                     "conflate", "eval", "report"))
STREAMS = (0, 1, 2)
MESSAGE_BYTES = 1 << 20


def serve(path: Path) -> None:
    """Listen at ``path`` at once (early requests wait in the backlog), preload, then serve until killed."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with contextlib.suppress(FileNotFoundError):
        path.unlink()
    listener = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    listener.bind(str(path))
    listener.listen(64)
    import mlnseq  # noqa: F401  (sets the BLAS thread count before numpy loads, as the mlnseq command does)

    for name in PRELOAD:
        importlib.import_module(name)
    for name in (*OPTIONAL_PRELOAD, *OWN_PRELOAD):  # a stage that fails to import fails in its own run, with its error
        with contextlib.suppress(Exception):
            importlib.import_module(name)
    preloaded = own_sources()
    signal.signal(signal.SIGCHLD, signal.SIG_IGN)  # the kernel reaps the children; each reports to its client
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))
    try:
        while True:
            connection, _ = listener.accept()
            if os.fork() == 0:
                listener.close()
                signal.signal(signal.SIGCHLD, signal.SIG_DFL)
                signal.signal(signal.SIGTERM, signal.SIG_DFL)
                forget_edited(preloaded)
                os._exit(run_request(connection))
            connection.close()
    finally:
        with contextlib.suppress(FileNotFoundError):
            path.unlink()


def own_sources() -> dict[str, int]:
    """The source file of every mlnseq module imported here, with its modification time."""
    return {module.__file__: os.stat(module.__file__).st_mtime_ns for name, module in list(sys.modules.items())
            if name.split(".")[0] == "mlnseq" and getattr(module, "__file__", None)}


def forget_edited(preloaded: dict[str, int]) -> None:
    """Drop every mlnseq module, the package's own included (it holds its submodules), if any source the server
    imported changed since: imported again, from disk, they run as edited."""
    try:
        unchanged = all(os.stat(path).st_mtime_ns == mtime for path, mtime in preloaded.items())
    except OSError:  # a source removed
        unchanged = False
    if not unchanged:
        for name in [name for name in sys.modules if name.split(".")[0] == "mlnseq"]:
            del sys.modules[name]


def run_request(connection: socket.socket) -> int:
    """In a forked child: take the client's streams, folder, environment and arguments; run the command."""
    message, streams, _, _ = socket.recv_fds(connection, MESSAGE_BYTES, len(STREAMS))
    request = json.loads(message)
    for target, fd in zip(STREAMS, streams):
        os.dup2(fd, target)
        os.close(fd)
    os.chdir(request["cwd"])
    os.environ.clear()
    os.environ.update(request["env"])
    sys.argv = request["argv"]
    try:
        from mlnseq_cli.main import main

        main()
        status = 0
    except SystemExit as done:
        status = done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    except BaseException:  # noqa: BLE001  (what an uncaught error does to a plain run: traceback, status 1)
        traceback.print_exc()
        status = 1
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    connection.send(str(status).encode())
    return status


def run(path: Path, command: list[str]) -> None:
    """Send ``command`` (the mlnseq executable and its arguments) to the server; exit with its status."""
    client = socket.socket(socket.AF_UNIX, socket.SOCK_SEQPACKET)
    try:
        client.connect(str(path))
    except OSError:  # no server: the command runs as a process of its own
        os.execv(command[0], command)
    request = {"argv": ["mlnseq", *command[1:]], "cwd": os.getcwd(), "env": dict(os.environ)}
    socket.send_fds(client, [json.dumps(request).encode()], list(STREAMS))
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C reaches the child too: its status answers
    reply = client.recv(16)
    if not reply:
        print(f"error: the process running `mlnseq {' '.join(command[1:])}` ended without a status (killed?)",
              file=sys.stderr)
        sys.exit(1)
    sys.exit(int(reply))


def main(argv: list[str]) -> None:
    if len(argv) >= 2 and argv[0] == "serve":
        serve(Path(argv[1]))
    elif len(argv) >= 3 and argv[0] == "run":
        run(Path(argv[1]), argv[2:])
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main(sys.argv[1:])
