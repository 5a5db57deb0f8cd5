# The training and test data sets (SPEC §3), reproduced from the BayesRace protocol.


rule dataset:
    input:
        TRACKS.files(),
    output:
        paths.DATASET,
    params:
        spec=lambda wildcards: JOBS.write_sections("dataset", "tracks", "data"),
    conda:
        CAPE_ENV
    log:
        paths.log("data", "{track}.log"),
    benchmark:
        paths.benchmark("data", "{track}.tsv")
    shell:
        "cape data --track {wildcards.track} --out {output:q} --spec {params.spec:q} > {log:q} 2>&1"
