"""Auditing demonstrations: what the labelled recordings of a task look like, learned (``profile.py``: the orders
their phases come in, how long each phase lasts, the rules that hold throughout a phase, how likely the chain found
them), the threshold between ok and suspect chosen by cross-validation on the training recordings (``calibration.py``),
a recording scored against it, reason by reason (``scoring.py``: whole recordings; ``monitor.py``: live, frame by
frame), and the verdicts as rows (``verdicts.py``). `mlnseq audit`, `export`, `stream --monitor` and `ros --monitor`
use it (docs/audit.md)."""
