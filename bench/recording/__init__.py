"""Recordings: replay speed, determinism and export."""
