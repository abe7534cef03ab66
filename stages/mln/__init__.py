"""The logic engine: the .mln parser, grounding on per-frame and consecutive-frame atoms, the native learners
(pseudo-likelihood: bpll; conditional likelihood of chains: cll), the pracmln bridge, the per-frame MLN
classifier, the MLN's chain factors and exact chain inference."""
