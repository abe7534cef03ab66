"""Frames in time: cutting them into episodes, segments and windows, and scoring predicted sequences."""
