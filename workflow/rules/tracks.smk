# Track data (SPEC §2): copy from the mirror or download, verify every SHA-256.


rule tracks:
    output:
        track_files(),
    params:
        cfg=lambda wildcards: config_json("tracks"),
    conda:
        CAPE_ENV
    log:
        paths.log("tracks.log"),
    localrule: True
    shell:
        # tee: a failure's message (what to do) shows on the console, not only in the log
        "cape tracks --config-json {params.cfg:q} 2>&1 | tee {log:q}"
