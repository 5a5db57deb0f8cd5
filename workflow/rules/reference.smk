# The closed-loop reference (SPEC §2): CAPE's minimum-curvature raceline of a track.


rule raceline:
    input:
        TRACKS.files(),
    output:
        line=paths.RACELINE,
        pdf=paths.figures("raceline_{track}.pdf"),
        png=paths.figures("raceline_{track}.png"),
    params:
        spec=lambda wildcards: JOBS.write_sections("raceline", "tracks", "reference"),
        # checked against the line's ideal lap before any run starts (a limit no lap can meet)
        time_limit=TRACKS.time_limit,
    conda:
        CAPE_ENV
    log:
        paths.log("raceline", "{track}.log"),
    shell:
        "cape raceline --track {wildcards.track} --out {output.line:q}"
        " --figure {output.pdf:q} --figure {output.png:q} --time-limit {params.time_limit}"
        " --spec {params.spec:q} > {log:q} 2>&1"
