"""The study from its runs to its answers (SPEC §8–§10). Here: the grid (``grid``), every run in
one tidy table (``aggregate``), the other files the scorecard reads (``inputs``) and an
aggregation missing runs (``stale``). Below: the statistics (``stats/``), the paper's claims and
tables 8 and 9 (``claims/``), the ground-truth question (``question/``), and the tables,
notebooks and published study (``reports/``)."""
