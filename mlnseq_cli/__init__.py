"""The mlnseq command line: one small module per stage command; main.py registers them."""
