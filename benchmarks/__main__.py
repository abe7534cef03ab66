"""Run every ``benchmarks/bench_*.py`` module's ``main()`` in turn, or only those named on the line.

``python -m benchmarks`` runs them all; ``python -m benchmarks collect`` runs ``bench_collect`` only.
"""

from __future__ import annotations

import importlib
import pkgutil
import sys
from pathlib import Path


def bench_modules() -> list[str]:
    names = [m.name for m in pkgutil.iter_modules([str(Path(__file__).parent)]) if m.name.startswith("bench_")]
    return sorted(names)


def main(argv: list[str]) -> int:
    available = bench_modules()
    wanted = [name if name.startswith("bench_") else f"bench_{name}" for name in argv] or available
    unknown = sorted(set(wanted) - set(available))
    if unknown:
        print(f"error: no benchmark {', '.join(unknown)}; choose from {', '.join(available)}", file=sys.stderr)
        return 2
    for name in wanted:
        print(f"== {name}", flush=True)
        importlib.import_module(f"benchmarks.{name}").main()
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
