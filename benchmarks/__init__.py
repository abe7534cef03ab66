"""Speed figures measured side by side: ``python -m benchmarks [name ...]`` runs every ``bench_*.py``."""
