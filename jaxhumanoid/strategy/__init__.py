"""Solution strategies: one stage (1S) and two stages (2S)."""
