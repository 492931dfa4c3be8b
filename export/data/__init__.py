"""Training-data sources: CC0 material seeds (and, later, procedural materials)."""
