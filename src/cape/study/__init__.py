"""The study's aggregation: every run in one tidy table, and the summaries the figures use."""
