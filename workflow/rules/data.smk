# The training and test data sets (SPEC §3), reproduced from the BayesRace protocol.


rule dataset:
    input:
        track_files(),
    output:
        paths.DATASET,
    params:
        cfg=lambda wildcards: config_json("tracks", "data"),
    conda:
        CAPE_ENV
    log:
        paths.log("data", "{track}.log"),
    benchmark:
        paths.benchmark("data", "{track}.tsv")
    shell:
        "cape data --track {wildcards.track} --out {output:q} --config-json {params.cfg:q} > {log:q} 2>&1"
