# Figures built straight from the data (the study's figures come from notebooks later).


rule figure_tracks:
    input:
        TRACKS.files(),
        data=[paths.dataset(t) for t in TRACKS.data_tracks],
    output:
        pdf=paths.figures("tracks_and_data.pdf"),
        png=paths.figures("tracks_and_data.png"),
    params:
        data=" ".join(f"--data {shlex.quote(f'{t}={paths.dataset(t)}')}" for t in TRACKS.data_tracks),
        spec=lambda wildcards: JOBS.write_sections("figure_tracks", "tracks", "data"),
    conda:
        CAPE_ENV
    log:
        paths.log("figures", "tracks_and_data.log"),
    shell:
        "cape plot-tracks {params.data} --out {output.pdf:q} --out {output.png:q}"
        " --spec {params.spec:q} > {log:q} 2>&1"
