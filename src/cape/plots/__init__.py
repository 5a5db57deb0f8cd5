"""Figures drawn from results (no computation lives here)."""
