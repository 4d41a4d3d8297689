"""Optimal control problem: tasks T1-T4, schemes, implicit-midpoint transcription (6)-(8)."""
