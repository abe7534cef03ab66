"""Fusion and decoding, the network weight, folds and cross-validation, and `Recognizer`."""
