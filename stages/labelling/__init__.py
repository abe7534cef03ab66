"""Labelling less: where a phase ends between two clicks (``clicks.py``), the unlabelled recordings learned from by
self-training (``self_training.py``) and which recording to label next (``label_next.py``)."""
