# The study (SPEC §8–§10): every run aggregated into one table, then the figure notebooks,
# executed by papermill into results/notebooks/ (with an HTML copy), writing the tables and
# figures of SPEC §9. Papermill writes a notebook as it runs, so each is executed under a
# `.part.ipynb` name and renamed when it and its HTML copy are complete: an interrupted notebook
# never looks finished.


rule aggregate:
    """Every run's metrics in results/study/runs.parquet; per-cell means, CIs and success rates
    in results/study/summary.parquet."""
    input:
        rollout_targets(),
    output:
        runs="results/study/runs.parquet",
        summary="results/study/summary.parquet",
    params:
        cfg=lambda wildcards: aggregate_config_json(),
    conda:
        CAPE_ENV
    log:
        "results/logs/study/aggregate.log",
    benchmark:
        "results/benchmarks/study/aggregate.tsv"
    shell:
        "cape aggregate --out {output.runs} --summary {output.summary}"
        " --config-json {params.cfg:q} > {log} 2>&1"


rule notebook_setup:
    """Figure 1 and tables 2–3, from the config alone."""
    input:
        notebook=f"{NOTEBOOKS}/setup.ipynb",
    output:
        report(multiext("results/figures/fig01_block_diagram", ".png"), caption="../report/fig01.rst", category="Set-up"),
        multiext("results/figures/fig01_block_diagram", ".pdf"),
        multiext("results/tables/table02_controller_parameters", ".csv", ".md", ".tex"),
        multiext("results/tables/table03_uncertainty_activation", ".csv", ".md", ".tex"),
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
        "papermill {input.notebook} {output.notebook}.part.ipynb --cwd . --no-progress-bar"
        " -r config_json {params.cfg:q} > {log} 2>&1"
        " && jupyter nbconvert --to html {output.notebook}.part.ipynb --output-dir results/notebooks"
        " --output $(basename {output.html} .html) >> {log} 2>&1"
        " && mv {output.notebook}.part.ipynb {output.notebook}"  # the notebook last: complete


