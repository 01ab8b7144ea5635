"""Contracts of carlaocc: pydantic models and the taxonomy table. No I/O, nothing of ours imported."""
