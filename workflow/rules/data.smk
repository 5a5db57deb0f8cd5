# The training and test data sets (SPEC §3), reproduced from the BayesRace protocol.


rule dataset:
    input:
        track_files(),
    output:
        "results/data/DYN-PP-{track}.npz",
    params:
        cfg=lambda wildcards: config_json("tracks", "data"),
    conda:
        CAPE_ENV
    log:
        "results/logs/data/{track}.log",
    benchmark:
        "results/benchmarks/data/{track}.tsv"
    shell:
        "cape data --track {wildcards.track} --out {output:q} --config-json {params.cfg:q} > {log:q} 2>&1"
