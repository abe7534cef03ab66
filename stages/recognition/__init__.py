"""Recognising at run time: `Recognizer` (a model file: frames in, class probabilities out), live ROS messages fed
to it (`live.py`), new recordings read as the model's were (`reading.py`), and predict's explanation columns
(`reasons.py`). A change to how frames are fused or decoded goes to fusion/; to how a decision is explained, to
explaining/."""
