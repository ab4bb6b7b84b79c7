"""The guard: the only road from model text to motion (extract, repair, validate, veto)."""
