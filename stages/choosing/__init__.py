"""Choosing on the training split, never on the test split: folds (`folds.py`), cross-validated figures
(`cross_validation.py`), the network factor's weight (`network_weight.py`), the choice of method, decoder and lag
within a latency budget (`latency.py`), and what they read: a workdir's trained pieces as arrays
(`workdir_inputs.py`) and the rows a network fits and is scored on (`training_rows.py`)."""
