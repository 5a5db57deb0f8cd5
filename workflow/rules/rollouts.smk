# Closed-loop runs (SPEC §5, §8): one job per (study, plant, internal model, controller, η, seed).


rule solver:
    input:
        unpack(solver_inputs),
    output:
        "results/solvers/{controller}/{internal}.json",
    params:
        cfg=lambda wildcards: rollout_config_json(wildcards.controller),
    conda:
        CAPE_ENV
    log:
        "results/logs/solvers/{controller}/{internal}.log",
    benchmark:
        "results/benchmarks/solvers/{controller}/{internal}.tsv"
    shell:
        "cape build-solver --controller {wildcards.controller} --internal {wildcards.internal}"
        " --raceline {input.raceline} --out {output} --config-json {params.cfg:q} > {log} 2>&1"


rule rollout:
    input:
        unpack(rollout_inputs),
    output:
        metrics="results/runs/{study}/{plant}/{internal}/{controller}/eta{eta}/seed{seed}/metrics.json",
        timing="results/runs/{study}/{plant}/{internal}/{controller}/eta{eta}/seed{seed}/timing.json",
        series="results/runs/{study}/{plant}/{internal}/{controller}/eta{eta}/seed{seed}/timeseries.parquet",
    params:
        cfg=lambda wildcards: rollout_config_json(wildcards.controller),
        out=lambda wildcards, output: os.path.dirname(output.metrics),
    conda:
        CAPE_ENV
    log:
        "results/logs/runs/{study}/{plant}/{internal}/{controller}/eta{eta}/seed{seed}.log",
    # no benchmark: Snakemake's monitor roughly doubled the wall time of these 1–3 s jobs; the
    # run times its own phases into timing.json (benchmarks/study_cost.py reads them)
    shell:
        "cape rollout --study {wildcards.study} --plant {wildcards.plant}"
        " --controller {wildcards.controller} --internal {wildcards.internal}"
        " --eta {wildcards.eta} --seed {wildcards.seed} --out {params.out}"
        " --raceline {input.raceline} --config-json {params.cfg:q} > {log} 2>&1"


rule rollouts:
    """Every closed-loop run of the grid (a named target)."""
    input:
        rollout_targets(),
    localrule: True


rule figure_rollout:
    """The path and signals of one run, e.g. results/figures/rollout/learned_epm_epm_pid_eta0_seed0.pdf"""
    input:
        metrics="results/runs/{study}/{plant}/{internal}/{controller}/eta{eta}/seed{seed}/metrics.json",
        series="results/runs/{study}/{plant}/{internal}/{controller}/eta{eta}/seed{seed}/timeseries.parquet",
        raceline=raceline_path(),
    output:
        pdf="results/figures/rollout/{study}_{plant}_{internal}_{controller}_eta{eta}_seed{seed}.pdf",
        png="results/figures/rollout/{study}_{plant}_{internal}_{controller}_eta{eta}_seed{seed}.png",
    params:
        cfg=lambda wildcards: config_json("tracks", "data", "reference"),
        run=lambda wildcards, input: os.path.dirname(input.metrics),
    conda:
        CAPE_ENV
    log:
        "results/logs/figures/rollout/{study}_{plant}_{internal}_{controller}_eta{eta}_seed{seed}.log",
    shell:
        "cape plot-rollout --run {params.run} --raceline {input.raceline} --out {output.pdf} --out {output.png}"
        " --config-json {params.cfg:q} > {log} 2>&1"
