# The study (SPEC §8–§10): every run aggregated into one table, then the figure notebooks,
# executed by papermill into results/notebooks/ (with an HTML copy), writing the tables and
# figures of SPEC §9. Papermill writes a notebook as it runs, so each is executed under a
# `.part.ipynb` name and renamed when it and its HTML copy are complete: an interrupted notebook
# never looks finished.


rule aggregate:
    """Every run's metrics of a scope in <scope>/study/runs.parquet; per-cell means, CIs and
    success rates in <scope>/study/summary.parquet (results/: replicate 0; results/replicates/:
    every training replicate)."""
    input:
        lambda wildcards: rollout_targets(set(SCOPES[wildcards.scope])),
    output:
        runs="{scope}/study/runs.parquet",
        summary="{scope}/study/summary.parquet",
    params:
        cfg=lambda wildcards: aggregate_config_json(SCOPES[wildcards.scope]),
    conda:
        CAPE_ENV
    log:
        "{scope}/logs/study/aggregate.log",
    benchmark:
        "{scope}/benchmarks/study/aggregate.tsv"
    shell:
        "cape aggregate --out {output.runs:q} --summary {output.summary:q} --models-root results/models"
        " --config-json {params.cfg:q} > {log:q} 2>&1"


rule notebook_setup:
    """Figure 1 and tables 2–3, from the config alone."""
    input:
        notebook=f"{NOTEBOOKS}/setup.ipynb",
    output:
        *reported_figures("setup", "results/figures", "../report/fig01.rst", "Set-up"),
        figures("setup", "results/figures", ".pdf"),
        tables("setup", "results/tables"),
        notebook="results/notebooks/setup.ipynb",
        html="results/notebooks/setup.html",
    params:
        cfg=lambda wildcards: config_json("controllers", "disturbances", "models"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/setup.log",
    localrule: True
    shell:
        run_notebook("-r config_json {params.cfg:q}")


rule notebook_closed_loop:
    """Figures 2, 3, 7–11 and tables 6–7 of a study of kind closed_loop (the learned and
    ground-truth studies, or one a user adds)."""
    input:
        notebook=f"{NOTEBOOKS}/closed_loop.ipynb",
        runs="results/study/runs.parquet",
        summary="results/study/summary.parquet",
        raceline=raceline_path(),
        series=lambda wildcards: example_series(wildcards.study),
    output:
        *reported_figures("closed_loop", "results/figures/{study}", "../report/closed_loop.rst", "{study} study"),
        figures("closed_loop", "results/figures/{study}", ".pdf"),
        tables("closed_loop", "results/tables/{study}"),
        notebook="results/notebooks/{study}.ipynb",
        html="results/notebooks/{study}.html",
    wildcard_constraints:
        study=studies_of_kind("closed_loop"),
    params:
        cfg=lambda wildcards: config_json("tracks", "data", "reference", "controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/{study}.log",
    benchmark:
        "results/benchmarks/notebooks/{study}.tsv"
    shell:
        run_notebook(
            "-r study {wildcards.study} -r config_json {params.cfg:q}"
            " -r figure_dir results/figures/{wildcards.study} -r table_dir results/tables/{wildcards.study}"
        )


rule notebook_bicycle:
    """Table 5 and figures 5–6 of a study of kind bicycle: its fixed-parameter plants against
    the paper's study's learned EPM."""
    input:
        notebook=f"{NOTEBOOKS}/bicycle.ipynb",
        summary="results/study/summary.parquet",
    output:
        *reported_figures("bicycle", "results/figures/{study}", "../report/bicycle.rst", "{study} study"),
        figures("bicycle", "results/figures/{study}", ".pdf"),
        tables("bicycle", "results/tables/{study}"),
        notebook="results/notebooks/{study}.ipynb",
        html="results/notebooks/{study}.html",
    wildcard_constraints:
        study=studies_of_kind("bicycle"),
    params:
        cfg=lambda wildcards: config_json("controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/{study}.log",
    localrule: True
    shell:
        run_notebook(
            "-r study {wildcards.study} -r config_json {params.cfg:q}"
            " -r figure_dir results/figures/{wildcards.study} -r table_dir results/tables/{wildcards.study}"
        )


rule notebook_ablation:
    """Figure 4 of a study of kind ablation: internal model against plant trajectories."""
    input:
        notebook=f"{NOTEBOOKS}/ablation.ipynb",
        runs="results/study/runs.parquet",
        raceline=raceline_path(),
        series=lambda wildcards: example_series(wildcards.study),
    output:
        *reported_figures("ablation", "results/figures/{study}", "../report/fig04.rst", "{study} study"),
        figures("ablation", "results/figures/{study}", ".pdf"),
        notebook="results/notebooks/{study}.ipynb",
        html="results/notebooks/{study}.html",
    wildcard_constraints:
        study=studies_of_kind("ablation"),
    params:
        cfg=lambda wildcards: config_json("tracks", "data", "reference", "controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/{study}.log",
    localrule: True
    shell:
        run_notebook(
            "-r study {wildcards.study} -r config_json {params.cfg:q}"
            " -r figure_dir results/figures/{wildcards.study}"
        )


rule notebook_failures:
    """Figure 12 of one study: where its failed runs left the lap, on the track map."""
    input:
        notebook=f"{NOTEBOOKS}/failures.ipynb",
        runs="results/study/runs.parquet",
        raceline=raceline_path(),
    output:
        *reported_figures("failures", "results/figures/{study}", "../report/failures.rst", "{study} study"),
        figures("failures", "results/figures/{study}", ".pdf"),
        notebook="results/notebooks/failures_{study}.ipynb",
        html="results/notebooks/failures_{study}.html",
    params:
        cfg=lambda wildcards: config_json("tracks", "data", "reference", "controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/failures_{study}.log",
    localrule: True
    shell:
        run_notebook(
            "-r study {wildcards.study} -r config_json {params.cfg:q}"
            " -r figure_dir results/figures/{wildcards.study}"
        )


rule notebook_scorecard:
    """Table 8 of a scope: the paper's headline claims beside ours, with three-valued verdicts
    per training replicate and pooled (from the config's paper study), the claims' effects
    figure, tables 4 and 1 over the replicates, and RESULTS.md."""
    input:
        unpack(scorecard_inputs),
        notebook=f"{NOTEBOOKS}/scorecard.ipynb",
        runs="{scope}/study/runs.parquet",
        summary="results/study/summary.parquet",
        raceline=raceline_path(),
    output:
        report("{scope}/tables/table08_scorecard.md", caption="../report/scorecard.rst", category="Claims"),
        multiext("{scope}/tables/table08_scorecard", ".csv", ".tex"),
        *(f"{{scope}}/tables/{name}{ext}" for name in WHOLE_STUDY_NOTEBOOKS["scorecard"].tables if name != "table08_scorecard" for ext in TABLE_EXTS),
        *reported_figures("scorecard", "{scope}/figures", "../report/scorecard.rst", "Claims"),
        figures("scorecard", "{scope}/figures", ".pdf"),
        report("{scope}/RESULTS.md", caption="../report/glance.rst", category="Claims"),
        notebook="{scope}/notebooks/scorecard.ipynb",
        html="{scope}/notebooks/scorecard.html",
    params:
        cfg=lambda wildcards: config_json(
            "tracks", "data", "reference", "controllers", "models", "study", "training", "scorecard"
        ),
        paths=scorecard_params,
    conda:
        CAPE_ENV
    log:
        "{scope}/logs/notebooks/scorecard.log",
    localrule: True
    shell:
        run_notebook("-r config_json {params.cfg:q} {params.paths}")


rule study:
    """Every table, figure and executed notebook of the study (a named target)."""
    input:
        study_targets(),
    localrule: True


rule replicates:
    """The paper's study for every training replicate (SPEC §4, §8) and its scorecard under
    results/replicates/ (a named target, outside the default: about as long again as it)."""
    input:
        replicate_targets(),
    localrule: True



# A scope's runs.parquet whose runs are not all there: the targets that name every file rebuild
# them and it; asked for alone it would stay as it is, so say so (cape/study/stale.py).
if workflow.is_main_process:
    for _scope, _replicates in SCOPES.items():
        _missing = missing_runs(
            f"{_scope}/study/runs.parquet",
            (f"{run.folder()}/metrics.json" for run in computed_runs(set(_replicates))),
        )
        if _missing:
            _target = "all" if _scope == "results" else "replicates"
            print(
                f"{_scope}/study/runs.parquet: {len(_missing)} of its runs are missing (e.g. "
                f"{_missing[0].parent}); `snakemake --cores 2 {_target}` rebuilds them and it",
                file=sys.stderr,
            )
