"""The paper's claims (SPEC §10) and their judgement: each declared once, evaluated on a
scope's runs (table 8, the scorecard) and ranked per model (table 9, the leaderboard)."""
