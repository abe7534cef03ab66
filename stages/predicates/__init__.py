"""The predicate spec and its rules (batch and streaming, written once)."""
