# Closed-loop runs (SPEC §5, §8): one job per (study, plant, internal model, controller, η, seed).


rule solver:
    input:
        unpack(RUNS.solver_inputs),
    output:
        paths.SOLVER,
    params:
        spec=lambda wildcards: JOBS.write_solver(wildcards.controller, wildcards.internal),
        models=lambda wildcards: RUNS.model_folder_args(wildcards, [wildcards.internal]),
    conda:
        CAPE_ENV
    log:
        paths.log("solvers", paths.REP, "{controller}", "{internal}.log"),
    benchmark:
        paths.benchmark("solvers", paths.REP, "{controller}", "{internal}.tsv")
    shell:
        "cape build-solver --controller {wildcards.controller} --internal {wildcards.internal}"
        " --raceline {input.raceline:q} --out {output:q} {params.models} --spec {params.spec:q} > {log:q} 2>&1"


rule rollout:
    input:
        unpack(RUNS.rollout_inputs),
    output:
        metrics=f"{RUN_FOLDER}/{paths.METRICS}",
        timing=f"{RUN_FOLDER}/{paths.TIMING}",
        series=f"{RUN_FOLDER}/{paths.SERIES}",
    params:
        spec=lambda wildcards: JOBS.write_rollout(wildcards.controller, wildcards.plant, wildcards.internal),
        out=lambda wildcards, output: os.path.dirname(output.metrics),
        models=lambda wildcards: RUNS.model_folder_args(wildcards, RUNS.rollout_models(wildcards)),
        data=lambda wildcards, input: RUNS.training_data_arg(input),
    conda:
        CAPE_ENV
    log:
        f"{RUN_LOG}.log",
    # no benchmark: its monitor costs these short jobs more than they run (docs/design.md); the
    # run times its own phases into timing.json (benchmarks/study_cost.py reads them)
    shell:
        "cape rollout --study {wildcards.study} --plant {wildcards.plant}"
        " --controller {wildcards.controller} --internal {wildcards.internal}"
        " --eta {wildcards.eta} --seed {wildcards.seed} --replicate {wildcards.replicate}"
        " --out {params.out:q} {params.models} {params.data}"
        " --raceline {input.raceline:q} --spec {params.spec:q} > {log:q} 2>&1"


rule rollouts:
    """Every closed-loop run of the default target (replicate 0; a named target)."""
    input:
        RUNS.solver_outputs(RUNS.computed_runs({0})),
        RUNS.run_outputs(RUNS.computed_runs({0})),
    localrule: True


rule figure_rollout:
    """The path and signals of one run, e.g. results/figures/rollout/learned_rep0_epm_epm_pid_eta0_seed0.pdf"""
    input:
        metrics=f"{RUN_FOLDER}/{paths.METRICS}",
        series=f"{RUN_FOLDER}/{paths.SERIES}",
        raceline=TRACKS.raceline(),
    output:
        pdf=f"{paths.ROLLOUT_FIGURES}/{RUN_STEM}.pdf",
        png=f"{paths.ROLLOUT_FIGURES}/{RUN_STEM}.png",
    params:
        spec=lambda wildcards: JOBS.write_sections("figure_rollout", "tracks", "data", "reference"),
        run=lambda wildcards, input: os.path.dirname(input.metrics),
    conda:
        CAPE_ENV
    log:
        paths.log("figures", "rollout", f"{RUN_STEM}.log"),
    shell:
        "cape plot-rollout --run {params.run:q} --raceline {input.raceline:q} --out {output.pdf:q} --out {output.png:q}"
        " --spec {params.spec:q} > {log:q} 2>&1"
