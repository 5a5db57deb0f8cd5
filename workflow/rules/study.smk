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
        lambda wildcards: RUNS.rollout_targets(set(SCOPES[wildcards.scope])),
    output:
        runs=paths.STUDY_RUNS,
        summary=paths.STUDY_SUMMARY,
    params:
        spec=lambda wildcards: JOBS.write_grid(),
        replicates=lambda wildcards: " ".join(map(str, SCOPES[wildcards.scope])),
        models=paths.MODELS,
    conda:
        CAPE_ENV
    log:
        paths.scoped("{scope}", "logs", "study", "aggregate.log"),
    benchmark:
        paths.scoped("{scope}", "benchmarks", "study", "aggregate.tsv")
    shell:
        "cape aggregate --out {output.runs:q} --summary {output.summary:q} --models-root {params.models:q}"
        " --replicates {params.replicates} --spec {params.spec:q} > {log:q} 2>&1"


rule notebook_setup:
    """Figure 1 and tables 2–3, from the config alone."""
    input:
        notebook=f"{NOTEBOOK_DIR}/setup.ipynb",
    output:
        *reported_figures("setup", paths.FIGURES, "../report/fig01.rst", "Set-up"),
        NOTEBOOKS.figures("setup", paths.FIGURES, ".pdf"),
        NOTEBOOKS.tables("setup", paths.TABLES),
        notebook=paths.notebooks("setup.ipynb"),
        html=paths.notebooks("setup.html"),
    params:
        nb=lambda wildcards: JOBS.write_parameters(
            "notebook_setup",
            spec=JOBS.write_notebook("setup"),
            figure_dir=paths.FIGURES,
            table_dir=paths.TABLES,
        ),
    conda:
        CAPE_ENV
    log:
        paths.log("notebooks", "setup.log"),
    localrule: True
    shell:
        run_notebook("-f {params.nb:q}")


rule notebook_closed_loop:
    """Figures 2, 3, 7–11 and tables 6–7 of a study of kind closed_loop (the learned and
    ground-truth studies, or one a user adds)."""
    input:
        notebook=f"{NOTEBOOK_DIR}/closed_loop.ipynb",
        runs=paths.study_runs(),
        summary=paths.study_summary(),
        raceline=TRACKS.raceline(),
        series=lambda wildcards: NOTEBOOKS.example_series(wildcards.study),
    output:
        *reported_figures("closed_loop", paths.figures("{study}"), "../report/closed_loop.rst", "{study} study"),
        NOTEBOOKS.figures("closed_loop", paths.figures("{study}"), ".pdf"),
        NOTEBOOKS.tables("closed_loop", paths.tables("{study}")),
        notebook=paths.notebooks("{study}.ipynb"),
        html=paths.notebooks("{study}.html"),
    wildcard_constraints:
        study=NOTEBOOKS.studies_of_kind("closed_loop"),
    params:
        nb=lambda wildcards, input: JOBS.write_parameters(
            "notebook_closed_loop",
            study=wildcards.study,
            spec=JOBS.write_notebook("closed_loop"),
            runs_path=input.runs,
            summary_path=input.summary,
            raceline=input.raceline,
            series_paths=input.series,
            figure_dir=paths.figures(wildcards.study),
            table_dir=paths.tables(wildcards.study),
        ),
    conda:
        CAPE_ENV
    log:
        paths.log("notebooks", "{study}.log"),
    benchmark:
        paths.benchmark("notebooks", "{study}.tsv")
    shell:
        run_notebook("-f {params.nb:q}")


rule notebook_bicycle:
    """Table 5 and figures 5–6 of a study of kind bicycle: its fixed-parameter plants against
    the paper's study's learned EPM."""
    input:
        notebook=f"{NOTEBOOK_DIR}/bicycle.ipynb",
        summary=paths.study_summary(),
    output:
        *reported_figures("bicycle", paths.figures("{study}"), "../report/bicycle.rst", "{study} study"),
        NOTEBOOKS.figures("bicycle", paths.figures("{study}"), ".pdf"),
        NOTEBOOKS.tables("bicycle", paths.tables("{study}")),
        notebook=paths.notebooks("{study}.ipynb"),
        html=paths.notebooks("{study}.html"),
    wildcard_constraints:
        study=NOTEBOOKS.studies_of_kind("bicycle"),
    params:
        nb=lambda wildcards, input: JOBS.write_parameters(
            "notebook_bicycle",
            study=wildcards.study,
            spec=JOBS.write_notebook("bicycle"),
            summary_path=input.summary,
            figure_dir=paths.figures(wildcards.study),
            table_dir=paths.tables(wildcards.study),
        ),
    conda:
        CAPE_ENV
    log:
        paths.log("notebooks", "{study}.log"),
    localrule: True
    shell:
        run_notebook("-f {params.nb:q}")


