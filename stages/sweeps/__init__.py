"""Sweeps: a grid of stage options times seeds on one dataset, run as a Snakemake workflow (pipeline/sweep.py).

grid.py reads and checks the sweep file and expands the grid; workflow.py writes the Snakefile whose rules
are the stage commands; results.py gathers the artifacts' figures into one table.
"""
