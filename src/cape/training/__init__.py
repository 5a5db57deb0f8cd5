"""Training the learned models (SPEC §3–§4): the loop and its kernels, one configured
training and its record, the health checks, the draws chosen among trainings, the saved
models, and their open-loop evaluation and tables."""
