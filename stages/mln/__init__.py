"""The logic engine: the .mln parser, grounding on per-frame atoms, the native BPLL learner, the
pracmln bridge and the MLN classifier."""