rule notebook_ablation:
    """Figure 4 of a study of kind ablation: internal model against plant trajectories."""
    input:
        notebook=f"{NOTEBOOK_DIR}/ablation.ipynb",
        runs=paths.study_runs(),
        raceline=TRACKS.raceline(),
        series=lambda wildcards: NOTEBOOKS.example_series(wildcards.study),
    output:
        *reported_figures("ablation", paths.figures("{study}"), "../report/fig04.rst", "{study} study"),
        NOTEBOOKS.figures("ablation", paths.figures("{study}"), ".pdf"),
        notebook=paths.notebooks("{study}.ipynb"),
        html=paths.notebooks("{study}.html"),
    wildcard_constraints:
        study=NOTEBOOKS.studies_of_kind("ablation"),
    params:
        nb=lambda wildcards, input: JOBS.write_parameters(
            "notebook_ablation",
            study=wildcards.study,
            spec=JOBS.write_notebook("ablation"),
            runs_path=input.runs,
            raceline=input.raceline,
            series_paths=input.series,
            figure_dir=paths.figures(wildcards.study),
        ),
    conda:
        CAPE_ENV
    log:
        paths.log("notebooks", "{study}.log"),
    localrule: True
    shell:
        run_notebook("-f {params.nb:q}")


rule notebook_failures:
    """Figure 12 of one study: where its failed runs left the lap, on the track map."""
    input:
        notebook=f"{NOTEBOOK_DIR}/failures.ipynb",
        runs=paths.study_runs(),
        raceline=TRACKS.raceline(),
    output:
        *reported_figures("failures", paths.figures("{study}"), "../report/failures.rst", "{study} study"),
        NOTEBOOKS.figures("failures", paths.figures("{study}"), ".pdf"),
        notebook=paths.notebooks("failures_{study}.ipynb"),
        html=paths.notebooks("failures_{study}.html"),
    params:
        nb=lambda wildcards, input: JOBS.write_parameters(
            "notebook_failures",
            study=wildcards.study,
            spec=JOBS.write_notebook("failures"),
            runs_path=input.runs,
            raceline=input.raceline,
            figure_dir=paths.figures(wildcards.study),
        ),
    conda:
        CAPE_ENV
    log:
        paths.log("notebooks", "failures_{study}.log"),
    localrule: True
    shell:
        run_notebook("-f {params.nb:q}")


rule notebook_scorecard:
    """Table 8 of a scope: the paper's headline claims beside ours, with three-valued verdicts
    per training replicate and pooled (from the config's paper study), the claims' effects
    figure, tables 4 and 1 over the replicates, and RESULTS.md; tables 8 and 9 computed from the
    scope's evidence folder, which it writes first (they re-derive from it alone)."""
    input:
        unpack(NOTEBOOKS.scorecard_inputs),
        notebook=f"{NOTEBOOK_DIR}/scorecard.ipynb",
        runs=paths.STUDY_RUNS,
        raceline=TRACKS.raceline(),
    output:
        report(paths.scoped("{scope}", "tables", "table08_scorecard.md"), caption="../report/scorecard.rst", category="Claims"),
        *(paths.evidence("{scope}", name) for name in paths.EVIDENCE_FILES),
        multiext(paths.scoped("{scope}", "tables", "table08_scorecard"), ".csv", ".tex"),
        *(paths.scoped("{scope}", "tables", f"{name}{ext}") for name in DECLARED["scorecard"].tables if name != "table08_scorecard" for ext in TABLE_EXTS),
        *reported_figures("scorecard", paths.scoped("{scope}", "figures"), "../report/scorecard.rst", "Claims"),
        NOTEBOOKS.figures("scorecard", paths.scoped("{scope}", "figures"), ".pdf"),
        report(paths.GLANCE, caption="../report/glance.rst", category="Claims"),
        notebook=paths.scoped("{scope}", "notebooks", "scorecard.ipynb"),
        html=paths.scoped("{scope}", "notebooks", "scorecard.html"),
    params:
        nb=lambda wildcards, input: JOBS.write_parameters(
            "notebook_scorecard",
            spec=JOBS.write_notebook("scorecard"),
            runs_path=input.runs,
            raceline=input.raceline,
            replicates=SCOPES[wildcards.scope],
            complexity_paths=input.complexity,
            openloop_paths=input.openloop,
            model_root=paths.MODELS,  # the draws' meta.json and loss.csv: input.models
            evidence_dir=paths.evidence(wildcards.scope),
            table_dir=paths.scoped(wildcards.scope, "tables"),
            figure_dir=paths.scoped(wildcards.scope, "figures"),
            glance_path=paths.glance(wildcards.scope),
        ),
    conda:
        CAPE_ENV
    log:
        paths.scoped("{scope}", "logs", "notebooks", "scorecard.log"),
    localrule: True
    shell:
        run_notebook("-f {params.nb:q}")


rule study:
    """Every table, figure and executed notebook of the study (a named target)."""
    input:
        NOTEBOOKS.study_targets(),
    localrule: True


rule replicates:
    """The paper's study for every training replicate (SPEC §4, §8) and its scorecard under
    results/replicates/ (a named target, outside the default: about as long again as it)."""
    input:
        W.replicate_targets(),
    localrule: True



# A scope's runs.parquet whose runs are not all there: say which target rebuilds it
# (cape/study/stale.py).
if workflow.is_main_process:
    for _message in NOTEBOOKS.stale_summaries():
        print(_message, file=sys.stderr)