rule notebook_closed_loop:
    """Figures 2, 3, 7–11 and tables 6–7 of one study (learned, truth, or one a user adds)."""
    input:
        notebook=f"{NOTEBOOKS}/closed_loop.ipynb",
        runs="results/study/runs.parquet",
        summary="results/study/summary.parquet",
        raceline=raceline_path(),
        series=lambda wildcards: example_series(wildcards.study),
    output:
        report(
            expand("results/figures/{{study}}/{name}.png", name=CLOSED_LOOP_FIGURES),
            caption="../report/closed_loop.rst",
            category="{study} study",
        ),
        expand("results/figures/{{study}}/{name}.pdf", name=CLOSED_LOOP_FIGURES),
        expand("results/tables/{{study}}/{name}.{ext}", name=CLOSED_LOOP_TABLES, ext=TABLE_EXTS),
        notebook="results/notebooks/closed_loop_{study}.ipynb",
        html="results/notebooks/closed_loop_{study}.html",
    wildcard_constraints:
        study="|".join(CLOSED_LOOP_STUDIES) or "learned",
    params:
        cfg=lambda wildcards: config_json("tracks", "data", "reference", "controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/closed_loop_{study}.log",
    benchmark:
        "results/benchmarks/notebooks/closed_loop_{study}.tsv"
    shell:
        "papermill {input.notebook} {output.notebook}.part.ipynb --cwd . --no-progress-bar"
        " -r study {wildcards.study} -r config_json {params.cfg:q}"
        " -r figure_dir results/figures/{wildcards.study} -r table_dir results/tables/{wildcards.study}"
        " > {log} 2>&1"
        " && jupyter nbconvert --to html {output.notebook}.part.ipynb --output-dir results/notebooks"
        " --output $(basename {output.html} .html) >> {log} 2>&1"
        " && mv {output.notebook}.part.ipynb {output.notebook}"  # the notebook last: complete


rule notebook_bicycle:
    """Table 5 and figures 5–6: the fixed-parameter bicycle study against the learned EPM."""
    input:
        notebook=f"{NOTEBOOKS}/bicycle.ipynb",
        summary="results/study/summary.parquet",
    output:
        report(
            expand("results/figures/bicycle/{name}.png", name=BICYCLE_FIGURES),
            caption="../report/bicycle.rst",
            category="bicycle study",
        ),
        expand("results/figures/bicycle/{name}.pdf", name=BICYCLE_FIGURES),
        multiext("results/tables/bicycle/table05_best_bicycle_controller", ".csv", ".md", ".tex"),
        notebook="results/notebooks/bicycle.ipynb",
        html="results/notebooks/bicycle.html",
    params:
        cfg=lambda wildcards: config_json("controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/bicycle.log",
    localrule: True
    shell:
        "papermill {input.notebook} {output.notebook}.part.ipynb --cwd . --no-progress-bar"
        " -r config_json {params.cfg:q} -r figure_dir results/figures/bicycle"
        " -r table_dir results/tables/bicycle > {log} 2>&1"
        " && jupyter nbconvert --to html {output.notebook}.part.ipynb --output-dir results/notebooks"
        " --output $(basename {output.html} .html) >> {log} 2>&1"
        " && mv {output.notebook}.part.ipynb {output.notebook}"  # the notebook last: complete


rule notebook_ablation:
    """Figure 4: internal model vs plant trajectories."""
    input:
        notebook=f"{NOTEBOOKS}/ablation.ipynb",
        runs="results/study/runs.parquet",
        raceline=raceline_path(),
        series=lambda wildcards: example_series("ablation"),
    output:
        report(
            "results/figures/ablation/fig04_ablation_trajectories.png",
            caption="../report/fig04.rst",
            category="ablation",
        ),
        "results/figures/ablation/fig04_ablation_trajectories.pdf",
        notebook="results/notebooks/ablation.ipynb",
        html="results/notebooks/ablation.html",
    params:
        cfg=lambda wildcards: config_json("tracks", "data", "reference", "controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/ablation.log",
    localrule: True
    shell:
        "papermill {input.notebook} {output.notebook}.part.ipynb --cwd . --no-progress-bar"
        " -r config_json {params.cfg:q} -r figure_dir results/figures/ablation > {log} 2>&1"
        " && jupyter nbconvert --to html {output.notebook}.part.ipynb --output-dir results/notebooks"
        " --output $(basename {output.html} .html) >> {log} 2>&1"
        " && mv {output.notebook}.part.ipynb {output.notebook}"  # the notebook last: complete


rule notebook_failures:
    """Figure 12 of one study: where its failed runs left the lap, on the track map."""
    input:
        notebook=f"{NOTEBOOKS}/failures.ipynb",
        runs="results/study/runs.parquet",
        raceline=raceline_path(),
    output:
        report(
            "results/figures/{study}/fig12_failure_locations.png",
            caption="../report/failures.rst",
            category="{study} study",
        ),
        "results/figures/{study}/fig12_failure_locations.pdf",
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
        "papermill {input.notebook} {output.notebook}.part.ipynb --cwd . --no-progress-bar"
        " -r study {wildcards.study} -r config_json {params.cfg:q}"
        " -r figure_dir results/figures/{wildcards.study} > {log} 2>&1"
        " && jupyter nbconvert --to html {output.notebook}.part.ipynb --output-dir results/notebooks"
        " --output $(basename {output.html} .html) >> {log} 2>&1"
        " && mv {output.notebook}.part.ipynb {output.notebook}"  # the notebook last: complete


rule notebook_scorecard:
    """Table 8: the paper's headline claims beside ours."""
    input:
        notebook=f"{NOTEBOOKS}/scorecard.ipynb",
        runs="results/study/runs.parquet",
        summary="results/study/summary.parquet",
        complexity="results/tables/table01_model_complexity.csv",
        openloop="results/tables/table04_openloop_rmse.csv",
    output:
        report(
            "results/tables/table08_scorecard.md", caption="../report/scorecard.rst", category="Claims"
        ),
        multiext("results/tables/table08_scorecard", ".csv", ".tex"),
        report("results/RESULTS.md", caption="../report/glance.rst", category="Claims"),
        notebook="results/notebooks/scorecard.ipynb",
        html="results/notebooks/scorecard.html",
    params:
        cfg=lambda wildcards: config_json("controllers", "models", "study"),
    conda:
        CAPE_ENV
    log:
        "results/logs/notebooks/scorecard.log",
    localrule: True
    shell:
        "papermill {input.notebook} {output.notebook}.part.ipynb --cwd . --no-progress-bar"
        " -r config_json {params.cfg:q} > {log} 2>&1"
        " && jupyter nbconvert --to html {output.notebook}.part.ipynb --output-dir results/notebooks"
        " --output $(basename {output.html} .html) >> {log} 2>&1"
        " && mv {output.notebook}.part.ipynb {output.notebook}"  # the notebook last: complete


rule study:
    """Every table, figure and executed notebook of the study (a named target)."""
    input:
        study_targets(),
    localrule: True
