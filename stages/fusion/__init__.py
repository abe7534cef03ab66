"""What every recogniser path shares: the network's and the MLN's class distributions fused (eq. 16), a decoded
method's chain, and the one dispatch to its decoder (`fuse.py`, `decoding.py`). conflate, cross-validation,
`Recognizer` and the explanations all fuse and decode here."""
