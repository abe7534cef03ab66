"""What a trained recogniser is saved as: network checkpoints in the workdir and the `.mlnseq` model file."""
