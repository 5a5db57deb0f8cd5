"""What a study shows and publishes: every table and figure declared once, the tables as
data, what the notebooks share, the scorecard's evidence, the one-page glance and the
published study."""
