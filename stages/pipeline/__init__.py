"""The one library that composes the stages, like Kedro's runner: ``fit`` (fit.py) runs collect, binarize, formulas,
learn-weights, train, conflate and export by their own ``run`` functions and returns what it chose; ``sweep``
(sweep.py) runs a grid of train, conflate and export options times seeds as a Snakemake workflow of the commands.

It stands above the stages: no stage and no other library imports it; only the command line (``mlnseq fit``,
``mlnseq sweep``) and the package's lazy ``mlnseq.fit`` and ``mlnseq.sweep`` do.
"""
