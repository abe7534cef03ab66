"""The mlnseq command line: one small module per stage command; main.py registers them."""

import mlnseq  # noqa: F401  (sets the BLAS thread count before numpy loads)
