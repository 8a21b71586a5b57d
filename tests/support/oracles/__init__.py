"""Slow, obviously right references for the FE plugin's tests (not shipped)."""
