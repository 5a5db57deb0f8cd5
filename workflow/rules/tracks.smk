# Track data (SPEC §2): copy from the mirror or download, verify every SHA-256.


rule tracks:
    output:
        TRACKS.files(),
    params:
        spec=lambda wildcards: JOBS.write_sections("tracks", "tracks"),
    conda:
        CAPE_ENV
    log:
        paths.log("tracks.log"),
    localrule: True
    shell:
        # tee: a failure's message (what to do) shows on the console, not only in the log
        "cape tracks --spec {params.spec:q} 2>&1 | tee {log:q}"
